// Finite Elements with Switch Detection (FESD) for Filippov systems written as step inclusions
// ([F] Sections 2.4-2.5, 4 and 5): where the event-driven engine (hybrid_flow.h) stops because
// a trajectory slides, FESD integrates through.
//
// Model. A step inclusion x' in f(x, a), a_j in gamma(c_j(x)), with gamma the set-valued
// Heaviside step (gamma(c) = {1} for c > 0, {0} for c < 0, [0, 1] at 0), written once:
//
//   struct M {
//     static constexpr int kStates = 2, kSwitches = 1;
//     template <typename T> void switching(const T* x, T* c) const;          // c(x)
//     template <typename T> void field(const T* x, const T* a, T* xdot) const; // f(x, a)
//   };
//
// A piecewise-smooth system is the special case f(x, a) = sum_i theta_i(a) f_i(x) with theta
// from a sign matrix (core/filippov.h). Time enters as a state (a clock t' = 1).
//
// Discretisation of one integration step [t, t + H] ([F] (33), (36)-(43)): N_FE finite elements
// of free length h_n (sum h_n = H), each an s-stage collocation method (butcher.h) on the DCS
// (22) with the selections a, and lambda^p, lambda^n of the step LP (16):
//   stage values X_nm = x_n + h_n sum_k A_mk f(X_nk, a_nk),  x_{n+1} = x_n + h_n sum_k b_k f(...)
//   c(X_nm) = lambda^p_nm - lambda^n_nm,  0 <= a <= 1,  lambda^p, lambda^n >= 0,
// the cross complementarity (37) between every point of an element, including its start
// lambda_{n,0} (the end of the previous element, (36); at the step's start from x by (17)), and
// for Gauss-Legendre (c_s < 1) an extra point at the element's end ((42)-(43)). The step
// equilibration (39) enters the objective: sum_n eta_n (h_n - h_{n-1})^2, eta_n the indicator of
// Section 4.4, normalised per switching function (nu / (nu + 1e-6)), so that elements without
// a switch between them get equal lengths. With `standard`, the h_n are fixed to H / N_FE and
// complementarity holds stage by stage only ((34), standard time-stepping). `formulation` and
// `lifting_depth` discretise Stewart's DCS (28) or the lifted step DCS (Algorithm 1) instead.
//
// Solution. A step is first solved by Newton's method on the FESD equations with its active set
// guessed: the sides of its start (no switch), else one switch (or two) at each element boundary
// in turn, the switch condition replacing that boundary's equal-length equation; among the
// guesses that are FESD solutions the one with the least step equilibration is taken. When no
// guess fits, the step is a homotopy of Scholtes-relaxed NLPs (products <= sigma, sigma from
// sigma_initial down to sigma_final, times sigma_factor, or sigma^1.5 when superlinear), solved
// by IPOPT with exact first derivatives from Jets and a limited-memory or exact Hessian (HessianJet
// by pieces, `exact_hessian`), each NLP warm-started from the previous one. A step whose
// homotopy fails is replaced by its two halves (up to four times); one that still does not
// converge ends the run with a status that quotes the complementarity residual and IPOPT's
// status. A step whose last NLP IPOPT solves only to its acceptable level, with complementarity
// products above sigma_final, is flagged (FesdResult::acceptable_only) but kept.
//
// Sensitivity. On the converged active set the step's equations are square in its unknowns
// (each complementarity pair fixed to its active branch, equal lengths where no switch); the
// implicit function theorem gives dx(t + H)/dx(t), and the product over steps dx(T)/dx0
// ([F] Theorem 18).
#ifndef BFLOW_FESD_FESD_H_
#define BFLOW_FESD_FESD_H_

#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/filippov.h"
#include "bflow/fesd/butcher.h"
#include "bflow/fesd/homotopy_options.h"
#include "bflow/fesd/linear_solver.h"
#include "bflow/fesd/solver_options.h"
#include "bflow/fesd/step_model.h"

namespace bflow {

/** How an element's cross complementarity ([F] (35), (37)) enters the NLP, with u_r the first
    member of a pair at point r of the element and v_m the second at point m or at its start:
      kElementSums  one row per pair, (sum_r u_r)(v_start + sum_m v_m), the sum of all the
                    pointwise products (npairs rows per element);
      kPointPairs   every product u_r v_m on a row of its own (nosnoc's STAGE_STAGE cross
                    complementarity; npairs P (P + 1) rows per element, P points);
      kPointSums    each point's u_r against the sum of the v's, u_r (v_start + sum_m v_m)
                    (the default of nosnoc's Python package, SUM_LAMBDAS_COMPLEMENT_WITH_EVERY_
                    THETA; npairs P rows per element).
    All vanish on the same points. Relaxed (every row <= sigma), the sums are the tighter, the
    point pairs give IPOPT more rows with one product each. Standard time-stepping keeps one
    row per pair either way. */
enum class CrossComplementarity { kElementSums, kPointPairs, kPointSums };

/** The algebraic variables of an OCP's or a step's guess: kSides, from the sides of the guessed
    states (PointDcs::initial); kNeutral, favouring no side (PointDcs::neutral: a = lambda+- =
    1/2; Stewart theta = 1/n_f, lambda = 1, mu = 0); kNosnoc, nosnoc's initialisation at its
    sigma_0 = 1 (a = lambda+- = 1/2; Stewart theta = lambda = 1/n_f, mu = 1). */
enum class AlgebraicGuess { kSides, kNeutral, kNosnoc };

/** "element-sums", "point-pairs" or "point-sums". */
inline const char* to_string(CrossComplementarity cross) {
  if (cross == CrossComplementarity::kPointSums) return "point-sums";
  return cross == CrossComplementarity::kPointPairs ? "point-pairs" : "element-sums";
}
/** The inverse of to_string. @throws InvalidArgument naming the text and the three names. */
inline CrossComplementarity parse_cross_complementarity(const std::string& text) {
  for (const CrossComplementarity c :
       {CrossComplementarity::kElementSums, CrossComplementarity::kPointPairs,
        CrossComplementarity::kPointSums}) {
    if (text == to_string(c)) return c;
  }
  throw InvalidArgument("unknown cross complementarity \"" + text +
                        "\"; use element-sums, point-pairs or point-sums");
}

/** One integration step taken by fesd_simulate, as FesdOptions::progress receives it. */
struct FesdStepReport {
  int index = 0;        ///< 0, 1, ...: the steps taken (halves of a halved step count apart)
  int planned = 0;      ///< N_sim, the steps of the run before any halving
  double t = 0.0;       ///< the step's start
  double length = 0.0;  ///< its length (T / N_sim, halved `halvings` times)
  int halvings = 0;
  bool newton = false;     ///< solved by Newton's method on a guessed active set
  int nlp_iterations = 0;  ///< IPOPT iterations of its homotopy (0 for Newton)
  double complementarity = 0.0;
};

struct FesdOptions {
  CollocationScheme scheme = CollocationScheme::kRadauIIA;
  int stages = 2;  ///< n_s, 1..9
  /** N_FE per integration step, >= 1; with N_sim bounded by kFesdMaxIndex and
      kFesdMaxMemoryBytes through fesd_problem_size(). */
  int elements = 3;
  int steps = 1;          ///< N_sim integration steps over [0, T], >= 1
  bool standard = false;  ///< standard time-stepping (34): fixed h, no switch detection
  /** The DCS discretised: the Heaviside step DCS (22) or Stewart's (28) on the 2^n_c base
      regions (modes f(x, vertex); equal to the step inclusion for f multi-affine in a). */
  DcsFormulation formulation = DcsFormulation::kStep;
  /** Step DCS only: 0 eliminates theta (f(x, a) directly); n_d >= 2 keeps theta and the
      lifting variables beta of Algorithm 1 with depth n_d as unknowns (products of at most n_d
      factors; n_d >= n_c: theta without beta). */
  int lifting_depth = 0;
  /** The sigma schedule and IPOPT's tolerance and iteration limit for each step's NLPs
      (homotopy_options.h; FESD's defaults: sigma from 1 to 1e-12 superlinearly, tol 1e-13, 500
      iterations per NLP). */
  HomotopyOptions homotopy;
  /** IPOPT with the exact Hessian of the Lagrangian (HessianJet on the pieces of each element
      and each equilibration term, hessian_blocks.h) instead of its limited-memory
      approximation. */
  bool exact_hessian = false;
  /** Try each step first by Newton's method on the active set predicted from its start (no
      switch inside); the IPOPT homotopy runs only when that prediction fails. */
  bool newton = true;
  bool sensitivities = true;
  /** IPOPT and its linear solver, shared with OcpOptions (solver_options.h). */
  SolverOptions solver;
  /** Polled before every integration step and after every IPOPT iteration; true ends the run
      with FesdStatus::kCancelled and the steps done so far (e.g. a Ctrl-C check). Called on
      the thread that runs fesd_simulate, inside IPOPT's callback under ipopt_mutex()
      (linear_solver.h): it must not wait for another thread's FESD or OCP solve. */
  std::function<bool()> cancelled;
  /** Called after every integration step taken (e.g. a progress line on stderr). */
  std::function<void(const FesdStepReport&)> progress;
};

/** cancelled: FesdOptions::cancelled asked to stop; the result covers [0, t] of the steps done
    (x_end the state there, no sensitivity) and `message` says where it stopped. */
enum class FesdStatus { kConverged, kStepFailed, kInvalidModel, kCancelled };
const char* to_string(FesdStatus status);

struct FesdResult {
  FesdStatus status = FesdStatus::kConverged;
  std::string message;
  Eigen::VectorXd x_end;
  /** Times of the finite-element boundaries, 0 .. T (N_sim N_FE + 1 values). */
  std::vector<double> grid;
  /** State at each grid time, d x grid.size(). */
  Eigen::MatrixXd states;
  /** h of each finite element. */
  std::vector<double> step_sizes;
  /** Grid times where some switching function's active set changes (a switch detected). */
  std::vector<double> switch_times;
  /** Per finite element and switching function: +1 (c > 0, a = 1), -1 (c < 0, a = 0), 0 (on
      the surface: sliding, a in [0, 1]). */
  std::vector<std::vector<int>> active_sets;
  /** Largest complementarity product at the final sigma, over all steps. */
  double max_complementarity = 0.0;
  /** The solver stack the step NLPs ran on (also when Newton's method solved every step):
      "IPOPT 3.14.19" and "mumps 5.8.2" (ipopt_description and linear_solver_description,
      linear_solver.h). */
  std::string ipopt;
  std::string linear_solver;
  /** The BLAS under the linear solver and its threads during the NLPs: "OpenBLAS 0.3.28, 1
      thread (libcasadi-tp-openblas.so.0)" (blas_description, linear_solver.h; blas_threads). */
  std::string blas;
  /** How the Jacobian and exact Hessian of the steps solved by IPOPT were computed
      (SolverOptions::derivative_programs), summed over the steps: as OcpResult::derivatives. */
  std::string derivatives;
  /** Integration steps whose homotopy failed and that were replaced by their two halves (at
      most four times in a row); the grid then has more elements than N_sim N_FE. */
  int halved_steps = 0;
  /** Integration steps solved by Newton's method on a guessed active set (no IPOPT). */
  int newton_steps = 0;
  /** Of those, the steps with a switch inside (the active set guessed element by element). */
  int newton_switch_steps = 0;
  /** Integration steps whose last NLP (at sigma_final) IPOPT solved only to its "acceptable"
      level (Solved_To_Acceptable_Level: the acceptable_* tolerances met for acceptable_iter
      iterations, the tolerance `tol` not) with a complementarity residual above
      sigma_final + nlp_tolerance. Such a step need not be an FESD solution: its switch times,
      active sets and sensitivity are suspect. An acceptable-level solve whose residual is within
      sigma_final + nlp_tolerance (IPOPT crawling along the flat directions of the step
      equilibration) is not counted. Newton-solved steps never are. */
  int acceptable_only_steps = 0;
  /** acceptable_only_steps > 0; then `message` names the first such step, its sigma and its
      residual. `status` stays kConverged: the run reached T. */
  bool acceptable_only = false;
  /** IPOPT iterations of each integration step (summed over its homotopy; 0 for Newton). */
  std::vector<int> nlp_iterations;
  /** dx(T)/dx0, d x d (empty unless options.sensitivities). */
  Eigen::MatrixXd sensitivity;
  bool ok() const { return status == FesdStatus::kConverged; }
};

/** IPOPT's Index is an int: the unknowns, constraints and Jacobian and Hessian nonzeros of one
    integration step's NLP must each be at most this (2147483647). */
inline constexpr std::int64_t kFesdMaxIndex = std::numeric_limits<int>::max();

/** The most memory a run may need by FesdProblemSize's estimate (4 GiB = 4294967296 bytes). The
    dense Newton and sensitivity systems of a step (about 16 unknowns^2 bytes) reach it first:
    with Radau IIA 2, N_FE = 1636 is the most for a scalar model with one switching function
    (10 unknowns per element), N_FE = 281 for IRMA (58 per element). */
inline constexpr double kFesdMaxMemoryBytes = 4294967296.0;

/** The longest integration step T / N_sim fesd_simulate takes (1e18): an element's length is
    bounded by 2 T / (N_sim N_FE), and IPOPT takes a bound from 1e19 on as none. */
inline constexpr double kFesdMaxStepLength = 1e18;

/** The size of the problem fesd_simulate builds, in 64 bits, from the model's dimensions and
    the options alone (nothing is allocated). Per collocation point: `point_variables` z,
    `point_equalities` and `point_pairs` complementarity pairs, which are [F] Table 4's n_alg,
    n_eq and n_comp for the lifted step and Stewart's formulation (dcs_size; the unlifted step
    eliminates theta: 3 n_c, n_c, 2 n_c); `points` per element is n_s, or n_s + 1 for
    Gauss-Legendre. One integration step's NLP (N_FE elements, d states) has
      unknowns    = N_FE (1 + (n_s + 1) d + points point_variables),
      constraints = N_FE (rows) + 1,  rows = (n_s + 1) d + points point_equalities + point_pairs,
      jacobian_nonzeros <= rows (1 + (n_s + 1) d + points point_variables)
                           + (N_FE - 1) rows (d + point_pairs + 1 + (n_s + 1) d
                                              + points point_variables) + N_FE,
    the last row (and its N_FE entries) being sum h_n = H, absent with `standard`. The Jacobian
    bound counts every row against every input of its element; the structure handed to IPOPT
    lists only the inputs each row reads (element_jacobian_pattern, transcription.h).
    A count that would pass 2^63 - 1 saturates there (far above every limit). */
struct FesdProblemSize {
  std::int64_t point_variables = 0;
  std::int64_t point_equalities = 0;
  std::int64_t point_pairs = 0;
  std::int64_t points = 0;
  std::int64_t unknowns = 0;
  std::int64_t constraints = 0;
  std::int64_t jacobian_nonzeros = 0;  ///< an upper bound (see above)
  /** With exact_hessian: an upper bound on the lower triangle's nonzeros (the element and
      equilibration blocks, counted as if they did not overlap); else 0. */
  std::int64_t hessian_nonzeros = 0;
  /** N_sim N_FE: the elements of the whole run (before any step is halved). */
  std::int64_t total_elements = 0;
  /** Estimated bytes of one step: the dense Newton and sensitivity Jacobians and their
      factors (16 unknowns^2, when options.newton or options.sensitivities), 24 per Jacobian
      nonzero (bflow's and IPOPT's triplets), 80 per Hessian nonzero (its position map) and
      200 per unknown and constraint (IPOPT's vectors). The linear solver's fill-in comes on top. */
  double step_bytes = 0.0;
  /** Estimated bytes of the run's results: per element its grid time, length, state and active
      set (48 + 8 d + 4 n_c), per integration step 16. */
  double run_bytes = 0.0;

  /** "" when one step is within kFesdMaxIndex and kFesdMaxMemoryBytes, else the first size
      over its limit with both numbers, e.g. "10737418240 NLP unknowns per integration step,
      above IPOPT's limit of 2147483647". */
  std::string step_excess() const;
  /** "" when step_bytes + run_bytes <= kFesdMaxMemoryBytes, else both numbers. */
  std::string run_excess() const;
};

/** The problem size of fesd_simulate(model, x0, T, options) (no x0 or T needed).
    @throws InvalidArgument for options that have no size (N_FE or N_sim < 1, stages outside
    [1, 9], a lifting depth of 1 or < 0, lifting with Stewart's formulation, Stewart with more
    than 10 switching functions), quoting the values. */
FesdProblemSize fesd_problem_size(const StepModel& model, const FesdOptions& options);
/** The same for a layout whose Radau IIA elements keep their end apart (end_apart, as
    fesd_simulate's) or identify it with the last stage (as ocp_solve's: d unknowns and d rows
    fewer per element; element.h). Gauss-Legendre elements always keep it. */
FesdProblemSize fesd_problem_size(const StepModel& model, const FesdOptions& options,
                                  bool end_apart);

/** Integrates x' in f(x, a) from x0 over [0, t_end] by FESD. Thread-safe; IPOPT solves run
    one at a time in a process (ipopt_mutex(), linear_solver.h): concurrent runs give the
    results each gives alone, their IPOPT parts taking turns NLP by NLP (Newton-solved steps
    run in parallel).
    @throws InvalidArgument for bad options (NaN or infinite numbers among them; exact_hessian_scale
    other than 1 without exact_hessian), a non-finite x0, a T that is not positive and finite or
    whose steps T / N_sim are above 1e18 (2 T / (N_sim N_FE) bounds an element's length, and
    IPOPT takes bounds from 1e19 on as none) or whose element length T / (N_sim N_FE) is below
    the smallest normal double (quoting the values), and, before
    allocating anything, for a problem whose fesd_problem_size() exceeds kFesdMaxIndex or
    kFesdMaxMemoryBytes (naming N_FE, or N_sim when the run's results are what does not fit). */
FesdResult fesd_simulate(const StepModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                         double t_end, const FesdOptions& options = {});

}  // namespace bflow

#endif  // BFLOW_FESD_FESD_H_

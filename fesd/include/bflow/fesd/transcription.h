// The FESD transcription on IPOPT, one for simulation and optimal control: N control stages of
// N_FE finite elements each (element.h), the costs and constraints a caller puts on top
// (TranscriptionTerms), one IPOPT problem at relaxation sigma, and one homotopy that drives
// sigma down and can polish the result with its active set fixed.
//
// fesd_simulate's integration step is the special case with one stage, no controls, no costs,
// absolute element lengths (sum h_n = H) and the step equilibration at full weight:
//
//   TranscriptionLayout layout(dcs, d, n_c, /*controls=*/0, tableau, /*stages=*/1, n_fe,
//                              /*time_scaled=*/false, /*end_apart=*/true);
//   TranscriptionSetup setup;  setup.x0 = x;  setup.horizon = H;
//   Transcription step(tableau, layout, setup, /*terms=*/nullptr);
//   HomotopySolver solver(ipopt_settings);
//   const HomotopyOutcome outcome = solver.run(step, rules);
//
// (fesd_simulate keeps a Radau IIA element's end apart, ocp_solve shares it with the last stage:
// element.h.) ocp_solve's problem has N stages, the controls u_k per stage, a time-scaling unknown
// T (fixed to the horizon, or free for a time-optimal problem; element lengths are then relative, T
// h_n, with sum h_n = 1/N per stage) and its costs and constraints through TranscriptionTerms.
// Whatever improves the transcription, its derivatives or the homotopy reaches both.
//
// Unknowns (TranscriptionLayout): [T (time-scaled only) | stage 0: u_0 (nu), its N_FE element
// blocks | stage 1: ...]. Constraint rows: every element's rows (element_residual), one length
// sum per stage (not with standard time-stepping, whose lengths are fixed), the path constraints
// at every element boundary (x0 with u_0 first, x(T) with u_{N-1} last), the terminal
// constraints at x(T), and during a polish one equal-length row per listed boundary.
#ifndef BFLOW_FESD_TRANSCRIPTION_H_
#define BFLOW_FESD_TRANSCRIPTION_H_

#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/fesd/butcher.h"
#include "bflow/fesd/dcs.h"
#include "bflow/fesd/element.h"
#include "bflow/fesd/solver_options.h"
#include "bflow/fesd/step_model.h"

namespace bflow {
namespace fesd {

/** Where the unknowns of a transcription live (see the file comment). An element's local vector
    (element.h) reads x_n and the pairs' v from the previous element (constants from x0 for the
    first), u of its stage and T. */
struct TranscriptionLayout : ElementShape {
  int stages = 1, per_stage = 1, elements = 1;

  TranscriptionLayout(const PointDcs& point, int states, int switches, int controls,
                      const ButcherTableau& tableau, int n_stages, int n_fe, bool time_scaled,
                      bool end_apart = false, CollocationForm form = CollocationForm::kIntegral)
      : ElementShape(point, states, switches, tableau, controls, time_scaled, end_apart, form),
        stages(n_stages),
        per_stage(n_fe),
        elements(n_stages * n_fe) {}
  /** The index of T (time-scaled layouts only). */
  static constexpr int kT = 0;
  int stage_base(int k) const { return (scaled ? 1 : 0) + k * (nu + per_stage * block); }
  int u(int k, int j) const { return stage_base(k) + j; }
  int var(int e, int offset) const {
    return stage_base(e / per_stage) + nu + (e % per_stage) * block + offset;
  }
  /** z_k at point m of element e. */
  int z(int e, int m, int k) const { return var(e, off_z + m * nz + k); }
  int x_end(int e, int i) const { return var(e, off_x + i); }
  int variables() const { return stage_base(stages); }
  /** The unknown behind local input k of element e, or -1 for a constant (x0 and the pairs' v
      at x0, read by the first element). */
  int global(int e, int k) const {
    if (k < d) return e == 0 ? -1 : x_end(e - 1, k);
    if (k < d + npairs) {
      return e == 0 ? -1 : z(e - 1, points - 1, dcs->pairs()[static_cast<std::size_t>(k - d)].v);
    }
    if (k < d + npairs + nu) return u(e / per_stage, k - d - npairs);
    if (scaled && k == d + npairs + nu) return kT;
    return var(e, k - own());
  }
};

/** Costs and constraints on top of the FESD equations, in the three scalar types of the
    derivative passes (values, Jet chunks for gradients and Jacobians, HessianScalar for the
    exact Hessian). A simulation has none; ocp_solve adapts its OcpProblem. x is a state, u the
    control of the stage it belongs to (nu values, none without controls). */
class TranscriptionTerms {
 public:
  virtual ~TranscriptionTerms() = default;
  /** The stage cost: T h_n sum_m b_m l_k(X_nm, u_k) summed over the elements of stage k. */
  virtual bool has_stage_cost() const { return false; }
  /** A cost at every stage's end: e_k(x_{k+1}, u_k) added once per stage (a rectangle rule in
      place of the stage cost's quadrature). */
  virtual bool has_stage_end_cost() const { return false; }
  /** The terminal cost m(x(T)). */
  virtual bool has_terminal_cost() const { return false; }
  /** Path constraints g(x, u) at every element boundary, bounds from TranscriptionSetup. */
  virtual int path_constraints() const { return 0; }
  /** Terminal constraints r(x(T)), bounds from TranscriptionSetup. */
  virtual int terminal_constraints() const { return 0; }

#define BFLOW_TRANSCRIPTION_TERMS(T)                                                               \
  virtual T stage_cost(int /*stage*/, const T* /*x*/, const T* /*u*/) const { return T(0.0); }     \
  virtual T stage_end_cost(int /*stage*/, const T* /*x*/, const T* /*u*/) const { return T(0.0); } \
  virtual T terminal_cost(const T* /*x*/) const { return T(0.0); }                                 \
  virtual void path(const T* /*x*/, const T* /*u*/, T* /*g*/) const {}                             \
  virtual void terminal(const T* /*x*/, T* /*r*/) const {}
  BFLOW_TRANSCRIPTION_TERMS(double)
  BFLOW_TRANSCRIPTION_TERMS(JetChunk)
  BFLOW_TRANSCRIPTION_TERMS(HessianScalar)
#undef BFLOW_TRANSCRIPTION_TERMS
};

/** How the complementarity products enter the relaxed NLP at sigma. */
enum class Relaxation {
  kScholtes,   ///< products <= sigma
  kL1Penalty,  ///< (1 / sigma) sum of products added to the objective (elastic)
  /** One slack s >= 0 bounds every product (products <= s) and s / sigma enters the objective:
      the l-infinity elastic mode (nosnoc's ELASTIC_INEQ). The NLP has one unknown more, the last
      one; s starts at the guess's largest product and is fixed at 0 in the polish. */
  kElastic,
};

/** The problem data of a transcription. Empty bound vectors mean unbounded. */
struct TranscriptionSetup {
  Eigen::VectorXd x0;    ///< the initial state (d)
  double horizon = 1.0;  ///< the horizon; T's value when not time-optimal
  /** Time-scaled layouts only: T is free in [T_min, T_max] and is the objective's first term. */
  bool time_optimal = false;
  double T_min = 0.0, T_max = 0.0;
  Eigen::VectorXd x_lower, x_upper;                ///< on every element's end state
  bool x_bounds_at_stage_points = false;           ///< and on every stage's state X_m
  Eigen::VectorXd u_lower, u_upper;                ///< on every stage's control
  Eigen::VectorXd path_lower, path_upper;          ///< empty: (-inf, 0]
  Eigen::VectorXd terminal_lower, terminal_upper;  ///< empty: 0
  /** A clock state pinned to k H / N at the end of stage k, or -1. */
  int clock_state = -1;
  double clock_tolerance = 0.0;  ///< the clock within this distance of k H / N, 0: pinned
  bool standard = false;         ///< standard time-stepping: fixed lengths, products per point
  Relaxation relaxation = Relaxation::kScholtes;
  /** Weight of the step equilibration (39) between the elements of a stage. */
  double equilibration_weight = 1.0;
  /** The weight times min(1, sigma): the equilibration regularises the lengths early and fades
      (ocp_solve, whose polish imposes the exact equilibration); else it keeps its weight
      (fesd_simulate, where it selects among the FESD solutions of a step). */
  bool equilibration_fades = false;
  /** rho_h sum_n (H (h_n - h_0))^2 over every element, H h_n its length in units of the horizon
      H and h_0 the uniform length (nosnoc's heuristic_mean step equilibration); 0: none. It keeps
      its weight through the homotopy. */
  double step_deviation_weight = 0.0;
  /** The guess's algebraic variables (AlgebraicGuess, fesd.h). */
  AlgebraicGuess algebraic_guess = AlgebraicGuess::kSides;
  bool exact_hessian = true;
  /** The Jacobian and Hessian structure IPOPT is given: true, the entries found nonzero at
      random points (sparsity.h), checked at every evaluation, with every candidate declared and
      the NLP solved again on a miss (HomotopyStep::structure_widened); false, every candidate
      (what each row reads, every pair of a field or algebraic piece's unknowns, the pairs the
      complementarity products multiply). False by default: cheaper iterations, but other pivots
      and with them other homotopy paths, some much longer (docs/ocp.md, "The cost of an
      iteration on IPOPT 3.14.19 with MUMPS 5.8.2"). */
  bool probe_sparsity = false;
  /** Tests only: the Hessian handed to IPOPT is multiplied by this. */
  double exact_hessian_scale = 1.0;
  /** SolverOptions::derivative_programs. */
  bool derivative_programs = true;
};

/** What SolverOptions::derivative_programs did in one transcription: the Hessian's blocks and
    the elements' Jacobian rows traced into programs (again where a branch went the other way),
    and those kept on Jets after their program disagreed with the Jets at a check. */
struct DerivativeCounts {
  long traced = 0;
  long on_jets = 0;
};
/** "programs: 180 traced, none kept on Jets", or "Jets (derivative_programs off)": the
    results' `derivatives`. */
std::string describe_derivatives(bool programs, const DerivativeCounts& counts);

class HomotopyNlp;

/** One transcription: its unknowns at the current point, the relaxed NLP at sigma (given to
    IPOPT by HomotopySolver), and the FESD equations' values and derivatives for the Newton and
    sensitivity passes of fesd_simulate. The tableau, layout, setup and terms must outlive it. */
class Transcription {
 public:
  /** @pre layout, setup and terms (may be null) consistent: setup.x0 has layout.d entries. */
  Transcription(const ButcherTableau& tableau, const TranscriptionLayout& layout,
                const TranscriptionSetup& setup, const TranscriptionTerms* terms);
  ~Transcription();
  Transcription(const Transcription&) = delete;
  Transcription& operator=(const Transcription&) = delete;

  const TranscriptionLayout& layout() const;
  int constraints() const;
  /** The nonzeros of the Jacobian and of the Hessian's lower triangle declared to IPOPT (the
      probed structure, TranscriptionSetup::probe_sparsity). */
  std::size_t jacobian_nonzeros() const;
  std::size_t hessian_nonzeros() const;
  /** The derivatives' programs so far (SolverOptions::derivative_programs). */
  DerivativeCounts derivative_counts() const;

  /** The states at each element's start and end (x_n, x_{n+1}), for set_guess. */
  using ElementEnds = std::function<std::pair<Eigen::VectorXd, Eigen::VectorXd>(int element)>;
  /** The initial point: controls u (nu x N, or nu x 1 for every stage), each element's start and
      end states (its stage values interpolate linearly, its algebraic variables from
      PointDcs::initial, its end state is x_{n+1}) and the element lengths (relative when
      time-scaled; empty for equal lengths). T starts at the horizon. The transcription starts
      from x0 held with u = 0. */
  void set_guess(const Eigen::MatrixXd& u, const ElementEnds& ends,
                 const std::vector<double>& lengths);
  const Eigen::VectorXd& solution() const;
  void set_solution(const Eigen::VectorXd& w);

  /** The caller's cost at w (T when time-optimal, stage and terminal costs); no equilibration,
      no penalty. */
  double cost(const Eigen::VectorXd& w) const;
  /** The step equilibration summed over the element boundaries of every stage, at its weight
      (without fading). */
  double equilibration(const Eigen::VectorXd& w) const;
  /** The largest aggregated complementarity product at w. */
  double complementarity(const Eigen::VectorXd& w) const;
  /** "" when IPOPT can start at w: the objective, its gradient, the constraints, their Jacobian
      and (exact Hessian) the Lagrangian's Hessian at unit multipliers are finite there; else
      the first that is not, named by row (element, stage, kind) or unknown, with its value. */
  std::string non_finite_at(const Eigen::VectorXd& w) const;
  /** The sides of every switching function on element e (+1, -1, 0 sliding), from the largest
      v of each pair over its points, with `tol` as zero. */
  std::vector<int> sides(const Eigen::VectorXd& w, int e, double tol) const;
  /** v of pair k at x0 ((17)). */
  double start_v(int k) const;
  /** Element e's local inputs at w (element.h). */
  std::vector<double> element_inputs(const Eigen::VectorXd& w, int e) const;
  /** The dense Jacobian of element e's rows against its local inputs at w; `values`, when
      given, receives the rows' values. */
  Eigen::MatrixXd element_jacobian(const Eigen::VectorXd& w, int e,
                                   Eigen::VectorXd* values = nullptr) const;

 private:
  friend HomotopyNlp& homotopy_nlp(Transcription& transcription);
  class Nlp;
  // The NLP behind an opaque handle: no IPOPT type in this header.
  struct Handle;
  std::unique_ptr<Handle> handle_;
};

/** The process's CPU seconds (clock_gettime(CLOCK_PROCESS_CPUTIME_ID)), as HomotopyStep and
    the results count them. */
double process_cpu_seconds();

/** bflow's IPOPT settings for one solver (fesd::set_ipopt_defaults) and the caller's options,
    set after them and before every NLP, so that they win. */
struct IpoptSettings {
  std::string who = "fesd";  ///< the prefix of error messages
  SolverOptions solver;
  bool exact_hessian = true;
  int max_iterations = 3000;
  /** Polled after every IPOPT iteration (IPOPT's intermediate callback, under ipopt_mutex):
      true stops the NLP (User_Requested_Stop) and with it the homotopy
      (HomotopyOutcome::cancelled). It must not wait for another thread's IPOPT solve. */
  std::function<bool()> cancelled;
};

/** IpoptSettings from FesdOptions or OcpOptions (their solver options, exact_hessian,
    max_nlp_iterations and cancelled). */
template <typename Options>
IpoptSettings ipopt_settings(const Options& options, const std::string& who) {
  IpoptSettings s;
  s.who = who;
  s.solver = options.solver;
  s.exact_hessian = options.exact_hessian;
  s.max_iterations = options.homotopy.max_nlp_iterations;
  s.cancelled = options.cancelled;
  return s;
}

/** The homotopy's schedule and stopping rules. Each relaxed NLP at sigma is solved to
    tol = nlp_tolerance at sigma_final, max(nlp_tolerance, 1e-2 sigma) before; IPOPT's acceptable
    level is acceptable_tol = max(acceptable_tol_min, acceptable_tol_factor tol), its constraint
    violation min(acceptable_violation_max, max(tol, acceptable_violation_min,
    acceptable_violation_sigma sigma)). */
struct HomotopyRules {
  double sigma_initial = 1.0, sigma_final = 1e-12, sigma_factor = 0.1;
  bool superlinear = true;  ///< sigma <- min(factor sigma, sigma^1.5)
  double nlp_tolerance = 1e-13;
  /** NLPs before the last are solved to IPOPT's tol max(nlp_tolerance, this times sigma); 0:
      every NLP to nlp_tolerance (nosnoc's rule). */
  double intermediate_tolerance_factor = 1e-2;
  /** Warm starts take the previous multipliers and stay at the bounds reached (bound pushes
      1e-9); without, IPOPT initialises them itself from the previous point. */
  bool warm_start = true;
  /** With warm_start: also the previous multipliers; without, every multiplier starts at 0
      (pushed to 1e-3 for the bounds, IPOPT's warm-start pushes of 1e-3 for the point). */
  bool warm_start_multipliers = true;
  /** The first NLP, too, starts as IPOPT's warm start: from the guess with every multiplier 0
      (bound multipliers pushed to 1e-3, the point 1e-3 into its bounds, mu_init 0.1), instead
      of IPOPT's own initialisation (least-squares constraint multipliers, bound multipliers 1,
      bound_push 1e-2). */
  bool first_from_zero_multipliers = false;
  /** > 0: the IPOPT iterations of the whole homotopy, early polishes included: each NLP and
      early polish gets at most what is left of it (and of IpoptSettings::max_iterations), and
      the homotopy ends, not done and with
      budget_exhausted, when an NLP stops for want of it or nothing is left; 0: no limit. */
  int max_total_iterations = 0;
  /** An NLP before the last that IPOPT does not solve (other than by invalid numbers or the
      budget) hands its last iterate to the next, smaller sigma (nosnoc's rule) instead of being
      retried at a larger sigma from the last solution (no NLP is retried, the last neither);
      HomotopyOutcome::continued lists them. */
  bool continue_after_failure = false;
  /** A failed NLP after a solved one is retried from the last solution at sqrt(sigma sigma_last)
      up to this many times. */
  int max_retries = 6;
  double mu_init_min = 1e-12;  ///< warm NLPs start at mu = max(mu_init_min, 1e-2 sigma)
  /** > 0: every NLP after the first starts at this mu instead (IPOPT's default is 0.1). */
  double later_mu_init = 0.0;
  /** A warm-started NLP (warm_start with its multipliers) at sigma >= this runs IPOPT's monotone
      mu strategy from its mu_init instead of the adaptive one, whose first mu follows the tiny
      complementarity of a start held at its bounds; every other NLP (the first, cold starts,
      the re-solve at nlp_tolerance of stop_complementarity, polishes) runs the adaptive
      strategy. Infinity: the adaptive strategy for every NLP. */
  double monotone_mu_down_to = std::numeric_limits<double>::infinity();
  double acceptable_tol_min = 1e-4, acceptable_tol_factor = 0.0;
  double acceptable_violation_min = 1e-12, acceptable_violation_sigma = 0.0,
         acceptable_violation_max = 1e19;
  double acceptable_compl_inf_tol = 1e-4;
  int acceptable_iter = 5;
  /** > 0: the homotopy ends at the first NLP whose complementarity residual is at most this
      (nosnoc's rule), re-solved at nlp_tolerance at the same sigma when it was solved more
      loosely; sigma_final then only bounds it. 0: every NLP down to sigma_final. */
  double stop_complementarity = 0.0;
  /** > 0: after every NLP solved at a sigma at most this (above sigma_final) the active set is
      fixed and the NLP polished (HomotopySolver::polish), unless the same active set was
      polished before; a polish that is kept (every product zero) is polished once more from its
      own solution (kept likewise only with every product zero) and ends the homotopy
      (HomotopyOutcome::polished_early). Its cost may exceed the
     relaxed NLP's by what the last step in sigma moved the cost (the relaxation's effect still
     left), at least 1e-6 (1 + |cost|). 0: no early polish. */
  double early_polish_sigma = 0.0;
};

/** HomotopyRules with the sigma schedule and nlp_tolerance of FesdOptions or OcpOptions, the
    stopping rules at their defaults. */
template <typename Options>
HomotopyRules homotopy_schedule(const Options& options) {
  HomotopyRules r;
  r.sigma_initial = options.homotopy.sigma_initial;
  r.sigma_final = options.homotopy.sigma_final;
  r.sigma_factor = options.homotopy.sigma_factor;
  r.superlinear = options.homotopy.superlinear;
  r.nlp_tolerance = options.homotopy.nlp_tolerance;
  return r;
}

/** One NLP of a homotopy. */
struct HomotopyStep {
  int index = 0;
  double sigma = 0.0;
  double objective = 0.0;        ///< the caller's cost at the NLP's solution (Transcription::cost)
  double complementarity = 0.0;  ///< largest aggregated complementarity product
  int iterations = 0;            ///< IPOPT iterations of this NLP
  double cpu_seconds = 0.0;
  std::string ipopt_status;  ///< e.g. "Solve_Succeeded"
  /** IPOPT's overall optimality error of its final point, the scaled measure it compares with
      tol (and acceptable_tol); infinity when IPOPT gave none. */
  double kkt_error = std::numeric_limits<double>::infinity();
  /** The final point's largest constraint violation, unscaled. */
  double constraint_violation = std::numeric_limits<double>::infinity();
  bool polish = false;  ///< the final solve with the active set fixed (sigma 0)
  /** IPOPT's mu strategy for this NLP, "adaptive" or "monotone" (HomotopyRules::
      monotone_mu_down_to; a caller's IPOPT option mu_strategy if given), and the mu_init it was
      given (read by the monotone strategy; a caller's mu_init if given). */
  std::string mu_strategy = "adaptive";
  double mu_init = 0.1;
  /** The multipliers of the complementarity rows relaxed to <= sigma (Scholtes' relaxation; 0
      for the l1 penalty, the elastic mode and the polish) at the NLP's final point: their sum
      and the largest (rows far from their bound carry multipliers of IPOPT's tolerance, of
      either sign). By the envelope theorem the sum is the rate at which the NLP's optimal
      objective falls as sigma grows, -dJ/dsigma. They tell what kind of point the relaxed
      optima approach as sigma -> 0: on a pair whose members both vanish (biactive), the MPCC's
      multipliers of the two members are -mu times the other member, both negative, so
      S-stationarity (B-stationarity under MPCC-LICQ) needs mu times the members -> 0; sigma
      times the largest mu staying away from 0 (mu ~ 1/sigma, members ~ sqrt(sigma)) means the
      relaxed optima approach no S-stationary point. */
  double product_multipliers = 0.0, largest_product_multiplier = 0.0;
  /** When IPOPT did not solve the NLP: the (at most three) rows its final point violates most,
      by kind and place with their violations, largest first (e.g. "element 17 (stage 5) end row
      of state 8: 0.012; ..."), so that an infeasible polish says where; "" otherwise. */
  std::string worst_rows;
  /** A Jacobian or Hessian entry outside the probed structure was nonzero (the model took a
      branch none of the probe points took): the entry had been left out, so the NLP was solved
      again from the same start with every candidate entry declared, as are all later NLPs of
      the transcription. `iterations` and `cpu_seconds` count both solves. */
  bool structure_widened = false;
};

struct HomotopyOutcome {
  std::vector<HomotopyStep> steps;
  int iterations = 0;
  /** Some NLP was solved; the transcription then holds the last solved one's solution. */
  bool any_solved = false;
  /** The NLP at sigma_final was solved, or (stop_complementarity) one whose residual is within
      it, at nlp_tolerance. */
  bool done = false;
  /** Done above sigma_final by stop_complementarity. */
  bool stopped_early = false;
  double last_sigma = 0.0;  ///< sigma of the last solved NLP
  /** IPOPT solved the last solved NLP only to its acceptable level. */
  bool acceptable_only = false;
  /** When not done: the failing NLP's IPOPT status, sigma and complementarity residual. */
  bool infeasible = false;
  std::string failed_status;
  double failed_sigma = 0.0, failed_complementarity = 0.0;
  /** The homotopy ended because HomotopyRules::max_total_iterations ran out. */
  bool budget_exhausted = false;
  /** With budget_exhausted: nothing was left when the NLP at failed_sigma was to start (the NLPs
      and early polishes before it used the budget up), rather than that NLP running out. */
  bool budget_exhausted_before = false;
  /** IpoptSettings::cancelled asked to stop: the NLP at failed_sigma was cut short; the
      transcription holds the last solved NLP's solution (any_solved) or that NLP's last
      iterate. */
  bool cancelled = false;
  /** sigma of every NLP that failed and handed its last iterate on (continue_after_failure). */
  std::vector<double> continued;
  /** HomotopyRules::early_polish_sigma: the homotopy ended with a kept polish of the NLP at
      last_sigma (the transcription holds it; its step is the last of `steps`). */
  bool polished_early = false;
  /** With polished_early: the index in `steps` of the polish the transcription holds (the
      second, from the first's solution, unless IPOPT did not solve it). */
  int result_step = -1;
  /** sigma of every early polish that was not kept (the homotopy went on). */
  std::vector<double> polishes_not_kept;
};

struct PolishOutcome {
  HomotopyStep step;
  double cost_before = 0.0;
  /** IPOPT solved it, every product is within the tolerance and the cost is not worse (1e-6
      relative): the transcription holds the polished solution; else the one before. */
  bool kept = false;
};

/** IPOPT for transcriptions: the relaxation homotopy and the polish.
    @throws InvalidArgument (constructor) naming an option IPOPT does not take or an unknown
    linear solver, or when IPOPT fails to initialise; LinearSolverUnavailable (constructor) when
    the linear solver's library cannot be loaded (check_linear_solver, on settings.linear_solver
    or on a "linear_solver" among the caller's string options, which wins).
    @throws InvalidArgument (run, polish) when IPOPT refuses its options (Invalid_Option), a
    LinearSolverUnavailable when the solver is not MUMPS. */
class HomotopySolver {
 public:
  explicit HomotopySolver(const IpoptSettings& settings);
  ~HomotopySolver();
  HomotopySolver(const HomotopySolver&) = delete;
  HomotopySolver& operator=(const HomotopySolver&) = delete;

  /** The relaxed NLPs from rules.sigma_initial down to rules.sigma_final, each warm-started from
      the previous solution; `on_step` is called after each. The first NLP starts from the
      transcription's current point. */
  HomotopyOutcome run(Transcription& nlp, const HomotopyRules& rules,
                      const std::function<void(const HomotopyStep&)>& on_step = {});

  /** The NLP once more with the active set of the current solution fixed (element sides at
      `active_tol`): the zero member of every complementarity pair at its bound (a shared member
      fixed by one pair only; in Stewart's formulation one region free at every point),
      equal lengths of neighbouring elements of a stage with the same sides, no relaxation and no
      equilibration:
      an exact FESD solution, kept only as PolishOutcome::kept says, its cost at most
      `cost_slack` above the relaxed one (negative: 1e-6 (1 + |cost|)). `index` numbers its
      step; `max_iterations` > 0 caps IPOPT's iterations below the settings' (what is left of a
      budget). */
  PolishOutcome polish(Transcription& nlp, double active_tol, double nlp_tolerance,
                       double complementarity_tolerance, int index,
                       const std::function<void(const HomotopyStep&)>& on_step = {},
                       double cost_slack = -1.0, int max_iterations = 0);

  /** The linear solver in use (the settings' or the caller's IPOPT string option) and the file
      IPOPT loads it from ("" when linked into IPOPT). */
  const std::string& linear_solver() const;
  const std::string& linear_solver_library() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_TRANSCRIPTION_H_

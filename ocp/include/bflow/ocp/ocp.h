// Optimal control of nonsmooth systems through FESD ([F] Sections 1, 4.6): the whole problem
// (44) is transcribed into one mathematical program with complementarity constraints (45) and
// solved by a homotopy of relaxed NLPs on IPOPT. Switch detection stays implicit: the element
// lengths are unknowns, so the switches of the optimal trajectory land on element boundaries.
//
// A problem is written once, as for simulation (fesd.h), with controls u:
//
//   struct Car {
//     static constexpr int kStates = 2, kControls = 1, kSwitches = 1;
//     template <typename T> void switching(const T* x, T* c) const { c[0] = x[1] - T(10.0); }
//     template <typename T> void field(const T* x, const T* u, const T* a, T* xdot) const {
//       xdot[0] = x[1];
//       xdot[1] = (T(1.0) + T(2.0) * a[0]) * u[0];   // u for v < 10, 3 u for v > 10
//     }
//     // Optional, each found by name: costs and constraints.
//     template <typename T> T lagrange(const T* x, const T* u) const;       // L(x, u)
//     template <typename T> T mayer(const T* x) const;                      // R(x(T))
//     static constexpr int kPath = 1;                                       // g(x, u)
//     template <typename T> void path(const T* x, const T* u, T* g) const;
//     static constexpr int kTerminal = 2;                                   // g_T(x(T))
//     template <typename T> void terminal(const T* x, T* g) const;
//   };
//   bflow::OcpProblem problem;           // x0, horizon, bounds, guesses (data)
//   bflow::OcpResult r = bflow::ocp_solve(bflow::adapt_ocp(Car{}), problem, options);
//
// A piecewise-smooth model with controls (modes f_i(x, u) and a sign matrix, unions allowed) is
// wrapped by ControlledPiecewiseSmoothAsStep.
//
// Transcription. N control stages of equal length T / N, u constant on each; every stage has
// N_FE finite elements of an n_s-stage Radau IIA or Gauss-Legendre method on the DCS of the
// chosen formulation, exactly as one integration step of fesd_simulate: cross complementarity
// through all elements of the horizon (a stage starts where the previous one ends), step
// equilibration between neighbouring elements of a stage, and sum h over a stage = T / N. The
// element lengths are fractions of the horizon (the physical length is T h), so a time-optimal
// problem only adds T as an unknown (time scaling) and T to the objective. The Lagrange cost is
// integrated by the collocation quadrature of each element; x bounds hold at every element
// boundary, path constraints at every element boundary with the control acting there (x0 with
// u_0, the start of every other element with its stage's control, and x(T) with u_{N-1}).
//
// Solution. Scholtes' relaxation (every aggregated complementarity product <= sigma) or the l1
// penalty (rho = 1 / sigma times the products' sum added to the objective), sigma from
// sigma_initial down to sigma_final, each NLP warm-started from the previous one, with exact
// sparse first derivatives from Jets element by element and exact sparse Hessians by
// HessianJet, piece by piece (or IPOPT's limited-memory approximation). The result is "solved" only
// when IPOPT solved the last NLP and the complementarity residual is at most
// complementarity_tolerance.
#ifndef BFLOW_OCP_OCP_H_
#define BFLOW_OCP_OCP_H_

#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/ad/tangent_jet.h"
#include "bflow/core/errors.h"
#include "bflow/core/filippov.h"
#include "bflow/fesd/butcher.h"
#include "bflow/fesd/fesd.h"
#include "bflow/fesd/transcription.h"

namespace bflow {

/** A controlled step inclusion with the costs and constraints of an OCP, seen through virtual
    calls (double, Jet chunks and HessianScalar), so the transcription compiles once. The
    optional parts report their presence (has_lagrange(), path_constraints() = 0, ...). */
class OcpModel {
 public:
  virtual ~OcpModel() = default;
  virtual int states() const = 0;
  virtual int controls() const = 0;
  virtual int switches() const = 0;
  virtual int path_constraints() const { return 0; }
  virtual int terminal_constraints() const { return 0; }
  virtual bool has_lagrange() const { return false; }
  virtual bool has_mayer() const { return false; }
  /** The sign matrix of a piecewise-smooth model (lifting), or nullptr. */
  virtual const SignMatrix* sign_matrix() const { return nullptr; }
  /** A piecewise-smooth model's number of modes, or 0; then mode_fields gives every f_i(x, u)
      in one call (F[i * d + k]), as StepModel::mode_fields. */
  virtual int modes() const { return 0; }

#define BFLOW_OCP_MODEL_CALLS(T)                                             \
  virtual void switching(const T* x, T* c) const = 0;                        \
  virtual void field(const T* x, const T* u, const T* a, T* xdot) const = 0; \
  virtual void mode_fields(const T*, const T*, T*) const {}                  \
  virtual T lagrange(const T* x, const T* u) const = 0;                      \
  virtual T mayer(const T* x) const = 0;                                     \
  virtual void path(const T* x, const T* u, T* g) const = 0;                 \
  virtual void terminal(const T* x, T* g) const = 0;
  BFLOW_OCP_MODEL_CALLS(double)
  BFLOW_OCP_MODEL_CALLS(JetChunk)
  BFLOW_OCP_MODEL_CALLS(HessianScalar)
#undef BFLOW_OCP_MODEL_CALLS
};

namespace detail {
template <typename M, typename = void>
struct HasLagrange : std::false_type {};
template <typename M>
struct HasLagrange<M, std::void_t<decltype(std::declval<const M&>().lagrange(
                          std::declval<const double*>(), std::declval<const double*>()))>>
    : std::true_type {};
template <typename M, typename = void>
struct HasMayer : std::false_type {};
template <typename M>
struct HasMayer<
    M, std::void_t<decltype(std::declval<const M&>().mayer(std::declval<const double*>()))>>
    : std::true_type {};
template <typename M, typename = void>
struct HasControlledModeFields : std::false_type {};
template <typename M>
struct HasControlledModeFields<
    M,
    std::void_t<decltype(M::kModes), decltype(std::declval<const M&>().mode_fields(
                                         std::declval<const double*>(),
                                         std::declval<const double*>(), std::declval<double*>()))>>
    : std::true_type {};
template <typename M, typename = void>
struct PathCount : std::integral_constant<int, 0> {};
template <typename M>
struct PathCount<M, std::void_t<decltype(M::kPath)>> : std::integral_constant<int, M::kPath> {};
template <typename M, typename = void>
struct TerminalCount : std::integral_constant<int, 0> {};
template <typename M>
struct TerminalCount<M, std::void_t<decltype(M::kTerminal)>>
    : std::integral_constant<int, M::kTerminal> {};
}  // namespace detail

/** Wraps a model written as templates (see the top of this file) as an OcpModel. */
template <typename Model>
class OcpModelAdapter final : public OcpModel {
 public:
  static_assert(Model::kStates >= 1 && Model::kControls >= 1 && Model::kSwitches >= 1,
                "an OCP model needs kStates, kControls and kSwitches >= 1");
  explicit OcpModelAdapter(Model model) : model_(std::move(model)) {}
  int states() const override { return Model::kStates; }
  int controls() const override { return Model::kControls; }
  int switches() const override { return Model::kSwitches; }
  int path_constraints() const override { return detail::PathCount<Model>::value; }
  int terminal_constraints() const override { return detail::TerminalCount<Model>::value; }
  bool has_lagrange() const override { return detail::HasLagrange<Model>::value; }
  bool has_mayer() const override { return detail::HasMayer<Model>::value; }
  const SignMatrix* sign_matrix() const override {
    if constexpr (bflow::detail::HasSignMatrix<Model>::value) {
      return &model_.sign_matrix();
    } else {
      return nullptr;
    }
  }
  int modes() const override {
    if constexpr (detail::HasControlledModeFields<Model>::value) {
      return Model::kModes;
    } else {
      return 0;
    }
  }
  const Model& model() const { return model_; }

#define BFLOW_OCP_ADAPTER_CALLS(T)                                                \
  void switching(const T* x, T* c) const override { model_.switching(x, c); }     \
  void field(const T* x, const T* u, const T* a, T* xdot) const override {        \
    model_.field(x, u, a, xdot);                                                  \
  }                                                                               \
  void mode_fields(const T* x, const T* u, T* f) const override {                 \
    if constexpr (detail::HasControlledModeFields<Model>::value) {                \
      model_.mode_fields(x, u, f);                                                \
    }                                                                             \
  }                                                                               \
  T lagrange(const T* x, const T* u) const override { return lagrange_of(x, u); } \
  T mayer(const T* x) const override { return mayer_of(x); }                      \
  void path(const T* x, const T* u, T* g) const override { path_of(x, u, g); }    \
  void terminal(const T* x, T* g) const override { terminal_of(x, g); }
  BFLOW_OCP_ADAPTER_CALLS(double)
  BFLOW_OCP_ADAPTER_CALLS(JetChunk)
  BFLOW_OCP_ADAPTER_CALLS(HessianScalar)
#undef BFLOW_OCP_ADAPTER_CALLS

 private:
  template <typename T>
  T lagrange_of(const T* x, const T* u) const {
    if constexpr (detail::HasLagrange<Model>::value) {
      return model_.lagrange(x, u);
    } else {
      return T(0.0);
    }
  }
  template <typename T>
  T mayer_of(const T* x) const {
    if constexpr (detail::HasMayer<Model>::value) {
      return model_.mayer(x);
    } else {
      return T(0.0);
    }
  }
  template <typename T>
  void path_of(const T* x, const T* u, T* g) const {
    if constexpr (detail::PathCount<Model>::value > 0) model_.path(x, u, g);
  }
  template <typename T>
  void terminal_of(const T* x, T* g) const {
    if constexpr (detail::TerminalCount<Model>::value > 0) model_.terminal(x, g);
  }
  Model model_;
};

template <typename Model>
OcpModelAdapter<Model> adapt_ocp(Model model) {
  return OcpModelAdapter<Model>(std::move(model));
}

/** A piecewise-smooth model with controls as a step inclusion with controls: the model provides
    kStates, kControls, kSwitches, kModes, `switching<T>(x, c)` and `modes<T>(x, u, F)` writing
    F[i * d + k] = f_i(x, u)_k, plus any optional cost and constraint members, which are
    forwarded. f(x, u, a) = sum_i theta_i(a) f_i(x, u) with theta from the sign matrix. */
template <typename Pss>
class ControlledPiecewiseSmoothAsStep {
 public:
  static constexpr int kStates = Pss::kStates;
  static constexpr int kControls = Pss::kControls;
  static constexpr int kSwitches = Pss::kSwitches;
  static constexpr int kModes = Pss::kModes;
  static constexpr int kPath = detail::PathCount<Pss>::value;
  static constexpr int kTerminal = detail::TerminalCount<Pss>::value;

  /** @throws InvalidArgument if S has other than kSwitches columns or kModes modes. */
  ControlledPiecewiseSmoothAsStep(Pss pss, SignMatrix s) : pss_(std::move(pss)), s_(std::move(s)) {
    if (s_.switches() != kSwitches || s_.modes() != kModes) {
      throw InvalidArgument("ControlledPiecewiseSmoothAsStep: S has " +
                            std::to_string(s_.switches()) + " columns and " +
                            std::to_string(s_.modes()) + " modes, the model " +
                            std::to_string(kSwitches) + " switching functions and " +
                            std::to_string(kModes) + " modes");
    }
  }
  template <typename T>
  void switching(const T* x, T* c) const {
    pss_.switching(x, c);
  }
  template <typename T>
  void field(const T* x, const T* u, const T* a, T* xdot) const {
    T theta[kModes];
    T f[kModes * kStates];
    s_.multipliers(a, theta);
    pss_.modes(x, u, f);
    for (int k = 0; k < kStates; ++k) {
      xdot[k] = T(0.0);
      for (int i = 0; i < kModes; ++i) xdot[k] += theta[i] * f[i * kStates + k];
    }
  }
  /** Every mode at (x, u), F[i * d + k] = f_i(x, u)_k. */
  template <typename T>
  void mode_fields(const T* x, const T* u, T* f) const {
    pss_.modes(x, u, f);
  }
  template <typename T, typename P = Pss,
            typename = std::enable_if_t<detail::HasLagrange<P>::value, T>>
  T lagrange(const T* x, const T* u) const {
    return pss_.lagrange(x, u);
  }
  template <typename T, typename P = Pss,
            typename = std::enable_if_t<detail::HasMayer<P>::value, T>>
  T mayer(const T* x) const {
    return pss_.mayer(x);
  }
  template <typename T>
  void path(const T* x, const T* u, T* g) const {
    if constexpr (kPath > 0) pss_.path(x, u, g);
  }
  template <typename T>
  void terminal(const T* x, T* g) const {
    if constexpr (kTerminal > 0) pss_.terminal(x, g);
  }
  const SignMatrix& sign_matrix() const { return s_; }
  const Pss& pss() const { return pss_; }

 private:
  Pss pss_;
  SignMatrix s_;
};

/** Where the initial guess of the NLP comes from. */
enum class OcpGuess {
  kConstant,   ///< x = guess_x (x0 if empty) everywhere, u = guess_u on every stage
  kReference,  ///< x from guess_trajectory(t), u = guess_u
  /** guess_u, or guess_policy's controls, simulated by FESD stage by stage (simulate_policy):
      states, element lengths and algebraic variables of one FESD solution. */
  kSimulation,
};

/** The data of an OCP (the functions are the model's). Vectors left empty mean "none" or
    "unbounded"; bounds are checked for size and order by ocp_solve. */
struct OcpProblem {
  Eigen::VectorXd x0;  ///< x(0), required
  /** The horizon; with time_optimal the initial guess of T. */
  double horizon = 1.0;
  /** T free and minimised (T is added to the objective), between T_min and T_max. */
  bool time_optimal = false;
  double T_min = 0.0;  ///< > 0 is enforced as max(T_min, 1e-9 horizon)
  double T_max = std::numeric_limits<double>::infinity();
  Eigen::VectorXd x_lower, x_upper;  ///< at every element boundary (d each)
  /** x_lower and x_upper also on the states of every collocation stage inside the elements
      (nosnoc's Python package bounds every stage point), not only at the element boundaries. */
  bool x_bounds_at_stage_points = false;
  Eigen::VectorXd u_lower, u_upper;        ///< on every stage (nu each)
  Eigen::VectorXd path_lower, path_upper;  ///< g(x, u) (kPath each; empty: g <= 0)
  /** g_T(x(T)) (kTerminal each; empty: g_T = 0, equalities). */
  Eigen::VectorXd terminal_lower, terminal_upper;
  /** The stage-wise clock constraint of time-freezing ([F] Section 7.2, time_freezing.h): with
      a state index i >= 0, x_i at the end of stage k is fixed to (k + 1) horizon / N, so the
      clock (which stands still during impacts) keeps up with the stages. Fixed horizon only;
      -1: none. */
  int clock_state = -1;
  /** With clock_state: the clock at the end of stage k lies within this distance of
      (k + 1) horizon / N instead of on it (nosnoc's time_freezing_tolerance); 0: pinned. */
  double clock_tolerance = 0.0;
  /** Least-squares tracking added to the Lagrange cost:
        (x - x_ref(t_k))' diag(Q) (x - x_ref(t_k)) + (u - u_ref)' diag(R) (u - u_ref),
      x_ref evaluated at the middle t_k of each stage (fixed horizon only), and
      (x(T) - x_ref(T))' diag(Q_terminal) (x(T) - x_ref(T)) added to the Mayer cost. */
  Eigen::VectorXd track_Q, track_R, track_Q_terminal;
  std::function<Eigen::VectorXd(double)> x_ref;
  Eigen::VectorXd u_ref;
  /** A control index j >= 0: the tracking of x_ref and u_ref in the stage cost is multiplied by
      u_j, so that with the speed of time of time-freezing (time_freezing.h) as u_j it is
      integrated over physical time, s dtau (the terminal tracking is not); -1: none. */
  int track_time_scale = -1;
  /** The initial guess. guess_u: one column per stage (nu x N) or a single column used on every
      stage; empty means 0 clamped into the u bounds. */
  OcpGuess guess = OcpGuess::kConstant;
  Eigen::VectorXd guess_x;
  Eigen::MatrixXd guess_u;
  std::function<Eigen::VectorXd(double)> guess_trajectory;
  /** With kSimulation, in place of guess_u: a sampled feedback law, the controls of stage k from
      the state at its start (e.g. a hopping controller). Its values are clamped into
      [u_lower, u_upper] (OcpResult::notes counts the stages clamped) and become the guess's
      controls. */
  std::function<Eigen::VectorXd(int stage, const Eigen::VectorXd& x)> guess_policy;
};

enum class OcpRelaxation {
  kScholtes,   ///< products <= sigma
  kL1Penalty,  ///< (1 / sigma) sum of products added to the objective (elastic)
  /** One slack s >= 0 bounds every product (products <= s), s / sigma added to the objective:
      the l-infinity elastic mode of nosnoc (ELASTIC_INEQ). The products may exceed sigma where
      that pays; the polish fixes s at 0. */
  kElastic,
};

/** How least-squares tracking (OcpProblem::track_Q, track_R) enters the cost. */
enum class OcpTracking {
  /** Integrated by each element's collocation quadrature, x_ref at the middle of each stage. */
  kQuadrature,
  /** (T / N) [(x_{k+1} - x_ref(t_{k+1}))' diag(Q) (.) + (u_k - u_ref)' diag(R) (.)] at the end
      t_{k+1} of every stage k (nosnoc's least-squares cost; fixed horizon). */
  kStageEnds,
};

/** One NLP of the homotopy (fesd/transcription.h). */
using OcpHomotopyStep = fesd::HomotopyStep;

/** The homotopy of ocp_solve: HomotopyOptions (fesd/homotopy_options.h) with the optimal
    control's defaults (sigma from 100 to 1e-10 by factors 0.1, IPOPT's tol 1e-10 for the last NLP,
    3000 iterations per NLP), and what only ocp_solve's homotopy has: the relaxation, the
    tolerances of the NLPs before the last, the warm starts, IPOPT's acceptable levels, the
    iteration budget and the polish. */
struct OcpHomotopyOptions : HomotopyOptions {
  OcpHomotopyOptions() : HomotopyOptions{100.0, 1e-10, 0.1, false, 1e-10, 3000} {}
  /** How the complementarity rows are relaxed: products <= sigma, or penalised. */
  OcpRelaxation relaxation = OcpRelaxation::kScholtes;
  /** The largest complementarity row (an aggregated product, or a point product with
      kPointPairs) a "solved" result may have. */
  double complementarity_tolerance = 1e-9;
  /** IPOPT's tol for the NLPs before the last: max(nlp_tolerance, this times sigma), so the
      early, loosely relaxed NLPs are solved only as far as sigma allows; 0 solves every NLP to
      nlp_tolerance (nosnoc's rule). */
  double intermediate_tolerance_factor = 1e-2;
  /** Every NLP but the first starts from the previous solution. With warm_start it also takes
      the previous multipliers and stays at the bounds it reached (IPOPT's warm start, bound
      pushes 1e-9); without, IPOPT moves the point off its bounds and recomputes the multipliers
      (its own initialisation), which keeps an NLP centred when the smaller sigma cuts into the
      previous solution (the monoped of docs/ocp.md needs it). */
  bool warm_start = true;
  /** With warm_start, whether the previous multipliers come along. Without them (nosnoc's warm
      start of the primal point only) every multiplier starts at 0, IPOPT pushes the point 1e-3
      into its bounds and the bound multipliers to 1e-3. */
  bool warm_start_multipliers = true;
  /** The first NLP starts from the guess with every multiplier 0, as IPOPT's warm start (nosnoc
      sets warm_start_init_point for every NLP), instead of IPOPT's own initialisation
      (least-squares constraint multipliers, bound multipliers 1, the point pushed 1e-2 into its
      bounds). */
  bool first_from_zero_multipliers = false;
  /** After the homotopy, solve once more with the last NLP's active set fixed (the zero member
      of every complementarity pair at its bound, equal lengths of neighbouring elements of a
      stage with the same sides, no relaxation and no equilibration penalty): an exact FESD
      solution. It is kept only when IPOPT solves it and its cost is not worse (by 1e-6
      relative); OcpResult::polished and notes say what happened. */
  bool polish = true;
  /** With `polish`: from the first NLP solved at sigma <= this on, the polish is tried after
      every NLP whose active set differs from the last one tried; the first polish kept is
      polished once more from its own solution (as exact as the final polish) and ends the
      homotopy there. Its cost may exceed the relaxed NLP's by what the last step in sigma moved
      the cost (at least 1e-6 relative); a polish not kept costs its iterations and the
      homotopy goes on. `notes` says where it stopped. 0: only the final polish after
      sigma_final. Over the turbo car (N = 3 ... 15) and the braking block (N = 5 ... 20) it took
      0.63 times the CPU of the homotopy down to sigma_final, at the same optima (docs/ocp.md,
      Early polish). */
  double early_polish_sigma = 1e-4;
  /** End the homotopy at the first NLP whose complementarity residual is at most
      complementarity_tolerance (nosnoc's rule; an NLP solved more loosely than nlp_tolerance is
      solved once more at the same sigma), instead of going down to sigma_final, which then
      only bounds the homotopy. OcpResult::notes says where it stopped. */
  bool stop_at_complementarity = false;
  /** > 0: IPOPT's acceptable level (acceptable_tol) on every NLP, with IPOPT's default
      acceptable constraint violation 1e-2; 0: bflow's rule, max(1e-6, 1e3 tol) with a violation
      that follows sigma. An acceptable stop counts as solved when IPOPT's KKT error is within
      nlp_tolerance (OcpResult::kkt_error), so acceptable_tolerance <= nlp_tolerance makes it one
      (nosnoc's setup: both 1e-5). */
  double acceptable_tolerance = 0.0;
  int acceptable_iterations = 15;  ///< IPOPT's acceptable_iter
  /** > 0: IPOPT's mu_init on every NLP after the first (IPOPT's default 0.1, as nosnoc); 0:
      max(1e-11, 1e-2 sigma), a start near the previous solution's barrier. */
  double later_mu_init = 0.0;
  /** With warm_start and warm_start_multipliers: the NLPs after the first at sigma >= this run
      IPOPT's monotone mu strategy from mu_init (max(1e-11, 1e-2 sigma), the NLP's own
      tolerance, or later_mu_init), the rest (and stop_at_complementarity's re-solve at
      nlp_tolerance) its adaptive strategy. The adaptive strategy reads
      its first mu from the warm start's complementarity, which a start held 1e-9 off its bounds
      makes tiny (1e-11), and then creeps off the bounds of the new, tighter relaxation. Over
      the 90 sizes of docs/ocp.md (Warm starts and IPOPT's mu strategy) the defaults with 1e-2 take
      17 503 IPOPT iterations instead of 23 160 with the adaptive strategy throughout
      (infinity), and end at or below nosnoc's optimum on every row instead of 87. >= 0 (0: every
      warm-started NLP); OcpResult::homotopy names each NLP's strategy. */
  double monotone_mu_down_to = 1e-2;
  /** > 0: IPOPT iterations of the whole homotopy, its early polishes included: each NLP and
      early polish gets at most what is left (an NLP solved again with a widened structure,
      probe_sparsity, shares it between both solves), and when it runs out the result is
      kBudgetExhausted with the last solved NLP's solution; the final polish after sigma_final
      is not bounded by it. 0: no limit but max_nlp_iterations per NLP. */
  int max_total_iterations = 0;
  /** An NLP before the last that IPOPT does not solve hands its last iterate to the next,
      smaller sigma (nosnoc's rule; notes name each), instead of being retried from the last
      solved NLP at sqrt(sigma sigma_last) (bflow's rule, up to 6 times). */
  bool continue_after_failure = false;
};

struct OcpOptions {
  int stages = 10;   ///< N control stages, >= 1
  int elements = 3;  ///< N_FE per stage, >= 1
  CollocationScheme scheme = CollocationScheme::kRadauIIA;
  int collocation_stages = 2;  ///< n_s, 1..9
  /** How the collocation equations are written (butcher.h): kIntegral, X = x_n + h A F (each
      row reads the field at every stage); kDerivative, D (X - x_n) = h F, nosnoc's form (each row
      reads it at one stage, a sparser KKT matrix). The same solutions; IPOPT's paths differ. */
  CollocationForm collocation_form = CollocationForm::kIntegral;
  DcsFormulation formulation = DcsFormulation::kStep;
  int lifting_depth = 0;  ///< as FesdOptions::lifting_depth
  /** Standard time-stepping: equal fixed element lengths and complementarity point by point
      ([F] (34)); no switch detection (offered for comparison). */
  bool standard = false;
  /** The rows of the cross complementarity (fesd.h): one aggregated product per pair and
      element, or every product of two points on its own row (nosnoc's Stewart benchmark). Each
      row is relaxed to <= sigma, and the complementarity residual is the largest row. */
  CrossComplementarity cross_complementarity = CrossComplementarity::kElementSums;
  /** Weight of the step equilibration (39) in the objective of the homotopy's NLPs, times
      min(1, sigma): it regularises the element lengths early and fades, so that it does not
      bias the optimum; the polish imposes the exact equilibration instead. */
  double equilibration_weight = 0.0;
  /** rho_h of rho_h sum_n (h_n - h_0)^2 over every element, h_n in units of time and h_0 =
      T / (N N_FE) (nosnoc's heuristic_mean step equilibration); unlike equilibration_weight it
      keeps its weight at every sigma and so biases the optimum towards uniform elements. Every
      element length lies in [0, 2 h_0] in any case. */
  double step_deviation_weight = 0.0;
  /** How the tracking cost is discretised. */
  OcpTracking tracking = OcpTracking::kQuadrature;
  /** The guess's algebraic variables (AlgebraicGuess, fesd.h): kSides (default), from the sides
      of the guessed states; kNeutral, favouring no side (Heaviside step a = lambda+ = lambda- =
      1/2, the lifted theta and beta consistent with it; Stewart theta = 1/n_f, lambda = 1,
      mu = 0); kNosnoc, nosnoc's initialisation at its sigma_0 = 1 (Stewart theta = lambda =
      1/n_f, mu = 1). */
  AlgebraicGuess algebraic_guess = AlgebraicGuess::kSides;
  bool exact_hessian = true;  ///< else IPOPT's limited-memory approximation
  /** The sigma schedule, the NLPs' tolerances, warm starts and the polish
      (OcpHomotopyOptions). */
  OcpHomotopyOptions homotopy;
  /** IPOPT and its linear solver for every NLP (and for the simulated guess), shared with
      FesdOptions (solver_options.h). */
  SolverOptions solver;
  /** Called after every NLP of the homotopy (e.g. a progress line on stderr). */
  std::function<void(const OcpHomotopyStep&)> progress;
  /** Polled after every IPOPT iteration (and by the simulated guess before each of its steps);
      true ends the homotopy with OcpStatus::kCancelled, the result from the last solved NLP
      (e.g. a Ctrl-C check). Called on the thread that runs ocp_solve, inside IPOPT's callback
      under ipopt_mutex() (linear_solver.h): it must not wait for another thread's solve. */
  std::function<bool()> cancelled;
  /** The Jacobian and Hessian structure handed to IPOPT. false (default): every entry an
      element's rows and Hessian pieces can read, as the transcription lists them; true: only the
      entries found nonzero at random points (fesd/sparsity.h), checked at every evaluation (a
      miss declares every candidate, solves that NLP again, and `notes` says so). The probed
      structure is about nosnoc's size (the braking block at N = 10: 1910 / 606 Jacobian / Hessian
      nonzeros against 3254 / 1806) and MUMPS 5.8.2 factorises it faster, but the other pivots
      send some homotopies along much longer paths (docs/ocp.md, "The cost of an iteration on
      IPOPT 3.14.19 with MUMPS 5.8.2"). */
  bool probe_sparsity = false;
};

enum class OcpStatus {
  /** Last NLP solved (KKT error <= nlp_tolerance), complementarity residual <= tolerance. */
  kSolved,
  kComplementarityNotReached,  ///< last NLP solved, residual above the tolerance
  kAcceptableOnly,  ///< last NLP stopped at IPOPT's acceptable level, KKT error > nlp_tolerance
  kNlpFailed,       ///< IPOPT failed on some NLP of the homotopy (result: last good)
  kInfeasible,      ///< IPOPT found the NLP locally infeasible
  /** OcpHomotopyOptions::max_total_iterations ran out before the homotopy ended (result: last
     good). */
  kBudgetExhausted,
  /** OcpOptions::cancelled asked to stop (result: the last solved NLP's, else the NLP's last
      iterate, or the guess when none had started). */
  kCancelled,
};
const char* to_string(OcpStatus status);  ///< "solved", "complementarity_not_reached", ...

struct OcpResult {
  OcpStatus status = OcpStatus::kNlpFailed;
  std::string message;  ///< why the status is not kSolved ("" when it is)
  /** Decisions taken for the caller, e.g. "the simulated guess failed: ...; the constant guess
      was used". */
  std::vector<std::string> notes;
  double objective = 0.0;  ///< the OCP's cost (T for a time-optimal problem, plus L and R)
  double T = 0.0;
  std::vector<double> stage_times;  ///< N + 1 stage boundaries, 0 .. T
  Eigen::MatrixXd x_stages;         ///< d x (N + 1), x at the stage boundaries
  Eigen::MatrixXd u;                ///< nu x N
  std::vector<double> grid;         ///< all N N_FE + 1 element boundaries, 0 .. T
  Eigen::MatrixXd x_grid;           ///< d x grid.size()
  std::vector<double> step_sizes;   ///< physical element lengths T h
  /** Element boundaries where some switching function's active set changes. */
  std::vector<double> switch_times;
  /** Per element and switching function: +1, -1 or 0 (sliding), as FesdResult::active_sets. */
  std::vector<std::vector<int>> active_sets;
  double max_complementarity = 0.0;
  /** How IPOPT ended the NLP the result comes from ("Solve_Succeeded",
      "Solved_To_Acceptable_Level", ...) and that NLP's KKT error (HomotopyStep::kkt_error):
      "solved" needs kkt_error <= nlp_tolerance whichever way IPOPT stopped. */
  std::string ipopt_status;
  double kkt_error = std::numeric_limits<double>::infinity();
  /** The solver stack the NLPs ran on: "IPOPT 3.14.19" (ipopt_description) and the linear
      solver with its version or library, "mumps 5.8.2", "ma57 (libcoinhsl.so)"
      (linear_solver_description, bflow/fesd/linear_solver.h). */
  std::string ipopt;
  std::string linear_solver;
  /** The BLAS under the linear solver and its threads during the NLPs: "OpenBLAS 0.3.28, 1
      thread (libcasadi-tp-openblas.so.0)" (blas_description, linear_solver.h; blas_threads). */
  std::string blas;
  /** How the Jacobian and exact Hessian were computed (SolverOptions::derivative_programs):
      "programs: 180 traced, none kept on Jets" (blocks and elements traced, again where a
      branch went the other way; those whose program disagreed with the Jets, computed by Jets
      from then on), or "Jets (derivative_programs off)". */
  std::string derivatives;
  /** The result is the polished solution (active set fixed, every product zero). */
  bool polished = false;
  std::vector<OcpHomotopyStep> homotopy;
  int ipopt_iterations = 0;  ///< summed over the homotopy
  double cpu_seconds = 0.0;
  double cpu_per_iteration = 0.0;
  int unknowns = 0, constraints = 0, jacobian_nonzeros = 0, hessian_nonzeros = 0;
  bool ok() const { return status == OcpStatus::kSolved; }
};

/** The size of the NLP ocp_solve builds, in 64 bits, from the model's dimensions and the
    options alone: N N_FE finite elements sized as one FESD integration step of that many
    elements (fesd_problem_size, without the dense Newton matrices), plus N nu controls and T
    (and kElastic's slack). */
struct OcpProblemSize {
  std::int64_t elements = 0;  ///< N N_FE
  std::int64_t unknowns = 0, constraints = 0, jacobian_nonzeros = 0, hessian_nonzeros = 0;
  double bytes = 0.0;  ///< FesdProblemSize::step_bytes of the elements
  /** "" when every count is within kFesdMaxIndex and bytes within kFesdMaxMemoryBytes, else the
      first excess with its numbers, e.g. "3000000000 finite elements, above IPOPT's limit of
      2147483647" or "4000001 NLP unknowns, needing about 9.5e+09 bytes, above the limit of
      4 GiB = 4294967296 bytes". */
  std::string excess() const;
};

/** @throws InvalidArgument for options that have no size (as fesd_problem_size). */
OcpProblemSize ocp_problem_size(const OcpModel& model, const OcpOptions& options);

/** Solves the OCP. Progress goes to options.progress; IPOPT prints only at print_level > 0.
    Thread-safe; IPOPT solves run one at a time in a process: the lock (ipopt_mutex(),
    linear_solver.h) is held for one NLP of the homotopy at a time, so concurrent calls take
    turns NLP by NLP, each with the result it gives alone.
    @throws InvalidArgument for inconsistent data (sizes of x0, bounds, guesses, references;
    lower > upper; a NaN anywhere; an infinite x0, guess, reference, weight, horizon or T_min, a
    lower bound of +inf or an upper bound of -inf (infinity means "unbounded" only); weights
    below 0; tracking with a free horizon; options out of range), for contradictory options
    (standard time-stepping with cross complementarity other than element sums, with an
    equilibration or step-deviation weight; exact_hessian_scale without exact_hessian;
    x_bounds_at_stage_points without x bounds; track_time_scale or stage-end tracking without
    tracking; T_min or T_max with a fixed horizon; guess_policy without the simulated guess,
    guess_trajectory without the reference guess), for a guess at which the NLP's objective,
    constraints or derivatives are not finite (naming the row: element, stage and kind, or the
    unknown), and for a problem whose ocp_problem_size() has an excess, quoting the values. An
    NLP that IPOPT cannot solve is a status, not an exception. */
OcpResult ocp_solve(const OcpModel& model, const OcpProblem& problem,
                    const OcpOptions& options = {});

/** Simulates piecewise-constant controls (nu x N, stage k on [k T / N, (k + 1) T / N]) by FESD,
    stage by stage: options.steps integration steps of options.elements elements per stage (a
    stage starts a new integration step, as the control changes there). The result's grid,
    states, step sizes, switch times, active sets and counters cover the whole horizon;
    sensitivity is left empty. Stops at the first stage that fails (status and message say
    which). @throws InvalidArgument as fesd_simulate, or for u of the wrong height. */
FesdResult simulate_controls(const OcpModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                             double horizon, const Eigen::Ref<const Eigen::MatrixXd>& u,
                             FesdOptions options = {});

/** A sampled feedback law: the controls of stage k from the state at its start. */
using OcpPolicy = std::function<Eigen::VectorXd(int stage, const Eigen::VectorXd& x)>;

/** As simulate_controls, with the controls of stage k = policy(k, x(k T / N)) clamped into
    [u_lower, u_upper] (empty: unbounded); `controls` (if not null) receives them (nu x N) and
    `clamped` (if not null) the number of stages whose policy value was clamped.
    @throws InvalidArgument for stages < 1, a horizon that is not positive and finite, bounds of
    the wrong size, or a policy value of the wrong size or not finite (naming the stage). */
FesdResult simulate_policy(const OcpModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                           double horizon, int stages, const OcpPolicy& policy,
                           FesdOptions options = {}, const Eigen::VectorXd& u_lower = {},
                           const Eigen::VectorXd& u_upper = {}, Eigen::MatrixXd* controls = nullptr,
                           int* clamped = nullptr);

/** The model with its controls held at u, as a StepModel for fesd_simulate. */
class HeldControlModel final : public StepModel {
 public:
  HeldControlModel(const OcpModel& model, Eigen::VectorXd u);
  int states() const override { return model_.states(); }
  int switches() const override { return model_.switches(); }
  void switching(const double* x, double* c) const override { model_.switching(x, c); }
  void switching(const JetChunk* x, JetChunk* c) const override { model_.switching(x, c); }
  void switching(const HessianScalar* x, HessianScalar* c) const override {
    model_.switching(x, c);
  }
  void field(const double* x, const double* a, double* xdot) const override;
  void field(const JetChunk* x, const JetChunk* a, JetChunk* xdot) const override;
  void field(const HessianScalar* x, const HessianScalar* a, HessianScalar* xdot) const override;
  const SignMatrix* sign_matrix() const override { return model_.sign_matrix(); }
  int modes() const override { return model_.modes(); }
  void mode_fields(const double* x, double* f) const override;
  void mode_fields(const JetChunk* x, JetChunk* f) const override;
  void mode_fields(const HessianScalar* x, HessianScalar* f) const override;

 private:
  const OcpModel& model_;
  Eigen::VectorXd u_;
};

}  // namespace bflow

#endif  // BFLOW_OCP_OCP_H_

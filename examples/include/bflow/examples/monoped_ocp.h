// The monoped's optimal control problem of [F] Section 7.2: from x(0) = (0, 0.4, 0, 0, 0, ..., 0)
// to q_target = (3, 0.4, 0, 0) at rest in T = 3, by time-freezing (time_freezing.h) of the
// monoped (monoped.h) with the speed of time s as a third control and the stage-wise clock
// constraint. Least squares: Q = diag(1, 1, 10, 1, 1e-6 x 4, 0 for the clock), rho_u = 0.01 on
// the torques (none on s), Q_T = diag(1e3 x 4, 10 x 4, 0), |u| <= 100, s in [s_min, s_max], the
// state bounds of Section 7.2, and the foot's gap at least -5 mm at every element boundary (the
// path constraint of the published experiment, MonopedTimeFreezingOcp). The reference passes
// through q_x = 3 t / T and the heights 0.4, 0.6, 0.4, 0.6, 0.4 at t / T = 0, 1/4, 1/2, 3/4, 1 (two
// hops) as the smooth curve q_z = 0.5 - 0.1 cos(4 pi t / T), with the angles and velocities 0; it
// is also the initial guess of the states.
#ifndef BFLOW_EXAMPLES_MONOPED_OCP_H_
#define BFLOW_EXAMPLES_MONOPED_OCP_H_

#include <cmath>
#include <limits>
#include <string>

#include <Eigen/Core>
#include <Eigen/LU>

#include "bflow/core/errors.h"
#include "bflow/examples/monoped.h"
#include "bflow/ocp/ocp.h"
#include "bflow/ocp/time_freezing.h"

namespace bflow::examples {

/** The time-freezing PSS of the monoped with the speed of time, in the three regions (Heaviside
    step formulation) or the eight base sets (Stewart). */
template <TimeFreezingRegions kRegions>
using MonopedTimeFreezing = TimeFreezing<Monoped, kRegions, true>;

/** The time-freezing PSS of the monoped with the path constraint of the published experiment:
    the foot's gap g = f_c(q) >= kGapLower at every element boundary (MonopedTask::problem gives
    the bound). Time-freezing reproduces an impact only where the foot meets the ground from
    above; inside the ground it stands on the auxiliary dynamics at any depth. The relaxed NLPs
    of the homotopy mix free flight into the auxiliary region and so let the foot sink, and the
    later NLPs keep it there: measured at N = 30 without this constraint (on an earlier form of
    the model, hip under the base), 59 of 91 element boundaries had the foot 1 mm to 6.3 cm
    deep. */
template <TimeFreezingRegions kRegions>
struct MonopedTimeFreezingOcp : MonopedTimeFreezing<kRegions> {
  static constexpr int kPath = 1;
  static constexpr double kGapLower = -0.005;  ///< m, as nosnoc's experiment
  using Base = MonopedTimeFreezing<kRegions>;
  using Base::Base;
  template <typename T>
  void path(const T* x, const T*, T* g) const {
    g[0] = this->system().gap(x);
  }
};

template <TimeFreezingRegions kRegions>
ControlledPiecewiseSmoothAsStep<MonopedTimeFreezingOcp<kRegions>> monoped_model() {
  const MonopedTimeFreezingOcp<kRegions> tf(Monoped{}, {0.8, 200.0});
  return {tf, MonopedTimeFreezing<kRegions>::sign_matrix()};
}

/** The monoped's model without a path constraint (nosnoc's benchmark). */
template <TimeFreezingRegions kRegions>
ControlledPiecewiseSmoothAsStep<MonopedTimeFreezing<kRegions>> monoped_free_model() {
  const MonopedTimeFreezing<kRegions> tf(Monoped{}, {0.8, 200.0});
  return {tf, MonopedTimeFreezing<kRegions>::sign_matrix()};
}

/** The not-a-knot cubic spline through (t_i, y_i) (t strictly increasing, at least 4 points),
    evaluated at t (extrapolated by the end pieces outside [t_0, t_n]): the interpolant of
    MATLAB's interp1(..., 'spline'). It reproduces every cubic exactly.
    @throws InvalidArgument for fewer than 4 points, sizes that differ or t not increasing. */
inline double not_a_knot_spline(const Eigen::Ref<const Eigen::VectorXd>& ts,
                                const Eigen::Ref<const Eigen::VectorXd>& ys, double t) {
  const Eigen::Index n = ts.size() - 1;
  bool increasing = ts.size() == ys.size() && n >= 3;
  for (Eigen::Index i = 0; increasing && i < n; ++i) increasing = ts[i] < ts[i + 1];
  if (!increasing) {
    throw InvalidArgument(
        "not_a_knot_spline: " + std::to_string(ts.size()) + " knots and " +
        std::to_string(ys.size()) +
        " values; at least 4 strictly increasing knots, one value each, expected");
  }
  // Second derivatives M_i: continuity of the first derivative inside, of the third at t_1 and
  // t_{n-1} (not-a-knot).
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(n + 1, n + 1);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(n + 1);
  const auto h = [&](Eigen::Index i) { return ts[i + 1] - ts[i]; };
  for (Eigen::Index i = 1; i < n; ++i) {
    A(i, i - 1) = h(i - 1);
    A(i, i) = 2.0 * (h(i - 1) + h(i));
    A(i, i + 1) = h(i);
    b[i] = 6.0 * ((ys[i + 1] - ys[i]) / h(i) - (ys[i] - ys[i - 1]) / h(i - 1));
  }
  A(0, 0) = -1.0 / h(0);
  A(0, 1) = 1.0 / h(0) + 1.0 / h(1);
  A(0, 2) = -1.0 / h(1);
  A(n, n - 2) = -1.0 / h(n - 2);
  A(n, n - 1) = 1.0 / h(n - 2) + 1.0 / h(n - 1);
  A(n, n) = -1.0 / h(n - 1);
  const Eigen::VectorXd M = A.fullPivLu().solve(b);
  Eigen::Index i = 0;
  while (i + 1 < n && t > ts[i + 1]) ++i;
  const double hi = h(i), a = ts[i + 1] - t, c = t - ts[i];
  return M[i] * a * a * a / (6.0 * hi) + M[i + 1] * c * c * c / (6.0 * hi) +
         (ys[i] / hi - M[i] * hi / 6.0) * a + (ys[i + 1] / hi - M[i + 1] * hi / 6.0) * c;
}

/** Which setup of the monoped's OCP MonopedTask gives. */
enum class MonopedSetup {
  /** nosnoc's benchmark behind [F] Figure 10 (its files monoped_model.m and
      monoped_stewart_model.m): least squares at the stage ends, R = 0.1 I, a spline reference,
      s in [0.99, 100], no path constraint, the constant guess with neutral algebraic variables,
      the homotopy from sigma = 1 (x 0.1 to 1e-4 for the step formulation, x 0.4 over 15 NLPs for
      Stewart's) that stops at complementarity <= 1e-5, IPOPT at tol = acceptable_tol = 1e-5. */
  kNosnoc,
  /** A stricter setup: complementarity <= 1e-6 down to sigma = 1e-7 at IPOPT tol 1e-6, the
      tracking integrated by quadrature, rho_u = 0.01 (the paper's text), the cosine reference as
      the guess, s in [1, 25], the foot at least 5 mm above the ground's level -5 mm. */
  kStrict,
};
inline const char* to_string(MonopedSetup setup) {
  return setup == MonopedSetup::kNosnoc ? "nosnoc" : "strict";
}
/** "nosnoc" or "strict". @throws InvalidArgument naming the text. */
inline MonopedSetup parse_monoped_setup(const std::string& text) {
  if (text == "nosnoc") return MonopedSetup::kNosnoc;
  if (text == "strict") return MonopedSetup::kStrict;
  throw InvalidArgument("unknown monoped setup \"" + text + "\": use nosnoc or strict");
}

struct MonopedTask {
  static constexpr double kHorizon = 3.0;
  static constexpr double kTargetX = 3.0;
  static constexpr double kHeight = 0.4;
  MonopedSetup setup = MonopedSetup::kNosnoc;

  /** The reference of the nosnoc setup: the not-a-knot cubic spline through the normalised
      times (0, 1/4, 1/2, 3/4, 1) of q_x = (0, 0.75, 1.5, 2.25, 3), q_z = (0.4, 0.6, 0.4, 0.6,
      0.4), v_x = (0, 1, 1, 1, 0), the angles and other velocities 0, and the clock t. */
  static Eigen::VectorXd spline_reference(double t) {
    const Eigen::VectorXd knots = (Eigen::VectorXd(5) << 0.0, 0.25, 0.5, 0.75, 1.0).finished();
    const double s = t / kHorizon;
    Eigen::VectorXd x = Eigen::VectorXd::Zero(9);
    x[0] = not_a_knot_spline(knots, kTargetX * knots, s);
    x[1] = not_a_knot_spline(knots, (Eigen::VectorXd(5) << 0.4, 0.6, 0.4, 0.6, 0.4).finished(), s);
    x[4] = not_a_knot_spline(knots, (Eigen::VectorXd(5) << 0.0, 1.0, 1.0, 1.0, 0.0).finished(), s);
    x[8] = t;
    return x;
  }

  /** The reference and guess of the strict setup: (q, v, clock) at time t, computed from
      s = t / T, q_x = 3 s and q_z = 0.5 - 0.1 cos(4 pi s). The homotopy's path depends on
      round-off: measured at N = 30, with q_x = 3 t / T in place of 3 (t / T) the iterates part
      within the first NLP and the last NLP ends far from the target (docs/ocp.md, the
      monoped). */
  static Eigen::VectorXd reference(double t) {
    const double pi = 3.14159265358979323846;
    Eigen::VectorXd x = Eigen::VectorXd::Zero(9);
    const double s = t / kHorizon;
    x[0] = kTargetX * s;
    x[1] = 0.5 - 0.1 * std::cos(4.0 * pi * s);
    x[8] = t;
    return x;
  }

  /** The solver options of the setup at N control stages (N_FE = 3 elements of Radau IIA,
      n_s = 2, as the library's defaults) for the formulation.
      nosnoc: sigma from 1 by factors of 0.1 to 1e-4 (step) or 0.4 to 0.4^14 (Stewart), stopping
      at the first NLP with complementarity <= 1e-5; IPOPT's tol and acceptable_tol 1e-5 with
      acceptable_iter 3 on every NLP (intermediate_tolerance_factor 0), each NLP from the previous
      primal point only (warm_start without multipliers; the first from the guess with every
      multiplier 0) at IPOPT's mu_init 0.1, an unsolved NLP's last iterate handed to the next
      sigma (continue_after_failure); the step equilibration rho_h sum (h - h_0)^2, rho_h = 1;
     the step functions lifted (lifting depth 2); Stewart's cross complementarity point by point
     (kPointPairs); no polish. strict: sigma from 1 by factors of 0.1
     to 1e-7, IPOPT's tolerance 1e-6, complementarity 1e-6, cold starts (warm_start = false) and no
     polish. Measured at N = 30 (step formulation): 11784 IPOPT iterations (1531 s), one hop with
     the foot sliding inside the 5 mm band below the ground (docs/ocp.md). Both allow 10000 IPOPT
     iterations per NLP. */
  OcpOptions options(int stages, DcsFormulation formulation = DcsFormulation::kStep) const {
    OcpOptions o;
    OcpHomotopyOptions& h = o.homotopy;
    o.stages = stages;
    o.formulation = formulation;
    h.sigma_initial = 1.0;
    h.polish = false;
    h.max_nlp_iterations = 10000;
    if (setup == MonopedSetup::kStrict) {
      h.warm_start = false;
      h.sigma_factor = 0.1;
      h.sigma_final = 1e-7;
      h.nlp_tolerance = 1e-6;
      h.complementarity_tolerance = 1e-6;
      return o;
    }
    const bool stewart = formulation == DcsFormulation::kStewart;
    h.sigma_factor = stewart ? 0.4 : 0.1;
    h.sigma_final = std::pow(h.sigma_factor, stewart ? 14 : 4);
    o.lifting_depth = stewart ? 0 : 2;
    // nosnoc's Stewart benchmark: cross complementarity over every pair of points (STAGE_STAGE);
    // its step benchmark: one aggregated product per element and pair (FE_FE).
    o.cross_complementarity =
        stewart ? CrossComplementarity::kPointPairs : CrossComplementarity::kElementSums;
    h.nlp_tolerance = 1e-5;
    h.complementarity_tolerance = 1e-5;
    h.stop_at_complementarity = true;
    h.acceptable_tolerance = 1e-5;
    h.acceptable_iterations = 3;
    h.warm_start = true;
    h.warm_start_multipliers = false;
    h.first_from_zero_multipliers = true;
    h.intermediate_tolerance_factor = 0.0;
    h.continue_after_failure = true;
    h.later_mu_init = 0.1;
    o.step_deviation_weight = 1.0;
    o.tracking = OcpTracking::kStageEnds;
    o.algebraic_guess = AlgebraicGuess::kNeutral;
    return o;
  }

  /** The target q(T) = (3, 0.4, 0, 0). */
  static Eigen::Vector4d target() { return {kTargetX, kHeight, 0.0, 0.0}; }

  /** The largest |q_i - q_target,i| of a time-freezing state x = (q, v, clock). */
  static double target_error(const Eigen::Ref<const Eigen::VectorXd>& x) {
    return (x.head(4) - target()).cwiseAbs().maxCoeff();
  }

  /** The number of hops in a run: flight phases that start from the ground, the foot on the
      ground where its gap is at most `contact` and in flight above `lift` (count_hops of
      time_freezing.h: a fall from a state in the air is no hop).
      @throws InvalidArgument if x has other than 9 rows or 0 <= contact < lift fails. */
  static int hops(const Eigen::Ref<const Eigen::MatrixXd>& x, double contact = 1e-4,
                  double lift = 1e-2) {
    return count_hops(Monoped{}, x, contact, lift);
  }

  /** The OCP at N control stages (the nosnoc setup's terminal weight is (T / N) Q_T). The
      strict setup's problem has the foot's path constraint: solve it with monoped_model(), the
      nosnoc setup's with monoped_free_model(). */
  OcpProblem problem(int stages) const {
    const double inf = std::numeric_limits<double>::infinity();
    const double pi = 3.14159265358979323846;
    const bool nosnoc = setup == MonopedSetup::kNosnoc;
    OcpProblem p;
    p.x0 = Eigen::VectorXd::Zero(9);
    p.x0[1] = kHeight;
    p.horizon = kHorizon;
    p.clock_state = 8;
    p.x_lower.resize(9);
    p.x_upper.resize(9);
    p.x_lower << -0.5, 0.0, -pi, -pi, -100, -100, -100, -100, -inf;
    p.x_upper << kTargetX + 0.5, 10.0, pi, pi, 100, 100, 100, 100, inf;
    p.u_lower = Eigen::Vector3d(-100.0, -100.0, nosnoc ? 0.99 : 1.0);
    p.u_upper = Eigen::Vector3d(100.0, 100.0, nosnoc ? 100.0 : 25.0);
    p.track_Q.resize(9);
    p.track_Q << 1.0, 1.0, 10.0, 1.0, 1e-6, 1e-6, 1e-6, 1e-6, 0.0;
    const double rho_u = nosnoc ? 0.1 : 0.01;
    p.track_R = Eigen::Vector3d(rho_u, rho_u, 0.0);
    p.u_ref = Eigen::Vector3d(0.0, 0.0, 1.0);
    p.track_Q_terminal.resize(9);
    p.track_Q_terminal << 1e3, 1e3, 1e3, 1e3, 10.0, 10.0, 10.0, 10.0, 0.0;
    if (nosnoc) {
      p.track_Q_terminal *= kHorizon / stages;
      p.x_ref = spline_reference;
      p.guess = OcpGuess::kConstant;
      p.guess_u = Eigen::Vector3d(0.0, 0.0, 1.0);
      return p;
    }
    p.path_lower = Eigen::VectorXd::Constant(
        1, MonopedTimeFreezingOcp<TimeFreezingRegions::kUnions>::kGapLower);
    p.path_upper = Eigen::VectorXd::Constant(1, inf);
    p.x_ref = reference;
    p.guess = OcpGuess::kReference;
    p.guess_trajectory = reference;
    p.guess_u = Eigen::Vector3d(0.0, 0.0, 1.0);
    return p;
  }
};

/** Calls f(model, problem) with the monoped's model for the setup and formulation (three
    regions for the step formulation, the eight base sets for Stewart's) and its problem at N
    stages. */
template <typename F>
auto with_monoped(const MonopedTask& task, DcsFormulation formulation, int stages, F&& f) {
  const OcpProblem problem = task.problem(stages);
  const bool stewart = formulation == DcsFormulation::kStewart;
  if (task.setup == MonopedSetup::kStrict) {
    if (stewart) return f(adapt_ocp(monoped_model<TimeFreezingRegions::kBaseSets>()), problem);
    return f(adapt_ocp(monoped_model<TimeFreezingRegions::kUnions>()), problem);
  }
  if (stewart) return f(adapt_ocp(monoped_free_model<TimeFreezingRegions::kBaseSets>()), problem);
  return f(adapt_ocp(monoped_free_model<TimeFreezingRegions::kUnions>()), problem);
}

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_MONOPED_OCP_H_

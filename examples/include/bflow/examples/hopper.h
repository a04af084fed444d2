// The hopping robot of nosnoc's Python package (`nosnoc_py`, examples/hopper_robot/hopper_ocp.py,
// after Lin's NIPOCPEC and Howell's motion_planning hopper): a body with a telescopic leg on the
// ground, by time-freezing (bflow/ocp/time_freezing.h), and its optimal control problem of five
// hops from x = 0.1 to x = 5 in T = 5.
//
// Configuration q = (x, y, theta, l): the body's position, its angle and the leg's length. The
// foot is at (x + l sin theta, y - l cos theta); the gap is its height and its tangential
// position its abscissa, so
//   J_n = (0, 1, l sin theta, -cos theta),   J_t = (1, 0, l cos theta, sin theta).
// The mass matrix is constant, M = diag(m_b + m_l, m_b + m_l, I_b + I_l, m_l), and
//   f_v(q, u) = (-u_2 sin theta, -(m_b + m_l) g + u_2 cos theta, u_1, u_2)
// with u_1 the torque on the body and u_2 the force along the leg (the package's model has no
// Coriolis terms; neither has this one). u_3 is a third control that enters only the cost (the
// package's slack for its no-slip complementarity, see below). The speed of time s is the
// fourth control. Friction mu = 0.45, auxiliary constant a_n = 100.
//
// The OCP (HopperTask): x(0) = (0.1, 0.5, 0, 0.5, 0, 0, 0, 0, clock 0), N = 50 stages of
// T = 5, the reference of five jumps (each the parabola through its start, its apex
// (x + 0.49, 1, 0, 0.1) and its end (x + 0.98, 0.5, 0, 0.5), velocities 0, sampled at ten
// points per jump), tracked with the stage's reference at the stage's end:
//   sum over stages of the quadrature of s [(x - x_ref,k)' Q (x - x_ref,k) + u' R u]
//   + (x(T) - x_end)' Q_T (x(T) - x_end),
// Q = diag(100, 100, 20, 50, 0.1 x 4), Q_T = diag(300 x 4, 0.1 x 4), R = diag(0.01, 0.01, 1e-5),
// u in [-50, 50] x [-50, 50] x [0, 100], s in [0.1, 20], the state bounds
// (0, 0, -pi, 0.1, -10, -10, -5, -5) <= x <= (5.1, 1.5, pi, 0.5, 10, 10, 5, 5), the clock within
// 1e-3 of k T / N at the end of stage k, Stewart's formulation on the eight base sets, N_FE = 3,
// Radau IIA n_s = 2, the step equilibration rho_h sum (h - h_0)^2, sigma from 100 by factors 0.1
// for at most six NLPs (to 1e-3), stopping at complementarity 1e-9, IPOPT's tol 1e-8 (its
// default) with acceptable_tol 1e-6, at most 4000 iterations per NLP, each NLP started from the
// previous primal point with IPOPT's own initialisation, and the reference as the guess.
//
// One part of the package's OCP is not stated: its path complementarity |J_t' v| (theta_7 +
// theta_8) <= sigma at every stage point (no tangential velocity while the auxiliary dynamics
// act: the foot sticks during impacts). bflow has no complementarity on algebraic variables of
// the user's; without it impacts obey Coulomb friction with mu = 0.45 (docs/ocp.md, the hopping
// robot, measures both).
#ifndef BFLOW_EXAMPLES_HOPPER_H_
#define BFLOW_EXAMPLES_HOPPER_H_

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/ocp/ocp.h"
#include "bflow/ocp/time_freezing.h"

namespace bflow::examples {

struct Hopper {
  static constexpr int kDof = 4, kControls = 3;
  double m_body = 1.0, m_leg = 0.1;     // kg
  double i_body = 0.25, i_leg = 0.025;  // kg m^2
  double g = 9.81;                      // m/s^2

  template <typename T>
  void mass(const T*, T* M) const {
    for (int k = 0; k < 16; ++k) M[k] = T(0.0);
    M[0] = M[5] = T(m_body + m_leg);
    M[10] = T(i_body + i_leg);
    M[15] = T(m_leg);
  }
  /** f_v(q, v, u), u = (torque on the body, force along the leg, slack), or nullptr. */
  template <typename T>
  void forces(const T* q, const T*, const T* u, T* f) const {
    using std::cos;
    using std::sin;
    const T u1 = u != nullptr ? u[0] : T(0.0), u2 = u != nullptr ? u[1] : T(0.0);
    f[0] = -u2 * sin(q[2]);
    f[1] = T(-(m_body + m_leg) * g) + u2 * cos(q[2]);
    f[2] = u1;
    f[3] = u2;
  }
  template <typename T>
  T gap(const T* q) const {
    using std::cos;
    return q[1] - q[3] * cos(q[2]);
  }
  template <typename T>
  T tangential_position(const T* q) const {
    using std::sin;
    return q[0] + q[3] * sin(q[2]);
  }
  template <typename T>
  void normal(const T* q, T* jn) const {
    using std::cos;
    using std::sin;
    jn[0] = T(0.0);
    jn[1] = T(1.0);
    jn[2] = q[3] * sin(q[2]);
    jn[3] = -cos(q[2]);
  }
  template <typename T>
  void tangent(const T* q, T* jt) const {
    using std::cos;
    using std::sin;
    jt[0] = T(1.0);
    jt[1] = T(0.0);
    jt[2] = q[3] * cos(q[2]);
    jt[3] = sin(q[2]);
  }
};

/** The hopper's time-freezing PSS with the speed of time (the fourth control). */
template <TimeFreezingRegions kRegions>
using HopperTimeFreezing = TimeFreezing<Hopper, kRegions, true>;

template <TimeFreezingRegions kRegions>
ControlledPiecewiseSmoothAsStep<HopperTimeFreezing<kRegions>> hopper_model() {
  const HopperTimeFreezing<kRegions> tf(Hopper{}, {0.45, 100.0});
  return {tf, HopperTimeFreezing<kRegions>::sign_matrix()};
}

struct HopperTask {
  static constexpr double kHorizon = 5.0;
  static constexpr int kJumps = 5;
  static constexpr double kStartX = 0.1, kGoalX = 5.0, kApex = 1.0;
  /** N, a multiple of kJumps (the package samples every jump at N / kJumps points). */
  int stages = 50;

  /** @throws InvalidArgument unless N is a positive multiple of kJumps. */
  explicit HopperTask(int n = 50) : stages(n) {
    if (n < kJumps || n % kJumps != 0) {
      throw InvalidArgument("the hopper's N = " + std::to_string(n) +
                            " must be a positive multiple of " + std::to_string(kJumps) +
                            " (the reference samples every jump at N / 5 points)");
    }
  }

  /** The state (q, v) of the reference at the normalised time s in [0, kJumps] (jump j on
      [j, j + 1]): the parabola through the jump's start (s = j), apex (j + 1/2) and end. */
  static Eigen::VectorXd reference_state(double s) {
    const double step = (kGoalX - kStartX) / kJumps;
    const int j = std::clamp(static_cast<int>(std::floor(s)), 0, kJumps - 1);
    const double r = s - j;  // in [0, 1]
    const double x0 = kStartX + j * step;
    const Eigen::Vector4d a(x0, 0.5, 0.0, 0.5), m(x0 + step / 2.0, kApex, 0.0, 0.1),
        b(x0 + step, 0.5, 0.0, 0.5);
    // Lagrange basis on the nodes 0, 1/2, 1.
    const double la = 2.0 * (r - 0.5) * (r - 1.0), lm = -4.0 * r * (r - 1.0),
                 lb = 2.0 * r * (r - 0.5);
    Eigen::VectorXd x = Eigen::VectorXd::Zero(8);
    x.head(4) = la * a + lm * m + lb * b;
    return x;
  }
  /** The reference row i = 0..N of the package: jump j's N / 5 samples at r = 0, 5 / N, ...
      for i = j N / 5 + r N / 5, then the goal. */
  Eigen::VectorXd reference_row(int i) const {
    const int per_jump = stages / kJumps;
    if (i >= stages) return reference_state(kJumps);
    return reference_state(i / per_jump + static_cast<double>(i % per_jump) / per_jump);
  }
  /** x_ref(t) as (q, v, clock 0): stage k's reference row k + 1, for t inside stage k. */
  Eigen::VectorXd stage_reference(double t) const {
    Eigen::VectorXd x = Eigen::VectorXd::Zero(9);
    x.head(8) = reference_row(stage_of(t) + 1);
    return x;
  }
  /** The guess of the package: every state of stage k at reference row k + 1, the clock at
      k T / (N - 1). */
  Eigen::VectorXd guess(double t) const {
    const int k = stage_of(t);
    Eigen::VectorXd x = stage_reference(t);
    x[8] = stages > 1 ? kHorizon * k / (stages - 1) : 0.0;
    return x;
  }
  /** The stage of time t: k with k T / N < t <= (k + 1) T / N (an element's end belongs to the
      stage it ends), 0 at t = 0. */
  int stage_of(double t) const {
    const double h = kHorizon / stages;
    return std::clamp(static_cast<int>(std::ceil(t / h - 1e-9)) - 1, 0, stages - 1);
  }
  /** The target (q, v) = (5, 0.5, 0, 0.5, 0, 0, 0, 0). */
  static Eigen::VectorXd target() { return reference_state(kJumps); }
  /** The largest |q_i - q_target,i| of a time-freezing state x = (q, v, clock). */
  static double target_error(const Eigen::Ref<const Eigen::VectorXd>& x) {
    return (x.head(4) - target().head(4)).cwiseAbs().maxCoeff();
  }
  /** Hops: flight phases that start from the ground (count_hops of time_freezing.h).
      @throws InvalidArgument if x has other than 9 rows or the levels are out of order. */
  static int hops(const Eigen::Ref<const Eigen::MatrixXd>& x, double contact = 1e-4,
                  double lift = 1e-2) {
    return count_hops(Hopper{}, x, contact, lift);
  }

  /** The package's solver settings (see the top of the file) at N stages. */
  OcpOptions options() const {
    OcpOptions o;
    OcpHomotopyOptions& h = o.homotopy;
    o.stages = stages;
    o.elements = 3;
    o.collocation_stages = 2;
    o.formulation = DcsFormulation::kStewart;
    h.sigma_initial = 100.0;
    h.sigma_factor = 0.1;
    h.sigma_final = 1e-3;
    h.stop_at_complementarity = true;
    h.complementarity_tolerance = 1e-9;
    h.nlp_tolerance = 1e-8;
    h.intermediate_tolerance_factor = 0.0;
    h.acceptable_tolerance = 1e-6;
    h.max_nlp_iterations = 4000;
    h.warm_start = false;
    h.later_mu_init = 0.1;
    h.continue_after_failure = true;
    o.step_deviation_weight = 1.0;
    h.polish = false;
    return o;
  }

  /** The OCP at N stages. */
  OcpProblem problem() const {
    const double inf = std::numeric_limits<double>::infinity();
    const double pi = 3.14159265358979323846;
    OcpProblem p;
    p.x0 = Eigen::VectorXd::Zero(9);
    p.x0.head(8) = reference_state(0.0);
    p.horizon = kHorizon;
    p.clock_state = 8;
    p.clock_tolerance = 1e-3;
    p.x_lower.resize(9);
    p.x_upper.resize(9);
    p.x_lower << 0.0, 0.0, -pi, 0.1, -10.0, -10.0, -5.0, -5.0, -inf;
    p.x_upper << kGoalX + 0.1, 1.5, pi, 0.5, 10.0, 10.0, 5.0, 5.0, inf;
    p.x_bounds_at_stage_points = true;
    p.u_lower = Eigen::Vector4d(-50.0, -50.0, 0.0, 0.1);
    p.u_upper = Eigen::Vector4d(50.0, 50.0, 100.0, 20.0);
    p.track_Q.resize(9);
    p.track_Q << 100.0, 100.0, 20.0, 50.0, 0.1, 0.1, 0.1, 0.1, 0.0;
    p.track_R = Eigen::Vector4d(0.01, 0.01, 1e-5, 0.0);
    p.u_ref = Eigen::Vector4d::Zero();
    p.track_time_scale = 3;
    p.track_Q_terminal.resize(9);
    p.track_Q_terminal << 300.0, 300.0, 300.0, 300.0, 0.1, 0.1, 0.1, 0.1, 0.0;
    const HopperTask task = *this;
    p.x_ref = [task](double t) {
      if (t >= kHorizon) {
        Eigen::VectorXd x = Eigen::VectorXd::Zero(9);
        x.head(8) = target();
        return x;
      }
      return task.stage_reference(t);
    };
    p.guess = OcpGuess::kReference;
    p.guess_trajectory = [task](double t) { return task.guess(t); };
    p.guess_u = Eigen::Vector4d(0.0, 0.0, 0.0, 1.0);
    return p;
  }
};

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_HOPPER_H_

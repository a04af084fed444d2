// The monoped's optimal control problem of [F] Section 7.2: from x(0) = (0, 0.4, 0, 0, 0, ..., 0)
// to q_target = (3, 0.4, 0, 0) at rest in T = 3, by time-freezing (time_freezing.h) of the
// monoped (monoped.h) with the speed of time s as a third control and the stage-wise clock
// constraint. Least squares: Q = diag(1, 1, 10, 1, 1e-6 x 4, 0 for the clock), rho_u = 0.01 on
// the torques (none on s), Q_T = diag(1e3 x 4, 10 x 4, 0), |u| <= 100, s in [s_min, s_max], the
// state bounds of Section 7.2. The reference passes through q_x = 3 t / T and the heights
// 0.4, 0.6, 0.4, 0.6, 0.4 at t / T = 0, 1/4, 1/2, 3/4, 1 (two hops) as the smooth curve
// q_z = 0.5 - 0.1 cos(4 pi t / T), with the angles and velocities 0; it is also the initial
// guess of the states.
#ifndef BFLOW_EXAMPLES_MONOPED_OCP_H_
#define BFLOW_EXAMPLES_MONOPED_OCP_H_

#include <cmath>
#include <limits>

#include <Eigen/Core>

#include "bflow/examples/monoped.h"
#include "bflow/ocp/ocp.h"
#include "bflow/ocp/time_freezing.h"

namespace bflow::examples {

/** The time-freezing PSS of the monoped with the speed of time, in the three regions (Heaviside
    step formulation) or the eight base sets (Stewart). */
template <TimeFreezingRegions kRegions>
using MonopedTimeFreezing = TimeFreezing<Monoped, kRegions, true>;

template <TimeFreezingRegions kRegions>
ControlledPiecewiseSmoothAsStep<MonopedTimeFreezing<kRegions>> monoped_model() {
  const MonopedTimeFreezing<kRegions> tf(Monoped{}, {0.8, 200.0});
  return {tf, MonopedTimeFreezing<kRegions>::sign_matrix()};
}

struct MonopedTask {
  static constexpr double kHorizon = 3.0;
  static constexpr double kTargetX = 3.0;
  static constexpr double kHeight = 0.4;
  double s_min = 1.0, s_max = 25.0;  ///< the speed of time's bounds

  /** The reference: (q, v, clock) at time t. */
  static Eigen::VectorXd reference(double t) {
    const double pi = 3.14159265358979323846;
    Eigen::VectorXd x = Eigen::VectorXd::Zero(9);
    x[0] = kTargetX * t / kHorizon;
    x[1] = 0.5 - 0.1 * std::cos(4.0 * pi * t / kHorizon);
    x[8] = t;
    return x;
  }

  OcpProblem problem() const {
    const double inf = std::numeric_limits<double>::infinity();
    const double pi = 3.14159265358979323846;
    OcpProblem p;
    p.x0 = Eigen::VectorXd::Zero(9);
    p.x0[1] = kHeight;
    p.horizon = kHorizon;
    p.clock_state = 8;
    p.x_lower.resize(9);
    p.x_upper.resize(9);
    p.x_lower << -0.5, 0.0, -pi, -pi, -100, -100, -100, -100, -inf;
    p.x_upper << kTargetX + 0.5, 10.0, pi, pi, 100, 100, 100, 100, inf;
    p.u_lower = Eigen::Vector3d(-100.0, -100.0, s_min);
    p.u_upper = Eigen::Vector3d(100.0, 100.0, s_max);
    p.track_Q.resize(9);
    p.track_Q << 1.0, 1.0, 10.0, 1.0, 1e-6, 1e-6, 1e-6, 1e-6, 0.0;
    p.track_R = Eigen::Vector3d(0.01, 0.01, 0.0);
    p.u_ref = Eigen::Vector3d(0.0, 0.0, 1.0);
    p.track_Q_terminal.resize(9);
    p.track_Q_terminal << 1e3, 1e3, 1e3, 1e3, 10.0, 10.0, 10.0, 10.0, 0.0;
    p.x_ref = reference;
    p.guess = OcpGuess::kReference;
    p.guess_trajectory = reference;
    p.guess_u = Eigen::Vector3d(0.0, 0.0, 1.0);
    return p;
  }
};

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_MONOPED_OCP_H_

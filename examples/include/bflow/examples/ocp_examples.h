// Two optimal control problems of nonsmooth systems with exact solutions (ocp.h, docs/ocp.md).
//
// Turbo car (time-optimal). q' = v, v' = u for v < 10 and 3 u for v > 10 (c = v - 10, step
// inclusion v' = (1 + 2a) u), |u| <= 5, |v| <= 20, from (q, v) = (0, 0) to q = 200, v = 0 in
// least time. The optimum accelerates at u = 5 until v = 20 (v = 10 at t = 2, v' = 15 after:
// v = 20 at t = 8/3, 20 m covered), cruises at the speed limit (u = 0) for 160 m (8 s) and brakes
// symmetrically: T* = 2 (2 + 2/3) + 8 = 40/3. The switching function crosses zero at t = 2 and
// t = T* - 2 = 34/3; the control switches at 8/3 and 32/3, which are stage boundaries exactly
// when N is a multiple of 5 (stage length T* / N = 8 / (3 (N / 5))).
//
// Braking block (an optimum that slides). A block moves at speed v against Coulomb friction
// (mu g = 1) under a force u: v' in u - sign(v), p' = v, c = v (v' = u + 1 - 2a), from
// (p, v) = (0, 2), T = 3, minimising int_0^T v^2 + u^2 dt. While v > 0 the problem is linear-
// quadratic with a free arrival time t_s at v = 0, after which the block sticks at no cost
// (sliding on c = 0 with u = 0, a = 1/2); the Hamiltonian vanishes along the first arc
// (v^2 - u^2 + 2u = 0 with the costate -2u), so u = 1 - sqrt(1 + v^2) and v' = -sqrt(1 + v^2):
//   v(t) = sinh(asinh 2 - t),  u(t) = 1 - cosh(asinh 2 - t)   for t <= t_s = asinh 2,
//   v = u = 0 after (the sliding arc), p(T) = sqrt 5 - 1,
//   J* = 2 int_0^2 (sqrt(1 + v^2) - 1) dv = 2 sqrt 5 + asinh 2 - 4 = 1.91577...
#ifndef BFLOW_EXAMPLES_OCP_EXAMPLES_H_
#define BFLOW_EXAMPLES_OCP_EXAMPLES_H_

#include <cmath>

#include <Eigen/Core>

#include "bflow/ocp/ocp.h"

namespace bflow::examples {

struct TurboCar {
  static constexpr int kStates = 2, kControls = 1, kSwitches = 1;
  static constexpr int kTerminal = 2;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[1] - T(10.0);
  }
  template <typename T>
  void field(const T* x, const T* u, const T* a, T* xdot) const {
    xdot[0] = x[1];
    xdot[1] = (T(1.0) + T(2.0) * a[0]) * u[0];
  }
  template <typename T>
  void terminal(const T* x, T* g) const {
    g[0] = x[0] - T(200.0);
    g[1] = x[1];
  }

  static constexpr double kOptimalTime = 40.0 / 3.0;
  /** Times where v crosses 10 on the optimal trajectory. */
  static constexpr double kSwitchTimes[2] = {2.0, 34.0 / 3.0};
  /** Times where the optimal control switches (5 -> 0 -> -5). */
  static constexpr double kControlSwitchTimes[2] = {8.0 / 3.0, 32.0 / 3.0};

  /** The problem above; the horizon 15 is the initial guess of T. */
  static OcpProblem problem() {
    OcpProblem p;
    p.x0 = Eigen::Vector2d(0.0, 0.0);
    p.horizon = 15.0;
    p.time_optimal = true;
    p.x_lower = Eigen::Vector2d(-1e19, -20.0);
    p.x_upper = Eigen::Vector2d(1e19, 20.0);
    p.u_lower = Eigen::VectorXd::Constant(1, -5.0);
    p.u_upper = Eigen::VectorXd::Constant(1, 5.0);
    return p;
  }
};

struct BrakingBlock {
  static constexpr int kStates = 2, kControls = 1, kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[1];
  }
  template <typename T>
  void field(const T* x, const T* u, const T* a, T* xdot) const {
    xdot[0] = x[1];
    xdot[1] = u[0] + T(1.0) - T(2.0) * a[0];  // u - sign(v), sign(v) = 2a - 1
  }
  template <typename T>
  T lagrange(const T* x, const T* u) const {
    return x[1] * x[1] + u[0] * u[0];
  }

  static double optimal_cost() { return 2.0 * std::sqrt(5.0) + std::asinh(2.0) - 4.0; }
  /** When the block comes to rest (and the sliding arc begins). */
  static double stop_time() { return std::asinh(2.0); }
  static double final_position() { return std::sqrt(5.0) - 1.0; }
  static double speed(double t) { return t < stop_time() ? std::sinh(stop_time() - t) : 0.0; }
  static double force(double t) { return t < stop_time() ? 1.0 - std::cosh(stop_time() - t) : 0.0; }

  static OcpProblem problem() {
    OcpProblem p;
    p.x0 = Eigen::Vector2d(0.0, 2.0);
    p.horizon = 3.0;
    return p;
  }
};

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_OCP_EXAMPLES_H_

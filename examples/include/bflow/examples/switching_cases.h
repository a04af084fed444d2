// The four switching cases of [F] Example 3 as step inclusions x' in f(x, a), a in gamma(x),
// with sign(x) in 2a - 1, and their exact solutions. Time-dependent fields carry a clock state
// tau' = 1 (x = (x, tau)).
//
//   crossing       x' in 2 - sign(x)            x(0) = -1:  x' = 3 until x = 0 at t = 1/3, then
//                                                           x' = 1: x(t) = t - 1/3
//   sliding-enter  x' in -sign(x) + 0.2 sin 5t  x(0) = 0.5: x(t) = 0.54 - t - 0.04 cos 5t until
//                                                           it reaches 0 at t_s (a root, 0.5 <
//                                                           t_s < 0.6), then slides, x = 0
//   sliding-leave  x' in -sign(x) + t           x(0) = 0:   slides (x = 0, a = (1 + t) / 2) until
//                                                           a = 1 at t = 1, then x = (t - 1)^2 / 2
//   spontaneous    x' in sign(x)                x(0) = 0:   x = 0 (a = 1/2) is a solution, and so
//   is
//                                                           leaving at any time; FESD returns
//                                                           x = 0 (see docs/fesd.md)
//
// Each case has T = 1 except sliding-leave (T = 2).
#ifndef BFLOW_EXAMPLES_SWITCHING_CASES_H_
#define BFLOW_EXAMPLES_SWITCHING_CASES_H_

#include <cmath>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/errors.h"

namespace bflow::examples {

struct CrossingCase {
  static constexpr int kStates = 1;
  static constexpr int kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0];
  }
  template <typename T>
  void field(const T*, const T* a, T* xdot) const {
    xdot[0] = 3.0 - 2.0 * a[0];  // 2 - sign(x), sign(x) = 2a - 1
  }
};

struct SlidingEnterCase {
  static constexpr int kStates = 2;  // (x, tau)
  static constexpr int kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0];
  }
  template <typename T>
  void field(const T* x, const T* a, T* xdot) const {
    using std::sin;
    xdot[0] = 1.0 - 2.0 * a[0] + 0.2 * sin(5.0 * x[1]);
    xdot[1] = T(1.0);
  }
};

struct SlidingLeaveCase {
  static constexpr int kStates = 2;  // (x, tau)
  static constexpr int kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0];
  }
  template <typename T>
  void field(const T* x, const T* a, T* xdot) const {
    xdot[0] = 1.0 - 2.0 * a[0] + x[1];
    xdot[1] = T(1.0);
  }
};

struct SpontaneousCase {
  static constexpr int kStates = 1;
  static constexpr int kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0];
  }
  template <typename T>
  void field(const T*, const T* a, T* xdot) const {
    xdot[0] = 2.0 * a[0] - 1.0;
  }
};

/** The exact solution of one case: initial state, horizon, switch times and x(T). */
struct SwitchingCaseSolution {
  Eigen::VectorXd x0;
  double t_end = 1.0;
  std::vector<double> switch_times;
  Eigen::VectorXd x_end;
};

/** When sliding-enter reaches x = 0: the root of 0.54 - t - 0.04 cos 5t in (0.5, 0.6), by Newton
    from 0.55 to machine precision (the derivative -1 + 0.2 sin 5t stays below -0.8). */
inline double sliding_enter_time() {
  double t = 0.55;
  for (int k = 0; k < 50; ++k) {
    const double g = 0.54 - t - 0.04 * std::cos(5.0 * t);
    const double dg = -1.0 + 0.2 * std::sin(5.0 * t);
    const double next = t - g / dg;
    if (next == t) break;
    t = next;
  }
  return t;
}

/** "crossing", "sliding-enter", "sliding-leave" or "spontaneous".
    @throws InvalidArgument for another name, listing the four. */
inline SwitchingCaseSolution exact_switching_case(const std::string& name) {
  SwitchingCaseSolution s;
  if (name == "crossing") {
    s.x0 = Eigen::VectorXd::Constant(1, -1.0);
    s.switch_times = {1.0 / 3.0};
    s.x_end = Eigen::VectorXd::Constant(1, 1.0 - 1.0 / 3.0);
  } else if (name == "sliding-enter") {
    s.x0 = Eigen::Vector2d(0.5, 0.0);
    s.switch_times = {sliding_enter_time()};
    s.x_end = Eigen::Vector2d(0.0, 1.0);
  } else if (name == "sliding-leave") {
    s.x0 = Eigen::Vector2d(0.0, 0.0);
    s.t_end = 2.0;
    s.switch_times = {1.0};
    s.x_end = Eigen::Vector2d(0.5, 2.0);
  } else if (name == "spontaneous") {
    s.x0 = Eigen::VectorXd::Zero(1);
    s.x_end = Eigen::VectorXd::Zero(1);
  } else {
    throw InvalidArgument("unknown switching case \"" + name +
                          "\": use crossing, sliding-enter, sliding-leave or spontaneous");
  }
  return s;
}

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_SWITCHING_CASES_H_

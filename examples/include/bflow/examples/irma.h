// IRMA, the five-gene regulatory network of [F] Section 7.1, as a step inclusion
//
//   x1' = -0.05 x1 + 1.1e-4 + 9e-4 a6
//   x2' = -0.04 x2 + 3e-4 + 0.15 a1 (1 - (1 - u) a7)
//   x3' = -0.05 x3 + 6e-4 + 0.018 a3
//   x4' = -0.02 x4 + 5e-4 a2 + 0.03 a2 (1 - a5)
//   x5' = -0.6 x5 + 7.5e-4 + 0.015 a4,          a_k in gamma(c_k(x)),
//
//   c(x) = (x1 - 0.01, x2 - 0.01, x2 - 0.06, x2 - 0.08, x3 - 0.035, x4 - 0.04, x5 - 0.01),
//
// with u = 1 and x(0) = (0.011, 0.09, 0.04, 0.05, 0.015) (the printed (50b) and (50d) have
// typos; these are the corrected equations). Time is in minutes.
//
// No rate depends on a step of its own variable (x2's thresholds steer x3, x4, x5, and so on),
// so every crossing is transversal and nothing slides: with the steps fixed, each x_i relaxes
// exponentially to r_i / k_i, and the exact solution is a chain of exponentials whose switch
// times are logarithms (exact_irma). Seen through bflow::EventDrivenView (fesd.h: surface j is
// c_j, side + is a_j = 1) the same system runs on the event-driven engine, so both engines meet
// on it.
#ifndef BFLOW_EXAMPLES_IRMA_H_
#define BFLOW_EXAMPLES_IRMA_H_

#include <array>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/errors.h"

namespace bflow::examples {

struct Irma {
  static constexpr int kStates = 5;
  static constexpr int kSwitches = 7;
  double u = 1.0;

  static constexpr std::array<double, kStates> kDecay = {0.05, 0.04, 0.05, 0.02, 0.6};
  static constexpr std::array<int, kSwitches> kVariable = {0, 1, 1, 1, 2, 3, 4};
  static constexpr std::array<double, kSwitches> kThreshold = {0.01,  0.01, 0.06, 0.08,
                                                               0.035, 0.04, 0.01};

  static Eigen::Matrix<double, kStates, 1> initial_state() {
    return (Eigen::Matrix<double, kStates, 1>() << 0.011, 0.09, 0.04, 0.05, 0.015).finished();
  }

  template <typename T>
  void switching(const T* x, T* c) const {
    for (int j = 0; j < kSwitches; ++j) c[j] = x[kVariable[j]] - kThreshold[j];
  }

  /** f(x, a) with the selections a_k in [0, 1]. */
  template <typename T>
  void field(const T* x, const T* a, T* xdot) const {
    xdot[0] = -0.05 * x[0] + 1.1e-4 + 9e-4 * a[5];
    xdot[1] = -0.04 * x[1] + 3e-4 + 0.15 * a[0] * (1.0 - (1.0 - u) * a[6]);
    xdot[2] = -0.05 * x[2] + 6e-4 + 0.018 * a[2];
    xdot[3] = -0.02 * x[3] + 5e-4 * a[1] + 0.03 * a[1] * (1.0 - a[4]);
    xdot[4] = -0.6 * x[4] + 7.5e-4 + 0.015 * a[3];
  }

  /** The constant part r(a) of x' = -k x + r(a), for 0/1 selections. */
  std::array<double, kStates> rates(const std::array<double, kSwitches>& a) const {
    const double zero[kStates] = {0, 0, 0, 0, 0};
    double xdot[kStates];
    field(zero, a.data(), xdot);
    return {xdot[0], xdot[1], xdot[2], xdot[3], xdot[4]};
  }
};

struct IrmaSwitch {
  double t = 0.0;
  int surface = 0;      ///< j: c_j crossed zero
  bool upward = false;  ///< c_j went from - to +
};

struct IrmaSolution {
  Eigen::Matrix<double, Irma::kStates, 1> x;
  std::vector<IrmaSwitch> switches;
};

/** The exact solution of IRMA on [0, t_end] from x0: exponentials between switches, each
    switch time a logarithm. @throws InvalidArgument if x0 lies on a threshold or t_end < 0. */
inline IrmaSolution exact_irma(const Irma& irma, Eigen::Matrix<double, Irma::kStates, 1> x0,
                               double t_end) {
  if (!(t_end >= 0.0) || !std::isfinite(t_end)) {
    throw InvalidArgument("exact_irma: t_end must be finite and >= 0, got " + format_number(t_end));
  }
  std::array<double, Irma::kSwitches> a{};
  for (int j = 0; j < Irma::kSwitches; ++j) {
    const double c = x0[Irma::kVariable[j]] - Irma::kThreshold[j];
    if (c == 0.0) {
      throw InvalidArgument("exact_irma: x0 lies on threshold c_" + std::to_string(j) + " = 0");
    }
    a[j] = c > 0 ? 1.0 : 0.0;
  }
  IrmaSolution out;
  double t = 0.0;
  Eigen::Matrix<double, Irma::kStates, 1> x = x0;
  while (true) {
    const std::array<double, Irma::kStates> r = irma.rates(a);
    // Earliest crossing: x_v(s) = e + (x_v - e) exp(-k s) meets the threshold.
    double first = std::numeric_limits<double>::infinity();
    int which = -1;
    for (int j = 0; j < Irma::kSwitches; ++j) {
      const int v = Irma::kVariable[j];
      const double k = Irma::kDecay[v];
      const double e = r[v] / k;
      const double ratio = (Irma::kThreshold[j] - e) / (x[v] - e);
      if (ratio > 0.0 && ratio < 1.0) {
        const double s = -std::log(ratio) / k;
        if (s < first) {
          first = s;
          which = j;
        }
      }
    }
    const double step = std::min(first, t_end - t);
    for (int i = 0; i < Irma::kStates; ++i) {
      const double e = r[i] / Irma::kDecay[i];
      x[i] = e + (x[i] - e) * std::exp(-Irma::kDecay[i] * step);
    }
    if (which < 0 || t + first >= t_end) {
      out.x = x;
      return out;
    }
    t += first;
    x[Irma::kVariable[which]] = Irma::kThreshold[which];  // exactly on the surface
    out.switches.push_back({t, which, a[which] == 0.0});
    a[which] = 1.0 - a[which];
  }
}

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_IRMA_H_

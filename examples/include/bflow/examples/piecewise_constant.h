// The piecewise-constant vector field of [B] Section 3.1, (3.1):
//
//   xdot = F(x) = 1 + Delta(sign(x)),   h(x) = x  (d surfaces, the coordinate planes).
//
// Every component of every Delta(b) must exceed -1, so each surface is crossed from - to +.
// The trajectory through rho = 0 meets all d surfaces at once; from rho- = -F_-(0)/2 it reaches
// rho+ = F_+(0)/2 in unit time. With Delta(b) = -delta b (|delta| < 1) the B-derivative is
// linear, B = (1 - delta)/(1 + delta) I ([B] (3.2)); in general it has up to d! pieces.
#ifndef BFLOW_EXAMPLES_PIECEWISE_CONSTANT_H_
#define BFLOW_EXAMPLES_PIECEWISE_CONSTANT_H_

#include <cstdint>
#include <random>
#include <string>
#include <utility>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/model.h"
#include "bflow/core/signs.h"

namespace bflow::examples {

class PiecewiseConstantField {
 public:
  static constexpr int kStates = kDynamic;
  static constexpr int kSurfaces = kDynamic;

  /** Delta as a d x 2^d table, column b.bits() is Delta(b).
      @throws InvalidArgument unless d in [1, 16] and every entry is finite and > -1. */
  explicit PiecewiseConstantField(Eigen::MatrixXd delta) : delta_(std::move(delta)) {
    const auto d = delta_.rows();
    if (d < 1 || d > 16 || delta_.cols() != (Eigen::Index{1} << d)) {
      throw InvalidArgument(
          "PiecewiseConstantField: Delta must be d x 2^d with 1 <= d <= 16, got " +
          std::to_string(delta_.rows()) + " x " + std::to_string(delta_.cols()));
    }
    for (Eigen::Index w = 0; w < delta_.cols(); ++w) {
      if (!delta_.col(w).allFinite() || !(delta_.col(w).minCoeff() > -1.0)) {
        throw InvalidArgument("PiecewiseConstantField: every component of Delta(" +
                              Signs(static_cast<int>(d), static_cast<std::uint64_t>(w)).str() +
                              ") must be finite and > -1, got " + format_vector(delta_.col(w)));
      }
    }
  }

  /** The linear case Delta(b) = -delta b of [B] (3.2). */
  static PiecewiseConstantField linear(int d, double delta) {
    Eigen::MatrixXd table(d, Eigen::Index{1} << d);
    for (Eigen::Index w = 0; w < table.cols(); ++w) {
      for (int i = 0; i < d; ++i) table(i, w) = ((w >> i) & 1) ? -delta : delta;
    }
    return PiecewiseConstantField(std::move(table));
  }

  /** A random Delta for tests and `bflow flow --scene pwconst --param seed=S`: every entry
      uniform in (-0.7, 1.5), drawn column by column (column b.bits() is Delta(b)) from
      std::mt19937_64 seeded with `seed`. The raw 64-bit draws are mapped to (0, 1) by hand,
      not by std::uniform_real_distribution (whose algorithm the standard leaves open), so a
      seed gives the same table with every standard library.
      @throws InvalidArgument unless d in [1, 16]. */
  static PiecewiseConstantField random(int d, std::uint64_t seed) {
    if (d < 1 || d > 16) {
      throw InvalidArgument("PiecewiseConstantField::random: d must be in [1, 16], got " +
                            std::to_string(d));
    }
    std::mt19937_64 rng(seed);
    Eigen::MatrixXd table(d, Eigen::Index{1} << d);
    for (Eigen::Index w = 0; w < table.cols(); ++w) {
      for (int i = 0; i < d; ++i) {
        // The top 53 bits, centred in their interval: u in (0, 1).
        const double u = (static_cast<double>(rng() >> 11) + 0.5) * 0x1.0p-53;
        table(i, w) = -0.7 + 2.2 * u;
      }
    }
    return PiecewiseConstantField(std::move(table));
  }

  /** The non-linear two-dimensional case shown by `bflow demo --scene pwconst`. */
  static PiecewiseConstantField planar_demo() {
    Eigen::MatrixXd table(2, 4);
    table.col(0) << 0.0, 0.0;    // "--"
    table.col(1) << -0.5, 0.6;   // "+-"
    table.col(2) << 0.7, -0.4;   // "-+"
    table.col(3) << -0.3, -0.3;  // "++"
    return PiecewiseConstantField(std::move(table));
  }

  int states() const { return static_cast<int>(delta_.rows()); }
  int surfaces() const { return static_cast<int>(delta_.rows()); }
  const Eigen::MatrixXd& delta() const { return delta_; }

  template <typename T>
  void field(const T* /*x*/, Signs b, T* xdot) const {
    const auto column = static_cast<Eigen::Index>(b.bits());
    for (Eigen::Index i = 0; i < delta_.rows(); ++i) xdot[i] = T(1.0 + delta_(i, column));
  }

  template <typename T>
  void surfaces(const T* x, T* h) const {
    for (Eigen::Index i = 0; i < delta_.rows(); ++i) h[i] = x[i];
  }

  /** The exact time-t flow from x: straight lines between crossings of the coordinate planes,
      sign(0) = +1. Every velocity component is positive, so each plane is crossed at most once
      and there are at most d + 1 segments. An independent reference for B: the flow is
      piecewise affine, so its one-sided differences equal B up to rounding. */
  Eigen::VectorXd flow(Eigen::VectorXd x, double t) const {
    const int d = states();
    Eigen::VectorXd velocity(d);
    for (int segment = 0; segment <= d && t > 0.0; ++segment) {
      std::uint64_t bits = 0;
      for (int i = 0; i < d; ++i) {
        if (x[i] >= 0.0) bits |= std::uint64_t{1} << i;
      }
      field(x.data(), Signs(d, bits), velocity.data());
      double step = t;
      int crossed = -1;
      for (int i = 0; i < d; ++i) {
        if (x[i] < 0.0 && -x[i] / velocity[i] < step) {
          step = -x[i] / velocity[i];
          crossed = i;
        }
      }
      x += step * velocity;
      t -= step;
      if (crossed >= 0) x[crossed] = 0.0;  // on the plane, hence on its + side
    }
    return x;
  }

  /** F_b(0) = 1 + Delta(b) for every word: the limits table at rho = 0. */
  Eigen::MatrixXd limits() const { return (delta_.array() + 1.0).matrix(); }

 private:
  Eigen::MatrixXd delta_;
};

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_PIECEWISE_CONSTANT_H_

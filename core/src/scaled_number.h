// A double with its own binary exponent, for the few quantities of the jump map that can leave
// the range of a double while the answer does not: crossing times of fields near 1e308,
// eta . F with huge or tiny normals, products of such numbers.
//
// value = m * 2^e with 0.5 <= |m| < 1, or m = 0. Products and quotients are exact up to one
// rounding of m; a sum rounds once, like a double sum. Only to_double() can overflow (to
// +-inf) or underflow (gradually, to subnormals and 0), and only when the true value does.
#ifndef BFLOW_CORE_SRC_SCALED_NUMBER_H_
#define BFLOW_CORE_SRC_SCALED_NUMBER_H_

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Core>

namespace bflow::internal {

class ScaledNumber {
 public:
  ScaledNumber() = default;
  /** From a finite double, exactly. */
  explicit ScaledNumber(double x) { m_ = std::frexp(x, &e_); }
  /** m * 2^e, exactly (renormalised). */
  static ScaledNumber from_parts(double m, long e) {
    ScaledNumber s(m);
    s.e_ = s.m_ == 0.0 ? 0 : static_cast<int>(std::clamp<long>(e + s.e_, -kLimit, kLimit));
    return s;
  }

  double mantissa() const { return m_; }
  int exponent() const { return e_; }
  bool is_zero() const { return m_ == 0.0; }
  int sign() const { return (m_ > 0.0) - (m_ < 0.0); }

  /** The nearest double: +-inf above the range, subnormal or 0 below it. */
  double to_double() const { return std::ldexp(m_, e_); }

  friend ScaledNumber operator-(const ScaledNumber& a) {
    ScaledNumber s = a;
    s.m_ = -s.m_;
    return s;
  }
  friend ScaledNumber operator*(const ScaledNumber& a, const ScaledNumber& b) {
    return from_parts(a.m_ * b.m_, static_cast<long>(a.e_) + b.e_);
  }
  /** b must not be zero. */
  friend ScaledNumber operator/(const ScaledNumber& a, const ScaledNumber& b) {
    return from_parts(a.m_ / b.m_, static_cast<long>(a.e_) - b.e_);
  }
  friend ScaledNumber operator+(const ScaledNumber& a, const ScaledNumber& b) {
    if (a.is_zero()) return b;
    if (b.is_zero()) return a;
    const ScaledNumber& big = a.e_ >= b.e_ ? a : b;
    const ScaledNumber& small = a.e_ >= b.e_ ? b : a;
    const long shift = static_cast<long>(big.e_) - small.e_;
    if (shift > 1100) return big;  // below half an ulp of big, even as a subnormal
    return from_parts(big.m_ + std::ldexp(small.m_, static_cast<int>(-shift)), big.e_);
  }
  friend ScaledNumber operator-(const ScaledNumber& a, const ScaledNumber& b) { return a + (-b); }
  friend bool operator<(const ScaledNumber& a, const ScaledNumber& b) { return (a - b).sign() < 0; }

 private:
  // Exponents stay far inside int; the clamp only guards against pathological chains.
  static constexpr long kLimit = 1L << 20;
  double m_ = 0.0;
  int e_ = 0;
};

/** A row of a column-major matrix, bound without a copy (rows have an inner stride). */
using RowRef = Eigen::Ref<const Eigen::RowVectorXd, 0, Eigen::InnerStride<>>;

/** The binary exponent e with max |v_i| in [2^(e-1), 2^e) (0 for a zero vector). */
inline int max_exponent(const Eigen::Ref<const Eigen::VectorXd>& v) {
  int e = 0;
  std::frexp(v.size() == 0 ? 0.0 : v.cwiseAbs().maxCoeff(), &e);
  return e;
}

/** a . v without overflow or harmful underflow: v is scaled by a power of two so that its
    largest entry is near 1, the dot product taken, and the scale put back in the exponent.
    Entries of v more than 2^1074 below its largest are lost, far below the rounding of any
    dot product. */
inline ScaledNumber scaled_dot(const RowRef& a, const Eigen::Ref<const Eigen::VectorXd>& v) {
  const int e = max_exponent(v);
  double sum = 0.0;
  for (Eigen::Index i = 0; i < v.size(); ++i) sum += a[i] * std::ldexp(v[i], -e);
  return ScaledNumber::from_parts(sum, e);
}

/** Scales a nonzero finite row to unit length: first by its largest entry (exact up to one
    rounding), then by the norm of the result, which lies in [1, sqrt(size)]. Unlike a plain or
    a single-division normalisation it neither overflows nor underflows. */
template <typename Row>
void normalize_row(Row&& row) {
  row /= row.cwiseAbs().maxCoeff();
  row /= row.norm();
}

/** Scales a nonzero finite row by a power of two, exactly, when its largest entry lies
    outside 2^-300 ... 2^300 (then the largest becomes [0.5, 1)); returns the exponent s with
    row_before = row_after * 2^s (0 when the row is left alone). A power of two changes no digit,
    so the surface and B stay exactly the same. */
template <typename Row>
int rescale_row(Row&& row) {
  int s = 0;
  const double largest = row.cwiseAbs().maxCoeff();
  if (largest > 0x1p300 || largest < 0x1p-300) {
    std::frexp(largest, &s);
    for (Eigen::Index i = 0; i < row.size(); ++i) row[i] = std::ldexp(row[i], -s);
  }
  return s;
}

/** True when x is a double whose relative precision is full (finite, normal or zero). */
inline bool full_precision(double x) {
  return x == 0.0 || (std::isfinite(x) && std::abs(x) >= std::numeric_limits<double>::min());
}

}  // namespace bflow::internal

#endif  // BFLOW_CORE_SRC_SCALED_NUMBER_H_

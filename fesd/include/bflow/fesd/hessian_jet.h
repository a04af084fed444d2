// HessianJet: a scalar that carries its value, its gradient and its Hessian in up to kLanes
// directions, for the exact second derivatives of FESD's and an OCP's Lagrangian.
//
// Worked example: with x = HessianJet::variable(2.0, 0), y = HessianJet::variable(3.0, 1),
//   HessianJet f = x * x * y;
// gives f.a = 12, f.v = (12, 4) and the lower triangle of the Hessian f.h = (6; 4, 0), stored
// packed by rows: h[i (i + 1) / 2 + j] = d2f / dx_i dx_j for j <= i.
//
// Why not nested first-order AD: forward-over-forward (Eigen's AutoDiffScalar nested in itself,
// or Jets of Jets) computes the full n x n block, both triangles, and every product of two
// nested scalars runs (n + 1)^2 inner products whatever the operands; this type keeps the lower
// triangle only (n (n + 1) / 2 entries) and tracks how many directions each value depends on
// (`n`: the first n lanes), so a constant costs what a double costs and a value that depends on
// the first few lanes only pays for those. The lanes of a value beyond its n are zero and are
// never read. bench/fesd_hessian_benchmark.cc measures it against nested AutoDiffScalar.
//
// Models written as templates on T with T(c) constants and mixed arithmetic with double compile
// with it. Comparisons look at values only: a model branches on values, never on derivatives,
// and the derivative is that of the branch taken.
#ifndef BFLOW_FESD_HESSIAN_JET_H_
#define BFLOW_FESD_HESSIAN_JET_H_

#include <algorithm>
#include <cmath>

namespace bflow {
// The type and its functions live in their own namespace, found by argument-dependent lookup, so
// that an unqualified sin(double) in namespace bflow still means std::sin.
namespace hessian_jet {

class HessianJet;

/** What a traced evaluation records (hessian_tape.h): a HessianJet whose `tape` is set is node
    `node` of that tape's expression graph, and every operation on it adds the operation's node
    (its value is computed as always, its lanes are not: a traced value has none). Constants
    (tape null) enter as constant nodes. Comparisons and the functions that branch on a value
    (abs, fmax, fmin, floor, ceil, isfinite, ...) record the outcome as a guard, which the
    program checks before its result is used. */
class HessianTape {
 public:
  enum class Op : unsigned char {
    kAdd,
    kSub,
    kMul,
    kDiv,
    kNeg,
    kSqrt,
    kSin,
    kCos,
    kTan,
    kExp,
    kLog,
    kLog1p,
    kSinh,
    kCosh,
    kTanh,
    kAtan,
    kCbrt,
    kAsin,
    kAcos,
    kExpm1,
    kLog10,
    kLog2,
    kPowC,   ///< x^c, c a constant
    kCPow,   ///< c^x, c > 0 a constant
    kAtan2,  ///< atan2(x, y)
  };
  enum class Test : unsigned char {
    kLess,
    kGreater,
    kLessEq,
    kGreaterEq,
    kEqual,
    kNotEqual,  ///< x op y
    kSignBit,   ///< signbit(x)
    kFinite,
    kNan,
    kInf,  ///< isfinite(x), ...
    kFloor,
    kCeil,  ///< floor(x) == y (ceil), y the constant recorded
  };
  /** The node of a constant. */
  virtual int constant(double value) = 0;
  /** The node of op(x) (c: kPowC's exponent, kCPow's base) and of op(x, y). */
  virtual int unary(Op op, int x, double c) = 0;
  virtual int binary(Op op, int x, int y) = 0;
  /** A branch on values: test(x, y) was `outcome` (y = -1 for the tests of one value). */
  virtual void guard(Test test, int x, int y, bool outcome) = 0;

 protected:
  ~HessianTape() = default;
};

class HessianJet {
 public:
  static constexpr int kLanes = 24;
  static constexpr int kEntries = kLanes * (kLanes + 1) / 2;
  /** Position of d2 / dx_i dx_j (j <= i) in h. */
  static constexpr int at(int i, int j) { return i * (i + 1) / 2 + j; }

  double a = 0.0;               ///< value
  int n = 0;                    ///< lanes this value depends on: v[0..n), h[0..at(n, 0))
  HessianTape* tape = nullptr;  ///< a traced value's tape (hessian_tape.h), else null
  int node = -1;                ///< a traced value's node in `tape`
  double v[kLanes];
  double h[kEntries];

  HessianJet() = default;
  explicit HessianJet(double value) : a(value) {}
  /** The independent variable of lane `lane` at `value` (gradient e_lane, Hessian 0). */
  static HessianJet variable(double value, int lane) {
    HessianJet x(value);
    x.n = lane + 1;
    for (int i = 0; i < x.n; ++i) x.v[i] = 0.0;
    for (int k = 0; k < at(x.n, 0); ++k) x.h[k] = 0.0;
    x.v[lane] = 1.0;
    return x;
  }
  HessianJet(const HessianJet& o) : a(o.a), n(o.n), tape(o.tape), node(o.node) { copy_lanes(o); }
  HessianJet& operator=(const HessianJet& o) {
    a = o.a;
    n = o.n;
    tape = o.tape;
    node = o.node;
    copy_lanes(o);
    return *this;
  }
  /** Node `node` of `tape` at `value` (no lanes). */
  static HessianJet traced(HessianTape* tape, int node, double value) {
    HessianJet r(value);
    r.tape = tape;
    r.node = node;
    return r;
  }
  /** The tape of either operand (null: neither is traced). */
  static HessianTape* tape_of(const HessianJet& x, const HessianJet& y) {
    return x.tape != nullptr ? x.tape : y.tape;
  }
  /** x's node in `t` (a constant's node for an untraced x). */
  static int node_in(HessianTape* t, const HessianJet& x) {
    return x.tape != nullptr ? x.node : t->constant(x.a);
  }
  static HessianJet record(HessianTape::Op op, const HessianJet& x, const HessianJet& y,
                           double value) {
    HessianTape* t = tape_of(x, y);
    return traced(t, t->binary(op, node_in(t, x), node_in(t, y)), value);
  }
  static HessianJet record(HessianTape::Op op, const HessianJet& x, double c, double value) {
    return traced(x.tape, x.tape->unary(op, x.node, c), value);
  }
  static void guard(HessianTape::Test test, const HessianJet& x, const HessianJet& y,
                    bool outcome) {
    HessianTape* t = tape_of(x, y);
    if (t != nullptr) t->guard(test, node_in(t, x), node_in(t, y), outcome);
  }
  static void guard(HessianTape::Test test, const HessianJet& x, bool outcome) {
    if (x.tape != nullptr) x.tape->guard(test, x.node, -1, outcome);
  }
  /** d2 / dx_i dx_j of this value (0 beyond its lanes). */
  double hessian(int i, int j) const {
    if (i < j) std::swap(i, j);
    return i < n ? h[at(i, j)] : 0.0;
  }
  double gradient(int i) const { return i < n ? v[i] : 0.0; }

  // In place, without a temporary: the same numbers as x + y and x - y (s = +-1 makes every
  // product exact), up to the sign of a zero lane.
  HessianJet& operator+=(const HessianJet& o) {
    if (tape != nullptr || o.tape != nullptr) return *this = *this + o;
    accumulate(1.0, o);
    a += o.a;
    return *this;
  }
  HessianJet& operator-=(const HessianJet& o) {
    if (tape != nullptr || o.tape != nullptr) return *this = *this - o;
    accumulate(-1.0, o);
    a -= o.a;
    return *this;
  }
  HessianJet& operator*=(const HessianJet& o) { return *this = *this * o; }
  HessianJet& operator/=(const HessianJet& o) { return *this = *this / o; }
  HessianJet& operator+=(double s) {
    if (tape != nullptr) return *this = *this + s;
    a += s;
    return *this;
  }
  HessianJet& operator-=(double s) {
    if (tape != nullptr) return *this = *this - s;
    a -= s;
    return *this;
  }
  HessianJet& operator*=(double s) {
    if (tape != nullptr) return *this = *this * s;
    scale(s);
    return *this;
  }
  HessianJet& operator/=(double s) {
    if (tape != nullptr) return *this = *this / s;
    scale(1.0 / s);
    return *this;
  }

  friend HessianJet operator+(const HessianJet& x) { return x; }
  friend HessianJet operator-(const HessianJet& x) {
    if (x.tape != nullptr) return record(HessianTape::Op::kNeg, x, 0.0, -x.a);
    return x * -1.0;
  }

  friend HessianJet operator+(const HessianJet& x, const HessianJet& y) {
    if (x.tape != nullptr || y.tape != nullptr)
      return record(HessianTape::Op::kAdd, x, y, x.a + y.a);
    return linear(1.0, x, 1.0, y, x.a + y.a);
  }
  friend HessianJet operator-(const HessianJet& x, const HessianJet& y) {
    if (x.tape != nullptr || y.tape != nullptr)
      return record(HessianTape::Op::kSub, x, y, x.a - y.a);
    return linear(1.0, x, -1.0, y, x.a - y.a);
  }
  friend HessianJet operator+(const HessianJet& x, double s) {
    if (x.tape != nullptr) return record(HessianTape::Op::kAdd, x, HessianJet(s), x.a + s);
    HessianJet r(x);
    r.a += s;
    return r;
  }
  friend HessianJet operator+(double s, const HessianJet& x) { return x + s; }
  friend HessianJet operator-(const HessianJet& x, double s) { return x + (-s); }
  friend HessianJet operator-(double s, const HessianJet& x) {
    if (x.tape != nullptr) return record(HessianTape::Op::kSub, HessianJet(s), x, s - x.a);
    return (x * -1.0) + s;
  }

  friend HessianJet operator*(const HessianJet& x, double s) {
    if (x.tape != nullptr) return record(HessianTape::Op::kMul, x, HessianJet(s), x.a * s);
    HessianJet r;
    r.a = x.a * s;
    r.n = x.n;
    for (int i = 0; i < x.n; ++i) r.v[i] = s * x.v[i];
    const int e = at(x.n, 0);
    for (int k = 0; k < e; ++k) r.h[k] = s * x.h[k];
    return r;
  }
  friend HessianJet operator*(double s, const HessianJet& x) { return x * s; }
  friend HessianJet operator*(const HessianJet& x, const HessianJet& y) {
    if (x.tape != nullptr || y.tape != nullptr)
      return record(HessianTape::Op::kMul, x, y, x.a * y.a);
    if (y.n == 0) return x * y.a;
    if (x.n == 0) return y * x.a;
    // (xy)'' = x y'' + y x'' + x' y'^T + y' x'^T
    HessianJet r = linear(y.a, x, x.a, y, x.a * y.a);
    // x_i y_j + y_i x_j (j <= i) is nonzero only where j < min(x.n, y.n): for j >= x.n both
    // x_j and x_i are zero (i >= j), likewise for y.
    const int m = std::min(x.n, y.n);
    for (int i = 0; i < r.n; ++i) {
      const double xi = i < x.n ? x.v[i] : 0.0;
      const double yi = i < y.n ? y.v[i] : 0.0;
      double* row = r.h + at(i, 0);
      const int jm = std::min(i + 1, m);
      for (int j = 0; j < jm; ++j) row[j] += xi * y.v[j] + yi * x.v[j];
    }
    return r;
  }
  friend HessianJet operator/(const HessianJet& x, double s) {
    if (x.tape != nullptr) return record(HessianTape::Op::kDiv, x, HessianJet(s), x.a / s);
    return x * (1.0 / s);
  }
  friend HessianJet operator/(const HessianJet& x, const HessianJet& y) {
    if (x.tape != nullptr || y.tape != nullptr)
      return record(HessianTape::Op::kDiv, x, y, x.a / y.a);
    return x * reciprocal(y);
  }
  friend HessianJet operator/(double s, const HessianJet& y) {
    if (y.tape != nullptr) return record(HessianTape::Op::kDiv, HessianJet(s), y, s / y.a);
    return reciprocal(y) * s;
  }

  // Comparisons of values.
#define BFLOW_HESSIAN_JET_COMPARE(op, test)                                             \
  friend bool operator op(const HessianJet& x, const HessianJet& y) {                   \
    const bool r = x.a op y.a;                                                          \
    guard(HessianTape::Test::test, x, y, r);                                            \
    return r;                                                                           \
  }                                                                                     \
  friend bool operator op(const HessianJet& x, double s) { return x op HessianJet(s); } \
  friend bool operator op(double s, const HessianJet& y) { return HessianJet(s) op y; }
  BFLOW_HESSIAN_JET_COMPARE(<, kLess)
  BFLOW_HESSIAN_JET_COMPARE(>, kGreater)
  BFLOW_HESSIAN_JET_COMPARE(<=, kLessEq)
  BFLOW_HESSIAN_JET_COMPARE(>=, kGreaterEq)
  BFLOW_HESSIAN_JET_COMPARE(==, kEqual)
  BFLOW_HESSIAN_JET_COMPARE(!=, kNotEqual)
#undef BFLOW_HESSIAN_JET_COMPARE

  /** phi(x, y) from its value and partial derivatives at (x.a, y.a):
      v' = px vx + py vy, H' = px Hx + py Hy + pxx vx vx^T + pxy (vx vy^T + vy vx^T) + pyy vy vy^T.
   */
  static HessianJet chain2(const HessianJet& x, const HessianJet& y, double value, double px,
                           double py, double pxx, double pxy, double pyy) {
    HessianJet r = linear(px, x, py, y, value);
    for (int i = 0; i < r.n; ++i) {
      const double xi = i < x.n ? x.v[i] : 0.0;
      const double yi = i < y.n ? y.v[i] : 0.0;
      double* row = r.h + at(i, 0);
      for (int j = 0; j <= i; ++j) {
        const double xj = j < x.n ? x.v[j] : 0.0;
        const double yj = j < y.n ? y.v[j] : 0.0;
        row[j] += pxx * xi * xj + pxy * (xi * yj + yi * xj) + pyy * yi * yj;
      }
    }
    return r;
  }

  /** phi(x) from phi(x.a) = value, phi' = d1, phi'' = d2: v' = d1 v, H' = d1 H + d2 v v^T. */
  static HessianJet chain(const HessianJet& x, double value, double d1, double d2) {
    HessianJet r;
    r.a = value;
    r.n = x.n;
    for (int i = 0; i < x.n; ++i) r.v[i] = d1 * x.v[i];
    for (int i = 0; i < x.n; ++i) {
      double* row = r.h + at(i, 0);
      const double* xrow = x.h + at(i, 0);
      const double di = d2 * x.v[i];
      for (int j = 0; j <= i; ++j) row[j] = d1 * xrow[j] + di * x.v[j];
    }
    return r;
  }

 private:
  // Loops, not std::copy: GCC cannot see that n lies in [0, kLanes] and warns of memcpy bounds.
  void copy_lanes(const HessianJet& o) {
    for (int i = 0; i < o.n; ++i) v[i] = o.v[i];
    const int e = at(o.n, 0);
    for (int k = 0; k < e; ++k) h[k] = o.h[k];
  }
  // this += s o on the lanes (o's lanes beyond this one's extend it, from zeros).
  void accumulate(double s, const HessianJet& o) {
    if (o.n > n) {
      for (int i = n; i < o.n; ++i) v[i] = 0.0;
      for (int k = at(n, 0); k < at(o.n, 0); ++k) h[k] = 0.0;
      n = o.n;
    }
    for (int i = 0; i < o.n; ++i) v[i] += s * o.v[i];
    const int e = at(o.n, 0);
    for (int k = 0; k < e; ++k) h[k] += s * o.h[k];
  }
  void scale(double s) {
    a *= s;
    for (int i = 0; i < n; ++i) v[i] *= s;
    const int e = at(n, 0);
    for (int k = 0; k < e; ++k) h[k] *= s;
  }
  // s x + t y with value `value` (lanes beyond a shorter operand are its zeros).
  static HessianJet linear(double s, const HessianJet& x, double t, const HessianJet& y,
                           double value) {
    HessianJet r;
    r.a = value;
    r.n = std::max(x.n, y.n);
    const HessianJet& big = x.n >= y.n ? x : y;
    const HessianJet& small = x.n >= y.n ? y : x;
    const double sb = x.n >= y.n ? s : t;
    const double ss = x.n >= y.n ? t : s;
    for (int i = 0; i < small.n; ++i) r.v[i] = sb * big.v[i] + ss * small.v[i];
    for (int i = small.n; i < big.n; ++i) r.v[i] = sb * big.v[i];
    const int es = at(small.n, 0), eb = at(big.n, 0);
    for (int k = 0; k < es; ++k) r.h[k] = sb * big.h[k] + ss * small.h[k];
    for (int k = es; k < eb; ++k) r.h[k] = sb * big.h[k];
    return r;
  }
  static HessianJet reciprocal(const HessianJet& y) {
    const double r = 1.0 / y.a;
    return chain(y, r, -r * r, 2.0 * r * r * r);
  }
};

// Elementary functions, each with its first and second derivative at the value.
inline HessianJet sqrt(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kSqrt, x, 0.0, std::sqrt(x.a));
  const double s = std::sqrt(x.a);
  return HessianJet::chain(x, s, 0.5 / s, -0.25 / (s * x.a));
}
inline HessianJet sin(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kSin, x, 0.0, std::sin(x.a));
  const double s = std::sin(x.a), c = std::cos(x.a);
  return HessianJet::chain(x, s, c, -s);
}
inline HessianJet cos(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kCos, x, 0.0, std::cos(x.a));
  const double s = std::sin(x.a), c = std::cos(x.a);
  return HessianJet::chain(x, c, -s, -c);
}
inline HessianJet tan(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kTan, x, 0.0, std::tan(x.a));
  const double t = std::tan(x.a), d = 1.0 + t * t;
  return HessianJet::chain(x, t, d, 2.0 * t * d);
}
inline HessianJet exp(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kExp, x, 0.0, std::exp(x.a));
  const double e = std::exp(x.a);
  return HessianJet::chain(x, e, e, e);
}
inline HessianJet log(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kLog, x, 0.0, std::log(x.a));
  return HessianJet::chain(x, std::log(x.a), 1.0 / x.a, -1.0 / (x.a * x.a));
}
inline HessianJet log1p(const HessianJet& x) {
  if (x.tape != nullptr)
    return HessianJet::record(HessianTape::Op::kLog1p, x, 0.0, std::log1p(x.a));
  const double p = 1.0 + x.a;
  return HessianJet::chain(x, std::log1p(x.a), 1.0 / p, -1.0 / (p * p));
}
inline HessianJet sinh(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kSinh, x, 0.0, std::sinh(x.a));
  const double s = std::sinh(x.a), c = std::cosh(x.a);
  return HessianJet::chain(x, s, c, s);
}
inline HessianJet cosh(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kCosh, x, 0.0, std::cosh(x.a));
  const double s = std::sinh(x.a), c = std::cosh(x.a);
  return HessianJet::chain(x, c, s, c);
}
inline HessianJet tanh(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kTanh, x, 0.0, std::tanh(x.a));
  const double t = std::tanh(x.a), d = 1.0 - t * t;
  return HessianJet::chain(x, t, d, -2.0 * t * d);
}
inline HessianJet atan(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kAtan, x, 0.0, std::atan(x.a));
  const double d = 1.0 / (1.0 + x.a * x.a);
  return HessianJet::chain(x, std::atan(x.a), d, -2.0 * x.a * d * d);
}
inline HessianJet cbrt(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kCbrt, x, 0.0, std::cbrt(x.a));
  const double c = std::cbrt(x.a), d = 1.0 / (3.0 * c * c);
  return HessianJet::chain(x, c, d, -2.0 * d / (3.0 * x.a));
}
/** x^p for a constant p (p = 0: the constant 1; p = 1: x itself; a term whose factor p (p - 1)
    or p is zero is left out, so that x = 0 gives no 0 * inf). */
inline HessianJet pow(const HessianJet& x, double p) {
  if (p == 0.0) return HessianJet(1.0);
  if (p == 1.0) return x;
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kPowC, x, p, std::pow(x.a, p));
  const double d2 = p == 2.0 ? 2.0 : p * (p - 1.0) * std::pow(x.a, p - 2.0);
  return HessianJet::chain(x, std::pow(x.a, p), p * std::pow(x.a, p - 1.0), d2);
}
/** s^y for a constant s > 0; 0^y = 0 for y > 0 (derivatives 0). */
inline HessianJet pow(double s, const HessianJet& y) {
  if (y.tape != nullptr) return HessianJet::record(HessianTape::Op::kCPow, y, s, std::pow(s, y.a));
  if (s == 0.0) return HessianJet::chain(y, std::pow(s, y.a), 0.0, 0.0);
  const double value = std::pow(s, y.a), l = std::log(s);
  return HessianJet::chain(y, value, value * l, value * l * l);
}
/** x^y: with a constant exponent (no lanes) as pow(x, double), with a constant base as
    pow(double, y), else exp(y log x) (x > 0). */
inline HessianJet pow(const HessianJet& x, const HessianJet& y) {
  if (x.tape != nullptr || y.tape != nullptr) {
    if (y.tape == nullptr) return pow(x, y.a);
    if (x.tape == nullptr) return pow(x.a, y);
    return exp(y * log(x));
  }
  if (y.n == 0) return pow(x, y.a);
  if (x.n == 0) return pow(x.a, y);
  return exp(y * log(x));
}
/** |x|: the derivative of the side of x's sign bit (-1 at -0.0, +1 at +0.0), as Ceres's Jets. */
inline HessianJet abs(const HessianJet& x) {
  const bool negative = std::signbit(x.a);
  HessianJet::guard(HessianTape::Test::kSignBit, x, negative);
  return negative ? -x : x;
}
inline HessianJet fabs(const HessianJet& x) { return abs(x); }
inline HessianJet asin(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kAsin, x, 0.0, std::asin(x.a));
  const double r = 1.0 / std::sqrt(1.0 - x.a * x.a);
  return HessianJet::chain(x, std::asin(x.a), r, x.a * r * r * r);
}
inline HessianJet acos(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kAcos, x, 0.0, std::acos(x.a));
  const double r = 1.0 / std::sqrt(1.0 - x.a * x.a);
  return HessianJet::chain(x, std::acos(x.a), -r, -x.a * r * r * r);
}
inline HessianJet expm1(const HessianJet& x) {
  if (x.tape != nullptr)
    return HessianJet::record(HessianTape::Op::kExpm1, x, 0.0, std::expm1(x.a));
  const double e = std::exp(x.a);
  return HessianJet::chain(x, std::expm1(x.a), e, e);
}
inline HessianJet log10(const HessianJet& x) {
  if (x.tape != nullptr)
    return HessianJet::record(HessianTape::Op::kLog10, x, 0.0, std::log10(x.a));
  const double k = 1.0 / std::log(10.0);
  return HessianJet::chain(x, std::log10(x.a), k / x.a, -k / (x.a * x.a));
}
inline HessianJet log2(const HessianJet& x) {
  if (x.tape != nullptr) return HessianJet::record(HessianTape::Op::kLog2, x, 0.0, std::log2(x.a));
  const double k = 1.0 / std::log(2.0);
  return HessianJet::chain(x, std::log2(x.a), k / x.a, -k / (x.a * x.a));
}
inline HessianJet hypot(const HessianJet& x, const HessianJet& y) { return sqrt(x * x + y * y); }
/** The larger (smaller) value and its derivatives; the first at a tie, as std::fmax. */
inline HessianJet fmax(const HessianJet& x, const HessianJet& y) { return y > x ? y : x; }
inline HessianJet fmin(const HessianJet& x, const HessianJet& y) { return y < x ? y : x; }
/** Piecewise constant: no derivatives. */
inline HessianJet floor(const HessianJet& x) {
  const HessianJet r(std::floor(x.a));
  HessianJet::guard(HessianTape::Test::kFloor, x, r, true);
  return r;
}
inline HessianJet ceil(const HessianJet& x) {
  const HessianJet r(std::ceil(x.a));
  HessianJet::guard(HessianTape::Test::kCeil, x, r, true);
  return r;
}
/** atan2(y, x): the angle's derivatives d theta = (x dy - y dx) / r^2 (r > 0). */
inline HessianJet atan2(const HessianJet& y, const HessianJet& x) {
  if (x.tape != nullptr || y.tape != nullptr)
    return HessianJet::record(HessianTape::Op::kAtan2, y, x, std::atan2(y.a, x.a));
  const double r2 = x.a * x.a + y.a * y.a, r4 = r2 * r2;
  return HessianJet::chain2(y, x, std::atan2(y.a, x.a), x.a / r2, -y.a / r2, -2.0 * x.a * y.a / r4,
                            (y.a * y.a - x.a * x.a) / r4, 2.0 * x.a * y.a / r4);
}
inline bool isfinite(const HessianJet& x) {
  const bool r = std::isfinite(x.a);
  HessianJet::guard(HessianTape::Test::kFinite, x, r);
  return r;
}
inline bool isnan(const HessianJet& x) {
  const bool r = std::isnan(x.a);
  HessianJet::guard(HessianTape::Test::kNan, x, r);
  return r;
}
inline bool isinf(const HessianJet& x) {
  const bool r = std::isinf(x.a);
  HessianJet::guard(HessianTape::Test::kInf, x, r);
  return r;
}

}  // namespace hessian_jet

using hessian_jet::HessianJet;
using hessian_jet::HessianTape;

}  // namespace bflow

#endif  // BFLOW_FESD_HESSIAN_JET_H_

#include "bflow/fesd/hessian_jet.h"

#include <cmath>
#include <functional>
#include <random>
#include <type_traits>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Core>
#include <unsupported/Eigen/AutoDiff>

#include "bflow/examples/monoped_ocp.h"
#include "bflow/fesd/hessian_blocks.h"

namespace bflow {
namespace {

// Every elementary function on u = x + 2 y (lanes 0 and 1): gradient phi'(u) (1, 2) and Hessian
// phi''(u) [1 2; 2 4], with phi' and phi'' written here by hand.
TEST(HessianJet, ElementaryFunctionsMatchTheirClosedForms) {
  struct Case {
    const char* name;
    double u;
    std::function<HessianJet(const HessianJet&)> f;
    double value, d1, d2;
  };
  const double u = 0.7;
  const std::vector<Case> cases = {
      {"sqrt", u, [](const HessianJet& x) { return sqrt(x); }, std::sqrt(u), 0.5 / std::sqrt(u),
       -0.25 / std::pow(u, 1.5)},
      {"sin", u, [](const HessianJet& x) { return sin(x); }, std::sin(u), std::cos(u),
       -std::sin(u)},
      {"cos", u, [](const HessianJet& x) { return cos(x); }, std::cos(u), -std::sin(u),
       -std::cos(u)},
      {"tan", u, [](const HessianJet& x) { return tan(x); }, std::tan(u),
       1.0 / std::pow(std::cos(u), 2), 2.0 * std::sin(u) / std::pow(std::cos(u), 3)},
      {"exp", u, [](const HessianJet& x) { return exp(x); }, std::exp(u), std::exp(u), std::exp(u)},
      {"log", u, [](const HessianJet& x) { return log(x); }, std::log(u), 1.0 / u, -1.0 / (u * u)},
      {"log1p", u, [](const HessianJet& x) { return log1p(x); }, std::log1p(u), 1.0 / (1.0 + u),
       -1.0 / ((1.0 + u) * (1.0 + u))},
      {"sinh", u, [](const HessianJet& x) { return sinh(x); }, std::sinh(u), std::cosh(u),
       std::sinh(u)},
      {"cosh", u, [](const HessianJet& x) { return cosh(x); }, std::cosh(u), std::sinh(u),
       std::cosh(u)},
      {"tanh", u, [](const HessianJet& x) { return tanh(x); }, std::tanh(u),
       1.0 / std::pow(std::cosh(u), 2), -2.0 * std::tanh(u) / std::pow(std::cosh(u), 2)},
      {"atan", u, [](const HessianJet& x) { return atan(x); }, std::atan(u), 1.0 / (1.0 + u * u),
       -2.0 * u / ((1.0 + u * u) * (1.0 + u * u))},
      {"cbrt", u, [](const HessianJet& x) { return cbrt(x); }, std::cbrt(u),
       std::pow(u, -2.0 / 3.0) / 3.0, -2.0 / 9.0 * std::pow(u, -5.0 / 3.0)},
      {"pow 2.5", u, [](const HessianJet& x) { return pow(x, 2.5); }, std::pow(u, 2.5),
       2.5 * std::pow(u, 1.5), 3.75 * std::sqrt(u)},
      {"3^x", u, [](const HessianJet& x) { return pow(3.0, x); }, std::pow(3.0, u),
       std::pow(3.0, u) * std::log(3.0), std::pow(3.0, u) * std::log(3.0) * std::log(3.0)},
      {"1/x", u, [](const HessianJet& x) { return 1.0 / x; }, 1.0 / u, -1.0 / (u * u),
       2.0 / (u * u * u)},
      {"x*x", u, [](const HessianJet& x) { return x * x; }, u * u, 2.0 * u, 2.0},
      {"-|x| at -u", -u, [](const HessianJet& x) { return -abs(x); }, -u, 1.0, 0.0},
      {"asin", u, [](const HessianJet& x) { return asin(x); }, std::asin(u),
       1.0 / std::sqrt(1.0 - u * u), u / std::pow(1.0 - u * u, 1.5)},
      {"acos", u, [](const HessianJet& x) { return acos(x); }, std::acos(u),
       -1.0 / std::sqrt(1.0 - u * u), -u / std::pow(1.0 - u * u, 1.5)},
      {"expm1", u, [](const HessianJet& x) { return expm1(x); }, std::expm1(u), std::exp(u),
       std::exp(u)},
      {"log10", u, [](const HessianJet& x) { return log10(x); }, std::log10(u),
       1.0 / (u * std::log(10.0)), -1.0 / (u * u * std::log(10.0))},
      {"log2", u, [](const HessianJet& x) { return log2(x); }, std::log2(u),
       1.0 / (u * std::log(2.0)), -1.0 / (u * u * std::log(2.0))},
  };
  for (const Case& c : cases) {
    // x + 2 y = c.u with x = c.u / 3, y = c.u / 3.
    const HessianJet x = HessianJet::variable(c.u / 3.0, 0);
    const HessianJet y = HessianJet::variable(c.u / 3.0, 1);
    const HessianJet r = c.f(x + 2.0 * y);
    const double tol = 1e-14 * (1.0 + std::abs(c.d2) * 4.0);
    EXPECT_NEAR(r.a, c.value, 1e-15 * (1.0 + std::abs(c.value))) << c.name;
    EXPECT_NEAR(r.gradient(0), c.d1, tol) << c.name;
    EXPECT_NEAR(r.gradient(1), 2.0 * c.d1, tol) << c.name;
    EXPECT_NEAR(r.hessian(0, 0), c.d2, tol) << c.name;
    EXPECT_NEAR(r.hessian(1, 0), 2.0 * c.d2, tol) << c.name;
    EXPECT_NEAR(r.hessian(0, 1), 2.0 * c.d2, tol) << c.name;
    EXPECT_NEAR(r.hessian(1, 1), 4.0 * c.d2, tol) << c.name;
  }
}

// Products and quotients of values with different numbers of lanes (a value depends on lanes
// [0, n) only): f = x0 x3 / (1 + x1) + x2^2 x0 against its closed-form derivatives.
TEST(HessianJet, ValuesOfDifferentLaneCountsCombineExactly) {
  const double a = 0.3, b = -1.7, c = 2.1, e = 0.9;
  const HessianJet x0 = HessianJet::variable(a, 0);
  const HessianJet x1 = HessianJet::variable(b, 1);
  const HessianJet x2 = HessianJet::variable(c, 2);
  const HessianJet x3 = HessianJet::variable(e, 3);
  const HessianJet f = x0 * x3 / (1.0 + x1) + x2 * x2 * x0;
  const double q = 1.0 + b;
  Eigen::Matrix4d h;
  // f = a e / q + c^2 a
  h << 0, -e / (q * q), 2 * c, 1 / q,                          //
      -e / (q * q), 2 * a * e / (q * q * q), 0, -a / (q * q),  //
      2 * c, 0, 2 * a, 0,                                      //
      1 / q, -a / (q * q), 0, 0;
  const Eigen::Vector4d g(e / q + c * c, -a * e / (q * q), 2 * c * a, a / q);
  EXPECT_NEAR(f.a, a * e / q + c * c * a, 1e-14);
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(f.gradient(i), g[i], 1e-13) << i;
    for (int j = 0; j < 4; ++j) EXPECT_NEAR(f.hessian(i, j), h(i, j), 1e-13) << i << " " << j;
  }
  // A constant costs nothing and keeps no lanes; mixed double arithmetic keeps the lanes.
  const HessianJet k = HessianJet(2.0) * HessianJet(3.0) + 1.0;
  EXPECT_EQ(k.n, 0);
  EXPECT_EQ(k.a, 7.0);
  const HessianJet s = 2.0 - x1 * 3.0;
  EXPECT_EQ(s.n, 2);
  EXPECT_EQ(s.gradient(1), -3.0);
  EXPECT_EQ(s.gradient(0), 0.0);
  // The in-place operators give the numbers of the binary ones, to the last bit, whichever
  // operand has more lanes.
  const HessianJet wide = f * x2, narrow = x1 * x1 * 0.7;
  for (const bool shorter_first : {false, true}) {
    const HessianJet& p = shorter_first ? narrow : wide;
    const HessianJet& r = shorter_first ? wide : narrow;
    HessianJet sum = p, difference = p, scaled = p, divided = p;
    sum += r;
    difference -= r;
    scaled *= -1.3;
    divided /= 0.7;
    const HessianJet expect[4] = {p + r, p - r, p * -1.3, p / 0.7};
    const HessianJet* got[4] = {&sum, &difference, &scaled, &divided};
    for (int t = 0; t < 4; ++t) {
      EXPECT_EQ(got[t]->n, expect[t].n) << t;
      EXPECT_EQ(got[t]->a, expect[t].a) << t;
      for (int i = 0; i < expect[t].n; ++i) {
        EXPECT_EQ(got[t]->gradient(i), expect[t].gradient(i)) << t << " " << i;
        for (int j = 0; j <= i; ++j)
          EXPECT_EQ(got[t]->hessian(i, j), expect[t].hessian(i, j)) << t << " " << i << " " << j;
      }
    }
  }
}

// The special cases of pow, where 0 * inf or log(0) would give NaN, and abs at -0.0 (as Ceres).
TEST(HessianJet, PowAtZeroAndNegativeBasesHasExactDerivatives) {
  const HessianJet zero = HessianJet::variable(0.0, 0);
  const HessianJet one = pow(zero, 1.0);  // x: d1 = 1, d2 = 0
  EXPECT_EQ(one.gradient(0), 1.0);
  EXPECT_EQ(one.hessian(0, 0), 0.0);
  const HessianJet square = pow(zero, HessianJet(2.0));  // constant exponent: x^2
  EXPECT_EQ(square.a, 0.0);
  EXPECT_EQ(square.gradient(0), 0.0);
  EXPECT_EQ(square.hessian(0, 0), 2.0);
  const HessianJet negative = pow(HessianJet::variable(-1.5, 0), HessianJet(2.0));
  EXPECT_EQ(negative.a, 2.25);
  EXPECT_EQ(negative.gradient(0), -3.0);
  EXPECT_EQ(negative.hessian(0, 0), 2.0);
  const HessianJet y = HessianJet::variable(1.0, 0);
  const HessianJet sum = pow(0.0, y) + y * y;  // 0^y = 0 for y > 0
  EXPECT_EQ(sum.a, 1.0);
  EXPECT_EQ(sum.gradient(0), 2.0);
  EXPECT_EQ(sum.hessian(0, 0), 2.0);
  const HessianJet both = pow(HessianJet::variable(2.0, 0), HessianJet::variable(3.0, 1));
  // x^y: d/dx = y x^(y-1) = 12, d/dy = x^y log x, d2/dx2 = y (y-1) x^(y-2) = 12,
  // d2/dxdy = x^(y-1) (1 + y log x), d2/dy2 = x^y log^2 x.
  const double l = std::log(2.0);
  EXPECT_NEAR(both.gradient(0), 12.0, 1e-13);
  EXPECT_NEAR(both.gradient(1), 8.0 * l, 1e-13);
  EXPECT_NEAR(both.hessian(0, 0), 12.0, 1e-12);
  EXPECT_NEAR(both.hessian(1, 0), 4.0 * (1.0 + 3.0 * l), 1e-12);
  EXPECT_NEAR(both.hessian(1, 1), 8.0 * l * l, 1e-12);
  EXPECT_EQ(abs(HessianJet::variable(-0.0, 0)).gradient(0), -1.0);
  EXPECT_EQ(abs(HessianJet::variable(0.0, 0)).gradient(0), 1.0);
}

// atan2 in all four quadrants: d theta = (x dy - y dx) / r^2, second derivatives
// d2/dx2 = 2xy / r^4, d2/dy2 = -2xy / r^4, d2/dxdy = (y^2 - x^2) / r^4.
TEST(HessianJet, Atan2HasTheAnglesDerivativesInEveryQuadrant) {
  for (const auto& [px, py] : std::vector<std::pair<double, double>>{
           {1.3, 0.4}, {-1.3, 0.4}, {-1.3, -0.4}, {1.3, -0.4}, {-2.0, 0.0}, {0.0, 1.5}}) {
    const HessianJet x = HessianJet::variable(px, 0);
    const HessianJet y = HessianJet::variable(py, 1);
    const HessianJet t = atan2(y, x);
    const double r2 = px * px + py * py, r4 = r2 * r2;
    EXPECT_NEAR(t.a, std::atan2(py, px), 1e-15) << px << " " << py;
    EXPECT_NEAR(t.gradient(0), -py / r2, 1e-14) << px << " " << py;
    EXPECT_NEAR(t.gradient(1), px / r2, 1e-14) << px << " " << py;
    EXPECT_NEAR(t.hessian(0, 0), 2 * px * py / r4, 1e-13) << px << " " << py;
    EXPECT_NEAR(t.hessian(1, 1), -2 * px * py / r4, 1e-13) << px << " " << py;
    EXPECT_NEAR(t.hessian(1, 0), (py * py - px * px) / r4, 1e-13) << px << " " << py;
  }
}

// The monoped's field weighted by multipliers, against nested forward AD (Eigen's AutoDiffScalar
// in itself, an independent implementation) at a random point: every second derivative over
// (x, u, a).
TEST(HessianJet, MonopedFieldAgreesWithNestedForwardAd) {
  const auto model = examples::monoped_model<TimeFreezingRegions::kUnions>();
  using M = std::decay_t<decltype(model)>;
  constexpr int d = M::kStates, nu = M::kControls, nc = M::kSwitches, m = d + nu + nc;
  static_assert(m <= HessianJet::kLanes, "the monoped's field fits the lanes");
  std::mt19937 gen(7);
  std::uniform_real_distribution<double> uniform(-0.5, 0.5);
  double base[m], w[d];
  for (double& b : base) b = uniform(gen);
  base[1] = 0.3;      // height
  base[d + 2] = 2.0;  // speed of time
  for (double& x : w) x = uniform(gen);
  const auto weighted = [&](const auto* y) {
    using T = std::remove_const_t<std::remove_pointer_t<decltype(y)>>;
    T f[d];
    model.field(y, y + d, y + d + nu, f);
    T s(0.0);
    for (int i = 0; i < d; ++i) s += w[i] * f[i];
    return s;
  };
  HessianJet in[m];
  for (int k = 0; k < m; ++k) in[k] = HessianJet::variable(base[k], k);
  const HessianJet mine = weighted(in);

  using Inner = Eigen::AutoDiffScalar<Eigen::Matrix<double, m, 1>>;
  using Outer = Eigen::AutoDiffScalar<Eigen::Matrix<Inner, m, 1>>;
  Outer nested[m];
  for (int k = 0; k < m; ++k) {
    nested[k] = Outer(Inner(base[k], m, k), m, k);
    nested[k].derivatives() = Eigen::Matrix<Inner, m, 1>::Constant(Inner(0.0));
    nested[k].derivatives()[k] = Inner(1.0);
    for (int j = 0; j < m; ++j) nested[k].derivatives()[j].derivatives().setZero();
  }
  const Outer ref = weighted(nested);
  double scale = 0.0;
  for (int i = 0; i < m; ++i)
    for (int j = 0; j < m; ++j)
      scale = std::max(scale, std::abs(ref.derivatives()[i].derivatives()[j]));
  ASSERT_GT(scale, 0.0);
  for (int i = 0; i < m; ++i) {
    EXPECT_NEAR(mine.gradient(i), ref.derivatives()[i].value(), 1e-13 * scale) << i;
    for (int j = 0; j <= i; ++j) {
      EXPECT_NEAR(mine.hessian(i, j), ref.derivatives()[i].derivatives()[j], 1e-13 * scale)
          << i << " " << j;
    }
  }
}

// HessianBlocks: two entries of a block naming one unknown (f(a, b) = a^2 b with a = b = g gives
// g^3, d2/dg2 = 6 g), and an unknown behind Ceres's pow(f, g) at f = 0, whose lanes the NaN pass
// cannot see (f = x^2 at x = 0: d2/dx2 = 2).
TEST(HessianJet, BlocksAddRepeatedUnknownsAndUnseenDependences) {
  fesd::HessianBlocks blocks;
  const std::vector<int> same = {0, 0};
  blocks.add_block(same);
  std::vector<double> values(blocks.size(), 0.0);
  const double one = 1.0;
  blocks.add(
      same, {1.5, 1.5}, 1, &one, [](const auto* in, auto* out) { out[0] = in[0] * in[0] * in[1]; },
      values.data());
  ASSERT_EQ(blocks.size(), 1u);
  EXPECT_NEAR(values[0], 9.0, 1e-14);

  fesd::HessianBlocks hidden;
  const std::vector<int> x = {0};
  hidden.add_block(x);
  std::vector<double> h(hidden.size(), 0.0);
  hidden.add(
      x, {0.0}, 1, &one,
      [](const auto* in, auto* out) {
        using T = std::remove_const_t<std::remove_pointer_t<decltype(in)>>;
        out[0] = pow(in[0], T(2.0));
      },
      h.data());
  EXPECT_EQ(h[0], 2.0);
}

// HessianBlocks: a function of 40 unknowns, some of which it does not read, through more lanes
// than one pass holds (groups of twelve, two at a time), against its closed form: the weighted
// sum of f_0 = 1/2 y^T A y and f_1 = y_0 y_39 has Hessian w_0 A + w_1 (e_0 e_39^T + e_39 e_0^T).
TEST(HessianJet, BlocksOverManyUnknownsMatchTheClosedForm) {
  constexpr int n = 40;
  std::mt19937 gen(3);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i < n; ++i) {
    if (i % 5 == 2) continue;  // unknowns 2, 7, ... not read
    for (int j = 0; j <= i; ++j) {
      if (j % 5 == 2) continue;
      a(i, j) = a(j, i) = uniform(gen);
    }
  }
  std::vector<int> globals(n);
  std::vector<double> base(n);
  for (int k = 0; k < n; ++k) {
    globals[static_cast<std::size_t>(k)] = n - 1 - k;  // reversed, to test the mapping
    base[static_cast<std::size_t>(k)] = uniform(gen);
  }
  globals[5] = -1;  // a constant
  fesd::HessianBlocks blocks;
  blocks.add_block(globals);
  std::vector<double> values(blocks.size(), 0.0);
  const double weights[2] = {0.7, -1.3};
  blocks.add(
      globals, base, 2, weights,
      [&](const auto* y, auto* out) {
        using T = std::remove_const_t<std::remove_pointer_t<decltype(y)>>;
        T sum(0.0);
        for (int i = 0; i < n; ++i) {
          if (i % 5 == 2) continue;
          T row(0.0);
          for (int j = 0; j < n; ++j) {
            if (a(i, j) != 0.0) row += a(i, j) * y[j];
          }
          sum += y[i] * row;
        }
        out[0] = 0.5 * sum;
        out[1] = y[0] * y[n - 1];
      },
      values.data());
  Eigen::MatrixXd expected = weights[0] * a;
  expected(0, n - 1) += weights[1];
  expected(n - 1, 0) += weights[1];
  for (std::size_t k = 0; k < blocks.size(); ++k) {
    // Global g is local n - 1 - g.
    const int li = n - 1 - blocks.rows()[k], lj = n - 1 - blocks.cols()[k];
    EXPECT_NEAR(values[k], expected(li, lj), 1e-14) << li << " " << lj;
  }
}

}  // namespace
// HessianBlocks::add_scaled: s g(y) + q(y), s the product of one or two factors (one of them a
// constant), against add on the whole function (every entry a lane, the product by HessianJet):
// over few unknowns (one pass) and over more than one pass holds (groups), on a plan kept from
// one evaluation to the next (the second evaluation reuses its positions).
TEST(HessianJet, ScaledBlocksMatchTheWholeFunction) {
  for (const int m : {5, 30}) {
    for (const int factors : {1, 2, 3}) {  // 3: two factors, the first a constant
      const int nf = factors == 1 ? 1 : 2;
      std::mt19937 gen(static_cast<unsigned>(7 * m + factors));
      std::uniform_real_distribution<double> uniform(-1.0, 1.0);
      std::vector<int> globals(static_cast<std::size_t>(m + nf));
      std::vector<double> base(globals.size());
      for (std::size_t k = 0; k < globals.size(); ++k) {
        globals[k] = static_cast<int>(globals.size() - 1 - k);
        base[k] = uniform(gen);
      }
      if (factors == 3) globals[static_cast<std::size_t>(m)] = -1;
      // g: weights[0] f_0 + weights[1] f_1, q: weights[2] f_2, functions of y = in[0..m).
      const auto parts = [m](const auto* y, auto* out) {
        using T = std::remove_const_t<std::remove_pointer_t<decltype(y)>>;
        T quad(0.0);
        for (int i = 0; i + 1 < m; ++i) quad += y[i] * y[i + 1] * (0.1 * i - 1.0);
        out[0] = sin(y[0]) * y[1] + y[2] * y[2] * y[3] + quad;
        out[1] = exp(0.3 * y[1]) * y[4] + y[m - 1] * y[0];
        out[2] = y[0] * y[3] + cos(y[2]);
      };
      const double weights[3] = {0.7, -1.3, 0.4};
      const auto whole = [&](const auto* in, auto* out) {
        using T = std::remove_const_t<std::remove_pointer_t<decltype(in)>>;
        T f[3];
        parts(in, f);
        T s = in[m];
        if (nf == 2) s = s * in[m + 1];
        out[0] = s * (weights[0] * f[0] + weights[1] * f[1]) + weights[2] * f[2];
      };
      fesd::HessianBlocks reference, blocks;
      reference.add_block(globals);
      blocks.add_block(globals);
      std::vector<double> expected(reference.size(), 0.0);
      const double one = 1.0;
      reference.add(globals, base, 1, &one, whole, expected.data());
      double scale = 0.0;
      for (double v : expected) scale = std::max(scale, std::abs(v));
      ASSERT_GT(scale, 0.1);
      for (int evaluation = 0; evaluation < 2; ++evaluation) {
        std::vector<double> values(blocks.size(), 0.0);
        blocks.begin_evaluation();
        blocks.add_scaled(globals, base, nf, 3, weights, parts, values.data(), 2);
        blocks.end_evaluation();
        EXPECT_EQ(blocks.missed(), 0);
        for (std::size_t k = 0; k < values.size(); ++k) {
          EXPECT_NEAR(values[k], expected[k], 1e-13 * scale)
              << "m " << m << " factors " << factors << " evaluation " << evaluation << " pair "
              << blocks.rows()[k] << " " << blocks.cols()[k];
        }
      }
    }
  }
}

}  // namespace bflow

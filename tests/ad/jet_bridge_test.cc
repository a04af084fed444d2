#include "bflow/ad/jet_bridge.h"

#include <cmath>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/core/errors.h"
#include "bflow/core/model.h"
#include "bflow/core/signs.h"
#include "support/error_message.h"

namespace bflow::ad {
namespace {

using ::testing::HasSubstr;

// AD derivatives are exact up to rounding: a few ulps of the O(1) entries below, so 1e-13 is
// a bound with margin for every small closed form here.
constexpr double kExact = 1e-13;

// f: R^3 -> R^3 with sin, exp, products and a quotient.
struct SmallFunction {
  template <typename T>
  void operator()(const T* x, T* y) const {
    y[0] = sin(x[0]) * x[1];
    y[1] = exp(x[2]) * x[0] * x[1];
    y[2] = x[0] / (T(1.0) + x[2] * x[2]);
  }
};

Eigen::Vector3d small_value(const Eigen::Vector3d& x) {
  return {std::sin(x[0]) * x[1], std::exp(x[2]) * x[0] * x[1], x[0] / (1.0 + x[2] * x[2])};
}

Eigen::Matrix3d small_jacobian(const Eigen::Vector3d& x) {
  const double q = 1.0 + x[2] * x[2];
  const double e = std::exp(x[2]);
  Eigen::Matrix3d j;
  j << std::cos(x[0]) * x[1], std::sin(x[0]), 0.0,  //
      e * x[1], e * x[0], e * x[0] * x[1],          //
      1.0 / q, 0.0, -2.0 * x[0] * x[2] / (q * q);
  return j;
}

// A function of d = 50 inputs and 51 outputs (d is a run-time size):
//   y_i = sin(x_i) x_{i+1 mod d} + exp(mean(x))   (i < d),   y_d = sum_j x_j^2 / 2,
// with Jacobian J_ij = [i = j] cos(x_i) x_{i+1} + [j = i+1 mod d] sin(x_i) + exp(mean(x)) / d,
// and row d equal to x^T.
struct Chain {
  int d = 50;
  int outputs() const { return d + 1; }
  template <typename T>
  void operator()(const T* x, T* y) const {
    T sum(0.0);
    for (int j = 0; j < d; ++j) sum += x[j];
    const T shared = exp(sum / T(d));
    T squares(0.0);
    for (int i = 0; i < d; ++i) {
      y[i] = sin(x[i]) * x[(i + 1) % d] + shared;
      squares += x[i] * x[i];
    }
    y[d] = T(0.5) * squares;
  }
  Eigen::VectorXd point() const {
    Eigen::VectorXd x(d);
    for (int i = 0; i < d; ++i) x[i] = 0.1 * (i % 7) - 0.3 + 0.01 * i;
    return x;
  }
  Eigen::VectorXd value(const Eigen::VectorXd& x) const {
    Eigen::VectorXd y(d + 1);
    const double shared = std::exp(x.mean());
    for (int i = 0; i < d; ++i) y[i] = std::sin(x[i]) * x[(i + 1) % d] + shared;
    y[d] = 0.5 * x.squaredNorm();
    return y;
  }
  Eigen::MatrixXd jacobian(const Eigen::VectorXd& x) const {
    Eigen::MatrixXd j = Eigen::MatrixXd::Constant(d + 1, d, std::exp(x.mean()) / d);
    for (int i = 0; i < d; ++i) {
      j(i, i) += std::cos(x[i]) * x[(i + 1) % d];
      j(i, (i + 1) % d) += std::sin(x[i]);
    }
    j.row(d) = x.transpose();
    return j;
  }
};

TEST(JetBridgeTest, JacobianOfSinExpProductQuotient) {
  const Eigen::Vector3d x(0.7, -1.3, 0.4);
  const Eigen::MatrixXd expected = small_jacobian(x);
  const Eigen::MatrixXd jac = jacobian(SmallFunction{}, 3, x);
  ASSERT_EQ(jac.rows(), 3);
  ASSERT_EQ(jac.cols(), 3);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) EXPECT_NEAR(jac(i, j), expected(i, j), kExact) << i << "," << j;
  }

  // The same with a generic lambda, and the value from the same passes.
  const Linearization lin =
      linearize([](const auto* in, auto* out) { SmallFunction{}(in, out); }, 3, x);
  EXPECT_LT((lin.value - small_value(x)).lpNorm<Eigen::Infinity>(), kExact);
  EXPECT_LT((lin.jacobian - expected).lpNorm<Eigen::Infinity>(), kExact);
}

TEST(JetBridgeTest, WritesIntoBlocksOfLargerMatrices) {
  const Eigen::Vector3d x(0.2, 0.5, -0.6);
  Eigen::MatrixXd big = Eigen::MatrixXd::Constant(6, 7, -7.0);
  Eigen::VectorXd values = Eigen::VectorXd::Constant(5, -7.0);
  // Outer stride 6 != 3 rows: the bridge must honour the Ref's stride.
  jacobian(SmallFunction{}, 3, x, values.segment(1, 3), big.block(2, 3, 3, 3));
  EXPECT_LT((big.block(2, 3, 3, 3) - small_jacobian(x)).lpNorm<Eigen::Infinity>(), kExact);
  EXPECT_LT((values.segment(1, 3) - small_value(x)).lpNorm<Eigen::Infinity>(), kExact);
  // Nothing outside the blocks was touched.
  EXPECT_EQ(big(1, 3), -7.0);
  EXPECT_EQ(big(5, 3), -7.0);
  EXPECT_EQ(big(2, 2), -7.0);
  EXPECT_EQ(big(2, 6), -7.0);
  EXPECT_EQ(values[0], -7.0);
  EXPECT_EQ(values[4], -7.0);
}

TEST(JetBridgeTest, FiftyInputsInChunksOfEight) {
  // 50 = 6 * 8 + 2: six full Jet<double, 8> passes and one partial pass of 2 directions.
  const Chain chain;
  const Eigen::VectorXd x = chain.point();
  const Eigen::MatrixXd expected = chain.jacobian(x);
  Eigen::VectorXd value(chain.outputs());
  Eigen::MatrixXd jac(chain.outputs(), chain.d);
  jacobian<8>(chain, chain.outputs(), x, value, jac);
  // Entries are O(1); rows sum 50 terms of the mean, so allow 1e-13 relative to max(1, |J|).
  for (int i = 0; i < chain.outputs(); ++i) {
    for (int j = 0; j < chain.d; ++j) {
      EXPECT_NEAR(jac(i, j), expected(i, j), kExact * std::max(1.0, std::abs(expected(i, j))))
          << "entry (" << i << ", " << j << ")";
    }
  }
  EXPECT_LT((value - chain.value(x)).lpNorm<Eigen::Infinity>(), kExact);
  // The last partial chunk (columns 48, 49) carries the wrap-around entry J(49, 0) too.
  EXPECT_NEAR(jac(49, 0), std::sin(x[49]) + std::exp(x.mean()) / 50, kExact);
  EXPECT_NEAR(jac(48, 49), std::sin(x[48]) + std::exp(x.mean()) / 50, kExact);
}

TEST(JetBridgeTest, JvpEqualsJacobianTimesVector) {
  const Chain chain;
  const Eigen::VectorXd x = chain.point();
  Eigen::VectorXd v(chain.d);
  for (int i = 0; i < chain.d; ++i) v[i] = std::cos(0.3 * i) - 0.2;
  const Eigen::VectorXd expected = chain.jacobian(x) * v;
  // Each entry sums 50 products of O(1) numbers: 1e-12 covers the rounding of either side.
  EXPECT_LT((jvp(chain, chain.outputs(), x, v) - expected).lpNorm<Eigen::Infinity>(), 1e-12);

  Eigen::VectorXd value(chain.outputs()), out(chain.outputs());
  jvp(chain, chain.outputs(), x, v, value, out);
  EXPECT_LT((out - expected).lpNorm<Eigen::Infinity>(), 1e-12);
  EXPECT_LT((value - chain.value(x)).lpNorm<Eigen::Infinity>(), kExact);
}

TEST(JetBridgeTest, JacobianTimesEqualsJacobianTimesBlock) {
  const Chain chain;
  const Eigen::VectorXd x = chain.point();
  // k = 11 directions: one full pass of 8 and a partial pass of 3.
  Eigen::MatrixXd directions(chain.d, 11);
  for (int i = 0; i < chain.d; ++i) {
    for (int c = 0; c < 11; ++c) directions(i, c) = std::sin(1.0 + i + 7.0 * c);
  }
  const Eigen::MatrixXd expected = chain.jacobian(x) * directions;
  const Eigen::MatrixXd out = jacobian_times(chain, chain.outputs(), x, directions);
  ASSERT_EQ(out.rows(), chain.outputs());
  ASSERT_EQ(out.cols(), 11);
  EXPECT_LT((out - expected).lpNorm<Eigen::Infinity>(), 1e-12);

  // The value comes with it; zero directions still give the value.
  Eigen::VectorXd value(chain.outputs());
  Eigen::MatrixXd none(chain.outputs(), 0);
  jacobian_times(chain, chain.outputs(), x, Eigen::MatrixXd(chain.d, 0), value, none);
  EXPECT_LT((value - chain.value(x)).lpNorm<Eigen::Infinity>(), kExact);
}

// A nonlinear model with two surfaces; the field depends on the word.
struct Curved {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 2;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    xdot[0] = x[1] * (b.plus(0) ? T(2.0) : T(-1.0));
    xdot[1] = -sin(x[0]) + (b.plus(1) ? x[0] * x[1] : T(0.5) * x[1] * x[1]);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0] * x[0] + x[1] * x[1] - T(1.0);  // unit circle
    h[1] = sin(x[0]) - x[1];
  }
};

TEST(JetBridgeTest, ModelFieldJacobianPerWord) {
  const Curved model;
  const Eigen::Vector2d x(0.6, -0.8);
  {
    const Signs b = Signs::parse("--");
    Eigen::Matrix2d expected;
    expected << 0.0, -1.0, -std::cos(x[0]), x[1];
    EXPECT_LT((field_jacobian(model, x, b) - expected).lpNorm<Eigen::Infinity>(), kExact);
    const Eigen::Vector2d f(-x[1], -std::sin(x[0]) + 0.5 * x[1] * x[1]);
    EXPECT_LT((field_value(model, x, b) - f).lpNorm<Eigen::Infinity>(), kExact);
  }
  {
    const Signs b = Signs::parse("++");
    Eigen::Matrix2d expected;
    expected << 0.0, 2.0, -std::cos(x[0]) + x[1], x[0];
    Eigen::VectorXd value(2);
    Eigen::MatrixXd jac(2, 2);
    field_jacobian(model, x, b, value, jac);
    EXPECT_LT((jac - expected).lpNorm<Eigen::Infinity>(), kExact);
    const Eigen::Vector2d f(2.0 * x[1], -std::sin(x[0]) + x[0] * x[1]);
    EXPECT_LT((value - f).lpNorm<Eigen::Infinity>(), kExact);

    // The variational right-hand side DF_b(x) V.
    Eigen::MatrixXd tangents(2, 3);
    tangents << 1.0, 0.5, -2.0, 0.0, 3.0, 0.25;
    Eigen::VectorXd value2(2);
    Eigen::MatrixXd out(2, 3);
    field_jacobian_times(model, x, b, tangents, value2, out);
    EXPECT_LT((out - expected * tangents).lpNorm<Eigen::Infinity>(), kExact);
    EXPECT_LT((value2 - f).lpNorm<Eigen::Infinity>(), kExact);
  }
}

TEST(JetBridgeTest, NormalsOfNonlinearSurfaces) {
  const Curved model;
  const Eigen::Vector2d x(0.6, -0.8);
  Eigen::Matrix2d expected;
  expected << 2.0 * x[0], 2.0 * x[1], std::cos(x[0]), -1.0;
  const Eigen::MatrixXd eta = normals(model, x);
  ASSERT_EQ(eta.rows(), 2);
  ASSERT_EQ(eta.cols(), 2);
  EXPECT_LT((eta - expected).lpNorm<Eigen::Infinity>(), kExact);
  const Eigen::VectorXd h = surface_values(model, x);
  EXPECT_NEAR(h[0], 0.0, kExact);  // (0.6, -0.8) is on the unit circle
  EXPECT_NEAR(h[1], std::sin(0.6) + 0.8, kExact);
}

// Sizes chosen at run time: x_i' = a_i x_{i+1}^2 (cyclic), one surface h = sum(x).
struct DynamicChain {
  static constexpr int kStates = kDynamic;
  static constexpr int kSurfaces = kDynamic;
  int d = 11;
  int states() const { return d; }
  int surfaces() const { return 1; }
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    for (int i = 0; i < d; ++i) xdot[i] = T(1.0 + i) * x[(i + 1) % d] * x[(i + 1) % d];
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = T(0.0);
    for (int i = 0; i < d; ++i) h[0] += x[i];
  }
};

TEST(JetBridgeTest, DynamicSizeModel) {
  const DynamicChain model;
  Eigen::VectorXd x(model.d);
  for (int i = 0; i < model.d; ++i) x[i] = 0.5 - 0.1 * i;
  Eigen::MatrixXd expected = Eigen::MatrixXd::Zero(model.d, model.d);
  for (int i = 0; i < model.d; ++i) {
    expected(i, (i + 1) % model.d) = 2.0 * (1.0 + i) * x[(i + 1) % model.d];
  }
  // Entries up to 2 * 11 * 0.5: rounding stays far below 1e-13.
  EXPECT_LT((field_jacobian(model, x, Signs(1)) - expected).lpNorm<Eigen::Infinity>(), kExact);
  EXPECT_LT((normals(model, x) - Eigen::RowVectorXd::Ones(model.d)).lpNorm<Eigen::Infinity>(),
            kExact);
}

using testing::message_of;

TEST(JetBridgeTest, RejectsWrongSizesWithMessage) {
  const Curved model;
  const Eigen::Vector3d x3(0.1, 0.2, 0.3);
  EXPECT_THAT(message_of([&] { field_jacobian(model, x3, Signs(2)); }),
              HasSubstr("field_jacobian: x has 3 entries, expected 2"));
  EXPECT_THAT(message_of([&] { field_value(model, Eigen::Vector2d(0.1, 0.2), Signs(1)); }),
              HasSubstr("sign word \"-\" has 1 surfaces, the model has 2"));
  Eigen::MatrixXd jac(2, 2);
  EXPECT_THAT(message_of([&] { jacobian(SmallFunction{}, 3, x3, jac); }),
              HasSubstr("jac is 2 x 2, expected 3 x 3"));
  EXPECT_THAT(message_of([&] { jvp(SmallFunction{}, 3, x3, Eigen::Vector2d(1, 1)); }),
              HasSubstr("v has 2 entries, expected 3"));
  EXPECT_THAT(message_of([&] { jacobian_times(SmallFunction{}, 3, x3, Eigen::MatrixXd(2, 4)); }),
              HasSubstr("V has 2 rows, expected d = 3"));
  EXPECT_THAT(message_of([&] { jacobian(SmallFunction{}, -1, x3); }),
              HasSubstr("n_out must be >= 0, got -1"));
}

TEST(JetBridgeTest, RejectsNonFiniteInputWithMessage) {
  const Curved model;
  const Eigen::Vector2d x(0.1, std::nan(""));
  const std::string message = message_of([&] { field_jacobian(model, x, Signs(2)); });
  EXPECT_THAT(message, HasSubstr("field_jacobian: x is not finite (entry 1 is "));
  EXPECT_THAT(message, HasSubstr("x = ["));
  Eigen::MatrixXd directions = Eigen::MatrixXd::Ones(3, 2);
  directions(2, 1) = INFINITY;
  EXPECT_THAT(
      message_of([&] { jacobian_times(SmallFunction{}, 3, Eigen::Vector3d(1, 2, 3), directions); }),
      HasSubstr("V is not finite (entry (2, 1) is "));
}

// log(x0) is NaN for x0 < 0; sqrt(x1) has an infinite derivative at x1 = 0.
struct Singular {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 2;
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    xdot[0] = x[1];
    xdot[1] = log(x[0]);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
    h[1] = sqrt(x[1]);
  }
};

TEST(JetBridgeTest, RejectsNonFiniteModelOutputsNamingTheRow) {
  const Singular model;
  const Eigen::Vector2d bad(-1.0, 0.5);
  const std::string message = message_of([&] { field_jacobian(model, bad, Signs::parse("+-")); });
  EXPECT_THAT(message, HasSubstr("field_jacobian: F_b(x) row 1 is non-finite"));
  EXPECT_THAT(message, HasSubstr("(b = \"+-\")"));
  EXPECT_THAT(message_of([&] { field_value(model, bad, Signs(2)); }),
              HasSubstr("field_value: F_b(x) row 1 is non-finite"));

  // h_1 = sqrt(x1) is finite at x1 = 0 but its gradient is not: Jet sqrt multiplies the seed
  // by 1 / (2 sqrt(0)) = inf, so column 0 is 0 * inf = nan and column 1 is inf.
  const Eigen::Vector2d edge(1.0, 0.0);
  EXPECT_EQ(surface_values(model, edge)[1], 0.0);
  EXPECT_THAT(message_of([&] { normals(model, edge); }),
              HasSubstr("normals: row 1 of the Jacobian Dh(x) is non-finite (column 0 is "));
  EXPECT_THAT(message_of([&] {
                jvp([](const auto* in, auto* out) { out[0] = sqrt(in[0]); }, 1,
                    Eigen::VectorXd::Zero(1), Eigen::VectorXd::Ones(1));
              }),
              HasSubstr("jvp: row 0 of Df(x) * V is non-finite (column 0 is "));
}

}  // namespace
}  // namespace bflow::ad

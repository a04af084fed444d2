// The computed collocation tableaus against Butcher's simplifying assumptions B(p), C(q), D(r),
// closed forms for small s, and an integration that shows the order.
#include "bflow/fesd/butcher.h"

#include <cmath>
#include <cstdio>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/LU>

#include "bflow/core/errors.h"
#include "support/error_message.h"

namespace bflow {
namespace {

// Residuals of the simplifying assumptions, max over their equations.
double residual_b(const ButcherTableau& t, int p) {
  double worst = 0;
  for (int k = 1; k <= p; ++k) {
    worst = std::max(worst, std::abs(t.b.dot(t.c.array().pow(k - 1).matrix()) - 1.0 / k));
  }
  return worst;
}
double residual_c(const ButcherTableau& t, int q) {
  double worst = 0;
  for (int k = 1; k <= q; ++k) {
    const Eigen::VectorXd lhs = t.a * t.c.array().pow(k - 1).matrix();
    const Eigen::VectorXd rhs = t.c.array().pow(k) / k;
    worst = std::max(worst, (lhs - rhs).cwiseAbs().maxCoeff());
  }
  return worst;
}
double residual_d(const ButcherTableau& t, int r) {
  double worst = 0;
  for (int k = 1; k <= r; ++k) {
    // sum_i b_i c_i^(k-1) a_ij = b_j (1 - c_j^k) / k
    const Eigen::VectorXd weighted = t.b.cwiseProduct(t.c.array().pow(k - 1).matrix());
    const Eigen::VectorXd lhs = t.a.transpose() * weighted;
    const Eigen::VectorXd rhs = t.b.array() * (1.0 - t.c.array().pow(k)) / k;
    worst = std::max(worst, (lhs - rhs).cwiseAbs().maxCoeff());
  }
  return worst;
}

class TableauTest : public ::testing::TestWithParam<std::tuple<CollocationScheme, int>> {};

TEST_P(TableauTest, SatisfiesTheSimplifyingAssumptionsOfItsOrder) {
  const auto [scheme, s] = GetParam();
  const ButcherTableau t = collocation_tableau(scheme, s);
  ASSERT_EQ(t.stages, s);
  const bool gauss = scheme == CollocationScheme::kGaussLegendre;
  EXPECT_EQ(t.order, gauss ? 2 * s : 2 * s - 1);
  // Coefficients are O(1); a long-double solve rounded to double leaves a few ulps, and the
  // powers c^k sum at most 2s terms.
  const double tol = 1e-14;
  EXPECT_LT(residual_b(t, t.order), tol);
  EXPECT_LT(residual_c(t, s), tol);
  EXPECT_LT(residual_d(t, gauss ? s : s - 1), tol);
  // One order more is not met: the order is exactly t.order. (The miss is the quadrature's
  // error constant, 2e-11 for 9-stage Gauss, far above the rounding level of 1e-14.)
  EXPECT_GT(residual_b(t, t.order + 1), 1e-12);
  // Nodes increasing in (0, 1], the last one 1 exactly for Radau IIA.
  for (int i = 1; i < s; ++i) EXPECT_LT(t.c(i - 1), t.c(i));
  EXPECT_GT(t.c(0), 0.0);
  if (gauss) {
    EXPECT_LT(t.c(s - 1), 1.0);
  } else {
    EXPECT_EQ(t.c(s - 1), 1.0);
    // Stiffly accurate: the last row of A is b.
    EXPECT_LT((t.a.row(s - 1).transpose() - t.b).cwiseAbs().maxCoeff(), tol);
  }
}

INSTANTIATE_TEST_SUITE_P(
    AllStages, TableauTest,
    ::testing::Combine(::testing::Values(CollocationScheme::kRadauIIA,
                                         CollocationScheme::kGaussLegendre),
                       ::testing::Range(1, kMaxCollocationStages + 1)),
    [](const ::testing::TestParamInfo<std::tuple<CollocationScheme, int>>& param) {
      return std::string(to_string(std::get<0>(param.param))) + "_" +
             std::to_string(std::get<1>(param.param));
    });

TEST(TableauTest, SmallCasesMatchTheirClosedForms) {
  const ButcherTableau euler = collocation_tableau(CollocationScheme::kRadauIIA, 1);
  EXPECT_DOUBLE_EQ(euler.a(0, 0), 1.0);  // implicit Euler
  const ButcherTableau midpoint = collocation_tableau(CollocationScheme::kGaussLegendre, 1);
  EXPECT_DOUBLE_EQ(midpoint.a(0, 0), 0.5);  // implicit midpoint
  EXPECT_DOUBLE_EQ(midpoint.c(0), 0.5);

  const ButcherTableau radau2 = collocation_tableau(CollocationScheme::kRadauIIA, 2);
  Eigen::Matrix2d a;
  a << 5.0 / 12, -1.0 / 12, 3.0 / 4, 1.0 / 4;
  EXPECT_LT((radau2.a - a).cwiseAbs().maxCoeff(), 1e-15);
  EXPECT_NEAR(radau2.c(0), 1.0 / 3, 1e-16);

  const ButcherTableau gauss2 = collocation_tableau(CollocationScheme::kGaussLegendre, 2);
  const double r = std::sqrt(3.0) / 6;
  Eigen::Matrix2d g;
  g << 0.25, 0.25 - r, 0.25 + r, 0.25;
  EXPECT_LT((gauss2.a - g).cwiseAbs().maxCoeff(), 1e-15);
  EXPECT_NEAR(gauss2.c(0), 0.5 - r, 1e-16);
  EXPECT_NEAR(gauss2.b(1), 0.5, 1e-16);

  const ButcherTableau radau3 = collocation_tableau(CollocationScheme::kRadauIIA, 3);
  const double q = std::sqrt(6.0);
  EXPECT_NEAR(radau3.c(0), (4 - q) / 10, 1e-16);
  EXPECT_NEAR(radau3.c(1), (4 + q) / 10, 1e-16);
  EXPECT_NEAR(radau3.b(0), (16 - q) / 36, 1e-15);
}

// y' = -y over [0, 1] in N steps: each stage system is linear, (I + h A) k = -y e, so the
// collocation step is exact algebra. Halving h divides the error by 2^order.
TEST(TableauTest, IntegratesAtItsOrder) {
  for (CollocationScheme scheme :
       {CollocationScheme::kRadauIIA, CollocationScheme::kGaussLegendre}) {
    for (int s = 1; s <= 3; ++s) {
      const ButcherTableau t = collocation_tableau(scheme, s);
      auto error = [&](int steps) {
        const double h = 1.0 / steps;
        const Eigen::MatrixXd m = Eigen::MatrixXd::Identity(s, s) + h * t.a;
        const Eigen::VectorXd k_per_y = m.partialPivLu().solve(-Eigen::VectorXd::Ones(s));
        const double growth = 1.0 + h * t.b.dot(k_per_y);
        return std::abs(std::pow(growth, steps) - std::exp(-1.0));
      };
      const double ratio = error(8) / error(16);
      const double expected = std::pow(2.0, t.order);
      EXPECT_GT(ratio, 0.8 * expected) << to_string(scheme) << " s = " << s;
      EXPECT_LT(ratio, 1.25 * expected) << to_string(scheme) << " s = " << s;
    }
  }
}

// The derivative form's weights (butcher.h): closed forms for Radau IIA 2 (A^-1 = [3/2 1/2;
// -9/2 5/2]) and the implicit midpoint (D = 2, x_{n+1} = 2 X - x_n), D A = I for every tableau,
// and one step of y' = -y in the derivative form, (D + h I) X = D 1 y_n, y_{n+1} = e_0 y_n + e.X,
// against the integral form's 1 + h b.k: the same step (bounds 1e-13 on both; D's entries grow
// with s, and round-off with them: measured worst 2.7e-15 on D A - I, 1.3e-15 between the
// steps).
TEST(TableauTest, DerivativeFormIsTheIntegralFormInverted) {
  const ButcherTableau radau2 = collocation_tableau(CollocationScheme::kRadauIIA, 2);
  Eigen::Matrix2d d;
  d << 1.5, 0.5, -4.5, 2.5;
  EXPECT_LT((radau2.derivative - d).cwiseAbs().maxCoeff(), 1e-14);
  EXPECT_LT((radau2.derivative_0 - Eigen::Vector2d(-2.0, 2.0)).cwiseAbs().maxCoeff(), 1e-14);
  EXPECT_EQ(radau2.end, Eigen::Vector2d(0.0, 1.0));
  EXPECT_EQ(radau2.end_0, 0.0);
  const ButcherTableau midpoint = collocation_tableau(CollocationScheme::kGaussLegendre, 1);
  EXPECT_NEAR(midpoint.derivative(0, 0), 2.0, 1e-15);
  EXPECT_NEAR(midpoint.end(0), 2.0, 1e-15);
  EXPECT_NEAR(midpoint.end_0, -1.0, 1e-15);
  double worst_inverse = 0.0, worst_step = 0.0;
  for (CollocationScheme scheme :
       {CollocationScheme::kRadauIIA, CollocationScheme::kGaussLegendre}) {
    for (int s = 1; s <= kMaxCollocationStages; ++s) {
      const ButcherTableau t = collocation_tableau(scheme, s);
      const Eigen::MatrixXd identity = Eigen::MatrixXd::Identity(s, s);
      const double inverse = (t.derivative * t.a - identity).cwiseAbs().maxCoeff();
      worst_inverse = std::max(worst_inverse, inverse);
      EXPECT_LT(inverse, 1e-13) << to_string(scheme) << " s = " << s;
      const double h = 0.3;
      const Eigen::VectorXd k_per_y =
          (identity + h * t.a).partialPivLu().solve(-Eigen::VectorXd::Ones(s));
      const double integral = 1.0 + h * t.b.dot(k_per_y);
      const Eigen::VectorXd x = (t.derivative + h * identity).partialPivLu().solve(-t.derivative_0);
      const double derivative = t.end_0 + t.end.dot(x);
      worst_step = std::max(worst_step, std::abs(derivative - integral));
      EXPECT_NEAR(derivative, integral, 1e-13) << to_string(scheme) << " s = " << s;
      // The rows' weights of each form (collocation_rows).
      const CollocationRows in = collocation_rows(t, CollocationForm::kIntegral);
      EXPECT_EQ(in.state, identity);
      EXPECT_EQ(in.rate, t.a);
      EXPECT_EQ(in.end_rate, t.b);
      const CollocationRows de = collocation_rows(t, CollocationForm::kDerivative);
      EXPECT_EQ(de.state, t.derivative);
      EXPECT_EQ(de.rate, identity);
      EXPECT_EQ(de.end_state, t.end);
      EXPECT_EQ(de.end_rate, Eigen::VectorXd::Zero(s));
    }
  }
  std::printf("largest |D A - I| %.1e, steps apart %.1e\n", worst_inverse, worst_step);
}

TEST(TableauTest, BadInputNamesTheValue) {
  EXPECT_THAT(bflow::testing::message_of(
                  [] { collocation_tableau(CollocationScheme::kGaussLegendre, 10); }),
              ::testing::HasSubstr("stages must be in [1, 9], got 10"));
  EXPECT_THAT(bflow::testing::message_of([] { parse_collocation_scheme("lobatto"); }),
              ::testing::HasSubstr("\"lobatto\""));
  EXPECT_THAT(bflow::testing::message_of([] { parse_collocation_form("weak"); }),
              ::testing::HasSubstr("unknown collocation form \"weak\""));
}

}  // namespace
}  // namespace bflow

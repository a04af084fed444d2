// Sign matrices, the step multipliers theta(a) ([F] (21), Section 6.2), Stewart's indicator
// ([F] (26)) and the problem sizes of [F] Table 4.
#include "bflow/core/filippov.h"

#include <random>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "support/error_message.h"

namespace bflow {
namespace {

TEST(SignMatrixTest, DenseRowsAreTheBaseRegionsInTheOrderOfThePaper) {
  const SignMatrix s = SignMatrix::dense(2);
  Eigen::MatrixXi expected(4, 2);
  expected << 1, 1, 1, -1, -1, 1, -1, -1;  // [F] (9)
  EXPECT_EQ(s.matrix(), expected);
  EXPECT_TRUE(s.is_dense());
  EXPECT_EQ(s.modes(), 4);
}

TEST(SignMatrixTest, MultipliersAreAConvexCombinationAndIndicateTheRegionAtVertices) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (int n_c = 1; n_c <= 5; ++n_c) {
    const SignMatrix s = SignMatrix::dense(n_c);
    std::vector<double> a(static_cast<std::size_t>(n_c)),
        theta(static_cast<std::size_t>(s.modes()));
    for (int trial = 0; trial < 20; ++trial) {
      for (double& v : a) v = unit(rng);
      s.multipliers(a.data(), theta.data());
      double sum = 0;
      for (double t : theta) {
        EXPECT_GE(t, 0.0);
        sum += t;
      }
      EXPECT_NEAR(sum, 1.0, 1e-14) << "n_c = " << n_c;  // [F] Proposition 5
    }
    // a in {0, 1}^n_c: theta is the indicator of the one row whose signs match.
    for (int r = 0; r < s.rows(); ++r) {
      for (int j = 0; j < n_c; ++j)
        a[static_cast<std::size_t>(j)] = s.matrix()(r, j) > 0 ? 1.0 : 0.0;
      s.multipliers(a.data(), theta.data());
      for (int i = 0; i < s.modes(); ++i)
        EXPECT_EQ(theta[static_cast<std::size_t>(i)], i == r ? 1.0 : 0.0);
    }
  }
}

TEST(SignMatrixTest, UnionsOfBaseRegionsGiveThePapersExample4) {
  Eigen::MatrixXi rows(3, 2);
  rows << 1, 0, -1, 1, -1, -1;
  const SignMatrix s(rows, {0, 0, 1});
  EXPECT_FALSE(s.is_dense());
  EXPECT_EQ(s.modes(), 2);
  for (double a1 : {0.0, 0.3, 1.0}) {
    for (double a2 : {0.0, 0.6, 1.0}) {
      const double a[2] = {a1, a2};
      double theta[2];
      s.multipliers(a, theta);
      EXPECT_NEAR(theta[0], a1 + (1 - a1) * a2, 1e-15);
      EXPECT_NEAR(theta[1], (1 - a1) * (1 - a2), 1e-15);
    }
  }
}

TEST(SignMatrixTest, StewartIndicatorIsSmallestOnTheRegionContainingX) {
  const SignMatrix s = SignMatrix::dense(3);
  const double c[3] = {0.4, -1.2, 0.7};  // signs (+, -, +): row 0b010 = 2
  double g[8];
  s.indicator(c, g);
  int best = 0;
  for (int r = 1; r < 8; ++r) best = g[r] < g[best] ? r : best;
  EXPECT_EQ(best, 2);
  EXPECT_DOUBLE_EQ(g[2], -(0.4 + 1.2 + 0.7));  // g = -S c
}

TEST(SignMatrixTest, LiftingCountsAndTable4) {
  // Dense S: n_beta = 2^n_c - 2^n_d; [F] Example 5 (n_c = 3, bilinear) has beta in R^4.
  EXPECT_EQ(SignMatrix::dense(3).lifting_variables(2), 4);
  EXPECT_EQ(SignMatrix::dense(5).lifting_variables(3), 32 - 8);
  EXPECT_EQ(SignMatrix::dense(3).lifting_variables(0), 0);
  EXPECT_EQ(SignMatrix::dense(3).lifting_variables(3), 0);

  const SignMatrix s = SignMatrix::dense(4);
  const DcsSize stewart = dcs_size(s, DcsFormulation::kStewart);
  EXPECT_EQ(stewart.modes, 16);
  EXPECT_EQ(stewart.algebraic, 2 * 16 + 1);
  EXPECT_EQ(stewart.complementarity, 16);
  EXPECT_EQ(stewart.equalities, 17);
  const DcsSize step = dcs_size(s, DcsFormulation::kStep, 2);
  EXPECT_EQ(step.lifting, 16 - 4);
  EXPECT_EQ(step.algebraic, 16 + 3 * 4 + 12);
  EXPECT_EQ(step.complementarity, 8);
  EXPECT_EQ(step.equalities, 4 + 12 + 16);
}

TEST(SignMatrixTest, BadInputNamesTheProblem) {
  using bflow::testing::message_of;
  Eigen::MatrixXi overlap(2, 2);
  overlap << 1, 0, 1, -1;
  EXPECT_THAT(message_of([&] {
                SignMatrix(overlap, {0, 1});
              }),
              ::testing::HasSubstr("rows 0 (1, 0) and 1 (1, -1) describe overlapping sets"));
  Eigen::MatrixXi bad(1, 1);
  bad << 2;
  EXPECT_THAT(message_of([&] { SignMatrix(bad, {0}); }), ::testing::HasSubstr("S(0, 0) = 2"));
  Eigen::MatrixXi rows(3, 2);
  rows << 1, 0, -1, 1, -1, -1;
  const SignMatrix unions(rows, {0, 0, 1});
  EXPECT_THAT(message_of([&] { dcs_size(unions, DcsFormulation::kStewart); }),
              ::testing::HasSubstr("3 rows for 2 switching functions and 2 modes"));
  EXPECT_THAT(message_of([] { parse_dcs_formulation("lcp"); }), ::testing::HasSubstr("\"lcp\""));
}

}  // namespace
}  // namespace bflow

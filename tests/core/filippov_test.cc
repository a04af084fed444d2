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

// Table 4 in closed form: equal to the counts of the built S up to n_c = 12, and exact in 64 bits
// beyond 2^31, where S cannot be built (2^40 rows).
TEST(SignMatrixTest, Table4ClosedFormMatchesTheSignMatrixAndHoldsAbove2To31) {
  for (int n_c = 1; n_c <= 12; ++n_c) {
    const SignMatrix s = SignMatrix::dense(n_c);
    for (int depth : {0, 2, 3, n_c - 1, n_c, n_c + 1}) {
      if (depth == 1) continue;
      for (DcsFormulation f : {DcsFormulation::kStep, DcsFormulation::kStewart}) {
        const int d = f == DcsFormulation::kStewart ? 0 : depth;
        const DcsSize built = dcs_size(s, f, d), closed = dcs_size_dense(n_c, f, d);
        EXPECT_EQ(closed.modes, built.modes) << n_c << " " << d;
        EXPECT_EQ(closed.lifting, built.lifting) << n_c << " " << d;
        EXPECT_EQ(closed.algebraic, built.algebraic) << n_c << " " << d;
        EXPECT_EQ(closed.complementarity, built.complementarity) << n_c << " " << d;
        EXPECT_EQ(closed.equalities, built.equalities) << n_c << " " << d;
      }
    }
  }
  // n_c = 40, n_d = 2: n_f = 2^40 = 1099511627776, n_beta = 2^40 - 4.
  const DcsSize step = dcs_size_dense(40, DcsFormulation::kStep, 2);
  EXPECT_EQ(step.modes, 1099511627776);
  EXPECT_EQ(step.lifting, 1099511627772);
  EXPECT_EQ(step.algebraic, 2199023255668);  // 2^40 + 3 * 40 + 2^40 - 4
  EXPECT_EQ(step.complementarity, 80);
  EXPECT_EQ(step.equalities, 2199023255588);  // 40 + (2^40 - 4) + 2^40
  const DcsSize stewart = dcs_size_dense(40, DcsFormulation::kStewart);
  EXPECT_EQ(stewart.algebraic, 2199023255553);  // 2^41 + 1
  EXPECT_EQ(stewart.complementarity, 1099511627776);
  EXPECT_EQ(stewart.equalities, 1099511627777);
  EXPECT_EQ(dcs_size_dense(kMaxTable4Switches, DcsFormulation::kStewart).algebraic,
            4611686018427387905);  // 2^62 + 1
  using bflow::testing::message_of;
  EXPECT_EQ(message_of([] { dcs_size_dense(62, DcsFormulation::kStep); }),
            "dcs_size_dense: need 1 <= n_c <= 61 switching functions, got 62");
  EXPECT_EQ(message_of([] { dcs_size_dense(0, DcsFormulation::kStep); }),
            "dcs_size_dense: need 1 <= n_c <= 61 switching functions, got 0");
  EXPECT_EQ(message_of([] { dcs_size_dense(5, DcsFormulation::kStep, 1); }),
            "lifting depth n_d must be >= 2 (or 0 for none), got 1");
}

// [F] Example 5: n_c = 3, n_d = 2 gives beta_1..4 = the four products of (a_1 | 1 - a_1) and
// (a_2 | 1 - a_2), and theta_i = beta_k times (a_3 | 1 - a_3).
TEST(SignMatrixTest, LiftingOfExample5IsBilinear) {
  using F = SignMatrix::Factor;
  const SignMatrix::Lifting lift = SignMatrix::dense(3).lifting(2);
  ASSERT_EQ(lift.betas(), 4);
  ASSERT_EQ(lift.beta_products[0].size(), 2u);
  EXPECT_EQ(lift.beta_products[0][0].kind, F::kAlpha);
  EXPECT_EQ(lift.beta_products[0][1].kind, F::kAlpha);
  EXPECT_EQ(lift.beta_products[1][1].kind, F::kOneMinusAlpha);  // a_1 (1 - a_2)
  EXPECT_EQ(lift.beta_products[3][0].kind, F::kOneMinusAlpha);
  for (int r = 0; r < 8; ++r) {
    const auto& p = lift.row_products[static_cast<std::size_t>(r)];
    ASSERT_EQ(p.size(), 2u) << r;
    EXPECT_EQ(p[0].kind, F::kBeta);
    EXPECT_EQ(p[0].index, r / 2);
    EXPECT_EQ(p[1].kind, r % 2 ? F::kOneMinusAlpha : F::kAlpha);
    EXPECT_EQ(p[1].index, 2);
  }
}

// The lifted products reproduce theta(a) (an independent evaluation: multipliers()) for dense
// and union sign matrices and every depth, with no product longer than n_d factors.
TEST(SignMatrixTest, LiftedMultipliersEqualTheMultiAffineOnes) {
  Eigen::MatrixXi union_rows(4, 4);
  union_rows << 1, 0, 0, 0, -1, 1, 1, 0, -1, 1, -1, 0, -1, -1, 0, 0;
  const std::vector<SignMatrix> matrices{SignMatrix::dense(4), SignMatrix::dense(5),
                                         SignMatrix(union_rows, {0, 1, 1, 2})};
  const double a[5] = {0.3, 0.85, 0.1, 0.55, 0.7};
  for (const SignMatrix& s : matrices) {
    std::vector<double> expected(static_cast<std::size_t>(s.modes()));
    s.multipliers(a, expected.data());
    for (int depth : {0, 2, 3, 4}) {
      const SignMatrix::Lifting lift = s.lifting(depth);
      EXPECT_EQ(lift.betas(), s.lifting_variables(depth));
      std::vector<double> beta(static_cast<std::size_t>(lift.betas()));
      lift.betas(a, beta.data());
      std::vector<double> theta(static_cast<std::size_t>(s.modes()), 0.0);
      for (int r = 0; r < s.rows(); ++r) {
        const auto& p = lift.row_products[static_cast<std::size_t>(r)];
        if (depth >= 2) {
          EXPECT_LE(static_cast<int>(p.size()), depth);
        }
        theta[static_cast<std::size_t>(s.mode_of_row()[static_cast<std::size_t>(r)])] +=
            SignMatrix::Lifting::product(p, a, beta.data());
      }
      for (const auto& p : lift.beta_products) {
        EXPECT_LE(static_cast<int>(p.size()), std::max(depth, 2));
      }
      for (int i = 0; i < s.modes(); ++i) {
        EXPECT_NEAR(theta[static_cast<std::size_t>(i)], expected[static_cast<std::size_t>(i)],
                    1e-15)
            << "n_c " << s.switches() << " depth " << depth << " mode " << i;
      }
    }
  }
  // The vertex of a row selects that row's mode alone.
  const SignMatrix u(union_rows, {0, 1, 1, 2});
  for (int r = 0; r < u.rows(); ++r) {
    const std::vector<double> v = u.vertex(r);
    std::vector<double> theta(3);
    u.multipliers(v.data(), theta.data());
    EXPECT_EQ(theta[static_cast<std::size_t>(u.mode_of_row()[static_cast<std::size_t>(r)])], 1.0);
  }
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

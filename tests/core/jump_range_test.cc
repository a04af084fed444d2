// JumpMap and Triangulation at the edges of the double range: limits near 1e308, subnormal
// crossing times, normals of 1e200 and 1e-200, images that overflow, and objects that were
// moved from. References are closed forms (one surface: B = I + (F+ - F-) eta^T / (eta . F-))
// and the invariances of B: positive scaling of a normal, of all limits together (a change of
// time unit, by an exact power of two) and of dx.
#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>

#include <gtest/gtest.h>

#include "bflow/core/errors.h"
#include "bflow/core/field_limits.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/triangulation.h"
#include "support/error_message.h"
#include "support/random_jump.h"

namespace bflow {
namespace {

using testing::message_of;

Eigen::MatrixXd row(std::initializer_list<double> values) {
  Eigen::MatrixXd m(1, static_cast<Eigen::Index>(values.size()));
  Eigen::Index i = 0;
  for (double v : values) m(0, i++) = v;
  return m;
}

Eigen::VectorXd vec(std::initializer_list<double> values) {
  Eigen::VectorXd v(static_cast<Eigen::Index>(values.size()));
  Eigen::Index i = 0;
  for (double x : values) v[i++] = x;
  return v;
}

// Relative error in the max norm.
double relative_error(const Eigen::VectorXd& got, const Eigen::VectorXd& want) {
  return (got - want).lpNorm<Eigen::Infinity>() / want.lpNorm<Eigen::Infinity>();
}

constexpr double kEps = std::numeric_limits<double>::epsilon();

TEST(JumpRangeTest, OneSurfaceWithLimitsNear1e308) {
  // eta . F_- = 2e308 overflows; the crossing time 1e-308 is subnormal. B = F+/F- = 1.5.
  Eigen::MatrixXd limits(1, 2);
  limits << 1e308, 1.5e308;
  const JumpMap jump(row({2.0}), limits);
  const Eigen::VectorXd image = jump.apply(vec({-1.0}));
  EXPECT_NEAR(image[0], -1.5, 2 * kEps);
  const CrossingOrder order = jump.order(vec({-1.0}));
  EXPECT_NEAR(order.times[0], 1e-308, 1e-308 * 2 * kEps);
  // The piece: M = 1 + (F+ - F-) / F- = 1.5.
  EXPECT_NEAR(jump.saltation({0})(0, 0), 1.5, 2 * kEps);
  EXPECT_NEAR(jump.pieces().matrix(0)(0, 0), 1.5, 2 * kEps);
  EXPECT_EQ(jump.transversality(Signs::parse("-"))[0], std::numeric_limits<double>::infinity());
}

TEST(JumpRangeTest, TwoDimensionalLimitsNear1e308) {
  // B dx = dx + (F+ - F-) (eta . dx) / (eta . F-) = [-1, 0] + [0.7, 0.7] (-1 / 2).
  Eigen::MatrixXd limits(2, 2);
  limits << 1e308, 1.7e308, 1e308, 1.7e308;
  const JumpMap jump(row({1.0, 1.0}), limits);
  const Eigen::VectorXd image = jump.apply(vec({-1.0, 0.0}));
  EXPECT_LT(relative_error(image, vec({-1.35, -0.35})), 4 * kEps) << image.transpose();
  // The same data a power of two lower never leaves the plain path, and agrees.
  const JumpMap low(row({1.0, 1.0}), std::ldexp(1.0, -1000) * limits);
  EXPECT_LT(relative_error(low.apply(vec({-1.0, 0.0})), image), 2 * kEps);
}

// Two surfaces, eta = 2 I, words in binary order "--", "+-", "-+", "++".
Eigen::MatrixXd hostile_two_surface_limits() {
  Eigen::MatrixXd limits(2, 4);
  limits.col(0) = vec({0.5, 1e307});
  limits.col(1) = vec({1.0, 1e308});
  limits.col(2) = vec({1e308, 1.0});
  limits.col(3) = vec({1.0, 1.0});
  return limits;
}

TEST(JumpRangeTest, TwoSurfacesWithHugeLimitsAndTangent) {
  // dx = [-1, -1e307] crosses surface 1 at t = 1 (F_-- carries it to [-0.5, 0]), then surface 0
  // after 0.5 / 1e308 under F_-+, landing at rho; then F_++ = [1, 1] for time 1 + 5e-309:
  // B(dx) = [-1, -1] (to rounding of the second time, far below an ulp of 1).
  const JumpMap jump(2.0 * Eigen::MatrixXd::Identity(2, 2), hostile_two_surface_limits());
  const Eigen::VectorXd dx = vec({-1.0, -1e307});
  EXPECT_LT(relative_error(jump.apply(dx), vec({-1.0, -1.0})), 2 * kEps);
  const CrossingOrder order = jump.order(dx);
  EXPECT_EQ(order.order, (std::vector<int>{1, 0}));
  EXPECT_NEAR(order.times[0], 1.0, kEps);
  EXPECT_NEAR(order.times[1], 1.0, kEps);
  // The active piece, by hand: v_1 = (F_-+ - F_--) / 1e307, v_0 = (F_++ - F_-+) / 1e308, and
  // M = (I + v_0 e_0^T)(I + v_1 e_1^T) = [[1e-308, 1e-307], [0, 1e-307]]. Its entries come from
  // 1 + (1 - 1e307) / 1e307, so they are right to an absolute ulp of 1, no better.
  Eigen::Matrix2d piece;
  piece << 1e-308, 1e-307, 0.0, 1e-307;
  EXPECT_LT((jump.active_jacobian(dx) - piece).lpNorm<Eigen::Infinity>(), 2 * kEps);
  // The triangulation represents the same map, but evaluating it at this dx cancels terms of
  // 1e307 to leave 1: its own error bound says so, and the image is only good to that bound.
  const Triangulation triangulation = jump.triangulation();
  EXPECT_NE(triangulation.scale_exponent(), 0);
  const BarycentricEvaluation barycentric = triangulation.apply_barycentric(dx);
  EXPECT_EQ(barycentric.order, (std::vector<int>{1, 0}));
  EXPECT_GT(barycentric.error_estimate, 1.0);
  EXPECT_LE((barycentric.image - vec({-1.0, -1.0})).lpNorm<Eigen::Infinity>(),
            barycentric.error_estimate);
  // Limits spanning 2^1024 leave vertices of 2^-1024 after scaling: even a mild dx has
  // coordinates beyond the range, and the estimate says the image is worthless.
  EXPECT_FALSE(triangulation.apply_barycentric(vec({-1.0, -2.0})).error_estimate < 1.0);
  // Limits of 2^1000 with an ordinary spread are scaled back and evaluated accurately.
  Eigen::MatrixXd big(2, 4);
  big << 1, 2, 1.5, 3, 1, 1.25, 2, 2.5;
  big *= std::ldexp(1.0, 1000);
  const JumpMap big_jump(Eigen::MatrixXd::Identity(2, 2), big);
  const Triangulation big_triangulation = big_jump.triangulation();
  EXPECT_EQ(big_triangulation.scale_exponent(), 1002);
  for (const Eigen::VectorXd& mild : {vec({-1.0, -2.0}), vec({-3.0, 0.5}), vec({2.0, -1.0})}) {
    const BarycentricEvaluation good = big_triangulation.apply_barycentric(mild);
    EXPECT_LT(good.error_estimate, 1e-12);  // measured 1.3e-13 ... 2.3e-13
    EXPECT_LE((good.image - big_jump.apply(mild)).lpNorm<Eigen::Infinity>(), good.error_estimate);
  }
}

TEST(JumpRangeTest, PositiveScalingOfNormalsDoesNotChangeB) {
  std::mt19937_64 rng(20261123);
  for (int trial = 0; trial < 20; ++trial) {
    const int n = 1 + trial % 4;
    const int d = n + trial % 3;
    const Eigen::MatrixXd eta = testing::random_normals(rng, n, d, false);
    const Eigen::MatrixXd limits = testing::random_limits(rng, eta, {});
    const JumpMap reference(eta, limits);
    for (double scale : {1e200, 1e-200, 1e300, 1e-300, 1e-307}) {
      Eigen::MatrixXd scaled = eta;
      for (int j = 0; j < n; ++j) scaled.row(j) *= (j % 2 == 0 ? scale : 1.0);
      const JumpMap jump(scaled, limits);
      for (int k = 0; k < 5; ++k) {
        const Eigen::VectorXd dx = testing::gaussian_vector(rng, d);
        // Measured: at most 1.1e-15 over these cases (normalising a row rounds by an ulp).
        EXPECT_LT(relative_error(jump.apply(dx), reference.apply(dx)), 1e-13)
            << "scale " << scale << " trial " << trial;
        EXPECT_EQ(jump.order(dx).order, reference.order(dx).order);
      }
    }
  }
}

TEST(JumpRangeTest, PowerOfTwoScalingOfLimitsAndTangentsDoesNotChangeB) {
  // Scaling all limits by 2^k changes the time unit only; scaling dx by 2^k scales B(dx) by
  // 2^k. Both are exact in doubles, so any difference is the engine's: the scaled path must
  // agree with the plain one to rounding.
  std::mt19937_64 rng(7);
  for (int trial = 0; trial < 20; ++trial) {
    const int n = 1 + trial % 4;
    const int d = n + 1;
    const Eigen::MatrixXd eta = testing::random_normals(rng, n, d, true);
    const Eigen::MatrixXd limits = testing::random_limits(rng, eta, {});
    const JumpMap reference(eta, limits);
    for (int k : {1010, 900, -900, -1000}) {
      const JumpMap scaled_limits(eta, std::ldexp(1.0, k) * limits);
      const Eigen::VectorXd dx = testing::gaussian_vector(rng, d);
      EXPECT_LT(relative_error(scaled_limits.apply(dx), reference.apply(dx)), 1e-12)
          << "limits 2^" << k << " trial " << trial;
      // With limits of 2^1010 and dx of 2^-60 the crossing times are below 2^-1070, subnormal
      // as doubles: the scaled path must keep their precision.
      const Eigen::VectorXd small = std::ldexp(1.0, -60) * dx;
      EXPECT_LT(
          relative_error(scaled_limits.apply(small), std::ldexp(1.0, -60) * reference.apply(dx)),
          1e-12)
          << "limits 2^" << k << ", dx 2^-60, trial " << trial;
      const Eigen::VectorXd big = std::ldexp(1.0, k > 0 ? 1000 : -1000) * dx;
      const Eigen::VectorXd want = std::ldexp(1.0, k > 0 ? 1000 : -1000) * reference.apply(dx);
      EXPECT_LT(relative_error(reference.apply(big), want), 1e-12) << "dx 2^+-1000";
    }
  }
}

TEST(JumpRangeTest, ImagesAndTimesBeyondTheRangeAreRefusedWithoutWritingOut) {
  // B = F+ / F- = 1e600: not a double.
  Eigen::MatrixXd limits(1, 2);
  limits << 1e-300, 1e300;
  const JumpMap jump(row({1.0}), limits);
  Eigen::VectorXd dx = vec({-1.0});
  const std::string message = message_of([&] { jump.apply(dx, dx); });
  EXPECT_NE(message.find("apply: component 0 of B(dx) is about -2^1994"), std::string::npos)
      << message;
  EXPECT_EQ(dx[0], -1.0);  // out aliases dx and was not written
  EXPECT_NE(message_of([&] { jump.saltation({0}); }).find("beyond the double range"),
            std::string::npos);
  EXPECT_NE(message_of([&] { jump.pieces(); }).find("pieces: M_sigma for sigma = [0]"),
            std::string::npos);
  // A crossing time of 1e10 / 1e-300 = 1e310.
  Eigen::MatrixXd slow(1, 2);
  slow << 1e-300, 2e-300;
  const JumpMap crawl(row({1.0}), slow);
  EXPECT_NEAR(crawl.apply(vec({-1e10}))[0], -2e10, 2e10 * 4 * kEps);  // the image is fine
  EXPECT_NE(message_of([&] {
              crawl.order(vec({-1e10}));
            }).find("order: the crossing time of surface 0 is about 2^1030"),
            std::string::npos);
}

TEST(JumpRangeTest, TransversalityIsJudgedWithoutOverflowOrUnderflow) {
  // eta . F with F = [1e308, -1e308 (1 - 2^-50)] is positive but both products are near the
  // limit; with eta = [1e-300, 1e-300] the plain product underflows.
  Eigen::MatrixXd limits(2, 2);
  limits.col(0) = vec({1e308, -1e308 * (1 - std::ldexp(1.0, -50))});
  limits.col(1) = vec({1.0, 1.0});
  EXPECT_NO_THROW(JumpMap(row({1e-300, 1e-300}), limits));
  limits.col(0) = vec({1e308, -1e308});  // exactly tangent
  EXPECT_NE(message_of([&] {
              JumpMap(row({1e-300, 1e-300}), limits);
            }).find("surface 0 is not transversal for word \"-\""),
            std::string::npos);
  // Subnormal limits: eta . F = 2.5e-324 > 0 for F = [5e-324, 0] and eta = [0.5, 0.5].
  limits.col(0) = vec({4.9e-324, 0.0});
  EXPECT_NO_THROW(JumpMap(row({0.5, 0.5}), limits));
}

TEST(JumpRangeTest, NormalsOf1e200AndBeyondAreAccepted) {
  Eigen::MatrixXd limits(2, 2);
  limits.col(0) = vec({1.0, 0.0});
  limits.col(1) = vec({2.0, 1.0});
  const JumpMap unit(row({1.0, 0.0}), limits);
  for (double scale : {1e200, 1e-200, 1.7e308, 4.9e-324}) {
    const JumpMap jump(row({scale, 0.0}), limits);
    EXPECT_EQ(jump.apply(vec({-1.0, 0.5})), unit.apply(vec({-1.0, 0.5}))) << scale;
    EXPECT_EQ(jump.normals()(0, 0), scale);
  }
  // Two equal entries of 1.7e308: the norm itself is beyond the double range.
  const JumpMap wide(row({1.7e308, 1.7e308}), limits);
  EXPECT_LT(relative_error(wide.apply(vec({-1.0, 0.0})),
                           JumpMap(row({1.0, 1.0}), limits).apply(vec({-1.0, 0.0}))),
            2 * kEps);
  EXPECT_EQ(message_of([&] { JumpMap(row({0.0, 0.0}), limits); }), "normals: row 0 is zero");
}

TEST(JumpRangeTest, MovedFromJumpMapThrowsInsteadOfUndefinedBehaviour) {
  Eigen::MatrixXd limits(1, 2);
  limits << 1.0, 2.0;
  JumpMap jump(row({1.0}), limits);
  JumpMap moved(std::move(jump));
  EXPECT_EQ(moved.apply(vec({-1.0}))[0], -2.0);
  EXPECT_THROW(jump.apply(vec({-1.0})), std::logic_error);  // NOLINT(bugprone-use-after-move)
  EXPECT_THROW(jump.surfaces(), std::logic_error);
  EXPECT_THROW(jump.pieces(), std::logic_error);
  EXPECT_THROW(jump.triangulation(), std::logic_error);
  const JumpMap copy(jump);  // copying an empty object gives an empty object
  EXPECT_THROW(copy.order(vec({-1.0})), std::logic_error);
  jump = moved;  // assignment makes it usable again
  EXPECT_EQ(jump.apply(vec({-1.0}))[0], -2.0);
}

TEST(JumpRangeTest, PublicTriangulationRejectsWhatItCannotRepresent) {
  Eigen::MatrixXd limits(2, 4);
  limits << 1, 2, 1, 2, 1, 1, 2, 2;
  EXPECT_NE(message_of([] {
              Triangulation(Eigen::MatrixXd::Identity(2, 2), Eigen::MatrixXd::Ones(2, 3));
            }).find("expected a 2 x 4 table"),
            std::string::npos);
  Eigen::MatrixXd zero_row = Eigen::MatrixXd::Identity(2, 2);
  zero_row.row(1).setZero();
  EXPECT_NE(message_of([&] { Triangulation(zero_row, limits); }).find("normal 1 is zero"),
            std::string::npos);
  Eigen::MatrixXd parallel(2, 2);
  parallel << 1, 0, 1, 0;  // rank deficient: never validated by a JumpMap
  EXPECT_NE(message_of([&] { Triangulation(parallel, limits); }).find("not finite"),
            std::string::npos);
  const Triangulation ok(Eigen::MatrixXd::Identity(2, 2), limits);
  EXPECT_NE(message_of([&] {
              ok.apply_barycentric(vec({1.0, 2.0, 3.0}));
            }).find("d = 2"),
            std::string::npos);
  EXPECT_NE(message_of([&] { ok.apply_linear_part(vec({1.0})); }).find("d = 2"), std::string::npos);
  // A tangent of 1e308 on the identity-like map stays finite after the rescaling.
  const JumpMap jump(Eigen::MatrixXd::Identity(2, 2), limits);
  const Eigen::VectorXd huge = vec({-1e307, -0.5e307});
  EXPECT_LT(relative_error(ok.apply_barycentric(huge).image, jump.apply(huge)), 1e-14);
}

TEST(JumpRangeTest, LimitsTableChecksMissingWordsBeforeAllocating) {
  // 2^24 columns of 10^6 numbers would be 1.3e14 bytes: a refusal must come first.
  std::map<std::string, Eigen::VectorXd> words;
  words.emplace(std::string(24, '-'), Eigen::VectorXd::Ones(1000000));
  const std::string message = message_of([&] { limits_table_from_words(24, 1000000, words); });
  EXPECT_EQ(message, "field_limits: missing word \"+" + std::string(23, '-') +
                         "\" (1 of 16777216 words given)");
}

}  // namespace
}  // namespace bflow

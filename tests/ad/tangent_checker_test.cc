#include "bflow/ad/tangent_checker.h"

#include <cmath>
#include <limits>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/core/errors.h"
#include "bflow/core/signs.h"

namespace bflow::ad {
namespace {

using ::testing::HasSubstr;

// Default step h = cbrt(eps) * max(1, |x_i|) ~ 6e-6: central differences are then accurate to
// about h^2 |f'''| / 6 + eps |f| / h ~ 1e-10 for the O(1) functions below, so 1e-8 bounds the
// relative error of a correct derivative with margin.
constexpr double kCentral = 1e-8;

// A damped pendulum whose damping depends on the side of surface 0, with a hand-written
// Jacobian that a user would want to check.
struct Pendulum {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    xdot[0] = x[1];
    xdot[1] = -sin(x[0]) - damping(b) * x[1];
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[1] - T(0.2) * x[0] * x[0];
  }
  static double damping(Signs b) { return b.plus(0) ? 0.1 : 0.3; }

  // Correct analytic Jacobian.
  Eigen::Matrix2d jacobian(const Eigen::Vector2d& x, Signs b) const {
    Eigen::Matrix2d j;
    j << 0.0, 1.0, -std::cos(x[0]), -damping(b);
    return j;
  }
  // The same with a deliberate sign error in entry (1, 0): d(-sin x0)/dx0 written as +cos x0.
  Eigen::Matrix2d wrong_jacobian(const Eigen::Vector2d& x, Signs b) const {
    Eigen::Matrix2d j = jacobian(x, b);
    j(1, 0) = std::cos(x[0]);
    return j;
  }
};

TEST(TangentCheckerTest, CorrectHandJacobianPasses) {
  const Pendulum model;
  const Eigen::Vector2d x(0.3, -1.1);
  const Signs b = Signs::parse("+");
  auto f = [&](const auto* in, auto* out) { model.field(in, b, out); };
  const TangentChecker checker;

  const TangentReport vs_fd = checker.check_jacobian(f, 2, x, model.jacobian(x, b));
  EXPECT_TRUE(vs_fd.ok) << vs_fd.str();
  EXPECT_LT(vs_fd.max_rel_error, kCentral);

  // Against AD the hand Jacobian agrees to rounding; a tight tolerance is meaningful.
  const TangentChecker tight({/*relative_step=*/1e-6, /*tolerance=*/1e-14});
  const TangentReport vs_ad = tight.check_against_ad(f, 2, x, model.jacobian(x, b));
  EXPECT_TRUE(vs_ad.ok) << vs_ad.str();
  EXPECT_EQ(vs_ad.step, 0.0);

  // The model's own AD Jacobian, checked the same way.
  const TangentReport ad = checker.check_field_jacobian(model, x, b);
  EXPECT_TRUE(ad.ok) << ad.str();
  EXPECT_LT(ad.max_rel_error, kCentral);
}

TEST(TangentCheckerTest, DetectsWrongHandJacobianAndLocatesTheEntry) {
  const Pendulum model;
  const Eigen::Vector2d x(0.3, -1.1);
  const Signs b = Signs::parse("-");
  auto f = [&](const auto* in, auto* out) { model.field(in, b, out); };
  const TangentChecker checker;
  // The wrong entry is off by 2 cos(0.3) = 1.91: relative error 1.91 / max(1, cos 0.3).
  const double wrong_by = 2.0 * std::cos(0.3);

  const TangentReport vs_fd = checker.check_jacobian(f, 2, x, model.wrong_jacobian(x, b));
  EXPECT_FALSE(vs_fd.ok);
  EXPECT_EQ(vs_fd.worst_row, 1);
  EXPECT_EQ(vs_fd.worst_col, 0);
  EXPECT_NEAR(vs_fd.max_abs_error, wrong_by, kCentral);
  EXPECT_NEAR(vs_fd.max_rel_error, wrong_by, kCentral);
  EXPECT_NEAR(vs_fd.candidate_value, std::cos(0.3), 0.0);
  EXPECT_NEAR(vs_fd.reference_value, -std::cos(0.3), kCentral);
  // Column 0 was differenced with h = cbrt(eps) * max(1, |0.3|).
  EXPECT_DOUBLE_EQ(vs_fd.step, std::cbrt(std::numeric_limits<double>::epsilon()));

  const TangentReport vs_ad = checker.check_against_ad(f, 2, x, model.wrong_jacobian(x, b));
  EXPECT_FALSE(vs_ad.ok);
  EXPECT_EQ(vs_ad.worst_row, 1);
  EXPECT_EQ(vs_ad.worst_col, 0);
  EXPECT_NEAR(vs_ad.max_abs_error, wrong_by, 1e-15);  // AD is exact: only rounding remains

  const std::string text = vs_fd.str();
  EXPECT_THAT(text, HasSubstr("Jacobian vs central differences (2 x 2): FAILED"));
  EXPECT_THAT(text, HasSubstr("at (1, 0)"));
  EXPECT_THAT(vs_ad.str(), HasSubstr("Jacobian vs AD (2 x 2): FAILED"));
}

// A function written for doubles only: the finite-difference check still applies.
struct DoubleOnly {
  void operator()(const double* x, double* y) const {
    y[0] = std::exp(x[0]) * x[1];
    y[1] = x[0] * x[0] * x[0];
  }
};

TEST(TangentCheckerTest, ChecksFunctionsThatAreNotTemplates) {
  const Eigen::Vector2d x(-0.4, 2.5);
  Eigen::Matrix2d hand;
  hand << std::exp(x[0]) * x[1], std::exp(x[0]), 3.0 * x[0] * x[0], 0.0;
  const TangentReport report = TangentChecker().check_jacobian(DoubleOnly{}, 2, x, hand);
  EXPECT_TRUE(report.ok) << report.str();
  EXPECT_LT(report.max_rel_error, kCentral);
  // Column 1 uses h = cbrt(eps) * 2.5 (|x_1| > 1).
  const Eigen::MatrixXd fd = TangentChecker().central_jacobian(DoubleOnly{}, 2, x);
  EXPECT_NEAR(fd(0, 1), std::exp(x[0]), kCentral);
}

struct Small {
  template <typename T>
  void operator()(const T* x, T* y) const {
    y[0] = x[0] * x[1] * x[2];
    y[1] = sin(x[0] + x[2]) * exp(T(0.5) * x[1]);
  }
};

TEST(TangentCheckerTest, AdJacobianAndJvpAgreeWithCentralDifferences) {
  const Eigen::Vector3d x(0.8, -0.5, 3.0);
  const TangentChecker checker;
  const TangentReport jac = checker.check_ad_jacobian(Small{}, 2, x);
  EXPECT_TRUE(jac.ok) << jac.str();
  EXPECT_LT(jac.max_rel_error, kCentral);
  EXPECT_DOUBLE_EQ(jac.step, checker.step_for(x[jac.worst_col]));
  EXPECT_THAT(jac.str(), HasSubstr("AD Jacobian vs central differences (2 x 3): OK"));

  const Eigen::Vector3d v(1.0, -2.0, 0.5);
  const TangentReport dir = checker.check_jvp(Small{}, 2, x, v);
  EXPECT_TRUE(dir.ok) << dir.str();
  EXPECT_LT(dir.max_rel_error, kCentral);
  EXPECT_EQ(dir.cols, 1);
  // h = cbrt(eps) * max(1, |x|_inf) / |v|_inf = cbrt(eps) * 3 / 2.
  EXPECT_DOUBLE_EQ(dir.step, checker.options().relative_step * 3.0 / 2.0);
}

TEST(TangentCheckerTest, CentralDifferenceErrorIsSecondOrderInTheStep) {
  // f = sin at x = 0.7: the error of central differences is h^2 cos(0.7) / 6 + O(h^4), with
  // rounding (~1e-16 / h ~ 1e-13) negligible at these steps, so halving h divides it by 4.
  auto f = [](const auto* in, auto* out) { out[0] = sin(in[0]); };
  const Eigen::VectorXd x = Eigen::VectorXd::Constant(1, 0.7);
  const TangentReport coarse = TangentChecker({1e-3, 1e-9}).check_ad_jacobian(f, 1, x);
  const TangentReport fine = TangentChecker({5e-4, 1e-9}).check_ad_jacobian(f, 1, x);
  EXPECT_NEAR(coarse.max_abs_error, 1e-6 * std::cos(0.7) / 6.0, 1e-9);
  EXPECT_NEAR(coarse.max_abs_error / fine.max_abs_error, 4.0, 0.05);
  EXPECT_FALSE(coarse.ok);  // 1.3e-7 > tolerance 1e-9
}

// Nonlinear surfaces and a word-dependent field.
struct Curved {
  static constexpr int kStates = 3;
  static constexpr int kSurfaces = 2;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    xdot[0] = x[1] * x[2];
    xdot[1] = b.plus(1) ? cos(x[0]) : exp(-x[2]);
    xdot[2] = T(b.sign(0)) * x[0] * x[1];
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0] * x[0] + T(2.0) * x[1] * x[1] + x[2] * x[2] - T(4.0);
    h[1] = atan2(x[1], x[0]) - T(0.5);
  }
};

TEST(TangentCheckerTest, ChecksModelFieldJacobiansAndNormals) {
  const Curved model;
  const Eigen::Vector3d x(1.2, -0.7, 0.4);
  const TangentChecker checker;
  for (const char* word : {"--", "+-", "-+", "++"}) {
    const TangentReport report = checker.check_field_jacobian(model, x, Signs::parse(word));
    EXPECT_TRUE(report.ok) << report.str();
    EXPECT_LT(report.max_rel_error, kCentral) << word;
    EXPECT_THAT(report.what, HasSubstr(std::string("b = \"") + word + "\""));
  }
  const TangentReport eta = checker.check_normals(model, x);
  EXPECT_TRUE(eta.ok) << eta.str();
  EXPECT_LT(eta.max_rel_error, kCentral);
  EXPECT_EQ(eta.rows, 2);
  EXPECT_EQ(eta.cols, 3);
}

TEST(TangentCheckerTest, NonFiniteCandidateFails) {
  const TangentChecker checker;
  Eigen::Matrix2d candidate = Eigen::Matrix2d::Identity();
  candidate(0, 1) = std::nan("");
  const TangentReport report = checker.compare(candidate, Eigen::Matrix2d::Identity());
  EXPECT_FALSE(report.ok);
  EXPECT_EQ(report.worst_row, 0);
  EXPECT_EQ(report.worst_col, 1);
  EXPECT_TRUE(std::isinf(report.max_rel_error));
}

TEST(TangentCheckerTest, RejectsBadOptionsAndShapesWithMessage) {
  try {
    TangentChecker checker({0.0, 1e-6});
    FAIL() << "expected InvalidArgument";
  } catch (const InvalidArgument& e) {
    EXPECT_THAT(e.what(), HasSubstr("relative_step must be positive and finite, got 0"));
  }
  try {
    TangentChecker checker({1e-6, -1.0});
    FAIL() << "expected InvalidArgument";
  } catch (const InvalidArgument& e) {
    EXPECT_THAT(e.what(), HasSubstr("tolerance must be >= 0"));
  }
  try {
    TangentChecker().check_jacobian(Small{}, 2, Eigen::Vector3d(1, 2, 3), Eigen::Matrix2d::Zero());
    FAIL() << "expected InvalidArgument";
  } catch (const InvalidArgument& e) {
    EXPECT_THAT(e.what(), HasSubstr("the candidate is 2 x 2, the reference is 2 x 3"));
  }
}

}  // namespace
}  // namespace bflow::ad

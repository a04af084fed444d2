#include "bflow/integrators/finite_differences.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/examples/piecewise_constant.h"
#include "bflow/integrators/model_adapter.h"
#include "support/error_message.h"

namespace bflow {
namespace {

// At a kink one-sided differences converge to the B-derivative; central ones do not.
TEST(FiniteDifferencesTest, OneSidedConvergesAtAKinkAndCentralDoesNot) {
  const auto field = examples::PiecewiseConstantField::planar_demo();
  const auto model = adapt(field);
  const Eigen::VectorXd rho_minus = -0.5 * field.limits().col(0);
  // A perturbation a dx separates the two crossings by about a |dx|; inside the simultaneity
  // window they would be grouped and the perturbed state would flip both sides at once. Keep
  // the window below the smallest alpha so every difference sees the true flow.
  FlowOptions options;
  options.simultaneity_window = 1e-14;
  const FlowDerivative derivative = flow_derivative(model, rho_minus, 1.0, options);
  const Eigen::Vector2d dx(1.0, 0.0);
  const Eigen::VectorXd b = derivative.apply(dx);
  // By hand from the pieces of the demo: M_(0,1) (1, 0) = (0.575, 0.2625).
  EXPECT_LE((b - Eigen::Vector2d(0.575, 0.2625)).norm(), 1e-12);
  const fd::Report report = fd::compare(model, rho_minus, 1.0, dx, b, options);
  ASSERT_EQ(report.rows.size(), 9u);
  // The flow is piecewise affine here: one-sided differences are exact up to rounding,
  // c eps |x| / alpha, c the integrator's rounding per unit (about 1 for dopri5, up to 13 for
  // dop853, the defaults' choice at rtol 1e-8: measured 1.6e-6 at alpha = 1e-10), so 5e-6.
  for (const fd::ReportRow& row : report.rows) {
    EXPECT_LE(row.one_sided_error, 5e-6) << "alpha " << row.alpha;
    // Central differences give (B(dx) - B(-dx)) / 2, off by |B(dx) + B(-dx)| / 2 = 0.13.
    EXPECT_GT(row.central_error, 0.1) << "alpha " << row.alpha;
  }
  EXPECT_THAT(report.str(), ::testing::HasSubstr("one-sided error"));
  EXPECT_THAT(testing::message_of([&] { fd::one_sided(model, rho_minus, 1.0, dx, 0.0); }),
              ::testing::HasSubstr("alpha must be positive, got 0"));
}

}  // namespace
}  // namespace bflow

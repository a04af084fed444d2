#include "bflow/core/parameters.h"

#include <cmath>

#include <gtest/gtest.h>

#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"

namespace bflow {
namespace {

// x' = -k x until x = c, then x' = -2 k x. p = (k, c).
struct Decay {
  static constexpr int kStates = 1;
  static constexpr int kSurfaces = 1;
  static constexpr int kParameters = 2;
  template <typename T>
  void field(const T* x, const T* p, Signs b, T* xdot) const {
    xdot[0] = (b.plus(0) ? -p[0] : -2.0 * p[0]) * x[0];
  }
  template <typename T>
  void surfaces(const T* x, const T* p, T* h) const {
    h[0] = p[1] - x[0];  // + once x has decayed below c
  }
};

// Closed form: x reaches c at s = ln(x0 / c) / (2k); then x(t) = c exp(-k (t - s)), that is
// x(t) = sqrt(c x0) exp(-k t). So d x / d k = -t x, d x / d c = x / (2 c), d x / d x0 = x / (2 x0):
// the crossing moves with k and c, and the saltation factor accounts for it.
TEST(ParametersTest, DerivativesWithRespectToParametersThroughAnEvent) {
  const double x0 = 2.0, k = 0.7, c = 1.0, t = 1.5;
  const auto model = adapt(WithParameters<Decay>{});
  FlowOptions options;
  options.integrator.rtol = 1e-12;
  options.integrator.atol = 1e-14;
  FlowResult trajectory;
  const FlowDerivative derivative =
      flow_derivative(model, Eigen::Vector3d(x0, k, c), t, options, &trajectory);
  ASSERT_EQ(trajectory.events.size(), 1u);
  const double s = std::log(x0 / c) / (2 * k);
  const double x = c * std::exp(-k * (t - s));
  EXPECT_NEAR(trajectory.events[0].t, s, 1e-10);
  EXPECT_NEAR(trajectory.x[0], x, 1e-10);
  const Eigen::MatrixXd jacobian = derivative.jacobian();
  // Tolerance: a small multiple of rtol times the size of the entries.
  EXPECT_NEAR(jacobian(0, 1), -t * x, 1e-9);
  EXPECT_NEAR(jacobian(0, 2), x / (2 * c), 1e-9);
  EXPECT_NEAR(jacobian(0, 0), x / (2 * x0), 1e-9);
  // Parameters do not move.
  EXPECT_EQ(jacobian.bottomRows(2), Eigen::MatrixXd::Identity(3, 3).bottomRows(2));
}

}  // namespace
}  // namespace bflow

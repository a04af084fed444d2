// Tightening rtol alone keeps improving the flow derivative: the default atol follows rtol
// (IntegratorOptions::absolute_tolerance() = rtol / 100), so the error does not stall where a
// fixed atol takes over (states that cross zero are held to atol alone near their crossings).
//
// The model has a closed-form flow, so the reference is exact: three Riccati equations
//   x_i' = a_i(b) (1 + x_i^2),   h_j(x) = x_j,
//   a_i(b) = 1 + 0.3 s_{i+1} + 0.2 s_i s_{i+2}   (s_j = +1 on side + of surface j, indices mod 3),
// coupled only through the switching: between events x_i = tan(u_i), u_i' = a_i(b). A crossing
// of surface j is u_j = 0, reached after -u_j / a_j; the event chain is evaluated in long double
// with ceres::Jet<long double, 3> on x0, which differentiates the crossing times too: the
// Jacobian of the flow, exact to rounding (~1e-18), sharing no code with the engine.
#include <cmath>
#include <cstdio>

#include <ceres/jet.h>
#include <gtest/gtest.h>
#include <Eigen/Core>

#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"

namespace bflow {
namespace {

double rate(int i, Signs b) {
  const auto s = [b](int j) { return b.plus(j % 3) ? 1.0 : -1.0; };
  return 1.0 + 0.3 * s(i + 1) + 0.2 * s(i) * s(i + 2);
}

struct Riccati {
  static constexpr int kStates = 3;
  static constexpr int kSurfaces = 3;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    for (int i = 0; i < 3; ++i) xdot[i] = T(rate(i, b)) * (T(1.0) + x[i] * x[i]);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    for (int j = 0; j < 3; ++j) h[j] = x[j];
  }
};

using LongJet = ceres::Jet<long double, 3>;

// phi_t(x0) in closed form, on Jets: crossings in time order (they are well separated here).
void closed_form_flow(const LongJet* x0, long double t, LongJet* x) {
  using std::atan;
  using std::tan;
  LongJet u[3];
  Signs b(3);
  for (int i = 0; i < 3; ++i) {
    u[i] = atan(x0[i]);
    if (x0[i].a > 0) b = b.with_plus(i);
  }
  LongJet now(0.0L);  // the time of the last crossing, a function of x0
  while (true) {
    int next = -1;
    LongJet soonest = LongJet(t) - now;
    for (int j = 0; j < 3; ++j) {
      if (b.plus(j)) continue;
      const LongJet tau = -u[j] / static_cast<long double>(rate(j, b));
      if (tau.a < soonest.a) {
        soonest = tau;
        next = j;
      }
    }
    for (int i = 0; i < 3; ++i) u[i] += static_cast<long double>(rate(i, b)) * soonest;
    if (next < 0) break;
    now += soonest;
    b = b.with_plus(next);
  }
  for (int i = 0; i < 3; ++i) x[i] = tan(u[i]);
}

TEST(ToleranceTest, TighteningRtolAloneKeepsImprovingTheDerivative) {
  const Eigen::Vector3d x0(-0.9, -0.5, -0.2);
  const double t = 1.0;
  LongJet x0_jet[3], x_jet[3];
  for (int i = 0; i < 3; ++i) x0_jet[i] = LongJet(static_cast<long double>(x0[i]), i);
  closed_form_flow(x0_jet, t, x_jet);
  Eigen::Matrix3d reference;
  for (int i = 0; i < 3; ++i) {
    for (int k = 0; k < 3; ++k) reference(i, k) = static_cast<double>(x_jet[i].v[k]);
  }

  const auto model = adapt(Riccati{});
  double previous = INFINITY;
  for (double rtol : {1e-6, 1e-8, 1e-10, 1e-12}) {
    FlowOptions options;  // atol left at its default, rtol / 100
    options.integrator.rtol = rtol;
    FlowResult trajectory;
    const FlowDerivative derivative = flow_derivative(model, x0, t, options, &trajectory);
    ASSERT_EQ(trajectory.events.size(), 3u) << "rtol=" << rtol;
    for (int i = 0; i < 3; ++i) {
      EXPECT_NEAR(trajectory.x[i], static_cast<double>(x_jet[i].a), 100 * rtol);
    }
    const double error = (derivative.jacobian() - reference).norm() / reference.norm();
    std::printf("rtol %.0e (atol %.0e): error of D phi %.2e\n", rtol,
                options.integrator.absolute_tolerance(), error);
    // Measured: 2.8e-6, 1.4e-8, 3.3e-10, 4.2e-13 (with atol fixed at 1e-10 instead: 3.2e-6,
    // 1.4e-8, 1.3e-9, 7.0e-10: the stall). Each 100x tighter rtol must buy >= 10x.
    EXPECT_LT(error, previous / 10) << "rtol=" << rtol;
    EXPECT_LT(error, 10 * rtol) << "rtol=" << rtol;
    previous = error;
  }
}

}  // namespace
}  // namespace bflow

// Hard cases for the flow's B-derivative: near-grazing crossings, six surfaces meeting on a
// trajectory in d = 12 with nonlinear surfaces and fields, and states scaled by 1e-6 and 1e6.
// (Near-simultaneous crossings are in hybrid_flow_test.cc.)
#include <cmath>
#include <random>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/core/biped.h"
#include "bflow/integrators/finite_differences.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;

// (b) F_b = (eps, 1 + b / 2) crossing h = x: eta . F = eps. M = [[1, 0], [1/eps, 1]].
struct Shallow {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  double eps = 1e-2;
  template <typename T>
  void field(const T*, Signs b, T* xdot) const {
    xdot[0] = T(eps);
    xdot[1] = T(b.plus(0) ? 1.5 : 0.5);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
  }
};

TEST(HardCasesTest, NearGrazingCrossingsKeepTheirAccuracy) {
  for (double eps : {1e-2, 1e-4, 1e-6, 1e-8, 1e-10}) {
    const auto model = adapt(Shallow{eps});
    const Eigen::Vector2d x0(-0.5 * eps, 0.0);
    const FlowDerivative derivative = flow_derivative(model, x0, 1.0);
    Eigen::Matrix2d m;
    m << 1.0, 0.0, 1.0 / eps, 1.0;
    // Condition-scaled: the crossing time carries relative error ~ eps_machine / eps.
    EXPECT_LE((derivative.jacobian() - m).norm(), 1e-12 * m.norm() / eps) << "eps=" << eps;
    // One-sided differences with alpha small against eps stay on the same side pattern.
    const Eigen::Vector2d dx(-0.3, 1.0);
    const Eigen::VectorXd fd = fd::one_sided(model, x0, 1.0, dx, 1e-3 * eps);
    const Eigen::VectorXd b = derivative.apply(dx);
    EXPECT_LE((fd - b).norm(), 1e-6 * b.norm()) << "eps=" << eps;
  }
  // Below the grazing threshold (1e-12 relative) the crossing is refused, with the value.
  const auto grazing = adapt(Shallow{1e-14});
  EXPECT_THAT(testing::message_of([&] { simulate(grazing, Eigen::Vector2d(-0.5e-14, 0.0), 1.0); }),
              HasSubstr("grazing at t = "));
}

// (c) Six nonlinear surfaces through one point of a nonlinear flow in d = 12.
struct SixSurfaces {
  static constexpr int kStates = 12;
  static constexpr int kSurfaces = 6;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    using std::cos;
    using std::sin;
    for (int i = 0; i < 12; ++i) xdot[i] = T(0.0);
    for (int j = 0; j < 6; ++j) {
      // The normal speed of surface j changes with the sides of j and of its neighbour.
      const double jump = (b.plus(j) ? 0.4 : 0.0) + (b.plus((j + 1) % 6) ? 0.2 * (j % 3) : 0.0);
      xdot[j] = 1.0 + jump + 0.1 * sin(x[j + 6]) + 0.05 * x[(j + 2) % 6] * x[(j + 2) % 6];
      xdot[j + 6] = 0.3 * cos(x[j]) - 0.2 * x[j + 6] + (b.plus(j) ? 0.5 : -0.1) * (j + 1) / 6.0;
    }
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    using std::sin;
    for (int j = 0; j < 6; ++j) h[j] = x[j] + 0.2 * sin(x[j + 6]) * x[(j + 1) % 6];
  }
};

// The same field reversed in time with no surfaces: to find where to start.
struct Backwards {
  static constexpr int kStates = 12;
  static constexpr int kSurfaces = 0;
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    SixSurfaces{}.field(x, Signs(6), xdot);
    for (int i = 0; i < 12; ++i) xdot[i] = -xdot[i];
  }
  template <typename T>
  void surfaces(const T*, T*) const {}
};

TEST(HardCasesTest, SixSurfacesMeetingOnANonlinearTrajectory) {
  FlowOptions precise;
  precise.integrator.rtol = 1e-12;
  precise.integrator.atol = 1e-14;
  // rho = (0, ..., 0, y) lies on all six surfaces; start where the all-minus flow from there
  // was half a time unit earlier.
  Eigen::VectorXd rho = Eigen::VectorXd::Zero(12);
  rho.tail(6) << 0.3, -0.2, 0.1, 0.5, -0.4, 0.2;
  const Eigen::VectorXd x0 = simulate(adapt(Backwards{}), rho, 0.5, precise).x;
  const auto model = adapt(SixSurfaces{});
  FlowResult trajectory;
  const FlowDerivative derivative = flow_derivative(model, x0, 1.0, precise, &trajectory);
  ASSERT_EQ(trajectory.events.size(), 1u);
  EXPECT_EQ(trajectory.events[0].group_size(), 6);
  EXPECT_NEAR(trajectory.events[0].t, 0.5, 1e-10);
  EXPECT_FALSE(derivative.is_linear());
  // Against one-sided differences. The perturbation separates the crossings by ~alpha, far
  // outside the window; the difference error is O(alpha) (curvature) plus rtol / alpha.
  std::mt19937_64 rng(3);
  std::normal_distribution<double> normal;
  FlowOptions fd_options = precise;
  fd_options.simultaneity_window = 1e-13;
  for (int trial = 0; trial < 4; ++trial) {
    Eigen::VectorXd dx(12);
    for (int i = 0; i < 12; ++i) dx[i] = normal(rng);
    const Eigen::VectorXd b = derivative.apply(dx);
    const Eigen::VectorXd fd = fd::one_sided(model, x0, 1.0, dx, 1e-6, fd_options);
    EXPECT_LE((fd - b).norm(), 1e-4 * b.norm()) << "trial " << trial;
    EXPECT_LE((derivative.active_jacobian(dx) * dx - b).norm(), 1e-10 * b.norm());
  }
}

// (e) States scaled by s: x~ = s x. The derivative is unchanged (D phi~ = S D phi S^-1 with
// S = s I), provided the absolute tolerance is scaled with the states.
template <typename Model>
struct Scaled {
  static constexpr int kStates = Model::kStates;
  static constexpr int kSurfaces = Model::kSurfaces;
  Model model;
  double s = 1.0;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    T y[kStates];
    for (int i = 0; i < kStates; ++i) y[i] = x[i] / s;
    model.field(y, b, xdot);
    for (int i = 0; i < kStates; ++i) xdot[i] *= s;
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    T y[kStates];
    for (int i = 0; i < kStates; ++i) y[i] = x[i] / s;
    model.surfaces(y, h);
  }
};

TEST(HardCasesTest, ScaledStatesGiveTheSameDerivative) {
  FlowOptions options;
  options.integrator.rtol = 1e-10;
  Eigen::VectorXd rho = Eigen::VectorXd::Zero(12);
  rho.tail(6) << 0.3, -0.2, 0.1, 0.5, -0.4, 0.2;
  const Eigen::VectorXd x0 = simulate(adapt(Backwards{}), rho, 0.5, options).x;
  options.integrator.atol = 1e-12;
  const FlowDerivative reference = flow_derivative(adapt(SixSurfaces{}), x0, 1.0, options);
  Eigen::VectorXd dx = Eigen::VectorXd::LinSpaced(12, -1.0, 1.0);
  const Eigen::VectorXd expected = reference.apply(dx);
  for (double s : {1e-6, 1e6}) {
    FlowOptions scaled = options;
    scaled.integrator.atol = 1e-12 * s;
    const FlowDerivative derivative =
        flow_derivative(adapt(Scaled<SixSurfaces>{SixSurfaces{}, s}), s * x0, 1.0, scaled);
    EXPECT_LE((derivative.apply(dx) - expected).norm(), 1e-7 * expected.norm()) << "s=" << s;
  }
}

// (d) The biped with stiff contacts, kappa = 1e6, on CVODES BDF: the feet touch down together,
// bounce within milliseconds and lift off together. BDF and Dormand-Prince must agree, and the
// derivative must match one-sided differences.
TEST(HardCasesTest, StiffBipedOnCvodesBdf) {
  BipedParams params;
  params.variant = BipedVariant::kModeDamping;
  params.kappa = 1e6;
  const auto model = adapt(make_biped_mode_damping(params));
  const Eigen::VectorXd x0 = biped_initial_state();
  const double t = 0.45;
  FlowOptions bdf;
  bdf.backend = Backend::kCvodesBdf;
  bdf.integrator.rtol = 1e-10;
  bdf.integrator.atol = 1e-12;
  FlowResult trajectory;
  const FlowDerivative derivative = flow_derivative(model, x0, t, bdf, &trajectory);
  ASSERT_GE(trajectory.events.size(), 2u);
  EXPECT_EQ(trajectory.events[0].group_size(), 2);
  EXPECT_EQ(trajectory.events[0].sides_after.str(), "++");
  EXPECT_EQ(trajectory.events.back().sides_after.str(), "--");
  FlowOptions dopri = bdf;
  dopri.backend = Backend::kDopri5;
  FlowResult reference;
  const FlowDerivative explicit_derivative = flow_derivative(model, x0, t, dopri, &reference);
  EXPECT_EQ(reference.events.size(), trajectory.events.size());
  EXPECT_LE((reference.x - trajectory.x).norm(), 1e-7 * reference.x.norm());
  const Eigen::VectorXd dx = (Eigen::VectorXd(6) << 0.3, -0.2, 0.5, 0.1, 0.0, -1.0).finished();
  const Eigen::VectorXd b = derivative.apply(dx);
  ASSERT_TRUE(b.allFinite());
  // Two adaptive methods at rtol 1e-10 through a 1e6-stiff contact: agreement to 1e-5.
  EXPECT_LE((explicit_derivative.apply(dx) - b).norm(), 1e-5 * b.norm());
  FlowOptions fd_options = bdf;
  fd_options.simultaneity_window = 1e-13;
  const Eigen::VectorXd fd = fd::one_sided(model, x0, t, dx, 1e-7, fd_options);
  EXPECT_LE((fd - b).norm(), 1e-3 * b.norm());
}

}  // namespace
}  // namespace bflow

// One suite for every backend: the variational solution of linear systems against exp(At),
// tangents against one-sided finite differences, convergence as the tolerance tightens, and
// crossings located where they are.
#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unsupported/Eigen/MatrixFunctions>

#include "bflow/examples/reference_flow.h"
#include "bflow/integrators/dop853.h"
#include "bflow/integrators/dopri5.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"

namespace bflow {
namespace {

// x' = A x with a rotation-and-decay A; no surfaces.
struct Linear {
  static constexpr int kStates = 3;
  static constexpr int kSurfaces = 0;
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    xdot[0] = -0.3 * x[0] + 2.0 * x[1];
    xdot[1] = -2.0 * x[0] - 0.3 * x[1] + 0.5 * x[2];
    xdot[2] = -1.5 * x[2];
  }
  template <typename T>
  void surfaces(const T*, T*) const {}
  static Eigen::Matrix3d matrix() {
    Eigen::Matrix3d a;
    a << -0.3, 2.0, 0.0, -2.0, -0.3, 0.5, 0.0, 0.0, -1.5;
    return a;
  }
};

// A pendulum with one surface, theta = level (0.4 unless set), crossed from below.
struct Pendulum {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  double level = 0.4;
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    using std::sin;
    xdot[0] = x[1];
    xdot[1] = -sin(x[0]);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0] - level;
  }
};

class IntegratorTest : public ::testing::TestWithParam<Backend> {
 protected:
  FlowOptions options(double rtol) const {
    FlowOptions o;
    o.backend = GetParam();
    o.integrator.rtol = rtol;
    o.integrator.atol = rtol * 1e-2;
    return o;
  }
};

TEST_P(IntegratorTest, LinearSystemAndItsVariationalEquationMatchTheExponential) {
  const auto model = adapt(Linear{});
  const Eigen::Vector3d x0(1.0, -0.5, 2.0);
  const double t = 2.5;
  const Eigen::Matrix3d exp_at = (Linear::matrix() * t).exp();
  const FlowResult r = simulate(model, x0, t, Eigen::Matrix3d::Identity(), options(1e-10));
  ASSERT_TRUE(r.ok()) << r.message;
  // Global error of a tolerance-controlled run: a small multiple of rtol over this horizon.
  EXPECT_LE((r.x - exp_at * x0).norm(), 1e-8 * x0.norm());
  EXPECT_LE((r.v - exp_at).norm(), 1e-8 * exp_at.norm());
  EXPECT_TRUE(r.events.empty());
}

TEST_P(IntegratorTest, ErrorFallsWithTheTolerance) {
  const auto model = adapt(Linear{});
  const Eigen::Vector3d x0(1.0, -0.5, 2.0);
  const Eigen::Vector3d exact = (Linear::matrix() * 2.5).exp() * x0;
  const double loose = (simulate(model, x0, 2.5, options(1e-5)).x - exact).norm();
  const double tight = (simulate(model, x0, 2.5, options(1e-10)).x - exact).norm();
  EXPECT_GT(loose, 0.0);
  // Five orders of tolerance must buy at least three orders of accuracy.
  EXPECT_LT(tight, 1e-3 * loose) << "loose " << loose << " tight " << tight;
}

TEST_P(IntegratorTest, TangentsAgreeWithOneSidedDifferences) {
  const auto model = adapt(Linear{});
  const Eigen::Vector3d x0(0.2, 0.1, -0.3);
  const Eigen::Vector3d dx(0.3, -1.0, 0.5);
  const FlowOptions o = options(1e-11);
  const FlowResult r = simulate(model, x0, 1.7, dx, o);
  const double alpha = 1e-6;
  const Eigen::VectorXd fd = (simulate(model, x0 + alpha * dx, 1.7, o).x - r.x) / alpha;
  // Linear system: the difference is exact up to rounding eps |x| / alpha and rtol / alpha.
  EXPECT_LE((r.v.col(0) - fd).norm(), 1e-4 * dx.norm());
}

TEST_P(IntegratorTest, CrossingIsLocatedAndItsSaltationIsTheIdentityForAContinuousField) {
  const auto model = adapt(Pendulum{});
  const Eigen::Vector2d x0(0.0, 1.0);
  const FlowResult r = simulate(model, x0, 1.0, Eigen::Matrix2d::Identity(), options(1e-11));
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.events.size(), 1u);
  // The surface theta = 0.4 on the pendulum: the event lies on it to the tolerance.
  EXPECT_NEAR(r.events[0].rho[0], 0.4, 1e-9);
  EXPECT_EQ(r.events[0].sides_before.str(), "-");
  EXPECT_EQ(r.events[0].sides_after.str(), "+");
  // The field is the same on both sides, so the flow is smooth and central differences are
  // valid: truncation O(alpha^2) ~ 1e-8, plus the run-to-run noise of adaptive steps,
  // ~ rtol / alpha ~ 1e-7.
  const FlowOptions o = options(1e-11);
  const double alpha = 1e-4;
  for (int c = 0; c < 2; ++c) {
    const Eigen::Vector2d dx = Eigen::Matrix2d::Identity().col(c);
    const Eigen::VectorXd fd =
        (simulate(model, x0 + alpha * dx, 1.0, o).x - simulate(model, x0 - alpha * dx, 1.0, o).x) /
        (2 * alpha);
    EXPECT_LE((r.v.col(c) - fd).norm(), 1e-5) << "column " << c;
  }
}

INSTANTIATE_TEST_SUITE_P(Backends, IntegratorTest,
                         ::testing::Values(Backend::kDopri5, Backend::kDop853, Backend::kCvodesBdf,
                                           Backend::kCvodesAdams),
                         [](const ::testing::TestParamInfo<Backend>& param) {
                           std::string name = to_string(param.param);
                           for (char& c : name)
                             if (c == '-') c = '_';
                           return name;
                         });

// DOP853 is eighth order: at fixed steps, halving the step divides the error by ~256 (measured
// 273 and 262 for the state and the tangents from 4 to 8 to 16 steps; a fifth-order stage or
// weight would show as ~32), for the state and for the tangents carried in Jets.
TEST(Dop853Test, EighthOrderConvergenceAtFixedSteps) {
  const auto model = adapt(Linear{});
  const Eigen::Vector3d x0(1.0, -0.5, 2.0);
  const double t = 2.0;
  const Eigen::Matrix3d exp_at = (Linear::matrix() * t).exp();
  double previous = 0, previous_tangent = 0;
  for (int steps : {4, 8, 16}) {
    IntegratorOptions o;
    o.rtol = 1e10;  // accept every step
    o.atol = 1e10;
    o.initial_step = o.max_step = t / steps;
    Dop853Integrator integrator;
    SegmentRequest request{Signs(0), 0.0, t, x0, Eigen::Matrix3d::Identity()};
    const SegmentResult r = integrator.integrate(model, request, o);
    ASSERT_EQ(r.status, IntegrationStatus::kReachedEnd);
    EXPECT_EQ(r.steps, steps);
    const double error = (r.x - exp_at * x0).norm();
    const double tangent = (r.v - exp_at).norm();
    if (previous > 0) {
      EXPECT_GT(previous / error, 160.0) << steps << " steps, error " << error;
      EXPECT_LT(previous / error, 400.0) << steps << " steps, error " << error;
      EXPECT_GT(previous_tangent / tangent, 160.0) << steps << " steps, tangent " << tangent;
      EXPECT_LT(previous_tangent / tangent, 400.0) << steps << " steps, tangent " << tangent;
    }
    previous = error;
    previous_tangent = tangent;
  }
}

// Crossings are located on DOP853's dense output (order 7, its three extra stages). With fixed
// steps h the error of the crossing time depends on where in its step the crossing falls, so the
// worst over 21 surface levels theta = 0.1 ... 0.9 is compared: it falls by 249 and 338 from
// h = 0.4 to 0.2 to 0.1 (measured), the order of the method; an interpolant of order 4 (as
// dopri5's, measured 27 and 26 the same way) or a wrong dense coefficient would fall by ~32 at
// most. The reference times: examples::ReferenceFlow, a long double sixth-order Runge-Kutta
// with bisection that shares no code with the integrator (crossing times to ~1e-17).
TEST(Dop853Test, CrossingsOnTheDenseOutputConvergeAtTheMethodsOrder) {
  Dop853Integrator integrator;
  const Eigen::Vector2d x0(0.0, 1.0);
  const SegmentRequest request{Signs(1, 0), 0.0, 3.0, x0, Eigen::MatrixXd(2, 0)};
  std::vector<double> reference;
  for (int k = 0; k <= 20; ++k) {
    Pendulum pendulum;
    pendulum.level = 0.1 + 0.04 * k;
    const examples::ReferenceFlow<Pendulum> flow(pendulum);
    const auto run = flow.flow(x0.cast<long double>(), 3.0L);
    ASSERT_FALSE(run.crossings.empty()) << "level " << pendulum.level;
    reference.push_back(static_cast<double>(run.crossings.front().t));
  }
  double previous = 0;
  for (double h : {0.4, 0.2, 0.1}) {
    IntegratorOptions o;
    o.rtol = 1e10;  // accept every step
    o.atol = 1e10;
    o.initial_step = o.max_step = h;
    double worst = 0;
    for (int k = 0; k <= 20; ++k) {
      Pendulum pendulum;
      pendulum.level = 0.1 + 0.04 * k;
      const SegmentResult r = integrator.integrate(adapt(pendulum), request, o);
      ASSERT_EQ(r.status, IntegrationStatus::kCrossing) << "level " << pendulum.level;
      worst = std::max(worst, std::abs(r.t - reference[static_cast<std::size_t>(k)]));
    }
    if (previous > 0) {
      EXPECT_GT(previous / worst, 150.0) << "h " << h << ", worst error " << worst;
      EXPECT_LT(previous / worst, 500.0) << "h " << h << ", worst error " << worst;
    }
    previous = worst;
  }
  EXPECT_LT(previous, 1e-12);
}

// Dormand-Prince is fifth order: at fixed steps, halving the step divides the error by ~32.
TEST(Dopri5Test, FifthOrderConvergenceAtFixedSteps) {
  const auto model = adapt(Linear{});
  const Eigen::Vector3d x0(1.0, -0.5, 2.0);
  const double t = 2.0;
  const Eigen::Vector3d exact = (Linear::matrix() * t).exp() * x0;
  double previous = 0;
  for (int steps : {10, 20, 40, 80}) {
    IntegratorOptions o;
    o.rtol = 1e10;  // accept every step
    o.atol = 1e10;
    o.initial_step = o.max_step = t / steps;
    Dopri5Integrator integrator;
    SegmentRequest request{Signs(0), 0.0, t, x0, Eigen::MatrixXd(3, 0)};
    const SegmentResult r = integrator.integrate(model, request, o);
    ASSERT_EQ(r.status, IntegrationStatus::kReachedEnd);
    EXPECT_EQ(r.steps, steps);
    const double error = (r.x - exact).norm();
    if (previous > 0) {
      const double ratio = previous / error;
      EXPECT_GT(ratio, 25.0) << steps << " steps";
      EXPECT_LT(ratio, 40.0) << steps << " steps";
    }
    previous = error;
  }
}

// A nonlinear field in three states, to exercise the Jet arithmetic of every width.
struct Nonlinear {
  static constexpr int kStates = 3;
  static constexpr int kSurfaces = 0;
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    using std::sin;
    xdot[0] = x[1] * x[2] - 0.2 * x[0];
    xdot[1] = sin(x[0]) - 0.5 * x[1];
    xdot[2] = -x[0] * x[1] + 0.1 * x[2] * x[2];
  }
  template <typename T>
  void surfaces(const T*, T*) const {}
};

// k directions run in chunks of up to sixteen, each in the narrowest Jet width (1, 2, 4, 6, 8,
// 12, 16): with the state alone in the error norm every chunk takes the first chunk's steps, so
// each column equals the same column integrated alone (Jet lanes are independent), for any k.
TEST(Dopri5Test, EveryChunkWidthGivesTheTangentsOfSingleDirections) {
  const auto model = adapt(Nonlinear{});
  const Eigen::Vector3d x0(0.4, -0.3, 0.8);
  IntegratorOptions o;
  o.rtol = 1e-9;
  o.atol = 1e-11;
  o.tangents_in_error_norm = false;  // with the tangents, a chunk's steps depend on its directions
  Dopri5Integrator integrator;
  for (int k : {1, 2, 3, 4, 5, 6, 7, 8, 9, 12, 13, 16, 17, 33}) {
    const Eigen::MatrixXd v0 = Eigen::MatrixXd::Random(3, k);
    const SegmentResult block = integrator.integrate(model, {Signs(0), 0.0, 2.0, x0, v0}, o);
    ASSERT_EQ(block.status, IntegrationStatus::kReachedEnd) << block.message;
    ASSERT_EQ(block.v.cols(), k);
    for (int c = 0; c < k; ++c) {
      const SegmentResult single =
          integrator.integrate(model, {Signs(0), 0.0, 2.0, x0, v0.col(c)}, o);
      EXPECT_EQ(single.steps, block.steps) << "k = " << k;
      EXPECT_LE((single.v.col(0) - block.v.col(c)).norm(), 1e-14 * single.v.col(0).norm())
          << "k = " << k << ", column " << c;
    }
  }
}

// A falling point mass that hits the floor h = -y (side + below it): two states, one surface.
struct Drop {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    xdot[0] = x[1];
    xdot[1] = b.plus(0) ? T(-9.81) - 400.0 * x[0] - 4.0 * x[1] : T(-9.81);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = -x[0];
  }
};

// An integrator object keeps its steppers between segments (one per Jet width, rebuilt when d or
// n changes): whatever it integrated before, each segment is exactly what a new object gives.
template <typename Integrator>
void expect_reuse_changes_nothing() {
  const auto nonlinear = adapt(Nonlinear{});
  const auto drop = adapt(Drop{});
  IntegratorOptions o;
  o.rtol = 1e-9;
  struct Case {
    const SegmentModel* model;
    SegmentRequest request;
  };
  const Eigen::Vector3d x3(0.4, -0.3, 0.8);
  const Eigen::Vector2d x2(1.0, 0.0);
  const std::vector<Case> cases = {
      {&nonlinear, {Signs(0), 0.0, 2.0, x3, Eigen::MatrixXd::Identity(3, 3)}},
      {&drop, {Signs(1), 0.0, 2.0, x2, Eigen::MatrixXd::Identity(2, 2)}},
      {&nonlinear, {Signs(0), 0.5, 1.5, x3, Eigen::MatrixXd::Random(3, 12)}},
      {&drop, {Signs(1), 0.0, 2.0, x2, Eigen::MatrixXd(2, 0)}},
      {&drop, {Signs(1), 0.0, 2.0, 0.5 * x2, Eigen::MatrixXd::Identity(2, 2)}},
      {&nonlinear, {Signs(0), 0.0, 2.0, -x3, Eigen::MatrixXd::Identity(3, 3)}},
  };
  Integrator kept;
  for (std::size_t c = 0; c < cases.size(); ++c) {
    const SegmentResult again = kept.integrate(*cases[c].model, cases[c].request, o);
    Integrator fresh;
    const SegmentResult alone = fresh.integrate(*cases[c].model, cases[c].request, o);
    EXPECT_EQ(again.status, alone.status) << "case " << c;
    EXPECT_EQ(again.steps, alone.steps) << "case " << c;
    EXPECT_EQ(again.rejected_steps, alone.rejected_steps) << "case " << c;
    EXPECT_EQ(again.t, alone.t) << "case " << c;
    EXPECT_EQ(again.x, alone.x) << "case " << c;
    EXPECT_EQ(again.v, alone.v) << "case " << c;
    EXPECT_EQ(again.crossed, alone.crossed) << "case " << c;
  }
  // The drop from x2 crosses its floor within the segment: the cases cover a crossing.
  Integrator fresh;
  EXPECT_EQ(fresh.integrate(drop, cases[1].request, o).status, IntegrationStatus::kCrossing);
}

TEST(Dopri5Test, AKeptIntegratorGivesWhatANewOneGives) {
  expect_reuse_changes_nothing<Dopri5Integrator>();
}

TEST(Dop853Test, AKeptIntegratorGivesWhatANewOneGives) {
  expect_reuse_changes_nothing<Dop853Integrator>();
}

// From x0 = 0 the linear system's state stays exactly 0, so the state's error estimate is 0 and a
// state-only norm lets the steps grow unchecked, while the tangents (exp(At) V) are anything but
// small. With the tangents in the norm each direction is held to rtol relative to its size.
TEST(Dopri5Test, TangentsInTheErrorNormHoldTheDerivativeToTheToleranceWhereTheStateIsBlind) {
  const auto model = adapt(Linear{});
  const double t = 2.5;
  const Eigen::Matrix3d exp_at = (Linear::matrix() * t).exp();
  const Eigen::Matrix3d v0 = Eigen::Matrix3d::Identity();
  Dopri5Integrator integrator;
  auto worst_column_error = [&](const SegmentResult& r) {
    double worst = 0;
    for (int c = 0; c < 3; ++c) {
      worst = std::max(worst, (r.v.col(c) - exp_at.col(c)).norm() / exp_at.col(c).norm());
    }
    return worst;
  };
  for (double rtol : {1e-6, 1e-8, 1e-10}) {
    IntegratorOptions o;
    o.rtol = rtol;
    o.atol = 1e-3 * rtol;
    o.tangents_in_error_norm = false;
    const SegmentResult blind =
        integrator.integrate(model, {Signs(0), 0.0, t, Eigen::Vector3d::Zero(), v0}, o);
    o.tangents_in_error_norm = true;
    const SegmentResult held =
        integrator.integrate(model, {Signs(0), 0.0, t, Eigen::Vector3d::Zero(), v0}, o);
    ASSERT_EQ(held.status, IntegrationStatus::kReachedEnd) << held.message;
    EXPECT_EQ(blind.x.norm(), 0.0);
    EXPECT_EQ(held.x.norm(), 0.0);
    // The global error of a tolerance-controlled run: within a small multiple of rtol.
    EXPECT_LE(worst_column_error(held), 10 * rtol) << "rtol " << rtol;
    EXPECT_GT(worst_column_error(blind), 1e3 * rtol) << "rtol " << rtol;
    EXPECT_GT(held.steps, blind.steps);
  }
}

TEST(Dopri5Test, FailuresAreStatusesWithMessages) {
  const auto model = adapt(Linear{});
  IntegratorOptions o;
  o.max_steps = 3;
  Dopri5Integrator integrator;
  SegmentRequest request{Signs(0), 0.0, 100.0, Eigen::Vector3d(1, 1, 1), Eigen::MatrixXd(3, 0)};
  const SegmentResult r = integrator.integrate(model, request, o);
  EXPECT_EQ(r.status, IntegrationStatus::kTooManySteps);
  EXPECT_THAT(r.message, ::testing::HasSubstr("max_steps = 3 steps taken, stopped at t = "));
  EXPECT_THAT(r.message, ::testing::HasSubstr(" before t_end = 100"));
}

}  // namespace
}  // namespace bflow

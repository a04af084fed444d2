#include "bflow/integrators/hybrid_flow.h"

#include <cmath>
#include <cstdio>
#include <random>
#include <tuple>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/examples/piecewise_constant.h"
#include "bflow/integrators/model_adapter.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using examples::PiecewiseConstantField;
using ::testing::HasSubstr;
using testing::message_of;

// [B] (3.2): from rho- = -F_-/2 for unit time the flow derivative of the linear
// piecewise-constant field is (1 - delta)/(1 + delta) I; all d surfaces are one event.
TEST(HybridFlowTest, PiecewiseConstantLinearCaseIsTheClosedForm) {
  std::mt19937_64 rng(1);
  std::normal_distribution<double> normal;
  for (int d = 2; d <= 8; ++d) {
    const double delta = 0.35;
    const auto model = adapt(PiecewiseConstantField::linear(d, delta));
    const Eigen::VectorXd rho_minus = -0.5 * Eigen::VectorXd::Constant(d, 1 + delta);
    FlowResult trajectory;
    const FlowDerivative derivative = flow_derivative(model, rho_minus, 1.0, {}, &trajectory);
    ASSERT_EQ(trajectory.events.size(), 1u) << "d=" << d;
    EXPECT_EQ(trajectory.events[0].group_size(), d);
    EXPECT_NEAR(trajectory.events[0].t, 0.5, 1e-12);
    // The field is constant between events, so the flow is exact up to rounding.
    EXPECT_LE((trajectory.x - Eigen::VectorXd::Constant(d, 0.5 * (1 - delta))).norm(), 1e-12);
    const double gain = (1 - delta) / (1 + delta);
    for (int trial = 0; trial < 5; ++trial) {
      Eigen::VectorXd dx(d);
      for (int i = 0; i < d; ++i) dx[i] = normal(rng);
      EXPECT_LE((derivative.apply(dx) - gain * dx).norm(), 1e-12 * dx.norm()) << "d=" << d;
    }
    ASSERT_TRUE(derivative.is_linear());
    EXPECT_LE((derivative.jacobian() - gain * Eigen::MatrixXd::Identity(d, d)).norm(), 1e-12);
  }
}

// The general case equals the jump module's B, and one-sided differences of the exact flow.
TEST(HybridFlowTest, PiecewiseConstantGeneralCaseIsTheJumpModulesB) {
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> uniform(-0.7, 1.5);
  std::normal_distribution<double> normal;
  for (int d : {2, 3, 5, 8}) {
    Eigen::MatrixXd delta(d, Eigen::Index{1} << d);
    for (Eigen::Index i = 0; i < delta.size(); ++i) delta.data()[i] = uniform(rng);
    const PiecewiseConstantField field(delta);
    const auto model = adapt(field);
    const JumpMap jump(Eigen::MatrixXd::Identity(d, d), field.limits());
    const Eigen::VectorXd rho_minus = -0.5 * field.limits().col(0);
    const FlowDerivative derivative = flow_derivative(model, rho_minus, 1.0);
    ASSERT_EQ(derivative.events(), 1);
    for (int trial = 0; trial < 5; ++trial) {
      Eigen::VectorXd dx(d);
      for (int i = 0; i < d; ++i) dx[i] = normal(rng);
      const Eigen::VectorXd b = jump.apply(dx);
      EXPECT_LE((derivative.apply(dx) - b).norm(), 1e-11 * b.norm()) << "d=" << d;
      // One-sided differences of the exact flow (piecewise affine: exact up to rounding).
      const double alpha = 1e-7;
      const Eigen::VectorXd fd =
          (field.flow(rho_minus + alpha * dx, 1.0) - field.flow(rho_minus, 1.0)) / alpha;
      EXPECT_LE((fd - b).norm(), 1e-6 * b.norm()) << "d=" << d;
      EXPECT_LE((derivative.active_jacobian(dx) * dx - b).norm(), 1e-11 * b.norm());
    }
    if (d <= 5) {
      EXPECT_EQ(derivative.pieces().size(), static_cast<std::size_t>(std::tgamma(d + 1) + 0.5));
    }
    EXPECT_FALSE(derivative.is_linear());
    EXPECT_THAT(message_of([&] { derivative.jacobian(); }),
                HasSubstr("only piecewise linear: the event at t = "));
  }
}

// One surface where the speed doubles: d phi / d x0 = F+ / F- = 2, the saltation matrix.
struct SpeedUp {
  static constexpr int kStates = 1;
  static constexpr int kSurfaces = 1;
  template <typename T>
  void field(const T*, Signs b, T* xdot) const {
    xdot[0] = T(b.plus(0) ? 2.0 : 1.0);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0] - 0.5;
  }
};

TEST(HybridFlowTest, OneSurfaceGivesTheSaltationMatrix) {
  const auto model = adapt(SpeedUp{});
  const FlowResult r = simulate(model, Eigen::VectorXd::Zero(1), 1.0, Eigen::MatrixXd::Ones(1, 1));
  ASSERT_TRUE(r.ok());
  ASSERT_EQ(r.events.size(), 1u);
  EXPECT_NEAR(r.events[0].t, 0.5, 1e-14);
  EXPECT_NEAR(r.x[0], 1.5, 1e-13);
  EXPECT_NEAR(r.v(0, 0), 2.0, 1e-13);
  const FlowDerivative derivative = flow_derivative(model, Eigen::VectorXd::Zero(1), 1.0);
  EXPECT_NEAR(derivative.jacobian()(0, 0), 2.0, 1e-13);
  EXPECT_NEAR(derivative.time_derivative()[0], 2.0, 0.0);
  // Starting delta further on, the crossing comes delta earlier: d t_event / d x0 = -1/F- = -1.
  const std::vector<CrossingOrder> shifts = derivative.crossing_orders(Eigen::VectorXd::Ones(1));
  ASSERT_EQ(shifts.size(), 1u);
  EXPECT_NEAR(shifts[0].times[0], -1.0, 1e-14);
}

// Event-time shifts against finite differences of the located event times (the biped-free
// two-surface case: each surface's own crossing time moves).
TEST(HybridFlowTest, EventTimeShiftsMatchDifferencesOfTheEventTimes) {
  Eigen::MatrixXd delta(2, 4);
  delta << 0.0, -0.5, 0.7, -0.3, 0.0, 0.6, -0.4, -0.3;
  const auto model = adapt(PiecewiseConstantField(delta));
  const Eigen::Vector2d x0(-0.5, -0.7);  // surface 0 at t = 0.5, surface 1 later
  const FlowDerivative derivative = flow_derivative(model, x0, 1.5);
  const Eigen::Vector2d dx(0.3, -0.8);
  const std::vector<CrossingOrder> shifts = derivative.crossing_orders(dx);
  const double alpha = 1e-7;
  const FlowResult base = simulate(model, x0, 1.5);
  const FlowResult moved = simulate(model, x0 + alpha * dx, 1.5);
  ASSERT_EQ(shifts.size(), 2u);
  ASSERT_EQ(moved.events.size(), 2u);
  for (int i = 0; i < 2; ++i) {
    const double fd = (moved.events[i].t - base.events[i].t) / alpha;
    // Piecewise-affine flow: exact up to rounding eps / alpha ~ 1e-9.
    EXPECT_NEAR(shifts[i].times[0], fd, 1e-7) << "event " << i;
  }
}

// Hard case (a): two surfaces crossed dt apart. With a fixed window (the automatic one is in
// grouping_test.cc) they are grouped exactly when dt is inside the window:
// then the derivative is the jump module's B; outside it is the sequential saltation product.
TEST(HybridFlowTest, NearSimultaneousCrossingsAreGroupedByTheWindow) {
  Eigen::MatrixXd delta(2, 4);
  delta << 0.0, -0.5, 0.7, -0.3, 0.0, 0.6, -0.4, -0.3;
  const PiecewiseConstantField field(delta);
  const auto model = adapt(field);
  const Eigen::MatrixXd limits = field.limits();
  const JumpMap b(Eigen::MatrixXd::Identity(2, 2), limits);
  FlowOptions options;
  options.grouping = Grouping::kFixedWindow;
  options.simultaneity_window = 1e-9;
  for (double dt : {1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12, 1e-14, 0.0}) {
    // Surface 0 at t = 0.5, surface 1 at t = 0.5 + dt (F_-- = (1, 1)).
    const Eigen::Vector2d x0(-0.5, -0.5 - dt);
    FlowResult trajectory;
    const FlowDerivative derivative = flow_derivative(model, x0, 1.0, options, &trajectory);
    const bool grouped = dt <= options.simultaneity_window;
    ASSERT_EQ(trajectory.events.size(), grouped ? 1u : 2u) << "dt=" << dt;
    Eigen::Matrix2d expected;
    if (grouped) {
      EXPECT_EQ(trajectory.events[0].group_size(), 2);
      // Compare on directions in both cones of B.
      for (const Eigen::Vector2d& dx :
           {Eigen::Vector2d(1, 0), Eigen::Vector2d(0, 1), Eigen::Vector2d(-1, 0.3)}) {
        EXPECT_LE((derivative.apply(dx) - b.apply(dx)).norm(), 1e-9) << "dt=" << dt;
      }
    } else {
      // Surface 0 first (word "--" -> "+-"), then surface 1 ("+-" -> "++").
      expected = b.saltation({0, 1});
      EXPECT_LE((derivative.jacobian() - expected).norm(), 1e-8 * expected.norm()) << "dt=" << dt;
    }
    EXPECT_TRUE(derivative.apply(Eigen::Vector2d(0.3, -0.7)).allFinite());
  }
}

// Errors: the starting side undecided, grazing, sliding, the event limit.
struct Slider {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  double after = -1.0;  // the normal component of the field on the + side
  template <typename T>
  void field(const T*, Signs b, T* xdot) const {
    xdot[0] = T(b.plus(0) ? after : 1.0);
    xdot[1] = T(1.0);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
  }
};

TEST(HybridFlowTest, SlidingGrazingAndUndecidedStartsAreErrorsWithValues) {
  const auto sliding = adapt(Slider{-1.0});
  EXPECT_THAT(message_of([&] { simulate(sliding, Eigen::Vector2d(-0.5, 0.0), 1.0); }),
              HasSubstr("after crossing surface 0 the field F_+ points back into it"));
  EXPECT_THAT(message_of([&] { simulate(sliding, Eigen::Vector2d(-0.5, 0.0), 1.0); }),
              HasSubstr("Simulate sliding with FESD"));
  EXPECT_THAT(message_of([&] { simulate(sliding, Eigen::Vector2d(0.0, 0.0), 1.0); }),
              HasSubstr("x0 = [0, 0] has h_0 = 0"));
}

struct Oscillator {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    xdot[0] = x[1];
    xdot[1] = -100.0 * x[0];
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
  }
};

TEST(HybridFlowTest, TheEventLimitIsAStatus) {
  FlowOptions options;
  options.max_events = 5;
  const FlowResult r = simulate(adapt(Oscillator{}), Eigen::Vector2d(0.1, 0.0), 10.0, options);
  EXPECT_EQ(r.status, IntegrationStatus::kTooManyEvents);
  EXPECT_THAT(r.message, HasSubstr("6 events by t = "));
  EXPECT_THAT(r.message, HasSubstr("Zeno"));
}

// Backend "auto" (the default): dopri5 at loose tolerances on a small model with surfaces, dop853
// at tight ones, with many states or without surfaces; the run reports its choice and is the run
// of the backend it names.
TEST(HybridFlowTest, TheAutomaticBackendIsChosenByToleranceAndSizeAndReported) {
  EXPECT_EQ(FlowOptions{}.backend, Backend::kAutomatic);
  EXPECT_EQ(parse_backend("auto"), Backend::kAutomatic);
  EXPECT_STREQ(to_string(Backend::kAutomatic), "auto");
  EXPECT_EQ(choose_backend(Backend::kAutomatic, 1e-6, 6, 2), Backend::kDopri5);
  EXPECT_EQ(choose_backend(Backend::kAutomatic, 1e-7, 7, 2), Backend::kDopri5);
  EXPECT_EQ(choose_backend(Backend::kAutomatic, 3.01e-8, 7, 2), Backend::kDopri5);
  EXPECT_EQ(choose_backend(Backend::kAutomatic, 3e-8, 6, 2), Backend::kDop853);
  EXPECT_EQ(choose_backend(Backend::kAutomatic, 1e-4, 8, 2), Backend::kDop853);
  EXPECT_EQ(choose_backend(Backend::kAutomatic, 1e-4, 2, 0), Backend::kDop853);
  for (Backend named : {Backend::kDopri5, Backend::kDop853, Backend::kCvodesAdams}) {
    EXPECT_EQ(choose_backend(named, 1e-12, 100, 0), named);
    EXPECT_EQ(choose_backend(named, 1e-3, 2, 3), named);
  }
  EXPECT_THAT(message_of([] { make_integrator(Backend::kAutomatic); }),
              HasSubstr("choose_backend(backend, rtol, states, surfaces)"));

  // x'' = -100 x with the surface x = 0 (a continuous field: the saltation matrix is the
  // identity): x(t) = 0.1 cos(10 t), and dx(T)/dx0 = [[c, s/10], [-10 s, c]], c = cos(10 T),
  // s = sin(10 T); T = 1 crosses three times.
  const auto model = adapt(Oscillator{});
  const Eigen::Vector2d x0(0.1, 0.0);
  const double t = 1.0;
  Eigen::Matrix2d exact;
  exact << std::cos(10 * t), std::sin(10 * t) / 10, -10 * std::sin(10 * t), std::cos(10 * t);
  for (const auto& [rtol, expected, bound] :
       {std::tuple{1e-5, Backend::kDopri5, 3e-6}, std::tuple{1e-8, Backend::kDop853, 1.5e-8}}) {
    FlowOptions automatic;
    automatic.integrator.rtol = rtol;
    const FlowResult chosen = simulate(model, x0, t, Eigen::Matrix2d::Identity(), automatic);
    ASSERT_TRUE(chosen.ok()) << chosen.message;
    EXPECT_EQ(chosen.backend, expected) << "rtol " << rtol;
    EXPECT_EQ(chosen.events.size(), 3u);
    FlowOptions named = automatic;
    named.backend = expected;
    const FlowResult same = simulate(model, x0, t, Eigen::Matrix2d::Identity(), named);
    EXPECT_EQ(same.backend, expected);
    EXPECT_EQ(same.x, chosen.x);
    EXPECT_EQ(same.v, chosen.v);
    EXPECT_EQ(same.steps, chosen.steps);
    // The defaults' derivative against the closed form, relative to its largest entry (10):
    // measured 9.9e-7 (0.1 rtol) and 5e-9 (0.5 rtol); the bounds are three times that.
    const double error = (chosen.v - exact).cwiseAbs().maxCoeff() / 10.0;
    std::printf("auto at rtol %g (%s): derivative error %.3g\n", rtol, to_string(expected), error);
    EXPECT_LE(error, bound) << "rtol " << rtol;
  }
}

// x' = a x, with a = y(1) of y' = 1 from y(0) = 0, simulated inside the field: a model whose field
// runs the engine again (a nested run on the same thread).
struct Growth {
  static constexpr int kStates = 1;
  static constexpr int kSurfaces = 0;
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    const FlowResult inner =
        simulate(adapt(Constant{}), Eigen::VectorXd::Zero(1), 1.0, inner_options);
    xdot[0] = T(inner.x[0]) * x[0];
  }
  template <typename T>
  void surfaces(const T*, T*) const {}
  struct Constant {
    static constexpr int kStates = 1;
    static constexpr int kSurfaces = 0;
    template <typename T>
    void field(const T*, Signs, T* xdot) const {
      xdot[0] = T(1.0);
    }
    template <typename T>
    void surfaces(const T*, T*) const {}
  };
  FlowOptions inner_options;
};

// Runs on one thread share the thread's kept integrator: one run leaves nothing that changes the
// next (another model, other sides and tolerances in between), and a run nested in a field
// (whose outer run holds the kept one) gets its own.
TEST(HybridFlowTest, RunsOnOneThreadGiveWhatFreshIntegratorsGive) {
  for (Backend backend : {Backend::kDopri5, Backend::kDop853}) {
    FlowOptions options;
    options.backend = backend;
    const auto model = adapt(Oscillator{});
    const Eigen::Vector2d x0(0.1, 0.0);
    const FlowResult first = simulate(model, x0, 1.0, Eigen::Matrix2d::Identity(), options);
    FlowOptions loose = options;
    loose.integrator.rtol = 1e-4;
    const auto other = adapt(SpeedUp{});
    ASSERT_TRUE(
        simulate(other, Eigen::VectorXd::Zero(1), 1.0, Eigen::MatrixXd::Ones(1, 1), loose).ok());
    const FlowResult again = simulate(model, x0, 1.0, Eigen::Matrix2d::Identity(), options);
    EXPECT_EQ(again.x, first.x) << to_string(backend);
    EXPECT_EQ(again.v, first.v) << to_string(backend);
    EXPECT_EQ(again.steps, first.steps) << to_string(backend);

    Growth growth;
    growth.inner_options = options;
    const FlowResult nested = simulate(adapt(growth), Eigen::VectorXd::Ones(1), 1.0,
                                       Eigen::MatrixXd::Ones(1, 1), options);
    ASSERT_TRUE(nested.ok()) << nested.message;
    std::printf("nested %s: %.3g %.3g\n", to_string(backend), nested.x[0] - std::exp(1.0),
                nested.v(0, 0) - std::exp(1.0));
    // x(1) = e and dx(1)/dx0 = e, to the tolerance: measured 4.7e-9 (dopri5) and 1.3e-9
    // (dop853) off at rtol 1e-8; bound 1.5e-8.
    EXPECT_NEAR(nested.x[0], std::exp(1.0), 1.5e-8) << to_string(backend);
    EXPECT_NEAR(nested.v(0, 0), std::exp(1.0), 1.5e-8) << to_string(backend);
  }
}

}  // namespace
}  // namespace bflow

// Every run ends, within its budget and with a status that names why: a field that is not finite
// at the start (it made dopri5's first step NaN, which no step-size test ever stopped), steps
// rejected without end (max_steps bounds them too, even with the step-size floor off), an atol
// below IntegratorOptions::kMinAtol (refused: the field's rounding alone made the steps tiny),
// and step options dopri5 used to take unchecked.
#include <chrono>
#include <cmath>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/core/biped.h"
#include "bflow/core/errors.h"
#include "bflow/integrators/cvodes.h"
#include "bflow/integrators/dopri5.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;

// x0' = x1^2 - x1^2 + 1, x1' = -x0: x0' = 1 wherever x1^2 is finite, NaN where it overflows
// (|x1| > 1.3e154), as a model's forces become inf - inf far from its scale.
struct Cancelling {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    xdot[0] = x[1] * x[1] - x[1] * x[1] + 1.0;
    xdot[1] = -x[0];
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0] - 10.0;
  }
};

// x' = 1 at x = 0 and NaN anywhere else: every trial step is rejected.
struct Point {
  static constexpr int kStates = 1;
  static constexpr int kSurfaces = 0;
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    xdot[0] = x[0] == 0.0 ? T(1.0) : T(std::nan(""));
  }
  template <typename T>
  void surfaces(const T*, T*) const {}
};

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

TEST(StepBudgetTest, FieldNotFiniteAtTheStartEndsAtOnceNamingTheRow) {
  const auto model = adapt(Cancelling{});
  Dopri5Integrator dopri5;
  const SegmentRequest request{Signs::parse("-"), 0.0, 1.0, Eigen::Vector2d(0.0, -1e306),
                               Eigen::MatrixXd(2, 0)};
  const auto start = std::chrono::steady_clock::now();
  const SegmentResult r = dopri5.integrate(model, request, IntegratorOptions{});
  EXPECT_LT(seconds_since(start), 2.0);
  EXPECT_EQ(r.status, IntegrationStatus::kNonFinite);
  EXPECT_EQ(r.t, 0.0);
  EXPECT_EQ(r.steps, 0);
  EXPECT_THAT(r.message, HasSubstr("dopri5: F_b(x) row 0 is non-finite (nan) at t = 0, x = [0, "
                                   "-1e+306] (b = \"-\")"));

  // With tangents (Jets) the same, and through the hybrid driver a result that is not ok().
  SegmentRequest tangents = request;
  tangents.v0 = Eigen::Matrix2d::Identity();
  EXPECT_EQ(dopri5.integrate(model, tangents, IntegratorOptions{}).status,
            IntegrationStatus::kNonFinite);
  for (Backend backend : {Backend::kDopri5, Backend::kCvodesBdf, Backend::kCvodesAdams}) {
    SCOPED_TRACE(to_string(backend));
    FlowOptions options;
    options.backend = backend;
    const FlowResult flow = simulate(model, request.x0, 1.0, options);
    EXPECT_FALSE(flow.ok());
    EXPECT_EQ(flow.status, IntegrationStatus::kNonFinite) << flow.message;
  }
}

// The biped of `bflow orbit` (mode-damping, stiff legs, thrust) pushed 1e306 into the ground: its
// contact forces are inf - inf. Both commands hung here.
TEST(StepBudgetTest, BipedFarBelowTheGroundEndsAtOnce) {
  BipedParams p;
  set_param(p, "variant", "mode-damping");
  set_param(p, "kappa", "1000");
  set_param(p, "beta", "4");
  set_param(p, "thrust", "10");
  set_param(p, "thrust_speed", "0.1");
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(6);
  x0[1] = -1e306;
  const auto start = std::chrono::steady_clock::now();
  const FlowResult r = visit_biped(p, [&](const auto& scene) {
    const auto model = adapt(scene);
    return simulate(model, x0, 0.6, FlowOptions{});
  });
  EXPECT_LT(seconds_since(start), 2.0);
  EXPECT_EQ(r.status, IntegrationStatus::kNonFinite);
  EXPECT_THAT(r.message, HasSubstr("is non-finite (nan) at t = 0, x = [0, -1e+306, 0, 0, 0, 0]"));
}

TEST(StepBudgetTest, RejectedStepsAreBoundedByMaxSteps) {
  const auto model = adapt(Point{});
  Dopri5Integrator dopri5;
  const SegmentRequest request{Signs(0), 0.0, 2.0, Eigen::VectorXd::Zero(1), Eigen::MatrixXd(1, 0)};
  IntegratorOptions options;
  options.min_step = 0.0;  // no step-size floor: only the budget ends the rejections
  options.max_steps = 50;
  const SegmentResult r = dopri5.integrate(model, request, options);
  EXPECT_EQ(r.status, IntegrationStatus::kTooManySteps);
  EXPECT_EQ(r.rejected_steps, 50);
  EXPECT_EQ(r.steps, 0);
  EXPECT_EQ(r.t, 0.0);
  EXPECT_EQ(r.message,
            "dopri5: max_steps = 50 rejected steps (and 0 accepted), stopped at t = 0 before "
            "t_end = 2");

  // With the floor, a non-finite state where the step can shrink no further.
  options.min_step = 1e-14;
  const SegmentResult floor = dopri5.integrate(model, request, options);
  EXPECT_EQ(floor.status, IntegrationStatus::kNonFinite);
  EXPECT_LT(floor.rejected_steps, 50);
  EXPECT_EQ(floor.message, "dopri5: the state becomes non-finite just after t = 0");
}

TEST(StepBudgetTest, TooManyStepsNamesTheBudgetAndWhereItStopped) {
  const auto model = adapt(Cancelling{});
  IntegratorOptions options;
  options.max_steps = 3;
  Dopri5Integrator dopri5;
  const SegmentRequest request{Signs::parse("-"), 0.0, 9.0, Eigen::Vector2d(0.0, 0.0),
                               Eigen::MatrixXd(2, 0)};
  const SegmentResult r = dopri5.integrate(model, request, options);
  EXPECT_EQ(r.status, IntegrationStatus::kTooManySteps);
  EXPECT_EQ(r.steps, 3);
  EXPECT_GT(r.t, 0.0);
  EXPECT_THAT(r.message, HasSubstr("dopri5: max_steps = 3 steps taken, stopped at t = " +
                                   format_number(r.t) + " before t_end = 9"));
}

TEST(StepBudgetTest, AtolBelowTheMinimumIsRefusedByBothBackends) {
  const auto model = adapt(Cancelling{});
  const SegmentRequest request{Signs::parse("-"), 0.0, 1.0, Eigen::Vector2d(0.0, 1.0),
                               Eigen::MatrixXd(2, 0)};
  IntegratorOptions options;
  options.atol = 1e-300;
  Dopri5Integrator dopri5;
  CvodesIntegrator cvodes(CvodesMethod::kBdf);
  const auto refusal = HasSubstr("and a finite atol >= 1e-20, got rtol = 1e-08, atol = 1e-300");
  try {
    dopri5.integrate(model, request, options);
    ADD_FAILURE() << "dopri5 took atol = 1e-300";
  } catch (const InvalidArgument& e) {
    EXPECT_THAT(e.what(), refusal);
  }
  try {
    cvodes.integrate(model, request, options);
    ADD_FAILURE() << "CVODES took atol = 1e-300";
  } catch (const InvalidArgument& e) {
    EXPECT_THAT(e.what(), refusal);
  }
  // kMinAtol itself is a tolerance like any other.
  options.atol = IntegratorOptions::kMinAtol;
  const auto start = std::chrono::steady_clock::now();
  const SegmentResult r = dopri5.integrate(model, request, options);
  EXPECT_LT(seconds_since(start), 2.0);
  EXPECT_EQ(r.status, IntegrationStatus::kReachedEnd) << r.message;
  EXPECT_NEAR(r.x[0], 1.0, 1e-12);
  EXPECT_NEAR(r.x[1], 0.5, 1e-12);
  EXPECT_EQ(cvodes.integrate(model, request, options).status, IntegrationStatus::kReachedEnd);
}

TEST(StepBudgetTest, Dopri5RefusesStepOptionsItCannotUse) {
  const auto model = adapt(Cancelling{});
  const SegmentRequest request{Signs::parse("-"), 0.0, 1.0, Eigen::Vector2d(0.0, 1.0),
                               Eigen::MatrixXd(2, 0)};
  Dopri5Integrator dopri5;
  const auto refused = [&](const IntegratorOptions& options, const std::string& what) {
    try {
      dopri5.integrate(model, request, options);
      ADD_FAILURE() << "accepted: " << what;
    } catch (const InvalidArgument& e) {
      EXPECT_THAT(e.what(), HasSubstr(what));
    }
  };
  IntegratorOptions o;
  o.max_steps = 0;
  refused(o, "dopri5: max_steps must be positive, got 0");
  o = IntegratorOptions{};
  o.min_step = std::nan("");
  refused(o, "dopri5: need initial_step >= 0, min_step >= 0 and max_step > 0, got 0, nan, inf");
  o = IntegratorOptions{};
  o.initial_step = -1.0;
  refused(o, "got -1, 1e-14, inf");
  o = IntegratorOptions{};
  o.max_step = 0.0;
  refused(o, "got 0, 1e-14, 0");
}

}  // namespace
}  // namespace bflow

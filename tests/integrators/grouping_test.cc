// Grouping crossings into events (hybrid_flow.h, "Grouping"): the automatic window against its
// closed form, what each EventRecord reports, near-simultaneity notices, and the crossing orders
// in the model's numbering. The piecewise-constant field is integrated exactly (up to rounding),
// so crossing times, spreads and gaps have closed forms.
#include <algorithm>
#include <cmath>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/examples/piecewise_constant.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using examples::PiecewiseConstantField;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

constexpr double kEps = 2.220446049250313e-16;

// Two surfaces of the plane, F_-- = (1, 1), F_+- = (0.5, 1.6): from (-0.5, -0.5 - dt) surface 0 is
// crossed at t = 0.5 and surface 1 dt / 1.6 later; seen from the first crossing with F_-- it is
// dt ahead, the located time the grouping compares.
PiecewiseConstantField plane() {
  Eigen::MatrixXd delta(2, 4);
  delta << 0.0, -0.5, 0.7, -0.3, 0.0, 0.6, -0.4, -0.3;
  return PiecewiseConstantField(delta);
}

// The automatic window at the first crossing, t1 = 0.5, rho = (0, -dt), from its definition:
// 2 safety (|Dh| |atol + rtol |rho|| / |Dh . F| + 16 eps t1) with Dh = e_0, F = (1, 1).
double automatic_window(const FlowOptions& options, double dt) {
  const double rtol = options.integrator.rtol;
  const double atol = options.integrator.absolute_tolerance();
  const double tol = std::hypot(atol, atol + rtol * dt);
  return 2.0 * options.grouping_safety * (tol + 16 * kEps * 0.5);
}

TEST(GroupingTest, DefaultAtolFollowsRtol) {
  IntegratorOptions options;
  EXPECT_EQ(options.absolute_tolerance(), 1e-10);  // rtol 1e-8 / 100
  options.rtol = 1e-12;
  EXPECT_EQ(options.absolute_tolerance(), 1e-14);
  options.atol = 3e-9;
  EXPECT_EQ(options.absolute_tolerance(), 3e-9);
}

// Grouped when dt is inside the automatic window (2.8e-9 at the defaults), split beyond it, with
// a notice while the gap dt / 1.6 is inside the band of 100 windows (2.8e-7), none beyond.
TEST(GroupingTest, AutomaticWindowGroupsInsideAndReportsNearSimultaneityOutside) {
  const auto model = adapt(plane());
  const FlowOptions options;  // the defaults: automatic grouping
  ASSERT_EQ(options.grouping, Grouping::kAutomatic);
  const double window = automatic_window(options, 0.0);
  ASSERT_NEAR(window, 2.83e-9, 0.01e-9);
  for (double dt : {0.0, 1e-14, 1e-12, 1e-10, 1e-9, 2e-9, 4e-9, 1e-8, 1e-7, 1e-6, 1e-4}) {
    const Eigen::Vector2d x0(-0.5, -0.5 - dt);
    FlowResult r;
    const FlowDerivative derivative = flow_derivative(model, x0, 1.0, options, &r);
    const bool grouped = dt <= window;
    ASSERT_EQ(r.events.size(), grouped ? 1u : 2u) << "dt=" << dt;
    const EventRecord& first = r.events[0];
    EXPECT_NEAR(first.t, 0.5, 4 * kEps) << "dt=" << dt;
    // The window is the closed form (rho_1 = -dt enters through rtol |rho_1|).
    EXPECT_NEAR(first.automatic_window, automatic_window(options, dt), 1e-6 * window)
        << "dt=" << dt;
    if (grouped) {
      EXPECT_THAT(first.surfaces, ElementsAre(0, 1));
      // Located times: surface 1 is reached dt after surface 0 (exact field, rounding only).
      EXPECT_NEAR(first.spread, dt, 8 * kEps) << "dt=" << dt;
      EXPECT_EQ(first.window, first.automatic_window);
      EXPECT_TRUE(std::isinf(first.gap));
      EXPECT_TRUE(r.notices.empty()) << "dt=" << dt;
      EXPECT_FALSE(derivative.is_linear());
    } else {
      EXPECT_THAT(first.surfaces, ElementsAre(0));
      EXPECT_THAT(r.events[1].surfaces, ElementsAre(1));
      EXPECT_EQ(first.spread, 0.0);
      EXPECT_NEAR(first.gap, dt / 1.6, 8 * kEps) << "dt=" << dt;
      EXPECT_EQ(r.events[1].gap, first.gap);
      const bool near = dt / 1.6 < 100 * window;
      ASSERT_EQ(r.notices.size(), near ? 1u : 0u) << "dt=" << dt;
      ASSERT_EQ(derivative.notices().size(), r.notices.size());
      EXPECT_TRUE(derivative.is_linear());
      if (near) {
        const FlowNotice& n = r.notices[0];
        EXPECT_EQ(n.kind, FlowNotice::Kind::kNearSimultaneous);
        EXPECT_THAT(n.surfaces, ElementsAre(0, 1));
        EXPECT_NEAR(n.gap, dt / 1.6, 8 * kEps);
        EXPECT_EQ(n.band, 100 * std::max(first.automatic_window, r.events[1].automatic_window));
        EXPECT_NEAR(n.band, 100 * window, 1e-5 * n.band);  // rho moves by dt: measured 5e-6
        EXPECT_THAT(n.message, HasSubstr("near-simultaneous crossings not grouped: surfaces [0]"));
        EXPECT_THAT(n.message, HasSubstr("[1] at t = 0.5"));
      }
    }
  }
}

// The window scales with the tolerances: at rtol 1e-12 (atol 1e-14) a 1e-10 gap is resolved.
TEST(GroupingTest, AutomaticWindowScalesWithTheTolerance) {
  const auto model = adapt(plane());
  FlowOptions tight;
  tight.integrator.rtol = 1e-12;
  const double window = automatic_window(tight, 0.0);
  EXPECT_NEAR(window, 3.18e-13, 0.01e-13);  // 20 (sqrt(2) 1e-14 + 16 eps / 2)
  FlowResult r = simulate(model, Eigen::Vector2d(-0.5, -0.5 - 1e-10), 1.0, tight);
  EXPECT_EQ(r.events.size(), 2u);
  EXPECT_EQ(r.notices.size(), 0u);  // 1e-10 > 100 windows
  r = simulate(model, Eigen::Vector2d(-0.5, -0.5 - 1e-13), 1.0, tight);
  EXPECT_EQ(r.events.size(), 1u);
  // The safety factor scales it linearly.
  FlowOptions wide;
  wide.grouping_safety = 1000.0;
  r = simulate(model, Eigen::Vector2d(-0.5, -0.5 - 1e-7), 1.0, wide);
  ASSERT_EQ(r.events.size(), 1u);
  EXPECT_NEAR(r.events[0].window, 100 * automatic_window(FlowOptions{}, 1e-7), 1e-15);
}

// A slow first crossing (eta . F = 1e-4 |eta| |F|) has a large crossing-time uncertainty, but its
// margin counts as 1e-2 in the window: a second surface 1e-5 later is not flipped with it (a
// window from the raw margin would be 1.4e-5 and flip it 1e-5 early, a state error of 1e-5,
// five orders above the tolerance); it is a separate event with a notice.
TEST(GroupingTest, ASlowCrossingDoesNotStretchTheWindow) {
  Eigen::MatrixXd delta(2, 4);
  delta << -1.0 + 1e-4, -0.5, 0.7, -0.3, 0.0, 0.6, -0.4, -0.3;
  const auto model = adapt(PiecewiseConstantField(delta));
  const FlowOptions options;
  const FlowResult r = simulate(model, Eigen::Vector2d(-0.5e-4, -0.5 - 1e-5), 1.0, options);
  ASSERT_EQ(r.events.size(), 2u);
  EXPECT_NEAR(r.events[0].margin_before[0], 1e-4, 1e-8);
  // 2 safety |tol| / (0.01 |F|), |F| = 1 to 5e-9, |tol| = sqrt(2) 1e-10 to 5e-9 (rho_1 = -1e-5).
  EXPECT_NEAR(r.events[0].automatic_window, 2 * 10 * std::sqrt(2.0) * 1e-10 / 0.01, 1e-9);
  ASSERT_EQ(r.notices.size(), 1u);
  EXPECT_NEAR(r.notices[0].gap, 1e-5 / 1.6, 1e-12);
}

// kNone groups only crossings located at the same time: 1e-12 apart is two events, with a notice.
TEST(GroupingTest, NoGroupingSplitsAndSaysSo) {
  const auto model = adapt(plane());
  FlowOptions options;
  options.grouping = Grouping::kNone;
  const FlowResult r = simulate(model, Eigen::Vector2d(-0.5, -0.5 - 1e-12), 1.0, options);
  ASSERT_EQ(r.events.size(), 2u);
  EXPECT_EQ(r.events[0].window, 0.0);
  ASSERT_EQ(r.notices.size(), 1u);
  EXPECT_NEAR(r.notices[0].gap, 1e-12 / 1.6, 8 * kEps);
  // Exactly simultaneous crossings are still one event.
  EXPECT_EQ(simulate(model, Eigen::Vector2d(-0.5, -0.5), 1.0, options).events.size(), 1u);
}

TEST(GroupingTest, BadGroupingOptionsAreRefusedWithTheirValues) {
  const auto model = adapt(plane());
  const Eigen::Vector2d x0(-0.5, -0.5);
  FlowOptions options;
  options.grouping_safety = 0.0;
  EXPECT_THAT(testing::message_of([&] { simulate(model, x0, 1.0, options); }),
              HasSubstr("grouping_safety must be finite and > 0, got 0"));
  options = FlowOptions{};
  options.near_simultaneity_band = 0.5;
  EXPECT_THAT(testing::message_of([&] { simulate(model, x0, 1.0, options); }),
              HasSubstr("near_simultaneity_band must be finite and >= 1, got 0.5"));
  options = FlowOptions{};
  options.simultaneity_window = NAN;
  EXPECT_THAT(testing::message_of([&] { simulate(model, x0, 1.0, options); }),
              HasSubstr("simultaneity_window must be finite and >= 0, got nan"));
  EXPECT_THAT(testing::message_of([] { parse_grouping("sometimes"); }),
              HasSubstr("grouping \"sometimes\" is unknown; choose auto, window or none"));
  EXPECT_EQ(parse_grouping("window"), Grouping::kFixedWindow);
  EXPECT_STREQ(to_string(Grouping::kNone), "none");
}

// d = 3, linear case F_b = 1 - delta b: surface 0 is crossed alone at t = 0.2, surfaces 1 and 2
// together at t = 0.5. Orders are reported in the model's surface indices, not the event's rows.
TEST(GroupingTest, OrdersAreInTheModelsNumbering) {
  const double delta = 0.35;
  const auto model = adapt(PiecewiseConstantField::linear(3, delta));
  const Eigen::Vector3d x0 = -(1 + delta) * Eigen::Vector3d(0.2, 0.5, 0.5);
  FlowResult r;
  const FlowDerivative derivative = flow_derivative(model, x0, 1.0, {}, &r);
  ASSERT_EQ(r.events.size(), 2u);
  EXPECT_THAT(r.events[0].surfaces, ElementsAre(0));
  EXPECT_THAT(r.events[1].surfaces, ElementsAre(1, 2));
  ASSERT_EQ(derivative.event_surfaces().size(), 2u);
  EXPECT_THAT(derivative.event_surfaces()[1], ElementsAre(1, 2));

  const std::vector<FlowPiece> pieces = derivative.pieces();
  ASSERT_EQ(pieces.size(), 2u);
  for (const FlowPiece& piece : pieces) {
    ASSERT_EQ(piece.orders.size(), 2u);
    EXPECT_THAT(piece.orders[0], ElementsAre(0));
    EXPECT_TRUE(piece.orders[1] == std::vector<int>({1, 2}) ||
                piece.orders[1] == std::vector<int>({2, 1}));
  }
  EXPECT_NE(pieces[0].orders[1], pieces[1].orders[1]);

  // Raising x_1 makes surface 1 come first at the second event; raising x_2, surface 2. The
  // shift of the first event's time is -dx_0 / F_0 = -dx_0 / (1 + delta), to rounding.
  std::vector<CrossingOrder> orders = derivative.crossing_orders(Eigen::Vector3d(0.1, 1, 0));
  ASSERT_EQ(orders.size(), 2u);
  EXPECT_THAT(orders[0].order, ElementsAre(0));
  EXPECT_THAT(orders[1].order, ElementsAre(1, 2));
  orders = derivative.crossing_orders(Eigen::Vector3d(0.1, 0, 1));
  EXPECT_THAT(orders[1].order, ElementsAre(2, 1));
  EXPECT_NEAR(orders[0].times[0], -0.1 / (1 + delta), 1e-15);
  EXPECT_THAT(testing::message_of([&] { derivative.crossing_orders(Eigen::Vector2d(1, 0)); }),
              HasSubstr("FlowDerivative::crossing_orders: tangent must have 3 finite numbers"));
}

TEST(GroupingTest, AppendJumpChecksTheModelIndices) {
  FlowDerivative derivative(2);
  const JumpMap jump(Eigen::MatrixXd::Identity(2, 2), plane().limits());
  EXPECT_THAT(testing::message_of([&] {
                derivative.append_jump(jump, 0.5, {1, 0});
              }),
              HasSubstr("a jump of 2 surfaces needs as many increasing, nonnegative model "
                        "indices, got [1, 0]"));
  derivative.append_jump(jump, 0.5, {3, 7});
  EXPECT_THAT(derivative.crossing_orders(Eigen::Vector2d(1, 0))[0].order, ElementsAre(3, 7));
}

}  // namespace
}  // namespace bflow

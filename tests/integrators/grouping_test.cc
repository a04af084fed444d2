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

// sigma_j of a coordinate plane, Dh_j = e_j, crossed at unit normal speed (F_j = 1, at least
// 1 % of |F|) at time t1 where x_j = rho_j, from its definition:
// sum_i |Dh_ji| (atol + rtol |rho_i|) / |Dh_j . F| + 16 eps t1 = atol + rtol |rho_j| + 16 eps t1.
double plane_sigma(const FlowOptions& options, double rho_j, double t1) {
  const double rtol = options.integrator.rtol;
  const double atol = options.integrator.absolute_tolerance();
  return atol + rtol * std::abs(rho_j) + 16 * kEps * t1;
}

// The automatic window at the first crossing, t1 = 0.5, rho = (0, -dt), Dh = e_0, F = (1, 1):
// 2 safety sigma_0, which only x_0's tolerance enters (rho_0 = 0): the same for every dt.
double automatic_window(const FlowOptions& options) {
  return 2.0 * options.grouping_safety * plane_sigma(options, 0.0, 0.5);
}

// The window of surface 1 (Dh = e_1, F_1 = 1, rho_1 = -dt) at that crossing:
// safety (sigma_1 + sigma_0), what its located delay dt is compared with.
double surface_1_window(const FlowOptions& options, double dt) {
  return options.grouping_safety * (plane_sigma(options, dt, 0.5) + plane_sigma(options, 0.0, 0.5));
}

TEST(GroupingTest, DefaultAtolFollowsRtol) {
  IntegratorOptions options;
  EXPECT_EQ(options.absolute_tolerance(), 1e-10);  // rtol 1e-8 / 100
  options.rtol = 1e-12;
  EXPECT_EQ(options.absolute_tolerance(), 1e-14);
  options.atol = 3e-9;
  EXPECT_EQ(options.absolute_tolerance(), 3e-9);
}

// Grouped when dt is inside surface 1's window (2.0e-9 at the defaults: 10 (2 x 1e-10 + 1e-8 dt
// + 16 eps)), split beyond it (1.99e-9 and 2.01e-9 lie on either side), with a notice while the
// gap dt / 1.6 is inside the band of 100 automatic windows (2.0e-7), none beyond.
TEST(GroupingTest, AutomaticWindowGroupsInsideAndReportsNearSimultaneityOutside) {
  const auto model = adapt(plane());
  const FlowOptions options;  // the defaults: automatic grouping
  ASSERT_EQ(options.grouping, Grouping::kAutomatic);
  const double window = automatic_window(options);
  ASSERT_NEAR(window, 2.0e-9, 0.0001e-9);  // 20 (1e-10 + 8 eps)
  for (double dt :
       {0.0, 1e-14, 1e-12, 1e-10, 1e-9, 1.99e-9, 2.01e-9, 4e-9, 1e-8, 1e-7, 1e-6, 1e-4}) {
    const Eigen::Vector2d x0(-0.5, -0.5 - dt);
    FlowResult r;
    const FlowDerivative derivative = flow_derivative(model, x0, 1.0, options, &r);
    const bool grouped = dt <= surface_1_window(options, dt);
    EXPECT_EQ(grouped, dt < 2e-9) << "dt=" << dt;
    ASSERT_EQ(r.events.size(), grouped ? 1u : 2u) << "dt=" << dt;
    const EventRecord& first = r.events[0];
    EXPECT_NEAR(first.t, 0.5, 4 * kEps) << "dt=" << dt;
    // The window is the closed form: rho_1 = -dt does not enter surface 0's sigma (Dh_0 = e_0).
    // The tolerance covers the rounding of rho_0 (1e-8 x 3e-17) and of t1.
    EXPECT_NEAR(first.automatic_window, window, 1e-10 * window) << "dt=" << dt;
    if (grouped) {
      EXPECT_THAT(first.surfaces, ElementsAre(0, 1));
      // Located times: surface 1 is reached dt after surface 0 (exact field, rounding only).
      EXPECT_NEAR(first.spread, dt, 8 * kEps) << "dt=" << dt;
      // The window used is surface 1's, wider by rtol dt than the automatic one.
      EXPECT_NEAR(first.window, surface_1_window(options, dt), 1e-10 * window) << "dt=" << dt;
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
        // The second event's window is 20 sigma_1 at t = 0.5 + dt / 1.6, rho_1 = 0.
        EXPECT_NEAR(n.band, 100 * 20 * plane_sigma(options, 0.0, 0.5 + dt / 1.6), 1e-10 * n.band);
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
  const double window = automatic_window(tight);
  EXPECT_NEAR(window, 2.355e-13, 0.001e-13);  // 20 (1e-14 + 16 eps / 2)
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
  // Surface 1's window: 1000 (sigma_1 + sigma_0) = 1000 (2 x 1e-10 + 1e-8 x 1e-7 + 16 eps).
  EXPECT_NEAR(r.events[0].window, surface_1_window(wide, 1e-7), 1e-12 * 2e-7);
  EXPECT_NEAR(r.events[0].window, 2.0000455e-7, 1e-14);
}

// A slow first crossing (eta . F = 1e-4 |eta| |F|) has a large crossing-time uncertainty, but its
// margin counts as 1e-2 in the window: a second surface 1e-5 later is not flipped with it (a
// window from the raw margin would be 10 (1e-10 / 1e-4 + 1e-10) = 1.0e-5 and flip it 1e-5 early,
// a state error of 1e-5,
// five orders above the tolerance); it is a separate event with a notice.
TEST(GroupingTest, ASlowCrossingDoesNotStretchTheWindow) {
  Eigen::MatrixXd delta(2, 4);
  delta << -1.0 + 1e-4, -0.5, 0.7, -0.3, 0.0, 0.6, -0.4, -0.3;
  const auto model = adapt(PiecewiseConstantField(delta));
  const FlowOptions options;
  const FlowResult r = simulate(model, Eigen::Vector2d(-0.5e-4, -0.5 - 1e-5), 1.0, options);
  ASSERT_EQ(r.events.size(), 2u);
  EXPECT_NEAR(r.events[0].margin_before[0], 1e-4, 1e-8);
  // 2 safety (tol_0 / (0.01 |F|) + 16 eps t1), tol_0 = atol (rho_0 = 0), |F| = |(1e-4, 1)|: only
  // x_0's tolerance enters, rho_1 = -1e-5 does not.
  const double window = 2 * 10 * (1e-10 / (0.01 * std::hypot(1e-4, 1.0)) + 16 * kEps * 0.5);
  EXPECT_NEAR(window, 2.0e-7, 0.0001e-7);
  EXPECT_NEAR(r.events[0].automatic_window, window, 1e-12 * window);
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

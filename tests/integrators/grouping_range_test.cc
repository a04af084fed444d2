// The grouping rule at the ends of the double range (hybrid_flow.h, "Range"): states, fields,
// normals and tolerances whose norms or products have no finite double must neither group a
// surface on an infinite window nor report one; a number that cannot be finite ends the run
// with kOverflow. The references are the piecewise-constant field's closed forms:
//
//   xdot = 1 - delta b (delta = 0.25, b_i = +-1 the side of x_i), h(x) = x.
//
// From x0 = (-1e200, -0.625) x_1 reaches 0 at t = 0.625 / 1.25 = 0.5 while x_0 moves by 1.25 per
// unit time and stays below zero until t ~ 8e199: the only event up to t = 1 is surface 1 alone,
// sides "--" -> "-+". Its saltation matrix I + (F_-+ - F_--) e_1^T / 1.25 maps e_0 to e_0 and e_1
// to (1 - 0.5 / 1.25) e_1 = 0.6 e_1; the transition matrices of a constant field are I. So the
// B-derivative at t = 1 is diag(1, 0.6), and grouping surface 0 into the event (giving 0.6 on
// e_0, [B] (3.2)) is wrong by 0.4.
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/core/errors.h"
#include "bflow/examples/piecewise_constant.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"

namespace bflow {
namespace {

using examples::PiecewiseConstantField;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

constexpr double kEps = std::numeric_limits<double>::epsilon();
constexpr double kDelta = 0.25;

// The automatic window of a first crossing of the coordinate plane x_j = 0 at t1, whose normal
// speed is the full |F . e_j| = v (v >= 1 % of |F|):
// 2 safety (sum_i |Dh_ji| (atol + rtol |rho_i|) / v + 16 eps t1) = 2 safety ((atol + rtol |rho_j|)
// / v + 16 eps t1): only x_j's tolerance enters, however far the other coordinates are.
double plane_window(const FlowOptions& options, double rho_j, double v, double t1) {
  const double rtol = options.integrator.rtol;
  const double atol = options.integrator.absolute_tolerance();
  return 2.0 * options.grouping_safety * ((atol + rtol * std::abs(rho_j)) / v + 16 * kEps * t1);
}

// One run of flow_derivative from x0 to t = 1 and the images of the unit directions.
struct FlowRun {
  FlowResult trajectory;
  std::vector<Eigen::VectorXd> images;
};

FlowRun run_flow(const SegmentModel& model, const Eigen::VectorXd& x0, const FlowOptions& options,
                 double t = 1.0) {
  FlowRun r;
  const FlowDerivative derivative = flow_derivative(model, x0, t, options, &r.trajectory);
  for (Eigen::Index i = 0; i < x0.size(); ++i) {
    r.images.push_back(derivative.apply(Eigen::VectorXd::Unit(x0.size(), i)));
  }
  return r;
}

// The expected single event of surface `j` alone at t = 0.5, with a finite window given by the
// closed form, and images diag(1, .., 0.6 at j, .., 1) to rounding (constant fields: the only
// arithmetic is the saltation matrix's).
void expect_surface_alone(const FlowRun& r, int j, const FlowOptions& options,
                          const std::vector<double>& rho) {
  const FlowResult& t = r.trajectory;
  ASSERT_TRUE(t.ok()) << t.message;
  ASSERT_EQ(t.events.size(), 1u);
  const EventRecord& e = t.events[0];
  EXPECT_NEAR(e.t, 0.5, 4 * kEps);
  EXPECT_THAT(e.surfaces, ElementsAre(j));
  EXPECT_THAT(e.crossing_times, ElementsAre(e.t));
  EXPECT_EQ(e.spread, 0.0);
  EXPECT_TRUE(std::isfinite(e.window));
  EXPECT_EQ(e.window, e.automatic_window);
  // rho_j is 0 to rounding (3e-17 here), which enters through rtol |rho_j|.
  EXPECT_LE(std::abs(e.rho[j] - rho[static_cast<std::size_t>(j)]), 4 * kEps);
  EXPECT_NEAR(e.window, plane_window(options, e.rho[j], 1.0 + kDelta, e.t), 4 * kEps * e.window);
  EXPECT_TRUE(std::isinf(e.gap));  // no other crossing before t = 1
  const int d = static_cast<int>(rho.size());
  std::string after(static_cast<std::size_t>(d), '-');
  after[static_cast<std::size_t>(j)] = '+';
  EXPECT_EQ(e.sides_before.str(), std::string(static_cast<std::size_t>(d), '-'));
  EXPECT_EQ(e.sides_after.str(), after);
  EXPECT_EQ(t.sides.str(), after);
  EXPECT_TRUE(t.notices.empty());
  for (int i = 0; i < d; ++i) {
    const Eigen::VectorXd expected =
        (i == j ? (1 - kDelta) / (1 + kDelta) : 1.0) * Eigen::VectorXd::Unit(d, i);
    EXPECT_LE((r.images[static_cast<std::size_t>(i)] - expected).lpNorm<Eigen::Infinity>(), kEps)
        << "e_" << i;
  }
}

// The defaults, from x0 = (-1e200, -0.625): tol_0 = atol + rtol |rho_0| = 1e192. Surface 0 is
// reached 8e199 after the event, far outside its window of 10 (1e192 / 1.25 + sigma_1) = 8e192;
// the event's window sees x_1's tolerance only: 20 (1e-10 / 1.25 + 8 eps) = 1.6e-9. One event of
// surface 1, the image of e_0 is e_0, as with Grouping::kNone.
TEST(GroupingRangeTest, AFarCoordinateDoesNotJoinTheEvent) {
  const auto model = adapt(PiecewiseConstantField::linear(2, kDelta));
  const FlowOptions options;
  const Eigen::Vector2d x0(-1e200, -0.625);
  const FlowRun r = run_flow(model, x0, options);
  expect_surface_alone(r, 1, options, {-1e200, 0.0});
  EXPECT_NEAR(r.trajectory.events[0].window, 1.6e-9, 0.0001e-9);
  EXPECT_EQ(r.trajectory.x[0], -1e200);  // + 1.25 is below its rounding
  EXPECT_NEAR(r.trajectory.x[1], 0.5 * 0.75, 4 * kEps);

  FlowOptions none;
  none.grouping = Grouping::kNone;
  const FlowRun split = run_flow(model, x0, none);
  ASSERT_EQ(split.trajectory.events.size(), 1u);
  EXPECT_EQ(split.trajectory.events[0].surfaces, r.trajectory.events[0].surfaces);
  EXPECT_EQ(split.images[0], r.images[0]);
  EXPECT_EQ(split.images[1], r.images[1]);
}

// The same in the other coordinate, nearer the end of the range (the squares of 1e292 and of
// 1.7e300 overflow), and in three dimensions with two far coordinates: every window is 1.6e-9.
TEST(GroupingRangeTest, FarCoordinatesAnywhereUpToTheEndOfTheRange) {
  const FlowOptions options;
  const auto plane = adapt(PiecewiseConstantField::linear(2, kDelta));
  for (double far : {-1e200, -1e300, -1.7e308}) {
    SCOPED_TRACE(far);
    expect_surface_alone(run_flow(plane, Eigen::Vector2d(far, -0.625), options), 1, options,
                         {far, 0.0});
    expect_surface_alone(run_flow(plane, Eigen::Vector2d(-0.625, far), options), 0, options,
                         {0.0, far});
  }
  const auto space = adapt(PiecewiseConstantField::linear(3, kDelta));
  expect_surface_alone(run_flow(space, Eigen::Vector3d(-1e300, -0.625, -1.5e300), options), 1,
                       options, {-1e300, 0.0, -1.5e300});
}

// A surface with a normal of 1e200, h = (x_0, 1e200 x_1): the normal cancels between
// |dh_1/dx_1| tol_1 and the normal speed 1.25e200, the window is the plane's 1.6e-9. With atol =
// 1e150 the weighted tolerance 1e200 x 1e150 has no finite double, and the window is the
// plane's 20 x 1e150 / 1.25 = 1.6e151 (surface 0, 8e199 ahead, still stays out of its 8e192).
struct SteepPlanes {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 2;
  PiecewiseConstantField field_ = PiecewiseConstantField::linear(2, kDelta);
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    field_.field(x, b, xdot);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
    h[1] = 1e200 * x[1];
  }
};

TEST(GroupingRangeTest, HugeNormalsGiveTheSameWindow) {
  const auto model = adapt(SteepPlanes{});
  FlowOptions options;
  expect_surface_alone(run_flow(model, Eigen::Vector2d(-1e200, -0.625), options), 1, options,
                       {-1e200, 0.0});
  options.integrator.atol = 1e150;
  const FlowRun r = run_flow(model, Eigen::Vector2d(-1e200, -0.625), options);
  expect_surface_alone(r, 1, options, {-1e200, 0.0});
  EXPECT_NEAR(r.trajectory.events[0].window, 1.6e151, 4 * kEps * 1.6e151);
}

// A field of 1e200, F_b = 1e200 (1 - delta b), whose |F| has no finite square: the normal speed
// 1.25e200 is compared with 1 % of |F| = 1.77e198 as it is. From x0 = (-0.625e200, -1e250) surface
// 0 is crossed at t = 0.5, surface 1 at 8e49; the window is 20 (tol_0 / 1.25e200 + 8 eps), x_1's
// tolerance 1e-8 x 1e250 does not enter it (surface 1's own window is 10 x 1e242 / 1.25e200).
struct FastField {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 2;
  PiecewiseConstantField field_ = PiecewiseConstantField::linear(2, kDelta);
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    field_.field(x, b, xdot);
    xdot[0] *= 1e200;
    xdot[1] *= 1e200;
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
    h[1] = x[1];
  }
};

TEST(GroupingRangeTest, AFieldBeyondTheSquareRootOfTheRange) {
  const auto model = adapt(FastField{});
  const FlowOptions options;
  FlowResult r;
  const FlowDerivative derivative =
      flow_derivative(model, Eigen::Vector2d(-0.625e200, -1e250), 1.0, options, &r);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.events.size(), 1u);
  const EventRecord& e = r.events[0];
  EXPECT_NEAR(e.t, 0.5, 4 * kEps);
  EXPECT_THAT(e.surfaces, ElementsAre(0));
  // rho_0 is zero to the rounding of 0.625e200 (1e184): the window is the time floor's
  // 20 x 16 eps x 0.5 = 3.55e-14 to 1e-9.
  const double window = 20.0 * ((1e-10 + 1e-8 * std::abs(e.rho[0])) / 1.25e200 + 16 * kEps * e.t);
  EXPECT_NEAR(window, 3.553e-14, 0.001e-14);
  EXPECT_NEAR(e.automatic_window, window, 4 * kEps * window);
  EXPECT_EQ(e.window, e.automatic_window);
  const Eigen::VectorXd image = derivative.apply(Eigen::Vector2d(1.0, 0.0));
  EXPECT_NEAR(image[0], 0.6, kEps);
  EXPECT_EQ(image[1], 0.0);
}

// Huge tolerances. rtol = 1e300 (atol 1e298): from (-0.625, -0.626) the automatic window is
// 20 x 1e298 / 1.25 = 1.6e299; surface 1, 8e-4 behind, is inside its window 10 (1e298 / 1.25 +
// (1e298 + 1e300 x 1e-3) / 1.25) = 1.68e299 and joins (the rule, at this tolerance). With
// x_1 = -1e9 instead, rtol |rho_1| = 1e309 itself leaves the range: surface 1, 8e8 behind, is
// inside its window 10 x 1e309 / 1.25 = 8e309, which is beyond it: kOverflow, no event.
TEST(GroupingRangeTest, HugeTolerances) {
  const auto model = adapt(PiecewiseConstantField::linear(2, kDelta));
  FlowOptions options;
  options.integrator.rtol = 1e300;
  FlowResult r = simulate(model, Eigen::Vector2d(-0.625, -0.626), 1.0, options);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.events.size(), 1u);
  const EventRecord& e = r.events[0];
  EXPECT_THAT(e.surfaces, ElementsAre(0, 1));
  EXPECT_NEAR(e.spread, 1e-3 / 1.25, 2e-16);  // an ulp of t = 0.5008 is 1.1e-16
  const double window = plane_window(options, e.rho[0], 1.25, e.t);
  EXPECT_NEAR(window, 1.6e299, 4 * kEps * 1.6e299);
  EXPECT_NEAR(e.automatic_window, window, 4 * kEps * window);
  // Surface 1's window: safety (sigma_1 + sigma_0) = (window of x_1 + window of x_0) / 2.
  const double window_1 = (plane_window(options, e.rho[1], 1.25, e.t) + window) / 2;
  EXPECT_NEAR(window_1, 1.68e299, 4 * kEps * 1.68e299);
  EXPECT_NEAR(e.window, window_1, 4 * kEps * window_1);

  r = simulate(model, Eigen::Vector2d(-0.625, -1e9), 1.0, options);
  EXPECT_EQ(r.status, IntegrationStatus::kOverflow);
  EXPECT_STREQ(to_string(r.status), "overflow");
  EXPECT_TRUE(r.events.empty());
  EXPECT_NEAR(r.t, 0.5, 4 * kEps);
  // 10 (1e309 / 1.25 + 1e298 / 1.25) = 8e309, from surface 1's weighted tolerance 1e309.
  EXPECT_THAT(r.message, HasSubstr("the event at t = " + format_number(r.t) + ", surfaces [0, 1]"));
  EXPECT_THAT(r.message,
              HasSubstr("the grouping window = 8.000e+309 is beyond the double range (surface 1: "
                        "sum_i |dh_1/dx_i| (atol + rtol |rho_i|) = 1.000e+309, normal speed 1.25"));
}

// A slow field, F_-- = (2^-52, 2^-52), from x0 = (-1e300, -2^-53): surface 1 is crossed at
// t = 0.5 with normal speed 2^-52. At the defaults its window, 20 x 1e-10 / 2^-52 = 9.007e6, does
// not see x_0. With atol = 1e293 it is 20 x 1e293 / 2^-52 = 9.007e309, beyond the range (surface
// 0, 4.5e315 away, would not join it). It cannot be reported under any grouping policy: kOverflow,
// not an infinite window.
TEST(GroupingRangeTest, AWindowBeyondTheRangeEndsTheRun) {
  Eigen::MatrixXd delta = PiecewiseConstantField::linear(2, kDelta).delta();
  delta.col(0).setConstant(-1.0 + 0x1p-52);  // F_-- = 1 + Delta(--)
  const auto model = adapt(PiecewiseConstantField(delta));
  const FlowResult slow = simulate(model, Eigen::Vector2d(-1e300, -0x1p-53), 1.0, FlowOptions{});
  ASSERT_TRUE(slow.ok()) << slow.message;
  ASSERT_EQ(slow.events.size(), 1u);
  EXPECT_THAT(slow.events[0].surfaces, ElementsAre(1));
  EXPECT_NEAR(slow.events[0].window, 20 * 1e-10 / 0x1p-52, 1e-12 * 9.007e6);
  for (Grouping grouping : {Grouping::kAutomatic, Grouping::kFixedWindow, Grouping::kNone}) {
    SCOPED_TRACE(to_string(grouping));
    FlowOptions options;
    options.grouping = grouping;
    options.integrator.atol = 1e293;
    const FlowResult r = simulate(model, Eigen::Vector2d(-1e300, -0x1p-53), 1.0, options);
    EXPECT_EQ(r.status, IntegrationStatus::kOverflow);
    EXPECT_TRUE(r.events.empty());
    EXPECT_NEAR(r.t, 0.5, 4 * kEps);
    EXPECT_THAT(r.message, HasSubstr("the event at t = " + format_number(r.t) +
                                     ", surfaces [1]: the automatic grouping window = 9.007e+309 "
                                     "is beyond the double range"));
    EXPECT_THROW(flow_derivative(model, Eigen::Vector2d(-1e300, -0x1p-53), 1.0, options),
                 InvalidArgument);
  }
  // A window just inside the range is a number: atol = 1e291 gives 9.007e307.
  FlowOptions inside;
  inside.integrator.atol = 1e291;
  const FlowResult r = simulate(model, Eigen::Vector2d(-1e300, -0x1p-53), 1.0, inside);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.events.size(), 1u);
  EXPECT_NEAR(r.events[0].window, 20 * 1e291 / 0x1p-52, 4 * kEps * 9.007e307);
}

// d = 3 from (-0.625, -2500.625, -1e10) with atol = 100: surface 0 at t = 0.5, surface 1 at
// t = 2000.5, both with windows of 20 x 100 / 1.25 = 1600 (x_2's tolerance 100 does not enter),
// surface 1's window at the first event 10 (80 + 80.0000002) = 1600 < 2000, so two events 2000
// apart inside the near-simultaneity band of 100 windows: a notice. With a band of 1e306 windows
// the band is beyond the range: kOverflow, and only the first event is kept.
TEST(GroupingRangeTest, ANearSimultaneityBandBeyondTheRange) {
  const auto model = adapt(PiecewiseConstantField::linear(3, kDelta));
  const Eigen::Vector3d x0(-0.625, -2500.625, -1e10);
  FlowOptions options;
  options.integrator.atol = 100.0;
  FlowResult r = simulate(model, x0, 3000.0, options);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.events.size(), 2u);
  EXPECT_THAT(r.events[0].surfaces, ElementsAre(0));
  EXPECT_THAT(r.events[1].surfaces, ElementsAre(1));
  // rho = (0, -2500, -1e10 + 0.625) at t = 0.5 and (1500, 0, -1e10 + 2500.625) at t = 2000.5.
  EXPECT_NEAR(r.events[0].automatic_window, plane_window(options, 0.0, 1.25, 0.5), 4 * kEps * 1600);
  EXPECT_NEAR(r.events[1].automatic_window, plane_window(options, 0.0, 1.25, 2000.5),
              4 * kEps * 1600);
  // dop853 (the defaults' choice) rounds a constant field's increment by up to ~13 eps a step:
  // measured 6.8e-12, 15 ulps of 2000.
  EXPECT_NEAR(r.events[0].gap, 2000.0, 2e-11);
  const double widest = std::max(r.events[0].automatic_window, r.events[1].automatic_window);
  ASSERT_EQ(r.notices.size(), 1u);
  EXPECT_EQ(r.notices[0].band, 100 * widest);

  options.near_simultaneity_band = 1e306;
  r = simulate(model, x0, 3000.0, options);
  EXPECT_EQ(r.status, IntegrationStatus::kOverflow);
  ASSERT_EQ(r.events.size(), 1u);
  EXPECT_THAT(r.events[0].surfaces, ElementsAre(0));
  EXPECT_TRUE(r.notices.empty());
  EXPECT_THAT(r.message, HasSubstr("the near-simultaneity band 1e+306 x " + format_number(widest)));
  EXPECT_THAT(r.message, HasSubstr("is beyond the double range"));
}

// d = 3 from (-1e200, -0.625, -1e10) at the defaults (bflow flow --scene pwconst --param d=3
// --x0=-1e200,-0.625,-1e10): surface 1 is crossed at t = 0.5, surface 2 at t = 1e10 / 1.25 = 8e9
// and surface 0 at 8e199. Surface 2's window at t = 0.5 is 10 (sigma_2 + sigma_1) =
// 10 ((1e-10 + 1e-8 (1e10 - 0.625)) / 1.25 + 8e-11 + 32 eps x 0.5) = 800: x_0's tolerance of
// 1e192 does not widen it, so surface 2 (not crossed before t = 1) stays out and the image of e_2
// is e_2 (grouping it would make it 0.6 e_2 and x_2(1) wrong by 0.25): x_2(1) = -1e10 + 1.25.
TEST(GroupingRangeTest, AFarCoordinateDoesNotWidenTheWindowsOfOtherSurfaces) {
  const auto model = adapt(PiecewiseConstantField::linear(3, kDelta));
  const FlowOptions options;
  const Eigen::Vector3d x0(-1e200, -0.625, -1e10);
  const FlowRun r = run_flow(model, x0, options);
  expect_surface_alone(r, 1, options, {-1e200, 0.0, -1e10 + 0.625});
  EXPECT_NEAR(r.trajectory.events[0].window, 1.6e-9, 0.0001e-9);
  EXPECT_NEAR(r.images[2][2], 1.0, 1e-15);
  EXPECT_EQ(r.images[2][0], 0.0);
  EXPECT_EQ(r.images[2][1], 0.0);
  EXPECT_EQ(r.trajectory.x[0], -1e200);
  EXPECT_NEAR(r.trajectory.x[1], 0.5 * 0.75, 4 * kEps);
  EXPECT_NEAR(r.trajectory.x[2], -1e10 + 1.25, 4 * kEps * 1e10);
}

// A near-grazing passage (y' = 2x above h = y, from (-1, 1.1): closest at distance 0.1) whose band
// 8 (atol + rtol |y|) is beyond the range with atol = 1e308: kOverflow instead of a notice with
// an infinite band. With atol = 1e300 the band, 8e300, is a number.
struct Parabola {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    xdot[0] = T(b.plus(0) ? 1.0 : 2.0);
    xdot[1] = (b.plus(0) ? 2.0 : 6.0) * x[0];
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[1];
  }
};

TEST(GroupingRangeTest, ANearGrazingBandBeyondTheRange) {
  const auto model = adapt(Parabola{});
  FlowOptions options;
  options.integrator.atol = 1e300;
  FlowResult r = simulate(model, Eigen::Vector2d(-1.0, 1.1), 2.0, options);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.notices.size(), 1u);
  EXPECT_EQ(r.notices[0].kind, FlowNotice::Kind::kNearGrazing);
  EXPECT_NEAR(r.notices[0].band, 8e300, 4 * kEps * 8e300);

  options.integrator.atol = 1e308;
  r = simulate(model, Eigen::Vector2d(-1.0, 1.1), 2.0, options);
  EXPECT_EQ(r.status, IntegrationStatus::kOverflow);
  EXPECT_TRUE(r.notices.empty());
  EXPECT_THAT(r.message, HasSubstr("near grazing of surface 0 at t = "));
  EXPECT_THAT(r.message, HasSubstr("at distance g = 0.1"));
  EXPECT_THAT(r.message, HasSubstr("(atol + rtol |x_i|), is beyond the double range"));
}

}  // namespace
}  // namespace bflow

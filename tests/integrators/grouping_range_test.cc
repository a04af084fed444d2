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

// The automatic window of a first crossing at t1 whose normal speed is the full |F . e_j| = v
// (a coordinate plane, v >= 1 % of |F|): 2 safety (|atol + rtol |rho|| / v + 16 eps t1), the norm
// by std::hypot, which does not overflow.
double plane_window(const FlowOptions& options, const std::vector<double>& rho, double v,
                    double t1) {
  const double rtol = options.integrator.rtol;
  const double atol = options.integrator.absolute_tolerance();
  double tol = 0.0;
  for (double r : rho) tol = std::hypot(tol, atol + rtol * std::abs(r));
  return 2.0 * options.grouping_safety * (tol / v + 16 * kEps * t1);
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
  EXPECT_NEAR(e.window, plane_window(options, rho, 1.0 + kDelta, 0.5), 4 * kEps * e.window);
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

// The defaults, from x0 = (-1e200, -0.625): |atol + rtol |rho|| = 1e192 has no finite square.
// Surface 0 is reached 8e199 after the event, far outside its window of 20 x 1e192 / 1.25 =
// 1.6e193: one event of surface 1, the image of e_0 is e_0, as with Grouping::kNone.
TEST(GroupingRangeTest, AFarCoordinateDoesNotJoinTheEvent) {
  const auto model = adapt(PiecewiseConstantField::linear(2, kDelta));
  const FlowOptions options;
  const Eigen::Vector2d x0(-1e200, -0.625);
  const FlowRun r = run_flow(model, x0, options);
  expect_surface_alone(r, 1, options, {-1e200, 0.0});
  EXPECT_NEAR(r.trajectory.events[0].window, 1.6e193, 4 * kEps * 1.6e193);
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
// 1.7e300 overflow), and in three dimensions with two far coordinates.
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

// A surface with a normal of 1e200, h = (x_0, 1e200 x_1): |Dh_1| |tol| = 1e200 x 1e192 has no
// finite double, the window (the normal cancels) is the plane's 1.6e193.
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
  const FlowOptions options;
  expect_surface_alone(run_flow(model, Eigen::Vector2d(-1e200, -0.625), options), 1, options,
                       {-1e200, 0.0});
}

// A field of 1e200, F_b = 1e200 (1 - delta b), whose |F| has no finite square: the normal speed
// 1.25e200 is compared with 1 % of |F| = 1.77e198 as it is. From x0 = (-0.625e200, -1e250) surface
// 0 is crossed at t = 0.5, surface 1 at 8e49; the window is 20 |tol| / 1.25e200 with |tol| =
// 1e-8 x 1e250 (x_1 moves by 0.625e200, below the rounding of 1e250).
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
  // rho_0 is zero to the rounding of 0.625e200 (1e184), 1e66 below |tol|.
  const double window =
      20.0 * std::hypot(1e-10 + 1e-8 * std::abs(e.rho[0]), 1e-10 + 1e-8 * 1e250) / 1.25e200;
  EXPECT_NEAR(window, 1.6e43, 4 * kEps * 1.6e43);
  EXPECT_NEAR(e.automatic_window, window, 4 * kEps * window);
  EXPECT_EQ(e.window, e.automatic_window);
  const Eigen::VectorXd image = derivative.apply(Eigen::Vector2d(1.0, 0.0));
  EXPECT_NEAR(image[0], 0.6, kEps);
  EXPECT_EQ(image[1], 0.0);
}

// Huge tolerances. rtol = 1e300 (atol 1e298): from (-0.625, -0.626) the window is 20 x
// hypot(1e298, 1e298 + 1e300 x 1e-3) / 1.25 = 2.4e299, whose norm has no finite square; surface
// 1, 8e-4 behind, is inside it and joins (the rule, at this tolerance). With x_1 = -1e9 instead,
// rtol |rho_1| = 1e309 itself leaves the range and so does the window: kOverflow, no event.
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
  const double window = plane_window(options, {0.0, -1e-3}, 1.25, 0.5);
  EXPECT_NEAR(window, 2.38e299, 0.01e299);
  EXPECT_NEAR(e.automatic_window, window, 4 * kEps * window);
  EXPECT_NEAR(e.window, window, 4 * kEps * window);  // surface 1's window is the same

  r = simulate(model, Eigen::Vector2d(-0.625, -1e9), 1.0, options);
  EXPECT_EQ(r.status, IntegrationStatus::kOverflow);
  EXPECT_STREQ(to_string(r.status), "overflow");
  EXPECT_TRUE(r.events.empty());
  EXPECT_NEAR(r.t, 0.5, 4 * kEps);
  // 20 x 1e309 / 1.25 = 1.6e310.
  EXPECT_THAT(r.message, HasSubstr("the event at t = " + format_number(r.t) + ", surfaces [0"));
  EXPECT_THAT(r.message,
              HasSubstr("the automatic grouping window = 1.600e+310 is beyond the double range "
                        "(|atol + rtol |rho|| = 1.000e+309"));
}

// The defaults on a slow field, F_-- = (2^-52, 2^-52), from x0 = (-1e300, -2^-53): surface 1 is
// crossed at t = 0.5 with normal speed 2^-52, so its window is 20 x 1e292 / 2^-52 = 9.007e308,
// beyond the range (surface 0, 4.5e315 away, would not join it). It cannot be reported under any
// grouping policy: kOverflow, not an infinite window.
TEST(GroupingRangeTest, AWindowBeyondTheRangeEndsTheRun) {
  Eigen::MatrixXd delta = PiecewiseConstantField::linear(2, kDelta).delta();
  delta.col(0).setConstant(-1.0 + 0x1p-52);  // F_-- = 1 + Delta(--)
  const auto model = adapt(PiecewiseConstantField(delta));
  for (Grouping grouping : {Grouping::kAutomatic, Grouping::kFixedWindow, Grouping::kNone}) {
    SCOPED_TRACE(to_string(grouping));
    FlowOptions options;
    options.grouping = grouping;
    const FlowResult r = simulate(model, Eigen::Vector2d(-1e300, -0x1p-53), 1.0, options);
    EXPECT_EQ(r.status, IntegrationStatus::kOverflow);
    EXPECT_TRUE(r.events.empty());
    EXPECT_NEAR(r.t, 0.5, 4 * kEps);
    EXPECT_THAT(r.message, HasSubstr("the event at t = " + format_number(r.t) +
                                     ", surfaces [1]: the automatic grouping window = 9.007e+308 "
                                     "is beyond the double range"));
    EXPECT_THROW(flow_derivative(model, Eigen::Vector2d(-1e300, -0x1p-53), 1.0, options),
                 InvalidArgument);
  }
  // A window just inside the range is a number: x_0 = -1e299 gives 9.007e307.
  const FlowResult r = simulate(model, Eigen::Vector2d(-1e299, -0x1p-53), 1.0, FlowOptions{});
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.events.size(), 1u);
  EXPECT_NEAR(r.events[0].window, 20 * 1e291 / 0x1p-52, 4 * kEps * 9.007e307);
}

// d = 3 from (-0.625, -2500.625, -1e10): surface 0 at t = 0.5, surface 1 at t = 2000.5, both
// with windows of about 20 x 1e-8 x 1e10 / 1.25 = 1600 (|tol| is x_2's), so two events 2000
// apart inside the near-simultaneity band of 100 windows: a notice. With a band of 1e306 windows
// the band is beyond the range: kOverflow, and only the first event is kept.
TEST(GroupingRangeTest, ANearSimultaneityBandBeyondTheRange) {
  const auto model = adapt(PiecewiseConstantField::linear(3, kDelta));
  const Eigen::Vector3d x0(-0.625, -2500.625, -1e10);
  FlowOptions options;
  FlowResult r = simulate(model, x0, 3000.0, options);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.events.size(), 2u);
  EXPECT_THAT(r.events[0].surfaces, ElementsAre(0));
  EXPECT_THAT(r.events[1].surfaces, ElementsAre(1));
  // rho = (0, -2500, -1e10 + 0.625) at t = 0.5 and (1500, 0, -1e10 + 2500.625) at t = 2000.5.
  EXPECT_NEAR(r.events[0].automatic_window,
              plane_window(options, {0.0, -2500.0, -1e10 + 0.625}, 1.25, 0.5), 4 * kEps * 1600);
  EXPECT_NEAR(r.events[1].automatic_window,
              plane_window(options, {1500.0, 0.0, -1e10 + 2500.625}, 1.25, 2000.5),
              4 * kEps * 1600);
  EXPECT_NEAR(r.events[0].gap, 2000.0, 2e-12);  // 4 ulps of 2000
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

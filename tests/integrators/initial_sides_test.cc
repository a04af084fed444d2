// FlowOptions::initial_sides names the side of each surface at x0 where h(x0) cannot tell it (a
// start on a surface). A side that contradicts h_j(x0) beyond what the integration tolerance
// moves h_j, |Dh_j(x0)|_1 (atol + rtol |x0|_inf), is refused with the surface, the side and
// h_j(x0); within it, it is the caller's choice.
#include <cmath>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "bflow/core/biped.h"
#include "bflow/core/errors.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;

// x' = -1 on side - of h = x - 1 and x' = 2 on side +: a run from the surface leaves it on the
// side given, and its end shows which field it used.
struct Wall {
  static constexpr int kStates = 1;
  static constexpr int kSurfaces = 1;
  template <typename T>
  void field(const T*, Signs b, T* xdot) const {
    xdot[0] = T(b.plus(0) ? 2.0 : -1.0);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0] - T(1.0);
  }
};

FlowOptions with_sides(const char* sides) {
  FlowOptions o;
  o.initial_sides = Signs::parse(sides);
  return o;
}

TEST(InitialSides, ASideContradictingHBeyondRoundingIsRefused) {
  const auto model = adapt(Wall{});
  // h(0.5) = -0.5: side + is refused, naming the surface, the side and h.
  const std::string message = testing::message_of(
      [&] { simulate(model, Eigen::VectorXd::Constant(1, 0.5), 0.1, with_sides("+")); });
  EXPECT_THAT(message, HasSubstr("surface 0"));
  EXPECT_THAT(message, HasSubstr("side +"));
  EXPECT_THAT(message, HasSubstr("h_0(x0) = -0.5"));
  // And the other way round: h(1.5) = 0.5 with side -.
  EXPECT_THROW(simulate(model, Eigen::VectorXd::Constant(1, 1.5), 0.1, with_sides("-")),
               InvalidArgument);
  // The side h agrees with is accepted, and the field of that side is used (x' = -1 below).
  const FlowResult r = simulate(model, Eigen::VectorXd::Constant(1, 0.5), 0.1, with_sides("-"));
  ASSERT_TRUE(r.ok()) << r.message;
  EXPECT_NEAR(r.x[0], 0.4, 1e-12);
}

TEST(InitialSides, WithinTheToleranceOfTheSurfaceEitherSideIsTheCallersChoice) {
  const auto model = adapt(Wall{});
  // The band at x0 = 1 with the default tolerances (rtol 1e-8, atol 1e-10) is 1.01e-8: h = 0,
  // -1e-8 and +1e-8 are within it.
  for (double x0 : {1.0, 1.0 - 1e-8, 1.0 + 1e-8}) {
    for (const char* side : {"+", "-"}) {
      const FlowResult r = simulate(model, Eigen::VectorXd::Constant(1, x0), 0.1, with_sides(side));
      ASSERT_TRUE(r.ok()) << x0 << " " << side << ": " << r.message;
      // The chosen side's field: x' = 2 on +, -1 on -.
      EXPECT_NEAR(r.x[0], x0 + (side[0] == '+' ? 0.2 : -0.1), 1e-12) << x0 << " " << side;
    }
  }
  // Just beyond the band (h = -1.1e-8) side + is refused; a tighter tolerance narrows the band.
  EXPECT_THROW(simulate(model, Eigen::VectorXd::Constant(1, 1.0 - 1.1e-8), 0.1, with_sides("+")),
               InvalidArgument);
  FlowOptions tight = with_sides("+");
  tight.integrator.rtol = 1e-12;
  EXPECT_THROW(simulate(model, Eigen::VectorXd::Constant(1, 1.0 - 1e-10), 0.1, tight),
               InvalidArgument);
}

// The biped high in the air: both feet above the ground. Giving the sides h(x0) does not have is
// refused, for simulate and flow_derivative alike.
TEST(InitialSides, BipedInTheAirWithTheFeetMarkedOnTheGroundIsRefused) {
  const auto model = adapt(make_biped_mode_damping(BipedParams{}));
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(model.states());
  x0[1] = 2.0;
  Eigen::VectorXd h(model.surfaces());
  model.surface_values(x0.data(), h.data());
  std::string wrong, right;
  for (int j = 0; j < model.surfaces(); ++j) {
    ASSERT_GT(std::abs(h[j]), 0.1);
    right += h[j] > 0.0 ? '+' : '-';
    wrong += h[j] > 0.0 ? '-' : '+';
  }
  FlowOptions o = with_sides(wrong.c_str());
  const std::string message = testing::message_of([&] { simulate(model, x0, 0.6, o); });
  EXPECT_THAT(message, HasSubstr("surface 0"));
  EXPECT_THAT(message, HasSubstr("h_0(x0) = " + format_number(h[0])));
  EXPECT_THROW(flow_derivative(model, x0, 0.6, o), InvalidArgument);
  EXPECT_TRUE(simulate(model, x0, 0.6, with_sides(right.c_str())).ok());
}

}  // namespace
}  // namespace bflow

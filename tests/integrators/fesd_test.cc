// FESD ([F] Sections 4-5) on the four switching cases of Example 3 against their exact
// solutions, IRMA against its closed form, and the sensitivity against the event-driven engine.
#include "bflow/integrators/fesd.h"

#include <cmath>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/examples/irma.h"
#include "bflow/examples/switching_cases.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "support/error_message.h"

namespace bflow {
namespace {

template <typename Model>
FesdResult run_case(const std::string& name, const FesdOptions& options) {
  const auto exact = examples::exact_switching_case(name);
  return fesd_simulate(adapt_step(Model{}), exact.x0, exact.t_end, options);
}

template <typename Model>
void expect_exact(const std::string& name, const FesdOptions& o, double tol) {
  const auto exact = examples::exact_switching_case(name);
  const FesdResult r = run_case<Model>(name, o);
  ASSERT_TRUE(r.ok()) << name << ": " << r.message;
  ASSERT_EQ(r.switch_times.size(), exact.switch_times.size()) << name;
  for (std::size_t k = 0; k < exact.switch_times.size(); ++k) {
    EXPECT_NEAR(r.switch_times[k], exact.switch_times[k], tol) << name;
  }
  EXPECT_LE((r.x_end - exact.x_end).cwiseAbs().maxCoeff(), tol) << name;
  EXPECT_LE(r.max_complementarity, 1e-11) << name;
}

// Piecewise-constant and piecewise-polynomial fields: the collocation solution is exact on each
// arc, so what is left is where the switches are put, to the NLP tolerance.
TEST(FesdTest, CrossingAndLeavingSlidingAreExactAtTheSwitch) {
  FesdOptions o;
  o.steps = 4;  // the switches fall inside integration steps
  expect_exact<examples::CrossingCase>("crossing", o, 1e-9);
  expect_exact<examples::SlidingLeaveCase>("sliding-leave", o, 1e-9);
}

// The arc before the sliding one is smooth but not polynomial: Radau IIA with 4 stages (order 7)
// and h = 1/16 leaves an error of order h^7 ~ 1e-11 in the arrival time.
TEST(FesdTest, EnteringSlidingIsLocatedToTheOrderOfTheScheme) {
  FesdOptions o;
  o.stages = 4;
  o.steps = 8;
  o.elements = 2;
  expect_exact<examples::SlidingEnterCase>("sliding-enter", o, 1e-9);
}

// Steps are solved by Newton's method on guessed active sets (with and without a switch); the
// IPOPT homotopy alone must reach the same FESD solution, and Newton must actually be used.
TEST(FesdTest, NewtonOnGuessedActiveSetsAgreesWithTheHomotopy) {
  FesdOptions o;
  o.stages = 4;
  o.steps = 8;
  o.elements = 2;
  const FesdResult fast = run_case<examples::SlidingEnterCase>("sliding-enter", o);
  o.newton = false;
  const FesdResult slow = run_case<examples::SlidingEnterCase>("sliding-enter", o);
  ASSERT_TRUE(fast.ok()) << fast.message;
  ASSERT_TRUE(slow.ok()) << slow.message;
  EXPECT_EQ(fast.newton_steps, 8);
  EXPECT_EQ(fast.newton_switch_steps, 1);  // the step where the sliding arc begins
  EXPECT_EQ(slow.newton_steps, 0);
  EXPECT_LE((fast.x_end - slow.x_end).cwiseAbs().maxCoeff(), 1e-10);
  ASSERT_EQ(fast.switch_times.size(), slow.switch_times.size());
  EXPECT_NEAR(fast.switch_times[0], slow.switch_times[0], 1e-10);
  ASSERT_EQ(fast.sensitivity.size(), slow.sensitivity.size());
  EXPECT_LE((fast.sensitivity - slow.sensitivity).cwiseAbs().maxCoeff(), 1e-8);
}

// One IRMA step across its first switch (c_6 at t = 25.54) from the exact state at t = 25:
// the switch guessed at each element boundary, against the homotopy and the closed form.
TEST(FesdTest, IrmaSwitchStepByNewtonAgreesWithTheHomotopy) {
  const examples::Irma irma;
  const auto model = adapt_step(irma);
  const Eigen::VectorXd x25 = examples::exact_irma(irma, examples::Irma::initial_state(), 25.0).x;
  const examples::IrmaSolution exact = examples::exact_irma(irma, x25, 5.0);
  ASSERT_EQ(exact.switches.size(), 1u);
  FesdOptions o;
  o.sensitivities = false;
  const FesdResult fast = fesd_simulate(model, x25, 5.0, o);
  o.newton = false;
  const FesdResult slow = fesd_simulate(model, x25, 5.0, o);
  ASSERT_TRUE(fast.ok()) << fast.message;
  ASSERT_TRUE(slow.ok()) << slow.message;
  EXPECT_EQ(fast.newton_switch_steps, 1);
  ASSERT_EQ(fast.switch_times.size(), 1u);
  ASSERT_EQ(slow.switch_times.size(), 1u);
  // Measured: switch times 1.6e-9 apart, x 1.2e-11 apart; against the closed form the switch
  // is 9.5e-9 early and x is off by 1.9e-6 (Radau IIA 2, order 3, h = 5/3).
  EXPECT_NEAR(fast.switch_times[0], slow.switch_times[0], 1e-8);
  EXPECT_LE((fast.x_end - slow.x_end).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_NEAR(fast.switch_times[0], exact.switches[0].t, 1e-7);  // from t = 25
  EXPECT_LE((fast.x_end - exact.x).cwiseAbs().maxCoeff(), 1e-5);
}

// x' in sign(x) from 0 has infinitely many solutions: stay at 0, or leave at any t_s with
// |x| = t - t_s. Whichever FESD returns must be one of them.
TEST(FesdTest, SpontaneousSwitchReturnsOneOfTheSolutions) {
  FesdOptions o;
  o.steps = 4;
  const FesdResult r = run_case<examples::SpontaneousCase>("spontaneous", o);
  ASSERT_TRUE(r.ok()) << r.message;
  if (r.switch_times.empty()) {
    EXPECT_LE(std::abs(r.x_end[0]), 1e-9);
  } else {
    ASSERT_EQ(r.switch_times.size(), 1u);
    EXPECT_NEAR(std::abs(r.x_end[0]), 1.0 - r.switch_times[0], 1e-9);
  }
}

// A 2-state system with a transversal crossing of a curved surface, written once as a step
// inclusion and seen by both engines.
struct CurvedCrossing {
  static constexpr int kStates = 2;
  static constexpr int kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0] + 0.2 * x[1] * x[1] - 0.5;
  }
  template <typename T>
  void field(const T* x, const T* a, T* xdot) const {
    xdot[0] = 1.0 + 0.3 * x[1] + 0.8 * a[0];
    xdot[1] = -0.5 * x[0] + 0.6 * a[0] * x[1];
  }
};

// [F] Section 5.4: FESD's sensitivity converges, as h -> 0, to the derivative of the flow,
// which across a transversal crossing is the saltation-corrected Jacobian of the event-driven
// engine.
TEST(FesdTest, SensitivityConvergesToTheSaltationCorrectedJacobian) {
  const Eigen::Vector2d x0(0.0, 0.4);
  const double t_end = 1.0;
  FlowOptions flow_options;
  flow_options.integrator.rtol = 1e-12;
  flow_options.integrator.atol = 1e-14;
  const auto event_model = adapt(EventDrivenView<CurvedCrossing>{});
  FlowResult trajectory;
  const Eigen::MatrixXd reference =
      flow_derivative(event_model, x0, t_end, flow_options, &trajectory).jacobian();
  ASSERT_EQ(trajectory.events.size(), 1u);

  const auto model = adapt_step(CurvedCrossing{});
  double previous = 0;
  for (int steps : {2, 4, 8}) {
    FesdOptions o;
    o.steps = steps;
    const FesdResult r = fesd_simulate(model, x0, t_end, o);
    ASSERT_TRUE(r.ok()) << r.message;
    ASSERT_EQ(r.sensitivity.rows(), 2) << r.message;
    ASSERT_EQ(r.switch_times.size(), 1u);
    EXPECT_NEAR(r.switch_times[0], trajectory.events[0].t, 1e-4);
    const double error = (r.sensitivity - reference).norm() / reference.norm();
    if (previous > 0) {
      // Radau IIA, 2 stages, order 3: halving h divides the error by about 8.
      EXPECT_LT(error, previous / 4) << steps << " steps";
    }
    previous = error;
  }
  EXPECT_LT(previous, 1e-5);
}

TEST(FesdTest, IrmaMatchesItsExactSolution) {
  const examples::Irma irma;
  const double t_end = 50.0;  // two switches, at t = 25.54 (c_5) and t = 39.19 (c_0)
  const examples::IrmaSolution exact =
      examples::exact_irma(irma, examples::Irma::initial_state(), t_end);
  ASSERT_EQ(exact.switches.size(), 2u);
  FesdOptions o;
  o.stages = 3;
  o.steps = 10;  // h = 5 / 3 min per element; Radau IIA (3), order 5

  const FesdResult r = fesd_simulate(adapt_step(irma), examples::Irma::initial_state(), t_end, o);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.switch_times.size(), exact.switches.size());
  for (std::size_t k = 0; k < exact.switches.size(); ++k) {
    EXPECT_NEAR(r.switch_times[k], exact.switches[k].t, 1e-6) << "switch " << k;
  }
  EXPECT_LE((r.x_end - exact.x).cwiseAbs().maxCoeff(), 1e-8);
}

// x' in 2 - sign(x) as a piecewise-smooth system: modes f_1 = 1 on {x > 0}, f_2 = 3 on
// {x < 0}, S = (+1; -1). Same inclusion, same FESD solution as the step form.
struct CrossingPss {
  static constexpr int kStates = 1;
  static constexpr int kSwitches = 1;
  static constexpr int kModes = 2;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0];
  }
  template <typename T>
  void modes(const T*, T* f) const {
    f[0] = T(1.0);
    f[1] = T(3.0);
  }
};

TEST(FesdTest, PiecewiseSmoothFormAndGaussLegendreGiveTheExactCrossing) {
  Eigen::MatrixXi rows(2, 1);
  rows << 1, -1;
  const auto model =
      adapt_step(PiecewiseSmoothAsStep<CrossingPss>(CrossingPss{}, SignMatrix(rows, {0, 1})));
  for (CollocationScheme scheme :
       {CollocationScheme::kRadauIIA, CollocationScheme::kGaussLegendre}) {
    FesdOptions o;
    o.scheme = scheme;
    o.steps = 4;
    const FesdResult r = fesd_simulate(model, Eigen::VectorXd::Constant(1, -1.0), 1.0, o);
    ASSERT_TRUE(r.ok()) << r.message;
    ASSERT_EQ(r.switch_times.size(), 1u) << to_string(scheme);
    EXPECT_NEAR(r.switch_times[0], 1.0 / 3.0, 1e-9) << to_string(scheme);
    EXPECT_NEAR(r.x_end[0], 2.0 / 3.0, 1e-9) << to_string(scheme);
  }
}

// Standard time-stepping (34) keeps the grid fixed: a switch inside an element is smeared, and
// the error falls only like h (order 1), where FESD is exact here.
TEST(FesdTest, StandardTimeSteppingIsFirstOrderAcrossTheSwitch) {
  const auto model = adapt_step(examples::CrossingCase{});
  auto error = [&](int steps) {
    FesdOptions o;
    o.standard = true;
    o.sensitivities = false;
    o.steps = steps;
    o.elements = 1;
    const FesdResult r = fesd_simulate(model, Eigen::VectorXd::Constant(1, -1.0), 1.0, o);
    EXPECT_TRUE(r.ok()) << r.message;
    return std::abs(r.x_end[0] - 2.0 / 3.0);
  };
  // Steps that put the switch at different places inside an element: 1/3 is never a node.
  // Measured: 0.033 at h = 0.2 and 0.0083 at h = 0.05, a ratio of 4 for h / 4: first order.
  const double coarse = error(5), fine = error(20);
  EXPECT_GT(coarse, 1e-3);
  EXPECT_GT(coarse / fine, 2.0);
  EXPECT_LT(coarse / fine, 8.0);
  EXPECT_GT(fine, 1e-4);  // far from the exactness of FESD on the same problem
}

TEST(FesdTest, BadInputNamesTheProblem) {
  using bflow::testing::message_of;
  const auto model = adapt_step(examples::CrossingCase{});
  EXPECT_THAT(message_of([&] { fesd_simulate(model, Eigen::Vector2d(0, 0), 1.0); }),
              ::testing::HasSubstr("x0 has 2 entries, the model 1 states"));
  EXPECT_THAT(message_of([&] { fesd_simulate(model, Eigen::VectorXd::Zero(1), -1.0); }),
              ::testing::HasSubstr("T must be finite and > 0, got -1"));
  FesdOptions o;
  o.stages = 12;
  EXPECT_THAT(message_of([&] { fesd_simulate(model, Eigen::VectorXd::Zero(1), 1.0, o); }),
              ::testing::HasSubstr("stages must be in [1, 9], got 12"));
}

}  // namespace
}  // namespace bflow

// FESD ([F] Sections 4-5) on the four switching cases of Example 3 against their exact
// solutions, IRMA against its closed form, and the sensitivity against the event-driven engine.
#include "bflow/fesd/fesd.h"

#include <cmath>
#include <cstdio>
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
  // Measured: 9e-33 and 0 (Newton solves every step: products exactly zero).
  EXPECT_LE(r.max_complementarity, 1e-14) << name;
}

// Piecewise-constant and piecewise-polynomial fields: the collocation solution is exact on each
// arc, so what is left is where the switches are put, to round-off (Newton on the FESD
// equations). Measured: switch times exact, x(T) 5.6e-17.
TEST(FesdTest, CrossingAndLeavingSlidingAreExactAtTheSwitch) {
  FesdOptions o;
  o.steps = 4;  // the switches fall inside integration steps
  expect_exact<examples::CrossingCase>("crossing", o, 1e-14);
  expect_exact<examples::SlidingLeaveCase>("sliding-leave", o, 1e-14);
}

// The arc before the sliding one is smooth but not polynomial: Radau IIA with 4 stages (order 7)
// and h = 1/16 leaves an error of order h^7 ~ 1e-11 in the arrival time. Measured: 3.0e-13
// (x(T) 5e-35).
TEST(FesdTest, EnteringSlidingIsLocatedToTheOrderOfTheScheme) {
  FesdOptions o;
  o.stages = 4;
  o.steps = 8;
  o.elements = 2;
  expect_exact<examples::SlidingEnterCase>("sliding-enter", o, 1e-11);
}

// Steps are solved by Newton's method on guessed active sets (with and without a switch); the
// IPOPT homotopy alone must reach the same FESD solution, and Newton must actually be used: on
// every step, as each has at most one switch, which the guesses cover, and with a switch on
// exactly one (the sliding arc begins once). The homotopy's point is the relaxed solution at
// sigma_final = 1e-12 to IPOPT's tol 1e-13, which may lie O(sigma_final) from the discrete
// solution Newton solves to round-off: the bounds are 10 sigma_final (a wrong active set is off
// by O(h)).
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
  // Measured: x 4.5e-15, switch time 3.4e-13, sensitivity 5.4e-16 apart.
  const double apart = 10.0 * o.homotopy.sigma_final;
  EXPECT_LE((fast.x_end - slow.x_end).cwiseAbs().maxCoeff(), apart);
  ASSERT_EQ(fast.switch_times.size(), slow.switch_times.size());
  EXPECT_NEAR(fast.switch_times[0], slow.switch_times[0], apart);
  ASSERT_EQ(fast.sensitivity.size(), slow.sensitivity.size());
  EXPECT_LE((fast.sensitivity - slow.sensitivity).cwiseAbs().maxCoeff(), apart);
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
  std::printf(
      "against the closed form: Newton switch %.1e, x %.1e; homotopy switch %.1e, x %.1e "
      "(%d steps at IPOPT's acceptable level)\n",
      std::abs(fast.switch_times[0] - exact.switches[0].t),
      (fast.x_end - exact.x).cwiseAbs().maxCoeff(),
      std::abs(slow.switch_times[0] - exact.switches[0].t),
      (slow.x_end - exact.x).cwiseAbs().maxCoeff(), slow.acceptable_only_steps);
  EXPECT_NEAR(fast.switch_times[0], slow.switch_times[0], 1e-8);
  // Where IPOPT solves the homotopy's last NLP, both are the same discrete solution (measured
  // 1.2e-11 apart). Where it stops at its acceptable level (reported in acceptable_only_steps;
  // measured on an AVX-512 machine, whose BLAS kernels round otherwise: one step), the homotopy's
  // point is that level's: 1.5e-6 from Newton's, 3.6e-7 from the closed form.
  const double apart = slow.acceptable_only_steps == 0 ? 3e-10 : 5e-6;
  EXPECT_LE((fast.x_end - slow.x_end).cwiseAbs().maxCoeff(), apart);
  EXPECT_LE((slow.x_end - exact.x).cwiseAbs().maxCoeff(), 1e-5);
  EXPECT_NEAR(fast.switch_times[0], exact.switches[0].t, 1e-7);  // from t = 25
  EXPECT_LE((fast.x_end - exact.x).cwiseAbs().maxCoeff(), 1e-5);
}

// A step that IPOPT accepts only at its "acceptable" level, with complementarity products above
// sigma_final, is flagged; forced here by acceptable tolerances so loose that IPOPT stops at its
// first iterate. The same homotopy with bflow's settings, and Newton, are not flagged.
TEST(FesdTest, AcceptableLevelSolvesAreFlagged) {
  const auto model = adapt_step(examples::CrossingCase{});
  const Eigen::VectorXd x0 = Eigen::VectorXd::Constant(1, -1.0);
  FesdOptions o;
  o.newton = false;
  o.steps = 2;
  o.sensitivities = false;
  const FesdResult normal = fesd_simulate(model, x0, 1.0, o);
  ASSERT_TRUE(normal.ok()) << normal.message;
  EXPECT_FALSE(normal.acceptable_only);
  EXPECT_EQ(normal.acceptable_only_steps, 0);
  EXPECT_LE(normal.max_complementarity,
            o.homotopy.sigma_final);  // the relaxation; measured 7.2e-13

  o.solver.ipopt_numeric_options = {{"acceptable_tol", 1e10},
                                    {"acceptable_constr_viol_tol", 1e10},
                                    {"acceptable_dual_inf_tol", 1e10},
                                    {"acceptable_compl_inf_tol", 1e10}};
  o.solver.ipopt_integer_options = {{"acceptable_iter", 1}};
  const FesdResult loose = fesd_simulate(model, x0, 1.0, o);
  EXPECT_TRUE(loose.acceptable_only);
  EXPECT_EQ(loose.acceptable_only_steps, 2);
  EXPECT_GT(loose.max_complementarity, o.homotopy.sigma_final);  // measured 0.15
  EXPECT_THAT(loose.message, ::testing::HasSubstr("solved by IPOPT only to its acceptable level"));

  FesdOptions n;
  n.steps = 2;
  const FesdResult newton = fesd_simulate(model, x0, 1.0, n);
  ASSERT_TRUE(newton.ok()) << newton.message;
  EXPECT_EQ(newton.newton_steps, 2);
  EXPECT_FALSE(newton.acceptable_only);

  using bflow::testing::message_of;
  o.solver.ipopt_numeric_options = {{"no_such_option", 1.0}};
  EXPECT_THAT(message_of([&] { fesd_simulate(model, x0, 1.0, o); }),
              ::testing::HasSubstr("IPOPT does not take the numeric option no_such_option"));
}

// x' in sign(x) from 0 has infinitely many solutions: stay at 0, or leave at any t_s with
// |x| = t - t_s. Whichever FESD returns must be one of them.
TEST(FesdTest, SpontaneousSwitchReturnsOneOfTheSolutions) {
  FesdOptions o;
  o.steps = 4;
  const FesdResult r = run_case<examples::SpontaneousCase>("spontaneous", o);
  ASSERT_TRUE(r.ok()) << r.message;
  // Measured: x = 0 exactly (sliding is guessed first).
  if (r.switch_times.empty()) {
    EXPECT_LE(std::abs(r.x_end[0]), 1e-14);
  } else {
    ASSERT_EQ(r.switch_times.size(), 1u);
    EXPECT_NEAR(std::abs(r.x_end[0]), 1.0 - r.switch_times[0], 1e-14);
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

// dx(T)/dx0 across sliding entry and exit, against closed forms derived by hand.
//
// A test problem that enters a sliding arc, moves along it and leaves: c = x1,
//   x1' = x2 + 1 - 2a,  x2' = a   (x1' in x2 - sign(x1); the Filippov combination a f+ +
//   (1 - a) f- of f+ = (x2 - 1, 1) and f- = (x2 + 1, 0)),
// from p = x1(0) < 0, q = x2(0) in (-1, 1):
//   - a = 0: x1 = p + (1 + q) t, x2 = q; x1 reaches 0 at t1 = -p / (1 + q);
//   - sliding (both sides point at x1 = 0 while |x2| < 1): x1' = 0 gives a = (1 + x2) / 2, so
//     x2' = (1 + x2) / 2 and 1 + x2 = (1 + q) e^{(t - t1)/2}; a reaches 1 (x2 = 1) at
//     t2 = t1 + 2 ln(2 / (1 + q));
//   - a = 1 (x1' = x2 - 1 > 0 from then on): x2 = 1 + (t - t2), x1 = (t - t2)^2 / 2.
// So x(T) = ((T - t2)^2 / 2, 1 + T - t2) with t2 = -p / (1 + q) + 2 ln 2 - 2 ln(1 + q), and
//   dt2/dp = -1 / (1 + q),  dt2/dq = p / (1 + q)^2 - 2 / (1 + q),
//   dx(T)/dx0 = -[T - t2; 1] [dt2/dp, dt2/dq].
// Only t2 carries x0 into x(T): the sliding arc forgets x1(0) except through when it began.
struct SlideThenLeave {
  static constexpr int kStates = 2;
  static constexpr int kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0];
  }
  template <typename T>
  void field(const T* x, const T* a, T* xdot) const {
    xdot[0] = x[1] + 1.0 - 2.0 * a[0];
    xdot[1] = a[0];
  }
};

constexpr double kSlideThenLeaveT = 1.5;

// x(T) of SlideThenLeave, arc by arc (valid while x1(0) < 0, |x2(0)| < 1 and t2 < T).
Eigen::Vector2d slide_then_leave_exact(const Eigen::Vector2d& x0) {
  const double p = x0[0], q = x0[1];
  const double t1 = -p / (1.0 + q);
  const double t2 = t1 + 2.0 * std::log(2.0 / (1.0 + q));
  EXPECT_GT(t1, 0.0);
  EXPECT_LT(t2, kSlideThenLeaveT);
  const double after = kSlideThenLeaveT - t2;
  return Eigen::Vector2d(after * after / 2.0, 1.0 + after);
}

Eigen::Matrix2d slide_then_leave_jacobian(const Eigen::Vector2d& x0) {
  const double p = x0[0], q = x0[1];
  const double t2 = -p / (1.0 + q) + 2.0 * std::log(2.0 / (1.0 + q));
  const Eigen::RowVector2d dt2(-1.0 / (1.0 + q), p / ((1.0 + q) * (1.0 + q)) - 2.0 / (1.0 + q));
  return -Eigen::Vector2d(kSlideThenLeaveT - t2, 1.0) * dt2;
}

// Example 3's sliding cases as functions of x0 = (x, tau), T as in switching_cases.h.
// sliding-enter: x = x0 - t - 0.04 (cos 5(tau0 + t) - cos 5 tau0) reaches 0 before T = 1 for
// x0 near (0.5, 0) and stays there (|0.2 sin 5 tau| < 1 keeps it sliding): x(T) = (0, tau0 + T),
// dx(T)/dx0 = [[0, 0], [0, 1]].
Eigen::Vector2d sliding_enter_exact(const Eigen::Vector2d& x0) {
  const double x = x0[0], tau = x0[1];
  double t = 0.55;  // the arrival, by Newton as in switching_cases.h
  for (int k = 0; k < 50; ++k) {
    t -= (x - t - 0.04 * (std::cos(5.0 * (tau + t)) - std::cos(5.0 * tau))) /
         (-1.0 + 0.2 * std::sin(5.0 * (tau + t)));
  }
  EXPECT_LT(t, 1.0);
  return Eigen::Vector2d(0.0, tau + 1.0);
}

// sliding-leave: from x0 near 0 on either side, x' = -1 + tau (x > 0) or 1 + tau (x < 0) brings
// x to 0 at t_r < 1 - tau0, it slides (a = (1 + tau) / 2) until tau = 1 and leaves with
// x = (tau - 1)^2 / 2: x(T) = ((T + tau0 - 1)^2 / 2, tau0 + T), T = 2, and
// dx(T)/dx0 = [[0, T + tau0 - 1], [0, 1]] = [[0, 1], [0, 1]] at x0 = 0. Both one-sided derivatives
// in x0 agree (0): the flow is differentiable across the surface it starts on.
Eigen::Vector2d sliding_leave_exact(const Eigen::Vector2d& x0) {
  const double x = x0[0], tau = x0[1];
  // x > 0: x - (1 - tau0) t + t^2 / 2 = 0; x < 0: x + (1 + tau0) t + t^2 / 2 = 0.
  const double t_r = x > 0 ? (1.0 - tau) - std::sqrt((1.0 - tau) * (1.0 - tau) - 2.0 * x)
                           : -(1.0 + tau) + std::sqrt((1.0 + tau) * (1.0 + tau) - 2.0 * x);
  EXPECT_LT(t_r, 1.0 - tau);
  return Eigen::Vector2d(0.5 * (tau + 1.0) * (tau + 1.0), tau + 2.0);
}

// The closed forms above against one-sided differences of the closed-form solutions (forward
// and backward, step 1e-7: truncation O(1e-7), cancellation O(1e-9)).
TEST(FesdTest, ClosedFormSlidingJacobiansMatchOneSidedDifferences) {
  const auto check = [](const auto& flow, const Eigen::Vector2d& x0, const Eigen::Matrix2d& jac,
                        const char* what) {
    const double step = 1e-7;
    for (int k = 0; k < 2; ++k) {
      const Eigen::Vector2d e = step * Eigen::Vector2d::Unit(k);
      const Eigen::Vector2d forward = (flow(x0 + e) - flow(x0)) / step;
      const Eigen::Vector2d backward = (flow(x0) - flow(x0 - e)) / step;
      // Measured: 2.2e-8 and 6.7e-8 (slide-then-leave, the curvature of t2), 0 (enter), 5.8e-10
      // and 5.1e-8 (leave): the truncation error, step / 2 times the second derivative.
      EXPECT_LE((forward - jac.col(k)).cwiseAbs().maxCoeff(), 1e-6) << what << " column " << k;
      EXPECT_LE((backward - jac.col(k)).cwiseAbs().maxCoeff(), 1e-6) << what << " column " << k;
    }
  };
  const Eigen::Vector2d x0(-0.3, 0.5);
  check(slide_then_leave_exact, x0, slide_then_leave_jacobian(x0), "slide-then-leave");
  Eigen::Matrix2d enter, leave;
  enter << 0, 0, 0, 1;
  leave << 0, 1, 0, 1;
  check(sliding_enter_exact, examples::exact_switching_case("sliding-enter").x0, enter,
        "sliding-enter");
  check(sliding_leave_exact, examples::exact_switching_case("sliding-leave").x0, leave,
        "sliding-leave");
}

TEST(FesdTest, SensitivityAcrossSlidingEntryAndExitMatchesTheClosedForm) {
  const Eigen::Vector2d x0(-0.3, 0.5);  // t1 = 0.2, t2 = 0.2 + 2 ln(4/3) = 0.7754
  FesdOptions o;
  o.stages = 4;
  o.steps = 6;
  const FesdResult r = fesd_simulate(adapt_step(SlideThenLeave{}), x0, kSlideThenLeaveT, o);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.sensitivity.rows(), 2) << r.message;
  ASSERT_EQ(r.switch_times.size(), 2u);
  const double t1 = 0.2, t2 = 0.2 + 2.0 * std::log(4.0 / 3.0);
  const Eigen::Matrix2d jac = slide_then_leave_jacobian(x0);
  // Measured: t1 2.8e-17, t2 1.1e-16, x(T) 2.2e-16, dx(T)/dx0 1.8e-15 (Radau IIA 4 is of
  // order 7 on the exponential sliding arc, h = 1/12; the other arcs are polynomial).
  EXPECT_NEAR(r.switch_times[0], t1, 1e-14);
  EXPECT_NEAR(r.switch_times[1], t2, 1e-14);
  EXPECT_LE((r.x_end - slide_then_leave_exact(x0)).cwiseAbs().maxCoeff(), 1e-14);
  EXPECT_LE((r.sensitivity - jac).cwiseAbs().maxCoeff(), 1e-13) << r.sensitivity;

  Eigen::Matrix2d enter, leave;
  enter << 0, 0, 0, 1;
  leave << 0, 1, 0, 1;
  FesdOptions e;
  e.stages = 4;
  e.steps = 8;
  e.elements = 2;
  const FesdResult re = run_case<examples::SlidingEnterCase>("sliding-enter", e);
  ASSERT_TRUE(re.ok()) << re.message;
  ASSERT_EQ(re.sensitivity.rows(), 2) << re.message;
  FesdOptions v;
  v.steps = 3;  // the exit at t = 1 inside a step (N_sim = 4 puts it on a step boundary)
  const FesdResult rl = run_case<examples::SlidingLeaveCase>("sliding-leave", v);
  ASSERT_TRUE(rl.ok()) << rl.message;
  ASSERT_EQ(rl.sensitivity.rows(), 2) << rl.message;
  // Measured: 1.2e-15 (enter) and 7.8e-16 (leave).
  EXPECT_LE((re.sensitivity - enter).cwiseAbs().maxCoeff(), 1e-13) << re.sensitivity;
  EXPECT_LE((rl.sensitivity - leave).cwiseAbs().maxCoeff(), 1e-13) << rl.sensitivity;
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
  // Measured: switch times 1.4e-10 and 1.8e-8 off, x(T) 1.7e-9 (order 5, h = 5/3).
  for (std::size_t k = 0; k < exact.switches.size(); ++k) {
    EXPECT_NEAR(r.switch_times[k], exact.switches[k].t, 1e-7) << "switch " << k;
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
    // Measured: switch time exact, x(T) 1.1e-16.
    EXPECT_NEAR(r.switch_times[0], 1.0 / 3.0, 1e-14) << to_string(scheme);
    EXPECT_NEAR(r.x_end[0], 2.0 / 3.0, 1e-14) << to_string(scheme);
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

// The three DCS formulations FESD discretises ([F] (22), (28) and the lifting of Section 6.3):
// each against exact solutions, and against each other.
#include <cmath>
#include <string>
#include <utility>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/examples/switching_cases.h"
#include "bflow/fesd/fesd.h"
#include "support/derivative_checker.h"
#include "support/error_message.h"

namespace bflow {
namespace {

// Three switching functions, one slides, one is crossed, one keeps its side:
//   x1' = (2 - 3 a1) a3,  x2' = 1 + x1 + a2,  c = (x1, x2 - 0.5, x2 + 2),
// from x = (-0.6, 0): x1 = -0.6 + 2t reaches 0 at t = 0.3 and slides there (a1 = 2/3);
// x2 = 0.4 t + t^2 until t = 0.3 (0.21), then x2' = 1 up to 0.5 at t = 0.59, then x2' = 2.
// Piecewise polynomial of degree <= 2, so Radau IIA with 2 stages is exact on every arc.
struct SlideAndCross {
  static constexpr int kStates = 2;
  static constexpr int kSwitches = 3;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0];
    c[1] = x[1] - T(0.5);
    c[2] = x[1] + T(2.0);
  }
  template <typename T>
  void field(const T* x, const T* a, T* xdot) const {
    xdot[0] = (T(2.0) - T(3.0) * a[0]) * a[2];
    xdot[1] = T(1.0) + x[0] + a[1];
  }
};

FesdResult run(DcsFormulation formulation, int lifting_depth, bool newton = true) {
  FesdOptions o;
  o.formulation = formulation;
  o.lifting_depth = lifting_depth;
  o.steps = 4;  // h = 1/12 per element; the switches fall inside steps
  o.newton = newton;
  Eigen::VectorXd x0(2);
  x0 << -0.6, 0.0;
  return fesd_simulate(adapt_step(SlideAndCross{}), x0, 1.0, o);
}

// Newton-solved runs are exact to round-off (measured: 1.1e-16); homotopy-only runs to what
// sigma_final = 1e-12 and IPOPT's tol 1e-13 leave (measured: 7.8e-13).
constexpr double kNewtonTol = 1e-14;
constexpr double kHomotopyTol = 3e-11;

void expect_exact(const FesdResult& r, const std::string& what, double tol) {
  ASSERT_TRUE(r.ok()) << what << ": " << r.message;
  ASSERT_EQ(r.switch_times.size(), 2u) << what;
  EXPECT_NEAR(r.switch_times[0], 0.3, tol) << what;
  EXPECT_NEAR(r.switch_times[1], 0.59, tol) << what;
  EXPECT_NEAR(r.x_end[0], 0.0, tol) << what;
  EXPECT_NEAR(r.x_end[1], 1.32, tol) << what;
  // Sides on the last element: sliding on c1, + on c2 and c3.
  EXPECT_THAT(r.active_sets.back(), ::testing::ElementsAre(0, 1, 1)) << what;
}

TEST(FesdFormulationTest, StepStewartAndLiftedAreExactOnSlidingAndCrossing) {
  const FesdResult step = run(DcsFormulation::kStep, 0);
  const FesdResult stewart = run(DcsFormulation::kStewart, 0);
  const FesdResult lifted = run(DcsFormulation::kStep, 2);  // theta and 4 betas as unknowns
  expect_exact(step, "step", kNewtonTol);
  expect_exact(stewart, "stewart", kNewtonTol);
  expect_exact(lifted, "lifted", kNewtonTol);
  // dx(1)/dx0 by three different sets of equations: the same derivative.
  ASSERT_EQ(step.sensitivity.size(), 4);
  ASSERT_EQ(stewart.sensitivity.size(), 4) << stewart.message;
  ASSERT_EQ(lifted.sensitivity.size(), 4) << lifted.message;
  // Measured: 3.9e-15 and 1.1e-15 apart.
  EXPECT_LE((stewart.sensitivity - step.sensitivity).cwiseAbs().maxCoeff(), 1e-13);
  EXPECT_LE((lifted.sensitivity - step.sensitivity).cwiseAbs().maxCoeff(), 1e-13);
  // Closed form: x1 reaches 0 at t1 = -x1(0)/2 and stays, x2(t1) = x2(0) - x1(0)/2 - x1(0)^2/4,
  // then x2' = 1 up to 0.5 and x2' = 2 after: x2(1) = 1.5 + 2 x2(0) - x1(0)^2 / 2. So
  // dx(1)/dx0 = [[0, 0], [-x1(0), 2]] = [[0, 0], [0.6, 2]]. Measured: at most 1.2e-15 off.
  EXPECT_NEAR(step.sensitivity(0, 0), 0.0, 1e-13);
  EXPECT_NEAR(step.sensitivity(0, 1), 0.0, 1e-13);
  EXPECT_NEAR(step.sensitivity(1, 0), 0.6, 1e-13);
  EXPECT_NEAR(step.sensitivity(1, 1), 2.0, 1e-13);
}

TEST(FesdFormulationTest, StewartHomotopyAlsoReachesTheExactSolution) {
  expect_exact(run(DcsFormulation::kStewart, 0, /*newton=*/false), "stewart, homotopy only",
               kHomotopyTol);
  expect_exact(run(DcsFormulation::kStep, 3, /*newton=*/false), "lifted n_d = 3, homotopy only",
               kHomotopyTol);
}

// Example 3's cases in Stewart's formulation (two modes, g = (-c, c)).
TEST(FesdFormulationTest, StewartOnTheSwitchingCases) {
  FesdOptions o;
  o.formulation = DcsFormulation::kStewart;
  o.steps = 4;
  for (const char* name : {"crossing", "sliding-leave"}) {
    const auto exact = examples::exact_switching_case(name);
    const FesdResult r =
        std::string(name) == "crossing"
            ? fesd_simulate(adapt_step(examples::CrossingCase{}), exact.x0, exact.t_end, o)
            : fesd_simulate(adapt_step(examples::SlidingLeaveCase{}), exact.x0, exact.t_end, o);
    ASSERT_TRUE(r.ok()) << name << ": " << r.message;
    ASSERT_EQ(r.switch_times.size(), exact.switch_times.size()) << name;
    // Measured: 5.6e-17 (Newton).
    EXPECT_NEAR(r.switch_times[0], exact.switch_times[0], kNewtonTol) << name;
    EXPECT_LE((r.x_end - exact.x_end).cwiseAbs().maxCoeff(), kNewtonTol) << name;
  }
}

// Exact Hessians (HessianJet by pieces): IPOPT's own second-order derivative checker (finite
// differences of the exact gradients) finds no error in them, in all three formulations, and
// the homotopy reaches the exact solution with them. Measured on this problem (N_sim 4): 374
// IPOPT iterations against 1389 with the limited-memory Hessian (step), 390 against 672
// (Stewart), 493 against 1802 (lifted, n_d = 2).
TEST(FesdFormulationTest, ExactHessiansPassIpoptsCheckerAndReachTheSolution) {
  Eigen::VectorXd x0(2);
  x0 << -0.6, 0.0;
  // The step formulation on the 3-switch problem; Stewart and the lifted form (theta as
  // unknowns) on the crossing case, where the checker's difference quotients are cheap.
  const auto check = [](const StepModel& model, const Eigen::VectorXd& start,
                        DcsFormulation formulation, int depth, double hessian_scale = 1.0) {
    FesdOptions o;
    o.solver.exact_hessian_scale = hessian_scale;
    o.formulation = formulation;
    o.lifting_depth = depth;
    o.exact_hessian = true;
    o.newton = false;
    o.steps = 1;
    o.sensitivities = false;
    o.homotopy.sigma_initial = o.homotopy.sigma_final =
        0.1;                   // one NLP, checked at its starting point
    o.solver.print_level = 5;  // the checker reports on IPOPT's console output
    o.solver.ipopt_string_options = {{"derivative_test", "second-order"}};
    ::testing::internal::CaptureStdout();
    fesd_simulate(model, start, 0.25, o);
    const std::string text = ::testing::internal::GetCapturedStdout();
    const std::string what = std::string(to_string(formulation)) + " n_d " + std::to_string(depth) +
                             " Hessian x " + std::to_string(hessian_scale);
    // Judged by the checker's stated criterion (support/derivative_checker.h).
    const bflow::testing::CheckerOutput out = bflow::testing::parse_checker_output(text);
    if (hessian_scale == 1.0) {
      bflow::testing::expect_checker_passes(out, what);
    } else {
      EXPECT_TRUE(out.second_order_started) << what;
      EXPECT_TRUE(out.errors) << what;
      EXPECT_GT(out.flagged_objective + out.flagged_constraint, 0) << what;
    }
  };
  check(adapt_step(SlideAndCross{}), x0, DcsFormulation::kStep, 0);
  // Negative controls: the same check on a Hessian scaled by 1.1, and by 1.001 (above the
  // checker's relative tolerance derivative_test_tol = 1e-4), must be reported.
  check(adapt_step(SlideAndCross{}), x0, DcsFormulation::kStep, 0, 1.1);
  check(adapt_step(SlideAndCross{}), x0, DcsFormulation::kStep, 0, 1.001);
  const auto crossing = adapt_step(examples::CrossingCase{});
  check(crossing, Eigen::VectorXd::Constant(1, -0.1), DcsFormulation::kStewart, 0);
  check(crossing, Eigen::VectorXd::Constant(1, -0.1), DcsFormulation::kStep, 2);

  FesdOptions e;
  e.exact_hessian = true;
  e.newton = false;
  e.steps = 4;
  const FesdResult r = fesd_simulate(adapt_step(SlideAndCross{}), x0, 1.0, e);
  expect_exact(r, "exact Hessian, step", kHomotopyTol);
}

TEST(FesdFormulationTest, BadFormulationOptionsNameTheProblem) {
  using bflow::testing::message_of;
  Eigen::VectorXd x0(2);
  x0 << -0.6, 0.0;
  const auto model = adapt_step(SlideAndCross{});
  FesdOptions o;
  o.lifting_depth = 1;
  EXPECT_THAT(message_of([&] { fesd_simulate(model, x0, 1.0, o); }),
              ::testing::HasSubstr("lifting depth n_d must be 0 (none) or >= 2, got 1"));
  o.lifting_depth = 2;
  o.formulation = DcsFormulation::kStewart;
  EXPECT_THAT(message_of([&] { fesd_simulate(model, x0, 1.0, o); }),
              ::testing::HasSubstr("applies to the step formulation only"));
}

}  // namespace
}  // namespace bflow

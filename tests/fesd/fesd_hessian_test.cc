// The exact Hessian of one FESD integration step's NLP (fesd.h, exact_hessian) against IPOPT's
// own second-order derivative checker, in the three DCS formulations with Gauss-Legendre (whose
// extra point at the element's end has its own rows) and Radau IIA, on a general step inclusion
// and on a piecewise-smooth system with its own sign matrix and modes.
//
// One NLP per run: the homotopy starts and ends at sigma = 0.1 and Newton's method is off. The
// checker compares the Hessian of the objective (the step equilibration) and of every
// constraint alone at a random point around the initial guess (tests/support/
// derivative_checker.h), so IPOPT's multipliers play no part. Every positive case must print
// "Starting derivative checker for second derivatives" and "No errors detected"; the negative
// controls (the Hessian times exact_hessian_scale = 1.001) must be reported, with flagged
// entries in the objective and in the constraints. The checker's cost grows as m n^2 nnz(H),
// so the NLPs are small (25 to 74 unknowns); the worst relative errors quoted per test were read
// with derivative_test_print_all = yes (tolerance 1e-4).
#include <cmath>
#include <string>
#include <utility>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/core/filippov.h"
#include "bflow/fesd/fesd.h"
#include "support/derivative_checker.h"

namespace bflow {
namespace {

using bflow::testing::CheckerOutput;
using bflow::testing::parse_checker_output;

// Three states, three switching functions, nonlinear in x and multi-affine in a with a product
// of all three selections, so that the lifting with n_d = 2 keeps theta and beta.
struct CurvedFlow {
  static constexpr int kStates = 3, kSwitches = 3;
  template <typename T>
  void switching(const T* x, T* c) const {
    using std::sin;
    c[0] = x[1] - T(0.2) * x[0] * x[0];
    c[1] = x[0] * x[2] + T(0.3);
    c[2] = sin(x[2]) + T(0.5) * x[1];
  }
  template <typename T>
  void field(const T* x, const T* a, T* xdot) const {
    using std::cos;
    using std::exp;
    xdot[0] = x[1] * (T(1.0) + a[0] * a[1]) + T(0.5);
    xdot[1] = T(1.0) + T(2.0) * a[0] - a[1] * a[2] * x[1] * x[1] + cos(x[2]);
    xdot[2] = (T(1.0) - a[0]) * x[2] * x[0] + a[0] * a[1] * a[2] * exp(T(0.1) * x[0]);
  }
};

// A piecewise-smooth system with two switching functions and four modes f_i(x), given by its
// own sign matrix (the dense one of two switching functions) and mode fields.
struct FourModes {
  static constexpr int kStates = 2, kSwitches = 2, kModes = 4;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0] * x[1] - T(0.1);
    c[1] = x[1] + T(0.3) * x[0] * x[0];
  }
  template <typename T>
  void modes(const T* x, T* f) const {
    using std::sin;
    f[0] = x[1] * x[1];
    f[1] = sin(x[0]);
    f[2] = -x[0] * x[1];
    f[3] = T(1.0) + x[0] * x[0];
    f[4] = T(0.5) * x[1] * x[0];
    f[5] = -T(1.0) - x[1] * x[1];
    f[6] = x[0] - x[1] * x[1] * x[1];
    f[7] = T(0.3) * x[0];
  }
};

struct Checked {
  CheckerOutput out;
  FesdResult result;
};

// One integration step of [0, t_end] in `elements` elements, one NLP at sigma = 0.1, checked at
// its starting point with the Hessian times `scale`.
Checked check(const StepModel& model, const Eigen::VectorXd& x0, double t_end, int elements,
              CollocationScheme scheme, int n_s, DcsFormulation formulation, int depth,
              double scale = 1.0) {
  FesdOptions o;
  o.scheme = scheme;
  o.stages = n_s;
  o.elements = elements;
  o.formulation = formulation;
  o.lifting_depth = depth;
  o.exact_hessian = true;
  o.solver.exact_hessian_scale = scale;
  o.newton = false;
  o.steps = 1;
  o.sensitivities = false;
  o.homotopy.sigma_initial = o.homotopy.sigma_final =
      0.1;                   // one NLP, checked at its starting point
  o.solver.print_level = 5;  // the checker reports on IPOPT's console output
  o.solver.ipopt_string_options = {{"derivative_test", "second-order"}};
  ::testing::internal::CaptureStdout();
  Checked c;
  c.result = fesd_simulate(model, x0, t_end, o);
  c.out = parse_checker_output(::testing::internal::GetCapturedStdout());
  return c;
}

void expect_passes(const Checked& c, const std::string& what) {
  bflow::testing::expect_checker_passes(c.out, what);
  // One NLP: a step that failed would be halved and checked again on each half.
  EXPECT_EQ(c.result.halved_steps, 0) << what;
}

// The negative control: reported, with flagged second derivatives of the objective (the step
// equilibration between the two elements) and of the constraints, and none of first ones.
void expect_reported(const Checked& c, const std::string& what) {
  bflow::testing::expect_checker_reports(c.out, what);
  EXPECT_GT(c.out.flagged_objective, 0) << what;
  EXPECT_GT(c.out.flagged_constraint, 0) << what;
}

std::string name(DcsFormulation formulation, int depth, CollocationScheme scheme, int n_s) {
  return std::string(to_string(formulation)) + (depth > 0 ? " lifted" : "") +
         (scheme == CollocationScheme::kRadauIIA ? ", Radau IIA " : ", Gauss-Legendre ") +
         std::to_string(n_s);
}

constexpr struct {
  DcsFormulation formulation;
  int depth;
} kFormulations[] = {
    {DcsFormulation::kStep, 0}, {DcsFormulation::kStep, 2}, {DcsFormulation::kStewart, 0}};

// The general step inclusion with three switching functions, one element over a short step (no
// switch, so the NLP is solved without halving): Gauss-Legendre 2 in the step formulation, the
// lifted one (theta and beta) and Stewart's (eight base regions); the step formulation also with
// Gauss-Legendre 1 and Radau IIA 3.
// Measured worst relative error of a second derivative: 6.6e-6 (Stewart).
TEST(FesdHessian, ThreeSwitchingFunctionsOnGaussLegendre) {
  const auto model = adapt_step(CurvedFlow{});
  const Eigen::VectorXd x0 = Eigen::Vector3d(0.4, -0.3, 0.5);
  for (const auto& f : kFormulations) {
    const auto scheme = CollocationScheme::kGaussLegendre;
    expect_passes(check(model, x0, 0.05, 1, scheme, 2, f.formulation, f.depth),
                  name(f.formulation, f.depth, scheme, 2));
  }
  for (const auto& [scheme, n_s] : {std::pair{CollocationScheme::kGaussLegendre, 1},
                                    std::pair{CollocationScheme::kRadauIIA, 3}}) {
    expect_passes(check(model, x0, 0.05, 1, scheme, n_s, DcsFormulation::kStep, 0),
                  name(DcsFormulation::kStep, 0, scheme, n_s));
  }
}

// The piecewise-smooth system with its own sign matrix and mode fields (Stewart's formulation
// evaluates the modes in one call), two elements (the second reads the first's end; the step
// equilibration between them is the objective), Gauss-Legendre 2 in the three formulations
// (lifted: n_d = 2 = n_c, theta without beta). Negative controls with Radau IIA 2, one per
// formulation.
// Measured worst relative error: 5.3e-6.
TEST(FesdHessian, PiecewiseSmoothSystemOnGaussLegendreWithNegativeControls) {
  const auto model =
      adapt_step(PiecewiseSmoothAsStep<FourModes>(FourModes{}, SignMatrix::dense(2)));
  const Eigen::VectorXd x0 = Eigen::Vector2d(0.5, 0.1);
  for (const auto& f : kFormulations) {
    const auto gauss = CollocationScheme::kGaussLegendre;
    const auto radau = CollocationScheme::kRadauIIA;
    expect_passes(check(model, x0, 0.25, 2, gauss, 2, f.formulation, f.depth),
                  name(f.formulation, f.depth, gauss, 2));
    expect_reported(check(model, x0, 0.25, 2, radau, 2, f.formulation, f.depth, 1.001),
                    name(f.formulation, f.depth, radau, 2) + ", Hessian x 1.001");
  }
}

}  // namespace
}  // namespace bflow

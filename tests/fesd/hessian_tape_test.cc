#include "bflow/fesd/hessian_tape.h"

#include <cmath>
#include <functional>
#include <limits>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "bflow/fesd/hessian_blocks.h"

namespace bflow {
namespace {

using fesd::HessianBlocks;
using fesd::HessianProgram;

using Function = std::function<HessianJet(const HessianJet*)>;

// A program for sum_r w_r f_r with lanes on every input, traced at `at`.
std::unique_ptr<HessianProgram> program_of(const std::vector<Function>& f, int inputs,
                                           const std::vector<double>& at, int scaled = -1,
                                           bool gradient = true) {
  HessianProgram::Shape shape;
  shape.inputs = inputs;
  for (int k = 0; k < inputs; ++k) shape.lanes.push_back(k);
  shape.outputs = static_cast<int>(f.size());
  shape.scaled = scaled < 0 ? shape.outputs : scaled;
  shape.gradient = gradient;
  auto eval = [&](const HessianJet* in, HessianJet* out) {
    for (std::size_t r = 0; r < f.size(); ++r) out[r] = f[r](in);
  };
  return HessianProgram::trace(shape, at.data(), eval);
}

struct Result {
  HessianProgram::Outcome outcome;
  std::vector<double> hessian, gradient;
  double value = 0.0;
};
Result run(HessianProgram& p, const std::vector<double>& in, const std::vector<double>& w,
           double product = 1.0) {
  const int lanes = static_cast<int>(p.shape().lanes.size());
  Result r;
  r.hessian.assign(static_cast<std::size_t>(HessianJet::at(lanes, 0)), 0.0);
  r.gradient.assign(static_cast<std::size_t>(lanes), 0.0);
  r.outcome = p.run(in.data(), w.data(), product, r.hessian.data(), r.gradient.data(), &r.value);
  return r;
}

// Every elementary function on u = x + 2 y, traced at one point and run at another: the
// program's value, gradient phi'(u) (1, 2) and Hessian phi''(u) [1 2; 2 4] at the second point
// against closed forms written here by hand (so a number of the traced point kept as a
// constant fails).
TEST(HessianProgram, ElementaryFunctionsAtAnotherPointMatchTheirClosedForms) {
  struct Case {
    const char* name;
    std::function<HessianJet(const HessianJet&)> f;
    std::function<double(double)> value, d1, d2;
  };
  const auto c = [](double k) { return [k](double) { return k; }; };
  const std::vector<Case> cases = {
      {"sqrt", [](const HessianJet& x) { return sqrt(x); }, [](double u) { return std::sqrt(u); },
       [](double u) { return 0.5 / std::sqrt(u); },
       [](double u) { return -0.25 / std::pow(u, 1.5); }},
      {"sin", [](const HessianJet& x) { return sin(x); }, [](double u) { return std::sin(u); },
       [](double u) { return std::cos(u); }, [](double u) { return -std::sin(u); }},
      {"cos", [](const HessianJet& x) { return cos(x); }, [](double u) { return std::cos(u); },
       [](double u) { return -std::sin(u); }, [](double u) { return -std::cos(u); }},
      {"tan", [](const HessianJet& x) { return tan(x); }, [](double u) { return std::tan(u); },
       [](double u) { return 1.0 / std::pow(std::cos(u), 2); },
       [](double u) { return 2.0 * std::sin(u) / std::pow(std::cos(u), 3); }},
      {"exp", [](const HessianJet& x) { return exp(x); }, [](double u) { return std::exp(u); },
       [](double u) { return std::exp(u); }, [](double u) { return std::exp(u); }},
      {"log", [](const HessianJet& x) { return log(x); }, [](double u) { return std::log(u); },
       [](double u) { return 1.0 / u; }, [](double u) { return -1.0 / (u * u); }},
      {"log1p", [](const HessianJet& x) { return log1p(x); },
       [](double u) { return std::log1p(u); }, [](double u) { return 1.0 / (1.0 + u); },
       [](double u) { return -1.0 / ((1.0 + u) * (1.0 + u)); }},
      {"sinh", [](const HessianJet& x) { return sinh(x); }, [](double u) { return std::sinh(u); },
       [](double u) { return std::cosh(u); }, [](double u) { return std::sinh(u); }},
      {"cosh", [](const HessianJet& x) { return cosh(x); }, [](double u) { return std::cosh(u); },
       [](double u) { return std::sinh(u); }, [](double u) { return std::cosh(u); }},
      {"tanh", [](const HessianJet& x) { return tanh(x); }, [](double u) { return std::tanh(u); },
       [](double u) { return 1.0 / std::pow(std::cosh(u), 2); },
       [](double u) { return -2.0 * std::tanh(u) / std::pow(std::cosh(u), 2); }},
      {"atan", [](const HessianJet& x) { return atan(x); }, [](double u) { return std::atan(u); },
       [](double u) { return 1.0 / (1.0 + u * u); },
       [](double u) { return -2.0 * u / ((1.0 + u * u) * (1.0 + u * u)); }},
      {"cbrt", [](const HessianJet& x) { return cbrt(x); }, [](double u) { return std::cbrt(u); },
       [](double u) { return std::pow(u, -2.0 / 3.0) / 3.0; },
       [](double u) { return -2.0 / 9.0 * std::pow(u, -5.0 / 3.0); }},
      {"pow 2.5", [](const HessianJet& x) { return pow(x, 2.5); },
       [](double u) { return std::pow(u, 2.5); }, [](double u) { return 2.5 * std::pow(u, 1.5); },
       [](double u) { return 3.75 * std::sqrt(u); }},
      {"x^2", [](const HessianJet& x) { return pow(x, 2.0); }, [](double u) { return u * u; },
       [](double u) { return 2.0 * u; }, c(2.0)},
      {"3^x", [](const HessianJet& x) { return pow(3.0, x); },
       [](double u) { return std::pow(3.0, u); },
       [](double u) { return std::pow(3.0, u) * std::log(3.0); },
       [](double u) { return std::pow(3.0, u) * std::log(3.0) * std::log(3.0); }},
      {"x^x", [](const HessianJet& x) { return pow(x, x); },
       [](double u) { return std::pow(u, u); },
       [](double u) { return std::pow(u, u) * (std::log(u) + 1.0); },
       [](double u) {
         return std::pow(u, u) * ((std::log(u) + 1.0) * (std::log(u) + 1.0) + 1.0 / u);
       }},
      {"1/x", [](const HessianJet& x) { return 1.0 / x; }, [](double u) { return 1.0 / u; },
       [](double u) { return -1.0 / (u * u); }, [](double u) { return 2.0 / (u * u * u); }},
      {"x/3 - 2 + x*x", [](const HessianJet& x) { return x / 3.0 - 2.0 + x * x; },
       [](double u) { return u / 3.0 - 2.0 + u * u; }, [](double u) { return 1.0 / 3.0 + 2.0 * u; },
       c(2.0)},
      {"-(2 - x) * x", [](const HessianJet& x) { return -(2.0 - x) * x; },
       [](double u) { return -(2.0 - u) * u; }, [](double u) { return 2.0 * u - 2.0; }, c(2.0)},
      {"asin", [](const HessianJet& x) { return asin(x); }, [](double u) { return std::asin(u); },
       [](double u) { return 1.0 / std::sqrt(1.0 - u * u); },
       [](double u) { return u / std::pow(1.0 - u * u, 1.5); }},
      {"acos", [](const HessianJet& x) { return acos(x); }, [](double u) { return std::acos(u); },
       [](double u) { return -1.0 / std::sqrt(1.0 - u * u); },
       [](double u) { return -u / std::pow(1.0 - u * u, 1.5); }},
      {"expm1", [](const HessianJet& x) { return expm1(x); },
       [](double u) { return std::expm1(u); }, [](double u) { return std::exp(u); },
       [](double u) { return std::exp(u); }},
      {"log10", [](const HessianJet& x) { return log10(x); },
       [](double u) { return std::log10(u); }, [](double u) { return 1.0 / (u * std::log(10.0)); },
       [](double u) { return -1.0 / (u * u * std::log(10.0)); }},
      {"log2", [](const HessianJet& x) { return log2(x); }, [](double u) { return std::log2(u); },
       [](double u) { return 1.0 / (u * std::log(2.0)); },
       [](double u) { return -1.0 / (u * u * std::log(2.0)); }},
      {"x += x; x *= x; x -= 1; x /= 2",
       [](const HessianJet& x) {
         HessianJet y = x;
         y += x;
         y *= y;
         y -= 1.0;
         y /= 2.0;
         return y;
       },
       [](double u) { return (4.0 * u * u - 1.0) / 2.0; }, [](double u) { return 4.0 * u; },
       c(4.0)},
  };
  const double traced_u = 0.7, u = 0.55;  // the trace's point and the run's
  const double w = 1.5;
  for (const Case& k : cases) {
    auto p = program_of({[&](const HessianJet* in) { return k.f(in[0] + 2.0 * in[1]); }}, 2,
                        {traced_u / 3.0, traced_u / 3.0});
    const Result r = run(*p, {u / 3.0, u / 3.0}, {w});
    ASSERT_EQ(r.outcome, HessianProgram::Outcome::kDone) << k.name;
    const double d1 = k.d1(u), d2 = k.d2(u);
    const double tol = 1e-14 * (1.0 + std::abs(d2) * 4.0 + std::abs(d1) * 2.0);
    EXPECT_NEAR(r.value, w * k.value(u), 1e-15 * (1.0 + std::abs(w * k.value(u)))) << k.name;
    EXPECT_NEAR(r.gradient[0], w * d1, w * tol) << k.name;
    EXPECT_NEAR(r.gradient[1], w * 2.0 * d1, w * tol) << k.name;
    EXPECT_NEAR(r.hessian[0], w * d2, w * tol) << k.name;
    EXPECT_NEAR(r.hessian[1], w * 2.0 * d2, w * tol) << k.name;
    EXPECT_NEAR(r.hessian[2], w * 4.0 * d2, w * tol) << k.name;
  }
}

// atan2 in both arguments: d theta = (x dy - y dx) / r^2 and its second derivatives, by hand.
TEST(HessianProgram, Atan2MatchesItsClosedForm) {
  auto p = program_of({[](const HessianJet* in) { return atan2(in[0], in[1]); }}, 2, {0.3, 0.8});
  const double y = -0.4, x = 0.9, r2 = x * x + y * y;
  const Result r = run(*p, {y, x}, {1.0});
  ASSERT_EQ(r.outcome, HessianProgram::Outcome::kDone);
  EXPECT_NEAR(r.value, std::atan2(y, x), 1e-16);
  EXPECT_NEAR(r.gradient[0], x / r2, 1e-15);
  EXPECT_NEAR(r.gradient[1], -y / r2, 1e-15);
  EXPECT_NEAR(r.hessian[0], -2.0 * x * y / (r2 * r2), 1e-14);     // d2 / dy2
  EXPECT_NEAR(r.hessian[1], (y * y - x * x) / (r2 * r2), 1e-14);  // d2 / dx dy
  EXPECT_NEAR(r.hessian[2], 2.0 * x * y / (r2 * r2), 1e-14);      // d2 / dx2
}

// L = P S + Q, S = w0 x y, Q = w1 x^2 y: the Hessian P w0 [0 1; 1 0] + w1 [2y 2x; 2x 0], the
// gradient of S alone (w0 y, w0 x) and its value w0 x y.
TEST(HessianProgram, ScaledAndPlainOutputsAsAddScaledAsksThem) {
  auto p = program_of({[](const HessianJet* in) { return in[0] * in[1]; },
                       [](const HessianJet* in) { return in[0] * in[0] * in[1]; }},
                      2, {0.5, 0.25}, 1);
  const double x = 1.3, y = -0.7, w0 = 2.0, w1 = 3.0, product = 0.25;
  const Result r = run(*p, {x, y}, {w0, w1}, product);
  ASSERT_EQ(r.outcome, HessianProgram::Outcome::kDone);
  EXPECT_DOUBLE_EQ(r.hessian[0], w1 * 2.0 * y);
  EXPECT_DOUBLE_EQ(r.hessian[1], product * w0 + w1 * 2.0 * x);
  EXPECT_DOUBLE_EQ(r.hessian[2], 0.0);
  EXPECT_DOUBLE_EQ(r.gradient[0], w0 * y);
  EXPECT_DOUBLE_EQ(r.gradient[1], w0 * x);
  EXPECT_DOUBLE_EQ(r.value, w0 * x * y);
}

// The second derivatives of a function linear in two of its three inputs: the entries that are
// identically zero are exact zeros and cost nothing, the others are constants or one product.
TEST(HessianProgram, IdenticallyZeroEntriesAreLeftOutOfTheProgram) {
  // theta (a x + b) + 3 x: d2 / dtheta dx = a, the rest 0 (inputs: x, theta, a; lanes on all
  // three, a's entries too).
  auto p =
      program_of({[](const HessianJet* in) { return in[1] * (in[2] * in[0] + 2.0) + 3.0 * in[0]; }},
                 3, {0.1, 0.2, 0.3}, -1, false);
  const Result r = run(*p, {1.7, -0.4, 0.9}, {1.0});
  ASSERT_EQ(r.outcome, HessianProgram::Outcome::kDone);
  // Lower triangle by rows: (x,x) (th,x) (th,th) (a,x) (a,th) (a,a).
  const std::vector<double> expected = {0.0, 0.9, 0.0, -0.4, 1.7, 0.0};
  for (std::size_t k = 0; k < expected.size(); ++k) EXPECT_EQ(r.hessian[k], expected[k]) << k;
  // The function's 5 operations, its weight w, the weight P w of its second derivatives and
  // one product by it per nonzero entry (3): none for the zero entries.
  EXPECT_LE(p->operations(), 10u);
}

// A branch the trace took is a guard: the program refuses to run where the evaluation would
// take the other one, and runs anywhere on the same side.
TEST(HessianProgram, BranchesAreGuards) {
  struct Case {
    const char* name;
    Function f;
    std::vector<double> traced, same_side, other_side;
  };
  const std::vector<Case> cases = {
      {"abs",
       [](const HessianJet* in) { return abs(in[0]) * in[1]; },
       {0.5, 1.0},
       {0.2, 3.0},
       {-0.2, 3.0}},
      {"fmax",
       [](const HessianJet* in) { return fmax(in[0], in[1]) * in[0]; },
       {0.5, 1.0},
       {0.1, 2.0},
       {3.0, 2.0}},
      {"fmin",
       [](const HessianJet* in) { return fmin(in[0], in[1]) * in[1]; },
       {0.5, 1.0},
       {0.1, 2.0},
       {3.0, 2.0}},
      {"x < y ?",
       [](const HessianJet* in) { return in[0] < in[1] ? in[0] * in[0] : in[1] * in[1]; },
       {0.5, 1.0},
       {0.1, 2.0},
       {3.0, 2.0}},
      {"x > 1 ?",
       [](const HessianJet* in) { return in[0] > 1.0 ? in[0] * in[1] : in[1]; },
       {1.5, 1.0},
       {1.1, 2.0},
       {0.9, 2.0}},
      {"floor",
       [](const HessianJet* in) { return floor(in[0]) * in[1] * in[1]; },
       {1.5, 1.0},
       {1.9, 2.0},
       {2.1, 2.0}},
      {"ceil",
       [](const HessianJet* in) { return ceil(in[0]) * in[1] * in[1]; },
       {1.5, 1.0},
       {1.9, 2.0},
       {2.1, 2.0}},
      {"isfinite",
       [](const HessianJet* in) { return isfinite(in[0]) ? in[1] * in[1] : in[1]; },
       {1.5, 1.0},
       {-4.0, 2.0},
       {std::numeric_limits<double>::infinity(), 2.0}},
  };
  for (const Case& c : cases) {
    auto p = program_of({c.f}, 2, c.traced);
    EXPECT_GE(p->guards(), 1u) << c.name;
    EXPECT_EQ(run(*p, c.same_side, {1.0}).outcome, HessianProgram::Outcome::kDone) << c.name;
    EXPECT_EQ(run(*p, c.other_side, {1.0}).outcome, HessianProgram::Outcome::kGuardFailed)
        << c.name;
  }
  // On the traced side, the branch's derivatives: |x| y at x < 0 is -x y.
  auto p = program_of({cases[0].f}, 2, {-0.5, 1.0});
  const Result r = run(*p, {-0.25, 3.0}, {1.0});
  ASSERT_EQ(r.outcome, HessianProgram::Outcome::kDone);
  EXPECT_EQ(r.gradient[0], -3.0);
  EXPECT_EQ(r.gradient[1], 0.25);
  EXPECT_EQ(r.hessian[1], -1.0);
}

TEST(HessianProgram, NumbersThatAreNotFiniteAreReported) {
  auto p = program_of({[](const HessianJet* in) { return sqrt(in[0]) * in[1]; }}, 2, {0.5, 1.0});
  EXPECT_EQ(run(*p, {0.0, 1.0}, {1.0}).outcome, HessianProgram::Outcome::kNotFinite);
  EXPECT_EQ(run(*p, {0.25, 1.0}, {1.0}).outcome, HessianProgram::Outcome::kDone);
}

// A block through HessianBlocks: the kept plan's program gives HessianJet's numbers (the same
// block added outside an evaluation, which has no plan) at every point; it is traced once for a
// smooth block and again where a branch flips; an eval that reads a number other than its
// inputs is caught at the program's 2nd run and the block stays on HessianJet.
TEST(HessianProgram, HessianBlocksRunProgramsWithHessianJetsNumbers) {
  const std::vector<int> globals = {0, 1, 2, -1};  // the last input a constant
  HessianBlocks blocks;
  blocks.add_block(globals);
  std::vector<double> with_plan(blocks.size()), without(blocks.size());
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> draw(-1.0, 1.0);
  auto smooth = [](const auto* in, auto* out) {
    out[0] = sin(in[0] * in[1]) + in[2] * in[2] * in[3];
    out[1] = exp(in[0]) * in[2];
  };
  for (int k = 0; k < 20; ++k) {
    const std::vector<double> base = {draw(rng), draw(rng), draw(rng), draw(rng)};
    const double weights[2] = {draw(rng), draw(rng)};
    std::fill(with_plan.begin(), with_plan.end(), 0.0);
    std::fill(without.begin(), without.end(), 0.0);
    blocks.begin_evaluation();
    blocks.add(globals, base, 2, weights, smooth, with_plan.data());
    blocks.end_evaluation();
    blocks.add(globals, base, 2, weights, smooth, without.data());
    for (std::size_t e = 0; e < with_plan.size(); ++e)
      EXPECT_NEAR(with_plan[e], without[e], 1e-14 * (1.0 + std::abs(without[e]))) << k << " " << e;
  }
  EXPECT_EQ(blocks.traces(), 1);
  EXPECT_EQ(blocks.jet_only_blocks(), 0);

  HessianBlocks branchy;
  branchy.add_block(globals);
  auto kinked = [](const auto* in, auto* out) { out[0] = abs(in[0]) * in[1] * in[2]; };
  const double one = 1.0;
  for (int k = 0; k < 6; ++k) {
    const std::vector<double> base = {k % 2 == 0 ? 0.5 : -0.5, 0.3 + k, 0.7, 0.0};
    std::fill(with_plan.begin(), with_plan.end(), 0.0);
    std::fill(without.begin(), without.end(), 0.0);
    branchy.begin_evaluation();
    branchy.add(globals, base, 1, &one, kinked, with_plan.data());
    branchy.end_evaluation();
    branchy.add(globals, base, 1, &one, kinked, without.data());
    for (std::size_t e = 0; e < with_plan.size(); ++e) EXPECT_EQ(with_plan[e], without[e]) << k;
  }
  EXPECT_EQ(branchy.traces(), 6);  // the sign of x flips at every call

  HessianBlocks impure;
  impure.add_block(globals);
  double captured = 2.0;
  auto reads_captured = [&](const auto* in, auto* out) { out[0] = captured * in[0] * in[1]; };
  for (int k = 0; k < 4; ++k) {
    captured = 2.0 + k;
    const std::vector<double> base = {0.5, 0.25, 0.125, 0.0};
    std::fill(with_plan.begin(), with_plan.end(), 0.0);
    impure.begin_evaluation();
    impure.add(globals, base, 1, &one, reads_captured, with_plan.data());
    impure.end_evaluation();
    // The (1, 0) entry: d2 / dx0 dx1 = captured.
    double mixed = 0.0;
    for (std::size_t e = 0; e < impure.size(); ++e) {
      if (impure.rows()[e] == 1 && impure.cols()[e] == 0) mixed = with_plan[e];
    }
    EXPECT_EQ(mixed, captured) << k;
  }
  EXPECT_EQ(impure.jet_only_blocks(), 1);
}

// A Jacobian program: the entries asked for, in their order, at a point other than the trace's,
// against closed forms; a branch is a guard there too.
TEST(JacobianProgram, EntriesAtAnotherPointMatchTheirClosedForms) {
  // f0 = x y + sin(z), f1 = exp(x) / y, f2 = |z| x
  auto eval = [](const HessianJet* in, HessianJet* out) {
    out[0] = in[0] * in[1] + sin(in[2]);
    out[1] = exp(in[0]) / in[1];
    out[2] = abs(in[2]) * in[0];
  };
  const std::vector<std::pair<int, int>> entries = {{0, 0}, {0, 1}, {0, 2}, {1, 0},
                                                    {1, 1}, {2, 2}, {2, 0}, {1, 2}};
  const std::vector<double> traced = {0.3, 0.8, 0.5};
  const auto p = fesd::JacobianProgram::trace(3, 3, entries, traced.data(), eval);
  const double x = -0.6, y = 1.7, z = 0.25;
  const std::vector<double> in = {x, y, z};
  std::vector<double> v(entries.size());
  ASSERT_EQ(p->run(in.data(), v.data()), HessianProgram::Outcome::kDone);
  const std::vector<double> expected = {y, x, std::cos(z), std::exp(x) / y, -std::exp(x) / (y * y),
                                        x, z, 0.0};
  for (std::size_t k = 0; k < expected.size(); ++k) EXPECT_NEAR(v[k], expected[k], 1e-15) << k;
  const std::vector<double> other_side = {x, y, -z};
  EXPECT_EQ(p->run(other_side.data(), v.data()), HessianProgram::Outcome::kGuardFailed);
}

}  // namespace
}  // namespace bflow

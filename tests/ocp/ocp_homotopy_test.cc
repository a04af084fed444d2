// The homotopy's stopping rule of ocp_solve (OcpHomotopyOptions::stop_at_complementarity): the
// homotopy ends at the first NLP whose complementarity residual is within
// complementarity_tolerance, solved at nlp_tolerance, and the polish then reaches the turbo car's
// exact optimal time T* = 40/3 (ocp_examples.h).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/core/errors.h"
#include "bflow/examples/ocp_examples.h"
#include "bflow/integrators/model_adapter.h"
#include "bflow/ocp/ocp.h"

namespace bflow {
namespace {

using examples::TurboCar;

OcpResult solve_car(const OcpOptions& options) {
  return ocp_solve(adapt_ocp(TurboCar{}), TurboCar::problem(), options);
}

// The steps of the homotopy without the polish.
std::vector<OcpHomotopyStep> relaxed_steps(const OcpResult& r) {
  std::vector<OcpHomotopyStep> steps;
  for (const OcpHomotopyStep& s : r.homotopy) {
    if (!s.polish) steps.push_back(s);
  }
  return steps;
}

// N = 5 (the switches fit the stages), sigma from 100 by factors of 10, complementarity
// tolerance 1e-6. Every NLP before the stop has a residual above 1e-6, the last one (at the
// sigma where the residual first fell within it, solved again at nlp_tolerance 1e-10 when it
// was solved more loosely) within it, and sigma_final 1e-10 is not reached. The NLPs up to the
// stop are those of the run down to 1e-10 (the rule changes only where the homotopy ends), which
// goes on below: every relaxed product is at most sigma (plus IPOPT's constraint violation,
// within its tol 1e-2 sigma), so the residual is within 1e-6 by sigma = 1e-7 at the latest, three
// NLPs above sigma_final, and the stop leaves at most one more NLP (the solve again). Measured: 10
// NLPs (sigma = 100 ... 1e-6, then 1e-6 again at nlp_tolerance) against 13 down to 1e-10; after the
// polish |T - 40/3| = 1.2e-10 in both.
TEST(OcpHomotopy, StopsAtTheFirstNlpWithinTheComplementarityTolerance) {
  OcpOptions options;
  options.stages = 5;
  options.homotopy.complementarity_tolerance = 1e-6;
  // This rule alone: the early polish would end both homotopies first.
  options.homotopy.early_polish_sigma = 0.0;
  const OcpResult full = solve_car(options);
  options.homotopy.stop_at_complementarity = true;
  const OcpResult r = solve_car(options);
  ASSERT_EQ(full.status, OcpStatus::kSolved) << full.message;
  ASSERT_EQ(r.status, OcpStatus::kSolved) << r.message;

  const std::vector<OcpHomotopyStep> steps = relaxed_steps(r);
  ASSERT_GE(steps.size(), 2u);
  const OcpHomotopyStep& last = steps.back();
  EXPECT_LE(last.complementarity, 1e-6);
  EXPECT_GT(last.sigma, options.homotopy.sigma_final);
  std::size_t first_within = steps.size() - 1;
  while (first_within > 0 && steps[first_within - 1].complementarity <= 1e-6) --first_within;
  for (std::size_t k = 0; k < first_within; ++k) EXPECT_GT(steps[k].complementarity, 1e-6) << k;
  // At most a second solve of the same NLP after the first one within the tolerance.
  EXPECT_LE(steps.size() - first_within, 2u);
  EXPECT_EQ(steps[first_within].sigma, last.sigma);
  const std::vector<OcpHomotopyStep> full_steps = relaxed_steps(full);
  ASSERT_GT(full_steps.size(), first_within);
  for (std::size_t k = 0; k <= first_within; ++k) {
    EXPECT_EQ(steps[k].sigma, full_steps[k].sigma) << k;
    EXPECT_EQ(steps[k].iterations, full_steps[k].iterations) << k;
  }
  EXPECT_LT(steps.size(), full_steps.size());
  EXPECT_THAT(r.notes, testing::Contains(testing::HasSubstr("the homotopy stopped at sigma")));
  EXPECT_THAT(full.notes, testing::Not(testing::Contains(testing::HasSubstr("stopped at"))));

  EXPECT_TRUE(r.polished);
  EXPECT_LE(r.max_complementarity, 1e-6);
  EXPECT_NEAR(r.T, 40.0 / 3.0, 1e-8);
  std::printf(
      "NLPs %zu (full %zu), iterations %d (full %d), last sigma %.1e, |T - 40/3| %.1e "
      "(full %.1e)\n",
      steps.size(), relaxed_steps(full).size(), r.ipopt_iterations, full.ipopt_iterations,
      last.sigma, std::abs(r.T - 40.0 / 3.0), std::abs(full.T - 40.0 / 3.0));
}

// OcpHomotopyOptions::max_total_iterations. A budget below what the homotopy needs ends it with
// kBudgetExhausted: the iterations spent never exceed the budget, the message names it, and the
// result is the last solved NLP's (its sigma in the message). A budget of exactly what it needs
// (its NLPs and the early polishes that end it) changes nothing: the same NLPs, iterations and
// T* = 40/3.
TEST(OcpHomotopy, TotalIterationBudget) {
  OcpOptions options;
  options.stages = 5;
  const OcpResult free = solve_car(options);
  ASSERT_EQ(free.status, OcpStatus::kSolved) << free.message;
  int relaxed_iterations = 0;
  for (const OcpHomotopyStep& s : relaxed_steps(free)) relaxed_iterations += s.iterations;

  ASSERT_TRUE(free.polished);
  options.homotopy.max_total_iterations =
      free.ipopt_iterations;  // exactly enough, the polishes included
  const OcpResult enough = solve_car(options);
  ASSERT_EQ(enough.status, OcpStatus::kSolved) << enough.message;
  EXPECT_EQ(enough.ipopt_iterations, free.ipopt_iterations);
  EXPECT_EQ(relaxed_steps(enough).size(), relaxed_steps(free).size());
  EXPECT_NEAR(enough.T, 40.0 / 3.0, 1e-8);

  const int budget = relaxed_iterations / 2;
  options.homotopy.max_total_iterations = budget;
  const OcpResult cut = solve_car(options);
  EXPECT_EQ(cut.status, OcpStatus::kBudgetExhausted) << cut.message;
  EXPECT_STREQ(to_string(cut.status), "budget_exhausted");
  EXPECT_EQ(cut.ipopt_iterations, budget);
  EXPECT_THAT(cut.message, testing::HasSubstr("budget of " + std::to_string(budget)));
  EXPECT_FALSE(cut.polished);
  // The NLPs before the cut are those of the free run, with the same iterations.
  const std::vector<OcpHomotopyStep> a = relaxed_steps(cut), b = relaxed_steps(free);
  ASSERT_GE(a.size(), 2u);
  for (std::size_t k = 0; k + 1 < a.size(); ++k) {
    EXPECT_EQ(a[k].iterations, b[k].iterations) << k;
    EXPECT_EQ(a[k].sigma, b[k].sigma) << k;
  }
  EXPECT_LT(a.back().iterations, b[a.size() - 1].iterations);
  std::printf("free: %d iterations in %zu NLPs; budget %d: %zu NLPs, %s\n", free.ipopt_iterations,
              b.size(), budget, a.size(), cut.message.c_str());

  options.homotopy.max_total_iterations = -1;
  EXPECT_THROW(solve_car(options), InvalidArgument);
}

// OcpHomotopyOptions::intermediate_tolerance_factor = 0 gives every NLP of the homotopy IPOPT's tol
// nlp_tolerance (nosnoc's rule), the default 1e-2 the NLPs before the last only
// max(nlp_tolerance, 1e-2 sigma): the first NLP (sigma = 100, tol 1) then ends "optimal" at a
// KKT error within 1 and above nlp_tolerance (measured 1.5e-4: IPOPT stops at the first iterate
// within its tol), with factor 0 every "optimal" NLP within 1e-8 (the first at 1.1e-9), among
// them NLPs at sigma >= 1e-6, where factor 1e-2 would have allowed more than 1e-8. Both reach
// T* = 40/3 (|T - 40/3| 1.4e-10 and 6.0e-11).
TEST(OcpHomotopy, IntermediateToleranceFactor) {
  OcpOptions options;
  options.stages = 5;
  options.homotopy.polish = false;
  options.homotopy.nlp_tolerance = 1e-8;
  const OcpResult loose = solve_car(options);
  options.homotopy.intermediate_tolerance_factor = 0.0;
  const OcpResult tight = solve_car(options);
  ASSERT_EQ(loose.status, OcpStatus::kSolved) << loose.message;
  // The last NLP may end at IPOPT's acceptable level (IPOPT 3.14.19 here: KKT error 2.6e-6);
  // what the factor sets is each NLP's tol, checked below.
  ASSERT_TRUE(tight.status == OcpStatus::kSolved || tight.status == OcpStatus::kAcceptableOnly)
      << tight.message;
  // IPOPT's "optimal" means a KKT error within the tol it was given; an NLP may still end at its
  // acceptable level instead (measured: sigma = 1e-6 at 2.1e-7).
  int optimal_above = 0;  // where the factor 1e-2 would have given a tol above 1e-8
  for (const OcpHomotopyStep& s : relaxed_steps(tight)) {
    if (s.ipopt_status != "Solve_Succeeded") continue;
    if (1e-2 * s.sigma > options.homotopy.nlp_tolerance) ++optimal_above;
    EXPECT_LE(s.kkt_error, 1e-8) << s.sigma;
  }
  EXPECT_GE(optimal_above, 1);
  EXPECT_EQ(relaxed_steps(loose).front().ipopt_status, "Solve_Succeeded");
  EXPECT_LE(relaxed_steps(loose).front().kkt_error, 1e-2 * relaxed_steps(loose).front().sigma);
  EXPECT_GT(relaxed_steps(loose).front().kkt_error, options.homotopy.nlp_tolerance);
  EXPECT_NEAR(loose.T, 40.0 / 3.0, 1e-6);
  EXPECT_NEAR(tight.T, 40.0 / 3.0, 1e-6);
  std::printf("first NLP's KKT error: %.1e (factor 1e-2), %.1e (factor 0); |T - 40/3| %.1e, %.1e\n",
              relaxed_steps(loose).front().kkt_error, relaxed_steps(tight).front().kkt_error,
              std::abs(loose.T - 40.0 / 3.0), std::abs(tight.T - 40.0 / 3.0));
}

// OcpHomotopyOptions::first_from_zero_multipliers: the first NLP starts as IPOPT's warm start with
// every multiplier 0 instead of IPOPT's own initialisation. Another path (the first NLP ends at
// another point: its iterations, objective or KKT error differ; equal to the last bit from two
// starts would mean the option was not applied), the same optimum T* = 40/3.
TEST(OcpHomotopy, FirstNlpFromZeroMultipliers) {
  OcpOptions options;
  options.stages = 5;
  const OcpResult own = solve_car(options);
  options.homotopy.first_from_zero_multipliers = true;
  const OcpResult zero = solve_car(options);
  ASSERT_EQ(own.status, OcpStatus::kSolved) << own.message;
  ASSERT_EQ(zero.status, OcpStatus::kSolved) << zero.message;
  const OcpHomotopyStep &a = own.homotopy.front(), &b = zero.homotopy.front();
  EXPECT_TRUE(a.iterations != b.iterations || a.objective != b.objective ||
              a.kkt_error != b.kkt_error)
      << a.iterations << " iterations, objective " << a.objective << ", KKT error " << a.kkt_error
      << " from either start";
  EXPECT_NEAR(zero.T, 40.0 / 3.0, 1e-8);
  std::printf("first NLP: %d iterations (IPOPT's start), %d (zero multipliers); |T - 40/3| %.1e\n",
              own.homotopy.front().iterations, zero.homotopy.front().iterations,
              std::abs(zero.T - 40.0 / 3.0));
}

// OcpHomotopyOptions::monotone_mu_down_to: the warm-started NLPs at sigma >= 1e-2 run IPOPT's
// monotone mu strategy, the first NLP, those below and the polishes the adaptive one, and each
// step says which. On the turbo car (Stewart, N = 10) both strategies reach T* = 40/3; another
// path shows the option was applied (the NLP at sigma = 10 ends elsewhere), and the caller's
// IPOPT options mu_strategy and mu_init, applied after bflow's, are what is reported and run
// (the same iterates as monotone_mu_down_to = inf: the adaptive strategy does not read mu_init).
// Measured: 214 IPOPT iterations against 577 with the adaptive strategy throughout (its NLP at
// sigma = 1 alone 134, creeping off the bounds of the new relaxation from mu = 1e-11). Warm starts
// without multipliers, cold starts and the re-solve at nlp_tolerance of stop_at_complementarity run
// the adaptive strategy.
TEST(OcpHomotopy, MonotoneMuForTheWarmStartedNlps) {
  OcpOptions options;
  options.stages = 10;
  options.formulation = DcsFormulation::kStewart;
  const OcpResult monotone = solve_car(options);
  options.homotopy.monotone_mu_down_to = std::numeric_limits<double>::infinity();
  const OcpResult adaptive = solve_car(options);
  options.homotopy.monotone_mu_down_to = 1e-2;
  options.solver.ipopt_string_options.push_back({"mu_strategy", "Adaptive"});
  options.solver.ipopt_numeric_options.push_back({"mu_init", 0.25});  // unread when adaptive
  const OcpResult caller = solve_car(options);
  for (const OcpResult* r : {&monotone, &adaptive, &caller}) {
    ASSERT_EQ(r->status, OcpStatus::kSolved) << r->message;
    EXPECT_NEAR(r->T, TurboCar::kOptimalTime, 1e-8);
  }
  const std::vector<OcpHomotopyStep> m = relaxed_steps(monotone), a = relaxed_steps(adaptive);
  // sigma = 100 (the first), then 10, 1, 0.1 and 0.01 warm-started at or above 1e-2.
  ASSERT_GE(m.size(), 6u);
  ASSERT_GE(a.size(), 2u);
  const double sigmas[] = {100.0, 10.0, 1.0, 0.1, 0.01};
  for (std::size_t k = 0; k < m.size(); ++k) {
    SCOPED_TRACE("sigma " + std::to_string(m[k].sigma));
    if (k < 5) {
      EXPECT_NEAR(m[k].sigma, sigmas[k], 1e-12 * sigmas[k]);
    }
    EXPECT_EQ(m[k].mu_strategy, k >= 1 && k <= 4 ? "monotone" : "adaptive");
    if (k >= 1 && k <= 4) {
      EXPECT_DOUBLE_EQ(m[k].mu_init, 1e-2 * sigmas[k]);
    }
  }
  for (const OcpHomotopyStep& s : monotone.homotopy) {
    if (s.polish) {
      EXPECT_EQ(s.mu_strategy, "adaptive");
    }
  }
  for (const OcpHomotopyStep& s : adaptive.homotopy) EXPECT_EQ(s.mu_strategy, "adaptive");
  for (const OcpHomotopyStep& s : caller.homotopy) {
    EXPECT_EQ(s.mu_strategy, "adaptive");
    EXPECT_EQ(s.mu_init, 0.25);
  }
  EXPECT_TRUE(m[1].iterations != a[1].iterations || m[1].objective != a[1].objective)
      << m[1].iterations << " iterations, objective " << m[1].objective << " with either strategy";
  EXPECT_EQ(caller.ipopt_iterations, adaptive.ipopt_iterations);
  EXPECT_EQ(caller.T, adaptive.T);
  std::printf("IPOPT iterations: %d (monotone mu down to sigma = 1e-2), %d (adaptive)\n",
              monotone.ipopt_iterations, adaptive.ipopt_iterations);

  // The other starts: every NLP adaptive, whatever monotone_mu_down_to says.
  OcpOptions other;
  other.stages = 5;
  other.homotopy.monotone_mu_down_to = 0.0;
  other.homotopy.warm_start_multipliers = false;  // nosnoc's warm start of the primal point
  const OcpResult primal = solve_car(other);
  other.homotopy.warm_start_multipliers = true;
  other.homotopy.warm_start = false;  // IPOPT's own initialisation from the previous point
  const OcpResult cold = solve_car(other);
  for (const OcpResult* r : {&primal, &cold}) {
    ASSERT_GE(r->homotopy.size(), 2u) << r->message;
    for (const OcpHomotopyStep& s : r->homotopy) EXPECT_EQ(s.mu_strategy, "adaptive") << s.sigma;
  }
  // stop_at_complementarity: the NLP solved loosely within the tolerance is solved again at the
  // same sigma to nlp_tolerance, with the adaptive strategy (its tolerance is far below 1e-2
  // sigma); the NLPs before it warm-started at sigma >= 1e-2 are monotone.
  OcpOptions stop;
  stop.stages = 5;
  stop.homotopy.polish = false;
  stop.homotopy.stop_at_complementarity = true;
  stop.homotopy.complementarity_tolerance = 0.05;  // reached at sigma = 1e-2
  const std::vector<OcpHomotopyStep> st = relaxed_steps(solve_car(stop));
  ASSERT_GE(st.size(), 3u);
  const OcpHomotopyStep &again = st.back(), &before = st[st.size() - 2];
  ASSERT_EQ(again.sigma, before.sigma) << "no re-solve at the last sigma";
  EXPECT_GE(again.sigma, 1e-2);
  EXPECT_EQ(before.mu_strategy, "monotone");
  EXPECT_EQ(again.mu_strategy, "adaptive");
  // The threshold is meant as written: 0.03 times 1/3 lands at 0.009999999999999998, which is
  // the sigma 1e-2 of the schedule and runs the monotone strategy; 1/3 of it does not.
  OcpOptions third;
  third.stages = 5;
  third.homotopy.sigma_initial = 0.03;
  third.homotopy.sigma_factor = 1.0 / 3.0;
  const std::vector<OcpHomotopyStep> t = relaxed_steps(solve_car(third));
  ASSERT_GE(t.size(), 3u);
  EXPECT_LT(t[1].sigma, 1e-2);
  EXPECT_EQ(t[1].mu_strategy, "monotone");
  EXPECT_EQ(t[2].mu_strategy, "adaptive");
}

// OcpHomotopyOptions::continue_after_failure (nosnoc's rule). With half the IPOPT iterations the
// turbo car's first NLP (sigma = 100) takes without a cap (measured 53), it stops unsolved: the
// capped run takes the same iterates and stops at the cap. bflow's rule has no solved NLP to go
// back to and ends there (nlp_failed, one NLP); nosnoc's hands every failed NLP's last iterate to
// the next sigma: the schedule 100, 10, ..., 1e-10 (13 NLPs) is walked once, and the notes name
// each failed sigma but the last's, which is the result's message.
TEST(OcpHomotopy, ContinueAfterFailure) {
  OcpOptions options;
  options.stages = 5;
  options.homotopy.polish = false;
  const OcpResult uncapped = solve_car(options);
  ASSERT_FALSE(uncapped.homotopy.empty());
  const OcpHomotopyStep& first = uncapped.homotopy.front();
  ASSERT_EQ(first.ipopt_status, "Solve_Succeeded");
  ASSERT_GE(first.iterations, 2);
  options.homotopy.max_nlp_iterations = first.iterations / 2;
  const OcpResult retried = solve_car(options);
  options.homotopy.continue_after_failure = true;
  const OcpResult continued = solve_car(options);

  EXPECT_EQ(retried.status, OcpStatus::kNlpFailed);
  EXPECT_EQ(relaxed_steps(retried).size(), 1u);
  EXPECT_TRUE(retried.notes.empty());

  const std::vector<OcpHomotopyStep> b = relaxed_steps(continued);
  ASSERT_EQ(b.size(), 13u);
  int failed = 0;
  for (std::size_t k = 0; k < b.size(); ++k) {
    EXPECT_NEAR(b[k].sigma, 100.0 * std::pow(0.1, static_cast<double>(k)), 1e-12 * b[k].sigma);
    const bool solved =
        b[k].ipopt_status == "Solve_Succeeded" || b[k].ipopt_status == "Solved_To_Acceptable_Level";
    if (!solved && k + 1 < b.size()) {
      ++failed;
      EXPECT_THAT(continued.notes,
                  testing::Contains(testing::StartsWith(
                      "the NLP at sigma = " + format_number(b[k].sigma) + " was not solved")));
    }
  }
  EXPECT_GE(failed, 1);
  EXPECT_EQ(continued.notes.size(), static_cast<std::size_t>(failed));
  std::printf("bflow's rule: %zu NLP; continue_after_failure: %zu NLPs, %d handed on, %s\n",
              relaxed_steps(retried).size(), b.size(), failed, to_string(continued.status));
}

}  // namespace
}  // namespace bflow

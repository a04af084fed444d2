// The homotopy's stopping rule of ocp_solve (OcpOptions::stop_at_complementarity): the homotopy
// ends at the first NLP whose complementarity residual is within complementarity_tolerance,
// solved at nlp_tolerance, and the polish then reaches the turbo car's exact optimal time
// T* = 40/3 (ocp_examples.h).
#include <cstdio>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

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
// was solved more loosely) within it, and sigma_final 1e-10 is not reached. Measured: 10 NLPs
// (sigma = 100 ... 1e-6, then 1e-6 again at nlp_tolerance) and 204 IPOPT iterations against 13
// NLPs and 659 iterations down to 1e-10; after the polish |T - 40/3| = 1.2e-10 in both.
TEST(OcpHomotopy, StopsAtTheFirstNlpWithinTheComplementarityTolerance) {
  OcpOptions options;
  options.stages = 5;
  options.complementarity_tolerance = 1e-6;
  const OcpResult full = solve_car(options);
  options.stop_at_complementarity = true;
  const OcpResult r = solve_car(options);
  ASSERT_EQ(full.status, OcpStatus::kSolved) << full.message;
  ASSERT_EQ(r.status, OcpStatus::kSolved) << r.message;

  const std::vector<OcpHomotopyStep> steps = relaxed_steps(r);
  ASSERT_GE(steps.size(), 2u);
  const OcpHomotopyStep& last = steps.back();
  EXPECT_LE(last.complementarity, 1e-6);
  EXPECT_GT(last.sigma, options.sigma_final);
  std::size_t first_within = steps.size() - 1;
  while (first_within > 0 && steps[first_within - 1].complementarity <= 1e-6) --first_within;
  for (std::size_t k = 0; k < first_within; ++k) EXPECT_GT(steps[k].complementarity, 1e-6) << k;
  // At most a second solve of the same NLP after the first one within the tolerance.
  EXPECT_LE(steps.size() - first_within, 2u);
  EXPECT_EQ(steps[first_within].sigma, last.sigma);
  EXPECT_LT(steps.size(), relaxed_steps(full).size());
  EXPECT_LT(r.ipopt_iterations, full.ipopt_iterations);
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

}  // namespace
}  // namespace bflow

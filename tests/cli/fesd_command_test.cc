// `bflow fesd` in-process: the JSON of a run against the exact solution, Table 4, bad options.
#include <sstream>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "cli_commands.h"

namespace bflow::cli {
namespace {

TEST(FesdCommandTest, CrossingPrintsTheExactSwitchAndState) {
  FesdCommandOptions o;
  o.example = "crossing";
  o.trajectory = true;
  std::ostringstream out, err;
  ASSERT_EQ(run_fesd(o, out, err), kExitOk) << err.str();
  const auto j = nlohmann::json::parse(out.str());
  // x' = 3 until x = 0 at t = 1/3, then x' = 1: x(1) = 2/3. Measured (Newton on every step):
  // x 1.1e-16, switch time and complementarity exact, sensitivity 3.9e-16.
  EXPECT_NEAR(j["x_T"][0].get<double>(), 2.0 / 3.0, 1e-14);
  ASSERT_EQ(j["switch_times"].size(), 1u);
  EXPECT_NEAR(j["switch_times"][0].get<double>(), 1.0 / 3.0, 1e-14);
  EXPECT_EQ(j["steps"].get<int>(), 4);
  EXPECT_LE(j["max_complementarity"].get<double>(), 1e-14);
  // d x(1) / d x0 = 3 / 3 ... the crossing time moves by -dx0/3, after which x' = 1: 1/3.
  EXPECT_NEAR(j["sensitivity"][0][0].get<double>(), 1.0 / 3.0, 1e-14);
  // Every step by Newton: nothing was accepted at IPOPT's acceptable level only.
  EXPECT_FALSE(j["acceptable_only"].get<bool>());
  EXPECT_EQ(j["acceptable_only_steps"].get<int>(), 0);
  EXPECT_FALSE(j.contains("status"));
  EXPECT_EQ(j["trajectory"]["t"].size(), 13u);  // 4 steps x 3 elements + 1
}

// x' in -sign(x) + t from x = 0 slides until t = 1 and leaves: x(2) = (2^2 - 1)/2 - (2 - 1) = 0.5.
TEST(FesdCommandTest, StewartAndLiftedFormulationsGiveTheExactLeavingSolution) {
  for (const char* formulation : {"stewart", "step"}) {
    FesdCommandOptions o;
    o.example = "sliding-leave";
    o.formulation = formulation;
    o.lifting = std::string(formulation) == "step" ? 2 : 0;
    std::ostringstream out, err;
    ASSERT_EQ(run_fesd(o, out, err), kExitOk) << err.str();
    const auto j = nlohmann::json::parse(out.str());
    EXPECT_EQ(j["formulation"].get<std::string>(), formulation);
    // Measured: x 5.6e-17, switch time exact.
    EXPECT_NEAR(j["x_T"][0].get<double>(), 0.5, 1e-14) << formulation;
    ASSERT_EQ(j["switch_times"].size(), 1u) << formulation;
    EXPECT_NEAR(j["switch_times"][0].get<double>(), 1.0, 1e-14) << formulation;
    EXPECT_EQ(j["newton_steps"].get<int>(), 4) << formulation;
  }
}

TEST(FesdCommandTest, SizesPrintTable4) {
  FesdCommandOptions o;
  o.example = "irma";
  o.sizes = true;
  o.lifting = 2;
  std::ostringstream out, err;
  ASSERT_EQ(run_fesd(o, out, err), kExitOk) << err.str();
  const auto j = nlohmann::json::parse(out.str());
  EXPECT_EQ(j["stewart"]["n_alg"].get<int>(), 2 * 128 + 1);
  EXPECT_EQ(j["step"]["n_beta"].get<int>(), 128 - 4);
  EXPECT_EQ(j["step"]["n_comp"].get<int>(), 14);
}

TEST(FesdCommandTest, BadOptionsAreNamed) {
  std::ostringstream out, err;
  FesdCommandOptions o;
  o.example = "lorenz";
  EXPECT_EQ(run_fesd(o, out, err), kExitBadInput);
  EXPECT_THAT(err.str(), ::testing::StartsWith("error: --example: unknown example \"lorenz\""));
  err.str("");
  o.example = "crossing";
  o.scheme = "lobatto";
  EXPECT_EQ(run_fesd(o, out, err), kExitBadInput);
  EXPECT_THAT(err.str(), ::testing::StartsWith("error: --scheme: unknown collocation scheme"));
  err.str("");
  o.scheme = "radau";
  o.stages = 0;
  EXPECT_EQ(run_fesd(o, out, err), kExitBadInput);
  EXPECT_THAT(err.str(), ::testing::HasSubstr("stages must be in [1, 9], got 0"));
  err.str("");
  o.stages = 2;
  o.formulation = "stewart";
  o.lifting = 3;
  EXPECT_EQ(run_fesd(o, out, err), kExitBadInput);
  EXPECT_THAT(err.str(), ::testing::HasSubstr("applies to the step formulation only"));
  EXPECT_TRUE(out.str().empty());
}

}  // namespace
}  // namespace bflow::cli

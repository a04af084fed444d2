// `bflow fesd` in-process: the JSON of a run against the exact solution, Table 4, bad options.
#include <algorithm>
#include <cstdint>
#include <limits>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "bflow/fesd/linear_solver.h"
#include "cli_commands.h"
#include "support/run_command.h"

namespace bflow::cli {
namespace {

using bflow::testing::command_line;
using bflow::testing::Outcome;
using ::testing::EndsWith;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;
using ::testing::StartsWith;

// `bflow fesd --help` and `bflow ocp --help` list their options in the groups of the options
// structs (fesd/homotopy_options.h): each option below the heading of its own group.
TEST(FesdCommandTest, HelpGroupsTheOptionsAsTheLibraryDoes) {
  const std::vector<std::string> headings = {
      "Problem:", "Discretisation (FESD):",
      "Homotopy (the relaxation's sigma and the NLPs' tolerances):",
      "Solver (IPOPT and its linear solver):", "Output:"};
  const std::vector<std::pair<std::string, std::vector<std::vector<std::string>>>> commands = {
      {"fesd",
       {{"--example", "--nsim", "--T"},
        {"--formulation", "--scheme", "--stages", "--nfe", "--standard", "--lifting"},
        {},
        {"--exact-hessian", "--linear-solver", "--linear-solver-library", "--blas-threads"},
        {"--trajectory", "--sizes", "--compact"}}},
      {"ocp",
       {{"--example", "--setup", "--N"},
        {"--nfe", "--stages", "--scheme", "--formulation", "--standard", "--cross", "--lifting"},
        {"--relaxation", "--sigma0", "--sigma-final", "--early-polish-sigma", "--tol",
         "--max-iterations"},
        {"--linear-solver", "--linear-solver-library", "--blas-threads"},
        {"--trajectory", "--plot", "--compact", "--quiet"}}}};
  for (const auto& [command, groups] : commands) {
    SCOPED_TRACE(command);
    const Outcome help = command_line({command, "--help"});
    ASSERT_EQ(help.code, 0);
    // Each group's heading and where the next one starts (the end for the last).
    std::vector<std::size_t> at;
    for (std::size_t g = 0; g < headings.size(); ++g) {
      at.push_back(groups[g].empty() ? std::string::npos : help.out.find("\n" + headings[g]));
      if (!groups[g].empty()) {
        ASSERT_NE(at.back(), std::string::npos) << headings[g] << "\n" << help.out;
      } else {
        EXPECT_EQ(help.out.find(headings[g]), std::string::npos) << headings[g];
      }
    }
    for (std::size_t g = 0; g < headings.size(); ++g) {
      if (groups[g].empty()) continue;
      std::size_t end = help.out.size();
      for (std::size_t k = g + 1; k < headings.size(); ++k) {
        if (at[k] != std::string::npos && at[k] > at[g]) end = std::min(end, at[k]);
      }
      const std::string section = help.out.substr(at[g], end - at[g]);
      for (const std::string& option : groups[g]) {
        EXPECT_THAT(section, HasSubstr("  " + option + " ")) << headings[g];
      }
    }
  }
}

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
  o.formulation = "stewart";
  o.lifting = 2;
  EXPECT_EQ(run_fesd(o, out, err), kExitBadInput);
  EXPECT_EQ(err.str(),
            "error: --lifting: a lifting depth (2) applies to --formulation step only, not "
            "stewart\n");
  EXPECT_TRUE(out.str().empty());
}

// Each option out of range, given in-process: exit code 2, exactly this line, nothing on stdout.
// The same from the command line: the bflow_cli_fesd_* tests (tests/cli/CMakeLists.txt).
TEST(FesdCommandTest, OptionsOutOfRangeAreRefusedWithTheirValues) {
  struct Case {
    void (*set)(FesdCommandOptions&);
    const char* line;
  };
  const Case cases[] = {
      {[](FesdCommandOptions& o) { o.t = -1.0; },
       "error: --T: the horizon must be finite and > 0, got -1"},
      {[](FesdCommandOptions& o) { o.t = 0.0; },
       "error: --T: the horizon must be finite and > 0, got 0"},
      {[](FesdCommandOptions& o) { o.t = std::numeric_limits<double>::quiet_NaN(); },
       "error: --T: the horizon must be finite and > 0, got nan"},
      {[](FesdCommandOptions& o) { o.t = std::numeric_limits<double>::infinity(); },
       "error: --T: the horizon must be finite and > 0, got inf"},
      {[](FesdCommandOptions& o) { o.nsim = 0; },
       "error: --nsim: the number of integration steps must be >= 1, got 0"},
      {[](FesdCommandOptions& o) { o.nsim = -5; },
       "error: --nsim: the number of integration steps must be >= 1, got -5"},
      {[](FesdCommandOptions& o) { o.lifting = -7; },
       "error: --lifting: the lifting depth must be 0 (none) or 2 for crossing (larger depths "
       "are the same as 2), got -7"},
      {[](FesdCommandOptions& o) {
         o.lifting = -7;
         o.sizes = true;
       },
       "error: --lifting: the lifting depth must be 0 (none) or 2 for crossing (larger depths "
       "are the same as 2), got -7"},
      {[](FesdCommandOptions& o) { o.lifting = 1; },
       "error: --lifting: the lifting depth must be 0 (none) or 2 for crossing (larger depths "
       "are the same as 2), got 1"},
      {[](FesdCommandOptions& o) { o.stages = 0; },
       "error: --stages: the number of Runge-Kutta stages must be in [1, 9], got 0"},
      {[](FesdCommandOptions& o) { o.stages = 10; },
       "error: --stages: the number of Runge-Kutta stages must be in [1, 9], got 10"},
      {[](FesdCommandOptions& o) { o.nfe = 0; },
       "error: --nfe: the number of finite elements per integration step must be >= 1, got 0"},
      {[](FesdCommandOptions& o) { o.nfe = -1; },
       "error: --nfe: the number of finite elements per integration step must be >= 1, got -1"},
      // 10 unknowns per element (d = 1, n_c = 1, Radau IIA 2): 10 N_FE.
      {[](FesdCommandOptions& o) { o.nfe = 1073741824; },
       "error: --nfe: 1073741824 finite elements of 2 stages give 10737418240 NLP unknowns per "
       "integration step, above IPOPT's limit of 2147483647 (see docs/fesd.md)"},
      {[](FesdCommandOptions& o) {
         o.nfe = 1073741824;
         o.sizes = true;
       },
       "error: --nfe: 1073741824 finite elements of 2 stages give 10737418240 NLP unknowns per "
       "integration step, above IPOPT's limit of 2147483647 (see docs/fesd.md)"},
      {[](FesdCommandOptions& o) { o.nfe = 2147483647; },
       "error: --nfe: 2147483647 finite elements of 2 stages give 21474836470 NLP unknowns per "
       "integration step, above IPOPT's limit of 2147483647 (see docs/fesd.md)"},
      // 9 stages: 1 + 10 + 9 * 3 = 38 unknowns per element.
      {[](FesdCommandOptions& o) {
         o.nfe = 1073741824;
         o.stages = 9;
       },
       "error: --nfe: 1073741824 finite elements of 9 stages give 40802189312 NLP unknowns per "
       "integration step, above IPOPT's limit of 2147483647 (see docs/fesd.md)"},
      // Within IPOPT's Index, but the dense Newton Jacobian alone would be 2.3 GB.
      {[](FesdCommandOptions& o) { o.nfe = 1700; },
       "error: --nfe: 1700 finite elements of 2 stages give 17000 NLP unknowns per integration "
       "step, needing about 4.6e+09 bytes, above the limit of 4 GiB = 4294967296 bytes (see "
       "docs/fesd.md)"},
      {[](FesdCommandOptions& o) { o.nsim = 2147483647; },
       "error: --nsim: 2147483647 integration steps of 3 finite elements give 6442450941 finite "
       "elements in all, needing about 7.8e+11 bytes, above the limit of 4 GiB = 4294967296 "
       "bytes (see docs/fesd.md)"},
  };
  for (const Case& c : cases) {
    FesdCommandOptions o;
    o.example = "crossing";
    c.set(o);
    std::ostringstream out, err;
    EXPECT_EQ(run_fesd(o, out, err), kExitBadInput) << c.line;
    EXPECT_EQ(err.str(), std::string(c.line) + "\n");
    EXPECT_EQ(out.str(), "");
  }
}

TEST(FesdCommandTest, TheHorizonAndStepsUsedAreEchoed) {
  FesdCommandOptions o;
  o.example = "sliding-leave";  // defaults T = 2, N_sim = 4
  std::ostringstream out, err;
  ASSERT_EQ(run_fesd(o, out, err), kExitOk) << err.str();
  auto j = nlohmann::json::parse(out.str());
  EXPECT_EQ(j["T"].get<double>(), 2.0);
  EXPECT_EQ(j["nsim"].get<int>(), 4);
  EXPECT_EQ(out.str().rfind("{\n  \"T\": 2.0,\n  \"nsim\": 4,\n  \"x_T\": ", 0), 0u) << out.str();
  o.example = "crossing";
  o.t = 0.5;
  o.nsim = 2;
  out.str("");
  ASSERT_EQ(run_fesd(o, out, err), kExitOk) << err.str();
  j = nlohmann::json::parse(out.str());
  EXPECT_EQ(j["T"].get<double>(), 0.5);
  EXPECT_EQ(j["nsim"].get<int>(), 2);
  // x' = 3 from -1 until the switch at t = 1/3, then x' = 1: x(0.5) = 1/6.
  EXPECT_NEAR(j["x_T"][0].get<double>(), 1.0 / 6.0, 1e-14);
}

TEST(FesdCommandTest, SizesIncludeOneStepsNlp) {
  FesdCommandOptions o;
  o.example = "crossing";
  o.sizes = true;
  std::ostringstream out, err;
  ASSERT_EQ(run_fesd(o, out, err), kExitOk) << err.str();
  const auto j = nlohmann::json::parse(out.str());
  // 3 elements of 10 unknowns and 7 rows, 92 N - 21 Jacobian nonzeros (fesd_limits_test.cc).
  EXPECT_EQ(j["nlp"]["unknowns"].get<std::int64_t>(), 30);
  EXPECT_EQ(j["nlp"]["constraints"].get<std::int64_t>(), 22);
  EXPECT_EQ(j["nlp"]["jacobian_nonzeros"].get<std::int64_t>(), 92 * 3 - 21);
}

// IRMA in one integration step of one element of implicit Euler (Radau IIA 1) crosses several
// surfaces at once: no guess fits, IPOPT's homotopy fails, the step is halved 4 times and the run
// stops at t = 25 (measured; about 3 s). The JSON is the partial record, stderr one line.
TEST(FesdCommandTest, AFailedStepPrintsThePartialRecordAndOneErrorLine) {
  FesdCommandOptions o;
  o.example = "irma";
  o.nfe = 1;
  o.nsim = 1;
  o.stages = 1;
  o.compact = true;
  std::ostringstream out, err;
  EXPECT_EQ(run_fesd(o, out, err), kExitFailure);
  const std::string line = err.str();
  EXPECT_THAT(line, ::testing::StartsWith("error: fesd: the integration step at t = "));
  EXPECT_THAT(line, ::testing::HasSubstr("did not converge"));
  EXPECT_EQ(line.find("fesd: fesd:"), std::string::npos);
  EXPECT_EQ(line.find('\n'), line.size() - 1);  // exactly one line
  const auto j = nlohmann::json::parse(out.str());
  EXPECT_EQ(j["T"].get<double>(), 100.0);
  EXPECT_EQ(j["nsim"].get<int>(), 1);
  EXPECT_EQ(j["status"].get<std::string>(), "step failed");
  EXPECT_EQ("error: " + j["message"].get<std::string>() + "\n", line);
  EXPECT_GT(j["t_reached"].get<double>(), 0.0);
  EXPECT_LT(j["t_reached"].get<double>(), 100.0);
  EXPECT_EQ(j["x_T"].size(), 5u);
}

// The options as typed: an empty value (which CLI11 took as the default), a number beyond its
// type or one that underflows is refused naming the option and the text; every range check of
// run_fesd still applies to what is read. --sizes makes every accepted case cheap.
TEST(FesdCommandTest, OptionTextIsReadWholeAndChecked) {
  const std::string underflow =
      " underflows: a nonzero number must be at least 2.2250738585072014e-308 (the smallest "
      "normal double) in magnitude";
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"--example", ""}, "--example: the value is empty"},
      {{"--formulation", ""}, "--formulation: the value is empty"},
      {{"--scheme", ""}, "--scheme: the value is empty"},
      {{"--stages", ""}, "--stages: the value is empty"},
      {{"--nfe", ""}, "--nfe: the value is empty"},
      {{"--nsim", ""}, "--nsim: the value is empty"},
      {{"--T", ""}, "--T: the value is empty"},
      {{"--lifting", ""}, "--lifting: the value is empty"},
      {{"--T", "1e-400"}, "--T: \"1e-400\"" + underflow},
      {{"--T", "4e-320"}, "--T: \"4e-320\"" + underflow},
      {{"--T", "1e999"}, "--T: \"1e999\" is out of the range of a double"},
      {{"--T", "soon"}, "--T: \"soon\" is not a number"},
      {{"--T", "inf"}, "--T: the horizon must be finite and > 0, got inf"},
      {{"--nsim", "3000000000"}, "--nsim: \"3000000000\" is too large (at most 2147483647)"},
      {{"--nsim=-3000000000"}, "--nsim: \"-3000000000\" is too small (at least -2147483648)"},
      {{"--nsim", "2.5"}, "--nsim: \"2.5\" is not an integer"},
      {{"--nsim=-5"}, "--nsim: the number of integration steps must be >= 1, got -5"},
      {{"--nfe", "1e3"}, "--nfe: \"1e3\" is not an integer"},
      {{"--stages", "ten"}, "--stages: \"ten\" is not an integer"},
      {{"--lifting", "99999999999999999999"},
       "--lifting: \"99999999999999999999\" is too large (at most 2147483647)"},
      {{"--formulation", "\xe2\x88\x92step\x07"},
       "--formulation: unknown formulation \"\xe2\x88\x92step\\u0007\": use step or stewart"},
      {{"--scheme", std::string(131072, 'r')},
       "--scheme: unknown collocation scheme \"" + std::string(60, 'r') +
           "...\": use radau or gauss"},
  };
  for (const auto& [args, error] : cases) {
    std::vector<std::string> all = {"fesd", "--example", "crossing", "--sizes"};
    if (args[0] == "--example") all = {"fesd", "--sizes"};
    all.insert(all.end(), args.begin(), args.end());
    const Outcome o = command_line(all);
    SCOPED_TRACE(error.substr(0, 40));
    EXPECT_EQ(o.code, kExitBadInput);
    EXPECT_EQ(o.out, "");
    EXPECT_EQ(o.err, "error: " + error + "\n");
  }
  // The defaults, and values given in full.
  const Outcome defaults = command_line({"fesd", "--example", "crossing", "--compact"});
  ASSERT_EQ(defaults.code, kExitOk) << defaults.err;
  auto j = nlohmann::json::parse(defaults.out);
  EXPECT_EQ(j["T"].get<double>(), 1.0);
  EXPECT_EQ(j["nsim"].get<int>(), 4);
  const Outcome given = command_line({"fesd", "--example", "crossing", "--T", " 0.5 ", "--nsim",
                                      "+2", "--stages", "3", "--nfe", "2", "--compact"});
  ASSERT_EQ(given.code, kExitOk) << given.err;
  j = nlohmann::json::parse(given.out);
  EXPECT_EQ(j["T"].get<double>(), 0.5);
  EXPECT_EQ(j["nsim"].get<int>(), 2);
  EXPECT_NEAR(j["x_T"][0].get<double>(), 1.0 / 6.0, 1e-14);
}

// --linear-solver as for `bflow ocp`: recorded in the JSON, an unknown name and a missing
// libhsl.so refused before the run (HSL_MA97 would end the process inside IPOPT).
TEST(FesdCommandTest, TheLinearSolverIsCheckedFirstAndRecorded) {
  const Outcome run =
      command_line({"fesd", "--example", "crossing", "--linear-solver", "mumps", "--compact"});
  ASSERT_EQ(run.code, kExitOk) << run.err;
  const nlohmann::json j = nlohmann::json::parse(run.out);
  // The stack by name and version: "IPOPT 3.14.19", "mumps 5.8.2" (the default build).
  EXPECT_THAT(j["ipopt"].get<std::string>(), MatchesRegex("IPOPT 3\\.[0-9]+\\.[0-9]+"));
  EXPECT_THAT(j["linear_solver"].get<std::string>(), MatchesRegex("mumps 5\\.[0-9]+\\.[0-9]+"));
  const Outcome unknown =
      command_line({"fesd", "--example", "crossing", "--linear-solver", "ma28"});
  EXPECT_EQ(unknown.code, kExitBadInput);
  EXPECT_EQ(unknown.out, "");
  EXPECT_EQ(unknown.err,
            "error: --linear-solver: unknown linear solver \"ma28\"; use mumps, spral, ma27, ma57, "
            "ma77, ma86, ma97, pardiso or pardisomkl\n");
  const std::string files = linear_solver_library("ma97", "fesd");
  const std::string first = files.substr(0, files.find(' '));
  const std::string reason = linear_solver_load_error("ma97", first);
  if (reason.empty()) GTEST_SKIP() << first << " is installed here";
  const Outcome missing =
      command_line({"fesd", "--example", "crossing", "--linear-solver", "ma97"});
  EXPECT_EQ(missing.code, kExitBadInput);
  EXPECT_EQ(missing.out, "");
  EXPECT_THAT(missing.err,
              StartsWith("error: --linear-solver: linear solver \"ma97\" needs HSL's " + first));
  EXPECT_THAT(missing.err, HasSubstr("which cannot be loaded (" + reason + "); get Coin-HSL"));
  EXPECT_THAT(missing.err, EndsWith("(docs/ocp.md, \"Linear solvers\"), or use mumps\n"));
}

// A linear solver's name is quoted at a bounded length, escaped (it used to come back whole).
TEST(FesdCommandTest, ALongLinearSolverNameIsQuotedBounded) {
  const std::string name = "ma\n" + std::string(5000, 'x');
  const Outcome line = command_line({"fesd", "--example", "crossing", "--linear-solver", name});
  EXPECT_EQ(line.code, kExitBadInput);
  EXPECT_EQ(line.out, "");
  EXPECT_EQ(line.err,
            "error: --linear-solver: unknown linear solver \"ma\\u000a" + std::string(57, 'x') +
                "...\"; use mumps, spral, ma27, ma57, ma77, ma86, ma97, pardiso or pardisomkl\n");
}

}  // namespace
}  // namespace bflow::cli

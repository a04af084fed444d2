// `bflow flow` in-process: the JSON holds the library's numbers (closed forms for the linear
// piecewise-constant field, the jump module for a random one, finite differences for the
// biped), and every malformed option gets one precise error line with exit code 2. A finite
// start that overflows, and output that cannot be written, exit with 1 and one line (the
// output check, finish_output() of cli_util.h, is tested here too).
#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <ostream>
#include <sstream>
#include <streambuf>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bflow/core/biped.h"
#include "bflow/core/jump_map.h"
#include "bflow/examples/piecewise_constant.h"
#include "cli_commands.h"
#include "cli_util.h"
#include "support/run_command.h"

namespace bflow::cli {
namespace {

using bflow::testing::capture;
using bflow::testing::command_line;
using bflow::testing::Outcome;

using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::StartsWith;
using Json = nlohmann::json;

Outcome flow(const FlowCommandOptions& options) {
  return capture([&](std::ostream& out, std::ostream& err) { return run_flow(options, out, err); });
}

// Parses a successful run.
Json result_of(const FlowCommandOptions& options) {
  const Outcome o = flow(options);
  EXPECT_EQ(o.code, 0) << o.err;
  EXPECT_EQ(o.err, "");
  return Json::parse(o.out);
}

Eigen::VectorXd vector_of(const Json& v) {
  Eigen::VectorXd out(static_cast<Eigen::Index>(v.size()));
  for (std::size_t i = 0; i < v.size(); ++i) out[static_cast<Eigen::Index>(i)] = v[i].get<double>();
  return out;
}

Eigen::MatrixXd matrix_of(const Json& rows) {
  Eigen::MatrixXd out(static_cast<Eigen::Index>(rows.size()),
                      static_cast<Eigen::Index>(rows[0].size()));
  for (std::size_t r = 0; r < rows.size(); ++r) {
    out.row(static_cast<Eigen::Index>(r)) = vector_of(rows[r]).transpose();
  }
  return out;
}

std::string text_of(const Eigen::VectorXd& v) {
  std::ostringstream text;
  text.precision(17);
  for (Eigen::Index i = 0; i < v.size(); ++i) text << (i ? "," : "") << v[i];
  return text.str();
}

FlowCommandOptions pwconst(std::vector<std::string> params) {
  FlowCommandOptions options;
  options.scene = "pwconst";
  options.params = std::move(params);
  return options;
}

FlowCommandOptions biped(std::vector<std::string> params) {
  FlowCommandOptions options;
  options.scene = "biped";
  options.params = std::move(params);
  return options;
}

// [B] (3.2): from rho- = -F_--(0)/2 for unit time, Delta(b) = -delta b gives
// B = (1 - delta)/(1 + delta) I; all three surfaces are crossed together at t = 1/2.
TEST(FlowCommandTest, LinearPiecewiseConstantIsTheClosedForm) {
  const double delta = 0.25;
  const double gain = (1.0 - delta) / (1.0 + delta);  // 0.6
  const Json out = result_of(pwconst({"d=3", "delta=0.25"}));
  EXPECT_EQ(out["scene"], "pwconst");
  EXPECT_EQ(out["params"], Json({{"d", 3}, {"delta", 0.25}}));
  EXPECT_EQ(out["integrator"], "auto");
  // d = 3 with surfaces at rtol 1e-8 <= 3e-8: auto takes dop853 (bflow::choose_backend).
  EXPECT_EQ(out["backend"], "dop853");
  EXPECT_EQ(out["t"], 1.0);
  EXPECT_EQ(vector_of(out["x0"]), Eigen::VectorXd::Constant(3, -0.625));
  // The field is constant between events, so the simulation is exact up to rounding.
  EXPECT_LE((vector_of(out["x_t"]) - Eigen::VectorXd::Constant(3, 0.5 * (1 - delta))).norm(),
            1e-12);
  ASSERT_EQ(out["events"].size(), 1u);
  const Json& event = out["events"][0];
  EXPECT_NEAR(event["t"].get<double>(), 0.5, 1e-12);
  EXPECT_THAT(event["surfaces"].get<std::vector<int>>(), ElementsAre(0, 1, 2));
  EXPECT_LE(vector_of(event["rho"]).norm(), 1e-12);
  EXPECT_EQ(event["sides_before"], "---");
  EXPECT_EQ(event["sides_after"], "+++");
  ASSERT_EQ(event["margins"].size(), 3u);
  for (const Json& margin : event["margins"]) {
    // eta_j = e_j, F = (1 +- delta) 1: eta . F / (|eta| |F|) = 1/sqrt(3) on both sides.
    EXPECT_NEAR(margin["before"].get<double>(), 1.0 / std::sqrt(3.0), 1e-15);
    EXPECT_NEAR(margin["after"].get<double>(), 1.0 / std::sqrt(3.0), 1e-15);
  }
  // The default directions are e_0, e_1, e_2.
  ASSERT_EQ(out["directions"].size(), 3u);
  for (int i = 0; i < 3; ++i) {
    SCOPED_TRACE(i);
    const Json& direction = out["directions"][static_cast<std::size_t>(i)];
    const Eigen::VectorXd dx = Eigen::VectorXd::Unit(3, i);
    EXPECT_EQ(vector_of(direction["dx"]), dx);
    EXPECT_LE((vector_of(direction["image"]) - gain * dx).norm(), 1e-12);
    EXPECT_LE((matrix_of(direction["jacobian"]) - gain * Eigen::MatrixXd::Identity(3, 3)).norm(),
              1e-12);
    // e_i is ahead along surface i only, so surface i is crossed first.
    ASSERT_EQ(direction["orders"].size(), 1u);
    EXPECT_EQ(direction["orders"][0][0], i);
    EXPECT_FALSE(direction.contains("fd"));
  }
  EXPECT_FALSE(out.contains("status"));
}

TEST(FlowCommandTest, DefaultsAreDeltaQuarterInTwoDimensions) {
  const Json out = result_of(pwconst({}));
  EXPECT_EQ(out["params"], Json({{"d", 2}, {"delta", 0.25}}));
  EXPECT_EQ(out["t"], 1.0);
  EXPECT_EQ(out["directions"].size(), 2u);
  EXPECT_EQ(out["rtol"], 1e-8);
  EXPECT_EQ(out["atol"], 1e-10);
}

TEST(FlowCommandTest, RandomDeltaIsFixedBySeedAndInRange) {
  const auto a = examples::PiecewiseConstantField::random(4, 11);
  const auto b = examples::PiecewiseConstantField::random(4, 11);
  const auto c = examples::PiecewiseConstantField::random(4, 12);
  EXPECT_EQ(a.delta(), b.delta());
  EXPECT_NE(a.delta(), c.delta());
  EXPECT_EQ(a.delta().rows(), 4);
  EXPECT_EQ(a.delta().cols(), 16);
  EXPECT_GT(a.delta().minCoeff(), -0.7);
  EXPECT_LT(a.delta().maxCoeff(), 1.5);
}

// A random Delta: the derivative of the simulated flow is the jump module's B at rho = 0 built
// from the same table (the transitions before and after are the identity: F is constant).
TEST(FlowCommandTest, SeededPiecewiseConstantIsTheJumpModulesB) {
  const int d = 3;
  const std::uint64_t seed = 7;
  const auto field = examples::PiecewiseConstantField::random(d, seed);
  const JumpMap jump(Eigen::MatrixXd::Identity(d, d), field.limits());
  std::vector<Eigen::VectorXd> directions = {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 0),
                                             Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(-1, 2, 0.5),
                                             Eigen::Vector3d(0.3, -0.2, -1)};
  FlowCommandOptions options = pwconst({"d=3", "seed=7"});
  for (const Eigen::VectorXd& dx : directions) options.dx.push_back(text_of(dx));
  const Json out = result_of(options);
  EXPECT_EQ(out["params"], Json({{"d", 3}, {"seed", 7}}));
  // The default start is rho- = -F_--(0)/2 exactly.
  EXPECT_EQ(vector_of(out["x0"]), Eigen::VectorXd(-0.5 * field.limits().col(0)));
  ASSERT_EQ(out["events"].size(), 1u);
  EXPECT_EQ(out["events"][0]["surfaces"].size(), 3u);
  ASSERT_EQ(out["directions"].size(), directions.size());
  std::vector<std::vector<int>> seen_orders;
  for (std::size_t k = 0; k < directions.size(); ++k) {
    SCOPED_TRACE(k);
    const Json& direction = out["directions"][k];
    const Eigen::VectorXd& dx = directions[k];
    const Eigen::VectorXd b = jump.apply(dx);
    // Integration is exact up to rounding; the event time and rho carry ~1e-16 errors that
    // B, with entries O(10), amplifies: 1e-11 relative leaves a wide margin.
    EXPECT_LE((vector_of(direction["image"]) - b).norm(), 1e-11 * b.norm());
    EXPECT_LE((matrix_of(direction["jacobian"]) - jump.active_jacobian(dx)).norm(),
              1e-11 * jump.active_jacobian(dx).norm());
    EXPECT_EQ(direction["orders"][0].get<std::vector<int>>(), jump.order(dx).order);
    seen_orders.push_back(jump.order(dx).order);
  }
  // The directions visit several pieces: B is not one matrix.
  std::sort(seen_orders.begin(), seen_orders.end());
  EXPECT_GE(std::unique(seen_orders.begin(), seen_orders.end()) - seen_orders.begin(), 3);
}

TEST(FlowCommandTest, FiniteDifferencesGiveOneRowPerStep) {
  FlowCommandOptions options = pwconst({"d=2", "seed=5"});
  options.dx = {"1,0", "-0.5,2"};
  options.fd = true;
  const Json out = result_of(options);
  ASSERT_EQ(out["directions"].size(), 2u);
  for (const Json& direction : out["directions"]) {
    ASSERT_TRUE(direction.contains("fd"));
    const Json& fd = direction["fd"];
    ASSERT_EQ(fd["rows"].size(), 9u);
    for (std::size_t r = 0; r < 9; ++r) {
      EXPECT_NEAR(fd["rows"][r]["alpha"].get<double>(), std::pow(10.0, -2.0 - r), 1e-25);
      EXPECT_TRUE(fd["rows"][r].contains("one_sided_error"));
      EXPECT_TRUE(fd["rows"][r].contains("central_error"));
    }
    double best = 1e300;
    for (const Json& row : fd["rows"]) best = std::min(best, row["one_sided_error"].get<double>());
    // The flow is piecewise affine: one-sided differences are exact up to rounding / alpha.
    EXPECT_LE(best, 1e-10);
    // "one_sided" and "central" are the differences at the reported alpha, the best one.
    const auto at = std::find_if(fd["rows"].begin(), fd["rows"].end(),
                                 [&fd](const Json& row) { return row["alpha"] == fd["alpha"]; });
    ASSERT_NE(at, fd["rows"].end());
    EXPECT_EQ((*at)["one_sided_error"].get<double>(), best);
    const Eigen::VectorXd image = vector_of(direction["image"]);
    EXPECT_LE((vector_of(fd["one_sided"]) - image).norm(), best * std::max(1.0, image.norm()) * 2);
    EXPECT_EQ(fd["central"].size(), 2u);
  }
}

// The biped of [B] Section 3.2.4 falls from (0, 1, 0, 0, 0, 0) and lands on both feet at once.
// Conservative and dissipative: the two pieces of the touchdown jump are one matrix ([B]
// (3.7): the saltations commute), so directions landing foot 0 first and foot 1 first get the
// same Jacobian; mode-damping: they differ. In every case the derivative agrees with one-sided
// differences of the simulated flow.
TEST(FlowCommandTest, BipedVariantsAgreeWithFiniteDifferences) {
  const BipedTouchdown touchdown = biped_touchdown(BipedParams{});
  for (const std::string variant : {"conservative", "dissipative", "mode-damping"}) {
    SCOPED_TRACE(variant);
    FlowCommandOptions options = biped({"variant=" + variant});
    options.rtol = "1e-10";
    options.atol = "1e-12";
    // Foot 1 first (+theta: foot 1 lowered), foot 0 first (-theta), then smooth directions.
    options.dx = {"0,0,1,0,0,0", "0,0,-1,0,0,0", "1,0,0,0,0,1", "0,1,0,0,0,0"};
    options.fd = true;
    const Json out = result_of(options);
    EXPECT_EQ(out["params"]["variant"], variant);
    EXPECT_EQ(out["t"], 0.6);
    EXPECT_EQ(vector_of(out["x0"]), Eigen::VectorXd(biped_initial_state()));
    ASSERT_EQ(out["events"].size(), 1u);
    const Json& event = out["events"][0];
    EXPECT_THAT(event["surfaces"].get<std::vector<int>>(), ElementsAre(0, 1));
    EXPECT_EQ(event["sides_before"], "--");
    EXPECT_EQ(event["sides_after"], "++");
    // Free fall until touchdown is a quadratic, which dopri5 integrates exactly.
    EXPECT_NEAR(event["t"].get<double>(), touchdown.time, 1e-12);
    EXPECT_LE((vector_of(event["rho"]) - Eigen::VectorXd(touchdown.state)).norm(), 1e-11);
    const Json& up = out["directions"][0];
    const Json& down = out["directions"][1];
    EXPECT_THAT(up["orders"][0].get<std::vector<int>>(), ElementsAre(1, 0));
    EXPECT_THAT(down["orders"][0].get<std::vector<int>>(), ElementsAre(0, 1));
    const Eigen::MatrixXd j_up = matrix_of(up["jacobian"]);
    const Eigen::MatrixXd j_down = matrix_of(down["jacobian"]);
    if (variant == "mode-damping") {
      EXPECT_GT((j_up - j_down).norm(), 0.1 * j_up.norm()) << "no kink";
    } else {
      EXPECT_LE((j_up - j_down).norm(), 1e-12 * j_up.norm());
    }
    for (const Json& direction : out["directions"]) {
      double best = 1e300;
      for (const Json& row : direction["fd"]["rows"]) {
        best = std::min(best, row["one_sided_error"].get<double>());
      }
      // Measured 3e-8 to 1e-7 (truncation O(alpha) against integration noise / alpha).
      EXPECT_LT(best, 1e-5) << direction["dx"];
      EXPECT_LE((matrix_of(direction["jacobian"]) * vector_of(direction["dx"]) -
                 vector_of(direction["image"]))
                    .norm(),
                1e-12 * std::max(1.0, vector_of(direction["image"]).norm()));
    }
    // Central differences average both pieces: wrong along +-theta only with the kink.
    double central = 1e300;
    for (const Json& row : up["fd"]["rows"]) {
      central = std::min(central, row["central_error"].get<double>());
    }
    if (variant == "mode-damping") {
      EXPECT_GT(central, 1e-2);
    } else {
      EXPECT_LT(central, 1e-5);
    }
  }
}

TEST(FlowCommandTest, BipedDefaultsAreTheRestStartAndSixUnitDirections) {
  const Json out = result_of(biped({}));
  EXPECT_EQ(out["params"]["variant"], "mode-damping");
  EXPECT_EQ(out["params"]["kappa"], 1.0);
  EXPECT_EQ(out["params"]["leg_length"], 0.5);
  EXPECT_EQ(out["t"], 0.6);
  ASSERT_EQ(out["directions"].size(), 6u);
  for (int i = 0; i < 6; ++i) {
    EXPECT_EQ(vector_of(out["directions"][static_cast<std::size_t>(i)]["dx"]),
              Eigen::VectorXd::Unit(6, i));
  }
  // Parameters change the scene: a stiffer ground, a later final time.
  FlowCommandOptions options = biped({"kappa=100", "beta=2.5"});
  options.t = "0.45";
  const Json stiff = result_of(options);
  EXPECT_EQ(stiff["params"]["kappa"], 100.0);
  EXPECT_EQ(stiff["params"]["beta"], 2.5);
  EXPECT_EQ(stiff["t"], 0.45);
  EXPECT_NE(stiff["x_t"], out["x_t"]);
}

TEST(FlowCommandTest, EarlyStopPrintsStatusAndExitsOne) {
  FlowCommandOptions options = biped({});
  options.max_steps = "1";
  const Outcome o = flow(options);
  EXPECT_EQ(o.code, 1);
  EXPECT_THAT(o.err, StartsWith("error: flow: the simulation stopped at t = "));
  EXPECT_THAT(o.err, HasSubstr("(too many steps): dop853: max_steps = 1 steps taken, stopped at "
                               "t = "));
  EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1);
  const Json out = Json::parse(o.out);
  EXPECT_EQ(out["status"], "too many steps");
  EXPECT_THAT(out["message"].get<std::string>(), HasSubstr("max_steps"));
  EXPECT_LT(out["t_reached"].get<double>(), 0.6);
  EXPECT_TRUE(out["events"].is_array());
  EXPECT_FALSE(out.contains("x_t"));
  EXPECT_FALSE(out.contains("directions"));
}

TEST(FlowCommandTest, LibraryRejectionsExitTwoWithFlowPrefix) {
  // x0 on surface 0: its side is undecided.
  FlowCommandOptions options = pwconst({});
  options.x0 = "0,-1";
  const Outcome o = flow(options);
  EXPECT_EQ(o.code, 2);
  EXPECT_EQ(o.out, "");
  EXPECT_THAT(o.err, StartsWith("error: flow: x0 = [0, -1] has h_0 = 0: its side of surface 0 is "
                                "undecided"));
  EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1);
}

// A named backend is passed through and is the one that runs, or is reported as not built.
TEST(FlowCommandTest, IntegratorIsPassedThrough) {
  for (const std::string name : {"dopri5", "dop853", "cvodes-bdf", "cvodes-adams"}) {
    FlowCommandOptions options = pwconst({});
    options.integrator = name;
    const Outcome o = flow(options);
    if (o.code == 0) {
      EXPECT_EQ(Json::parse(o.out)["integrator"], name);
      EXPECT_EQ(Json::parse(o.out)["backend"], name);
    } else {
      EXPECT_EQ(o.code, 2);
      EXPECT_EQ(o.err, "error: flow: integrator " + name + " is not built\n");
    }
  }
}

struct BadOption {
  std::vector<std::string> args;  // after "bflow flow"
  std::string error;              // the whole line, without "error: " and the newline
};

TEST(FlowCommandTest, MalformedOptionsExitTwoWithOneLine) {
  const std::vector<BadOption> cases = {
      {{}, "--scene: required; the scenes are pwconst, biped and pronk"},
      {{"--scene", "pendulum"},
       "--scene: unknown scene \"pendulum\"; the scenes are pwconst, biped and pronk"},
      {{"--scene", "biped", "--param", "mass=2"},
       "--param: unknown biped parameter \"mass\" (known: m, J, g, leg_length, psi, kappa, beta, "
       "thrust, thrust_speed, variant)"},
      {{"--scene", "biped", "--param", "kappa=-1"},
       "--param: biped parameter \"kappa\" must be > 0, got -1"},
      {{"--scene", "biped", "--param", "kappa=stiff"},
       "--param: biped parameter \"kappa\" = \"stiff\" is not a number"},
      {{"--scene", "biped", "--param", "variant=bouncy"},
       "--param: biped variant \"bouncy\" is not one of conservative, dissipative, mode-damping"},
      {{"--scene", "biped", "--param", "kappa"}, "--param: \"kappa\" is not key=value"},
      {{"--scene", "biped", "--param", "kappa=2", "--param", "kappa=3"},
       "--param: \"kappa\" is given twice"},
      {{"--scene", "pwconst", "--param", "kappa=2"},
       "--param: unknown pwconst parameter \"kappa\" (known: d, delta, seed)"},
      {{"--scene", "pwconst", "--param", "d=0"},
       "--param: pwconst parameter \"d\" must be an integer in [1, 16], got \"0\""},
      {{"--scene", "pwconst", "--param", "d=2.5"},
       "--param: pwconst parameter \"d\" must be an integer in [1, 16], got \"2.5\""},
      {{"--scene", "pwconst", "--param", "delta=1"},
       "--param: pwconst parameter \"delta\" must be in (-1, 1) (every component of Delta(b) = "
       "-delta b must exceed -1), got \"1\""},
      {{"--scene", "pwconst", "--param", "seed=-3"},
       "--param: pwconst parameter \"seed\" must be an integer in [0, 2^64), got \"-3\""},
      {{"--scene", "pwconst", "--param", "delta=0.1", "--param", "seed=3"},
       "--param: give delta (the linear case) or seed (a random Delta), not both"},
      {{"--scene", "pwconst", "--t", "-1"}, "--t: must be >= 0, got -1"},
      {{"--scene", "pwconst", "--t", "soon"}, "--t: \"soon\" is not a number"},
      {{"--scene", "pwconst", "--t", "1e999"}, "--t: \"1e999\" is out of the range of a double"},
      {{"--scene", "pwconst", "--t", "nan"}, "--t: \"nan\" is not a finite number"},
      {{"--scene", "pwconst", "--rtol", "0"},
       "--rtol: must be >= 1e-15 (below that no step can meet it in double precision), got 0"},
      // 1e-300 used to shrink the steps forever.
      {{"--scene", "pwconst", "--rtol", "1e-300"},
       "--rtol: must be >= 1e-15 (below that no step can meet it in double precision), got "
       "1e-300"},
      {{"--scene", "pwconst", "--atol", "-1e-9"},
       "--atol: must be >= 1e-20 (below that the field's rounding alone makes the steps tiny), got "
       "-1e-09"},
      // 1e-300 made every step of the biped's orbit tiny: a million per simulation.
      {{"--scene", "biped", "--atol", "1e-300"},
       "--atol: must be >= 1e-20 (below that the field's rounding alone makes the steps tiny), got "
       "1e-300"},
      {{"--scene", "pwconst", "--integrator", "euler"},
       "--integrator: integrator \"euler\" is unknown; choose auto, dopri5, dop853, cvodes-bdf "
       "or cvodes-adams"},
      {{"--scene", "pwconst", "--max-steps", "0"}, "--max-steps: must be >= 1, got 0"},
      {{"--scene", "pwconst", "--grouping", "often"},
       "--grouping: grouping \"often\" is unknown; choose auto, window or none"},
      {{"--scene", "pwconst", "--grouping", "window"}, "--grouping: window needs --window T"},
      {{"--scene", "pwconst", "--window", "1e-9"}, "--window: needs --grouping window"},
      {{"--scene", "pwconst", "--grouping", "window", "--window", "-1"},
       "--window: must be finite and >= 0, got -1"},
      {{"--scene", "pwconst", "--x0", "1,2,3"},
       "--x0: has 3 numbers, expected d = 2 (comma-separated)"},
      {{"--scene", "pwconst", "--x0", "1,x"}, "--x0[1]: \"x\" is not a number"},
      {{"--scene", "pwconst", "--x0", "1,"}, "--x0[1]: expected a number, got an empty string"},
      {{"--scene", "biped", "--dx", "1,0,0,0,0,0", "--dx", "1,0"},
       "--dx[1]: has 2 numbers, expected d = 6 (comma-separated)"},
      {{"--scene", "pwconst", "--param", "d=3", "--dx", "1,0"},
       "--dx[0]: has 2 numbers, expected d = 3 (comma-separated)"},
  };
  for (const BadOption& c : cases) {
    std::vector<std::string> args = {"flow"};
    args.insert(args.end(), c.args.begin(), c.args.end());
    const Outcome o = command_line(args);
    std::string joined;
    for (const auto& a : args) joined += a + " ";
    EXPECT_EQ(o.code, 2) << joined;
    EXPECT_EQ(o.out, "") << joined;
    EXPECT_EQ(o.err, "error: " + c.error + "\n") << joined;
  }
}

TEST(FlowCommandTest, CommandLineParsesNegativeNumbersAndRepeatedDirections) {
  const Outcome o =
      command_line({"flow", "--scene", "pwconst", "--param", "d=2", "--param", "delta=-0.5", "--dx",
                    "-1,0", "--dx=0,-2", "--t", "1", "--compact"});
  ASSERT_EQ(o.code, 0) << o.err;
  EXPECT_EQ(std::count(o.out.begin(), o.out.end(), '\n'), 1);  // --compact: one line
  const Json out = Json::parse(o.out);
  // (1 - delta)/(1 + delta) = 3 for delta = -1/2.
  EXPECT_LE((vector_of(out["directions"][0]["image"]) - Eigen::Vector2d(-3, 0)).norm(), 1e-12);
  EXPECT_LE((vector_of(out["directions"][1]["image"]) - Eigen::Vector2d(0, -6)).norm(), 1e-12);

  const Outcome unknown = command_line({"flow", "--scene", "pwconst", "--frobnicate"});
  EXPECT_EQ(unknown.code, 2);
  EXPECT_THAT(unknown.err, StartsWith("error: flow: "));
  EXPECT_THAT(unknown.err, HasSubstr("--frobnicate"));
  EXPECT_THAT(unknown.err, HasSubstr("(see 'bflow flow --help')"));

  const Outcome help = command_line({"flow", "--help"});
  EXPECT_EQ(help.code, 0);
  EXPECT_THAT(help.out, HasSubstr("--scene NAME"));
  EXPECT_THAT(help.out, HasSubstr("\"directions\""));
}

// The default scene's two planes crossed 1e-8 apart (F_-- = 1.25: x0_1 is 1.25e-8 further):
// beyond the automatic window (1.6e-9), inside the band: two events, a notice in the JSON and one
// warning line. With --grouping window --window 1e-7 they are one event and nothing is said.
TEST(FlowCommandTest, NearSimultaneousCrossingsAreReportedInTheJsonAndOnStderr) {
  Outcome o = command_line({"flow", "--scene", "pwconst", "--x0", "-0.625,-0.6250000125"});
  ASSERT_EQ(o.code, 0) << o.err;
  Json out = Json::parse(o.out);
  EXPECT_EQ(out["grouping"], "auto");
  ASSERT_EQ(out["events"].size(), 2u);
  EXPECT_NEAR(out["events"][0]["gap"].get<double>(), 1e-8, 1e-15);
  ASSERT_EQ(out["notices"].size(), 1u);
  EXPECT_EQ(out["notices"][0]["kind"], "near-simultaneous");
  EXPECT_EQ(out["notices"][0]["surfaces"], Json({0, 1}));
  EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1);
  EXPECT_THAT(o.err, StartsWith("warning: near-simultaneous crossings not grouped: surfaces [0]"));

  o = command_line({"flow", "--scene", "pwconst", "--x0", "-0.625,-0.6250000125", "--grouping",
                    "window", "--window", "1e-7"});
  ASSERT_EQ(o.code, 0) << o.err;
  EXPECT_EQ(o.err, "");
  out = Json::parse(o.out);
  EXPECT_EQ(out["window"], 1e-7);
  ASSERT_EQ(out["events"].size(), 1u);
  EXPECT_EQ(out["events"][0]["surfaces"], Json({0, 1}));
  EXPECT_NEAR(out["events"][0]["spread"].get<double>(), 1e-8, 1e-15);
  EXPECT_TRUE(out["events"][0]["gap"].is_null());
  EXPECT_TRUE(out["notices"].empty());
}

TEST(FlowCommandTest, ZeroTimeIsTheIdentity) {
  FlowCommandOptions options = biped({});
  options.t = "0";
  const Json out = result_of(options);
  EXPECT_EQ(out["events"].size(), 0u);
  for (const Json& direction : out["directions"]) {
    EXPECT_EQ(vector_of(direction["image"]), vector_of(direction["dx"]));
    EXPECT_EQ(direction["orders"].size(), 0u);
  }
}

// ---------------------------------------------------------------------------------------------
// The options' edges: empty values, numbers that underflow, offending text quoted short.

const std::string kUnderflow =
    " underflows: a nonzero number must be at least 2.2250738585072014e-308 (the smallest normal "
    "double) in magnitude";

// Every option of flow that takes a value, given '' (CLI11 took it as the default), is refused
// naming it; so are the same scene options of sweep, which go through the same checks.
TEST(FlowCommandTest, EmptyValuesAreRefusedNamingTheOption) {
  const std::vector<std::vector<std::string>> options = {
      {"--scene"},      {"--param"},    {"--t"},
      {"--x0"},         {"--dx"},       {"--rtol"},
      {"--atol"},       {"--grouping"}, {"--grouping", "window", "--window"},
      {"--integrator"}, {"--max-steps"}};
  for (const char* command : {"flow", "sweep"}) {
    for (const std::vector<std::string>& option : options) {
      std::vector<std::string> args = {command};
      if (option[0] != "--scene") args.insert(args.end(), {"--scene", "pwconst"});
      if (std::string(command) == "sweep") args.insert(args.end(), {"--vary", "0=-1:-0.5:2"});
      args.insert(args.end(), option.begin(), option.end());
      args.push_back("");
      const Outcome o = command_line(args);
      SCOPED_TRACE(::testing::PrintToString(args));
      EXPECT_EQ(o.code, 2);
      EXPECT_EQ(o.out, "");
      EXPECT_EQ(o.err, "error: " + option.back() + ": the value is empty\n");
    }
  }
  // In-process, the same check (an empty optional is "not given", an empty string is not).
  FlowCommandOptions given = pwconst({});
  given.t = "";
  EXPECT_EQ(flow(given).err, "error: --t: the value is empty\n");
  given = pwconst({""});
  EXPECT_EQ(flow(given).err, "error: --param: the value is empty\n");
  given = pwconst({});
  given.integrator = "";
  EXPECT_EQ(flow(given).err, "error: --integrator: the value is empty\n");
}

// A number that underflows (strtod's ERANGE with 0 or a subnormal, or nonzero text read as 0)
// is refused as one that overflows is, naming the option and the text: --t 1e-400 used to run
// to t = 0.
TEST(FlowCommandTest, NumbersThatUnderflowAreRefused) {
  const std::vector<BadOption> cases = {
      {{"--scene", "pwconst", "--t", "1e-400"}, "--t: \"1e-400\"" + kUnderflow},
      {{"--scene", "pwconst", "--t", "5e-324"}, "--t: \"5e-324\"" + kUnderflow},
      {{"--scene", "pwconst", "--t", "0x1p-1074"}, "--t: \"0x1p-1074\"" + kUnderflow},
      {{"--scene", "pwconst", "--t", "2e-308"}, "--t: \"2e-308\"" + kUnderflow},
      {{"--scene", "pwconst", "--t", "0.0000e-999"}, ""},  // zero, written so: not refused
      {{"--scene", "pwconst", "--x0", "-0.5, 1e-330"}, "--x0[1]: \"1e-330\"" + kUnderflow},
      {{"--scene", "pwconst", "--dx", "1e-400,0"}, "--dx[0][0]: \"1e-400\"" + kUnderflow},
      {{"--scene", "pwconst", "--rtol", "1e-400"}, "--rtol: \"1e-400\"" + kUnderflow},
      {{"--scene", "pwconst", "--atol", "-1e-310"}, "--atol: \"-1e-310\"" + kUnderflow},
      {{"--scene", "pwconst", "--grouping", "window", "--window", "1e-320"},
       "--window: \"1e-320\"" + kUnderflow},
      {{"--scene", "pwconst", "--param", "delta=1e-400"},
       "--param: pwconst parameter \"delta\" = \"1e-400\"" + kUnderflow},
      {{"--scene", "pwconst", "--param", "delta=1e999"},
       "--param: pwconst parameter \"delta\" = \"1e999\" is out of the range of a double"},
      {{"--scene", "biped", "--param", "kappa=1e-320"},
       "--param: biped parameter \"kappa\" = \"1e-320\"" + kUnderflow},
      {{"--scene", "biped", "--param", "beta=-3e-400"},
       "--param: biped parameter \"beta\" = \"-3e-400\"" + kUnderflow},
      {{"--scene", "biped", "--param", "m=1e999"},
       "--param: biped parameter \"m\" = \"1e999\" is out of the range of a double"},
  };
  for (const BadOption& c : cases) {
    std::vector<std::string> args = {"flow"};
    args.insert(args.end(), c.args.begin(), c.args.end());
    const Outcome o = command_line(args);
    SCOPED_TRACE(::testing::PrintToString(args));
    if (c.error.empty()) {
      EXPECT_EQ(o.code, 0) << o.err;
      continue;
    }
    EXPECT_EQ(o.code, 2);
    EXPECT_EQ(o.out, "");
    EXPECT_EQ(o.err, "error: " + c.error + "\n");
  }
  // The smallest normal double is a time like any other, and so is a spaced biped value.
  EXPECT_EQ(command_line({"flow", "--scene", "pwconst", "--t", "2.2250738585072014e-308"}).code, 0);
  EXPECT_EQ(command_line({"flow", "--scene", "biped", "--param", "kappa= 2 ", "--t", "0"}).code, 0);
}

// What the user typed reaches the error line as a bounded, printable prefix: a 131 KB value or
// key, an unknown option of 131 KB (CLI11's message), bytes that are not UTF-8 and control
// characters, in whichever option they come.
TEST(FlowCommandTest, OffendingTextIsQuotedShortAndPrintable) {
  const std::string huge(131072, '7');
  const std::string cut = std::string(60, '7') + "...";
  const std::vector<BadOption> cases = {
      {{"--scene", "biped", "--param", "kappa=x" + huge},
       "--param: biped parameter \"kappa\" = \"x" + std::string(59, '7') + "...\" is not a number"},
      {{"--scene", "biped", "--param", huge + "=1"},
       "--param: unknown biped parameter \"" + cut +
           "\" (known: m, J, g, leg_length, psi, kappa, beta, thrust, thrust_speed, variant)"},
      {{"--scene", "biped", "--param", "variant=" + huge},
       "--param: biped variant \"" + cut +
           "\" is not one of conservative, dissipative, mode-damping"},
      {{"--scene", "pwconst", "--param", "d=" + huge},
       "--param: pwconst parameter \"d\" must be an integer in [1, 16], got \"" + cut + "\""},
      {{"--scene", "pwconst", "--param", "delta=" + huge},
       "--param: pwconst parameter \"delta\" = \"" + cut + "\" is out of the range of a double"},
      {{"--scene", "pwconst", "--param", huge}, "--param: \"" + cut + "\" is not key=value"},
      {{"--scene", "pwconst", "--t", "x" + huge},
       "--t: \"x" + std::string(59, '7') + "...\" is not a number"},
      {{"--scene", "pwconst", "--integrator", huge},
       "--integrator: integrator \"" + cut +
           "\" is unknown; choose auto, dopri5, dop853, cvodes-bdf or cvodes-adams"},
      {{"--scene", "pwconst", "--grouping", huge},
       "--grouping: grouping \"" + cut + "\" is unknown; choose auto, window or none"},
      {{"--scene", "pwconst", "--max-steps", huge},
       "--max-steps: \"" + cut + "\" is too large (at most 1000000000)"},
      {{"--scene", huge},
       "--scene: unknown scene \"" + cut + "\"; the scenes are pwconst, biped and pronk"},
      // Bytes that are not UTF-8 as \xNN, control characters as \u00NN, UTF-8 kept.
      {{"--scene", "\xff\xfe\x01x\xc3\xa9"},
       "--scene: unknown scene \"\\xff\\xfe\\u0001x\xc3\xa9\"; the scenes are pwconst, biped and "
       "pronk"},
      {{"--scene", "pwconst", "--param", "d=\xe2\x88\x92\x31"},
       "--param: pwconst parameter \"d\" must be an integer in [1, 16], got \"\xe2\x88\x92\x31\""},
      {{"--scene", "pwconst", "--param", "delta=\xe2\x88"},
       "--param: pwconst parameter \"delta\" = \"\\xe2\\x88\" is not a number"},
  };
  for (const BadOption& c : cases) {
    std::vector<std::string> args = {"flow"};
    args.insert(args.end(), c.args.begin(), c.args.end());
    const Outcome o = command_line(args);
    SCOPED_TRACE(c.error.substr(0, 40));
    EXPECT_EQ(o.code, 2);
    EXPECT_EQ(o.out, "");
    EXPECT_EQ(o.err, "error: " + c.error + "\n");
    EXPECT_LT(o.err.size(), 300u);
  }
  const Outcome unknown = command_line({"flow", "--scene", "pwconst", "--" + huge});
  EXPECT_EQ(unknown.code, 2);
  EXPECT_THAT(unknown.err, StartsWith("error: flow: "));
  EXPECT_THAT(unknown.err, HasSubstr("--7777"));
  EXPECT_LT(unknown.err.size(), 300u);
  EXPECT_EQ(std::count(unknown.err.begin(), unknown.err.end(), '\n'), 1);
  const Outcome stray = command_line({"flow", "--scene", "pwconst", "\xff\x02"});
  EXPECT_EQ(stray.code, 2);
  EXPECT_THAT(stray.err, HasSubstr("\\xff\\u0002"));
}

// quote(): code points, not bytes, are counted and never cut; what is not printable is escaped.
TEST(QuoteTest, CountsCodePointsAndEscapesWhatIsNotPrintable) {
  EXPECT_EQ(quote("\xe2\x88\x92+"), "\"\xe2\x88\x92+\"");
  EXPECT_EQ(quote("\xe2\x88\x92\xe2\x88\x92\xe2\x88\x92", 2), "\"\xe2\x88\x92\xe2\x88\x92...\"");
  EXPECT_EQ(quote("ab", 2), "\"ab\"");
  EXPECT_EQ(quote("abc", 2), "\"ab...\"");
  EXPECT_EQ(quote("\xf0\x9f\x98\x80", 1), "\"\xf0\x9f\x98\x80\"");  // U+1F600, four bytes
  EXPECT_EQ(quote("a\"b\\c"), "\"a\\\"b\\\\c\"");
  EXPECT_EQ(quote("\n\x7f\xc2\x85"), "\"\\u000a\\u007f\\u0085\"");  // C0, DEL, C1 (NEL)
  EXPECT_EQ(quote("\xe2\x80\xa8"), "\"\\u2028\"");
  // Not UTF-8: a stray continuation byte, a cut sequence, an overlong '/', a surrogate, a code
  // point above U+10FFFF; each byte escaped and counted as one character.
  EXPECT_EQ(quote("\x80"), "\"\\x80\"");
  EXPECT_EQ(quote("\xe2\x88"), "\"\\xe2\\x88\"");
  EXPECT_EQ(quote("\xc0\xaf"), "\"\\xc0\\xaf\"");
  EXPECT_EQ(quote("\xed\xa0\x80"), "\"\\xed\\xa0\\x80\"");
  EXPECT_EQ(quote("\xf4\x90\x80\x80", 2), "\"\\xf4\\x90...\"");
  EXPECT_EQ(one_line("a\nb\xff"), "a b\\xff");
  std::size_t length = 0;
  EXPECT_EQ(quote_character("x\xe2\x88\x92", 1, length), "\"\xe2\x88\x92\" (U+2212)");
  EXPECT_EQ(length, 3u);
  EXPECT_EQ(quote_character("\xff", 0, length), "\"\\xff\"");
  EXPECT_EQ(length, 1u);
}

// ---------------------------------------------------------------------------------------------
// Overflow: finite options, a computation that leaves the double range. Exit code 1 with the
// record computed so far, "status": "overflow"; never exit code 2 (the input is well-formed).

TEST(FlowCommandTest, OverflowingStartIsAFailedComputation) {
  struct Case {
    std::string x0;
    std::string what;  // the first overflow the command saw
  };
  // -1e100: the state stays finite, the tangents through the touchdown do not (the library ends
  // flow_derivative with an InvalidArgument). -1e300: |F| = 1e300 has no finite norm, so the
  // state itself leaves the double range in the first step.
  for (const Case& c : {Case{"0,1,0,0,-1e100,0",
                             "F_++ or its derivative on the tangents is not "
                             "finite at x = [0, -"},
                        Case{"0,1,0,0,-1e300,0",
                             "|F_--| is beyond the double range at x = "
                             "[0, 1, 0, 0, -1e+300, 0]; the library then "
                             "reported: flow_derivative: the simulation ended "
                             "with non-finite state"}}) {
    SCOPED_TRACE(c.x0);
    FlowCommandOptions options = biped({});
    options.x0 = c.x0;
    const Outcome o = flow(options);
    EXPECT_EQ(o.code, 1);
    EXPECT_THAT(o.err, StartsWith("error: flow: the computation overflowed: " + c.what));
    EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1);
    const Json out = Json::parse(o.out);
    EXPECT_EQ(out["scene"], "biped");
    EXPECT_EQ(vector_of(out["x0"])[4], std::stod(c.x0.substr(8)));
    EXPECT_EQ(out["status"], "overflow");
    EXPECT_THAT(out["message"].get<std::string>(), StartsWith(c.what));
    EXPECT_FALSE(out.contains("x_t"));
    EXPECT_FALSE(out.contains("directions"));
  }
}

// The hopping biped of `bflow orbit` 1e306 below the ground: its contact forces are inf - inf
// from the start. The integrator's first step was NaN and the command never returned; now the
// run stops at t = 0 naming the field's row, and the record is printed.
TEST(FlowCommandTest, StartFarBelowTheGroundStopsAtOnceNamingTheField) {
  FlowCommandOptions options =
      biped({"variant=mode-damping", "kappa=1000", "beta=4", "thrust=10", "thrust_speed=0.1"});
  options.x0 = "0,-1e306,0,0,0,0";
  const auto start = std::chrono::steady_clock::now();
  const Outcome o = flow(options);
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 2.0);
  EXPECT_EQ(o.code, 1);
  EXPECT_EQ(o.err,
            "error: flow: the simulation stopped at t = 0 before t = 0.6 (non-finite state): "
            "dop853: F_b(x) row 3 is non-finite (nan) at t = 0, x = [0, -1e+306, 0, 0, 0, 0] "
            "(b = \"++\")\n");
  const Json out = Json::parse(o.out);
  EXPECT_EQ(out["status"], "non-finite state");
  EXPECT_EQ(out["t_reached"], 0.0);
  EXPECT_FALSE(out.contains("x_t"));
  // The default biped: its field overflows instead (|F| beyond the double range).
  FlowCommandOptions plain = biped({});
  plain.x0 = "0,-1e306,0,0,0,0";
  const Outcome p = flow(plain);
  EXPECT_EQ(p.code, 1);
  EXPECT_THAT(p.err, StartsWith("error: flow: the computation overflowed: |F_++| is beyond the "
                                "double range at x = [0, -1e+306, 0, 0, 0, 0]"));
}

// An atol at the minimum is an ordinary tolerance: the biped's run takes as long as at 1e-12.
TEST(FlowCommandTest, SmallestAtolRunsLikeAnyOther) {
  FlowCommandOptions options = biped({});
  options.atol = "1e-20";
  const auto start = std::chrono::steady_clock::now();
  const Json out = result_of(options);
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 2.0);
  EXPECT_EQ(out["atol"], 1e-20);
  EXPECT_TRUE(out.contains("x_t"));
}

// B is linear on each piece: a direction scaled by 1e300 has the image scaled by 1e300; at
// 1e308 the image leaves the double range, and the trajectory, computed, is still printed.
TEST(FlowCommandTest, DirectionWhoseImageOverflowsIsAFailedComputation) {
  FlowCommandOptions unit = biped({});
  unit.dx = {"1,0,0,0,0,0"};
  const Json reference = result_of(unit);
  const Eigen::VectorXd image = vector_of(reference["directions"][0]["image"]);

  FlowCommandOptions large = biped({});
  large.dx = {"1e300,0,0,0,0,0"};
  const Json scaled = result_of(large);
  EXPECT_LT((vector_of(scaled["directions"][0]["image"]) / 1e300 - image).norm(),
            1e-15 * image.norm());

  FlowCommandOptions huge = biped({});
  huge.dx = {"1e308,0,0,0,0,0"};
  const Outcome o = flow(huge);
  EXPECT_EQ(o.code, 1);
  // FlowDerivative refuses the tangent it carried beyond the range (it used to return inf).
  EXPECT_EQ(o.err,
            "error: flow: the computation overflowed: directions[0]: FlowDerivative::apply: the "
            "tangent at the final time is beyond the double range\n");
  const Json out = Json::parse(o.out);
  EXPECT_EQ(out["status"], "overflow");
  EXPECT_EQ(out["message"],
            "directions[0]: FlowDerivative::apply: the tangent at the final time is beyond the "
            "double range");
  EXPECT_EQ(out["x_t"], reference["x_t"]);
  EXPECT_EQ(out["events"], reference["events"]);
  EXPECT_FALSE(out.contains("directions"));
}

// ---------------------------------------------------------------------------------------------
// Output that cannot be written.

// Refuses every write.
class FailingBuffer : public std::streambuf {
 protected:
  int_type overflow(int_type) override { return traits_type::eof(); }
  std::streamsize xsputn(const char*, std::streamsize) override { return 0; }
};

// Takes every write, fails every flush.
class FailingFlushBuffer : public std::stringbuf {
 protected:
  int sync() override { return -1; }
};

const char* const kWriteFailed = "error: stdout: write failed\n";

TEST(FinishOutputTest, WrittenOutputKeepsTheCode) {
  for (int code : {kExitOk, kExitFailure, kExitBadInput}) {
    std::ostringstream out, err;
    out << "result\n";
    EXPECT_EQ(finish_output(out, err, code), code);
    EXPECT_EQ(err.str(), "");
  }
}

TEST(FinishOutputTest, FailedWriteIsOneLineAndExitCodeOne) {
  FailingBuffer failing;
  std::ostream out(&failing);
  std::ostringstream err;
  out << "result\n";
  EXPECT_EQ(finish_output(out, err, kExitOk), kExitFailure);
  EXPECT_EQ(err.str(), kWriteFailed);
  // Idempotent: the entry point and main() both call it.
  EXPECT_EQ(finish_output(out, err, kExitFailure), kExitFailure);
  EXPECT_EQ(err.str(), kWriteFailed);
}

TEST(FinishOutputTest, FailedCommandKeepsItsCodeAndItsOneLine) {
  FailingBuffer failing;
  std::ostream out(&failing);
  out << "partial\n";
  for (int code : {kExitFailure, kExitBadInput}) {
    std::ostringstream err;
    EXPECT_EQ(finish_output(out, err, code), code);
    EXPECT_EQ(err.str(), "");
  }
}

TEST(FinishOutputTest, FailedFlushIsAFailedWrite) {
  FailingFlushBuffer failing;
  std::ostream out(&failing);
  std::ostringstream err;
  out << "result\n";
  ASSERT_TRUE(out.good());
  EXPECT_EQ(finish_output(out, err, kExitOk), kExitFailure);
  EXPECT_EQ(err.str(), kWriteFailed);
}

// /dev/full: every write(2) fails with ENOSPC. The buffer keeps that errno, however many other
// calls overwrite errno before the command ends.
TEST(FinishOutputTest, StdioBufferNamesTheErrnoOfTheFirstFailure) {
  for (std::size_t size : {std::size_t{1}, std::size_t{1} << 20}) {  // fails on flush, on write
    SCOPED_TRACE(size);
    std::FILE* file = std::fopen("/dev/full", "w");
    ASSERT_NE(file, nullptr) << std::strerror(errno);
    StdioOutputBuffer buffer(file);
    std::ostream out(&buffer);
    std::ostringstream err;
    out << std::string(size, 'x');
    errno = EINVAL;
    EXPECT_EQ(finish_output(out, err, kExitOk), kExitFailure);
    EXPECT_TRUE(buffer.failed());
    EXPECT_EQ(buffer.error_number(), ENOSPC);
    EXPECT_EQ(err.str(),
              "error: stdout: write failed (" + std::string(std::strerror(ENOSPC)) + ")\n");
    std::fclose(file);
  }
}

TEST(FlowCommandTest, UnwritableOutputExitsOneWithOneLine) {
  FailingBuffer failing;
  std::ostream out(&failing);
  {
    std::ostringstream err;
    EXPECT_EQ(run_flow(pwconst({}), out, err), kExitFailure);
    EXPECT_EQ(err.str(), kWriteFailed);
  }
  {
    // A simulation that stops early has its own line; the lost partial record adds none.
    FlowCommandOptions options = biped({});
    options.max_steps = "1";
    std::ostringstream err;
    EXPECT_EQ(run_flow(options, out, err), kExitFailure);
    const std::string line = err.str();
    EXPECT_THAT(line, StartsWith("error: flow: the simulation stopped at t = "));
    EXPECT_EQ(std::count(line.begin(), line.end(), '\n'), 1);
  }
  {
    FlowCommandOptions options = pwconst({});
    options.scene = "pendulum";
    std::ostringstream err;
    EXPECT_EQ(run_flow(options, out, err), kExitBadInput);
    const std::string line = err.str();
    EXPECT_THAT(line, StartsWith("error: --scene: unknown scene \"pendulum\""));
    EXPECT_EQ(std::count(line.begin(), line.end(), '\n'), 1);
  }
}

}  // namespace
}  // namespace bflow::cli

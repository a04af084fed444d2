// `bflow orbit` in-process: the hopping biped's orbit (the command's defaults) is a fixed point of
// the flow itself, simulated here for one period with bflow::simulate on a biped built from the
// JSON's parameters; a family along thrust converges point by point; pwconst, which has no
// periodic orbit, is a failed computation (exit code 1) with the library's message; every
// malformed option is one line naming the option and the value (exit code 2); --plot draws
// non-empty PNGs from data that hold the orbit.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bflow/core/biped.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "bflow/orbits/periodic_orbit.h"
#include "cli_commands.h"
#include "orbit_json.h"
#include "support/run_command.h"

namespace bflow::cli {
namespace {

using bflow::testing::command_line;
using bflow::testing::Outcome;

using ::testing::HasSubstr;
using ::testing::StartsWith;
using Json = nlohmann::json;
namespace fs = std::filesystem;

using bflow::testing::columns_of;
using bflow::testing::gnuplot_on_path;
using bflow::testing::vector_of;

Outcome orbit(const OrbitCommandOptions& options) {
  return bflow::testing::run_orbit_command(options);
}

BipedParams params_of(const Json& params) {
  return bflow::testing::params_from_json<BipedParams>(params);
}

// One period of the biped of `params` by a plain simulation (orbit_json.h).
bflow::testing::PeriodReturn simulate_one_period(const Json& params, const Eigen::VectorXd& x,
                                                 double period) {
  return visit_biped(params_of(params), [&](const auto& scene) {
    return bflow::testing::one_period(adapt(scene), x, period);
  });
}

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream stream(text);
  for (std::string line; std::getline(stream, line);) lines.push_back(line);
  return lines;
}

OrbitCommandOptions biped() {
  OrbitCommandOptions o;
  o.scene = "biped";
  o.compact = true;
  return o;
}

TEST(OrbitCommandTest, BipedDefaultsFindTheHoppingOrbit) {
  const Outcome r = orbit(biped());
  ASSERT_EQ(r.code, kExitOk) << r.err;
  const Json j = Json::parse(r.out);
  // The orbit's defaults, all printed.
  EXPECT_EQ(j["scene"], "biped");
  EXPECT_EQ(j["params"]["variant"], "mode-damping");
  EXPECT_EQ(j["params"]["kappa"], 1000.0);
  EXPECT_EQ(j["params"]["beta"], 4.0);
  EXPECT_EQ(j["params"]["thrust"], 10.0);
  EXPECT_EQ(j["params"]["thrust_speed"], 0.1);
  EXPECT_EQ(j["section"], "-x4");
  EXPECT_EQ(j["rtol"], 1e-10);
  EXPECT_EQ(j["atol"], 1e-12);
  EXPECT_EQ(vector_of(j["x0"]), (Eigen::VectorXd(6) << 0, 0.8, 0, 0, 0, 0).finished());

  ASSERT_TRUE(j["converged"].get<bool>()) << j["message"];
  EXPECT_EQ(j["message"], "");
  const Eigen::VectorXd x = vector_of(j["x"]);
  const double period = j["period"].get<double>();
  EXPECT_EQ(x[4], 0.0);  // on the section
  EXPECT_GT(period, 0.0);
  EXPECT_LE(j["residual"].get<double>(), 1e-8 * (1.0 + x.lpNorm<Eigen::Infinity>()));
  EXPECT_LE(j["correction"].get<double>(), 1e-8 * (1.0 + x.lpNorm<Eigen::Infinity>()));

  // The independent check: x is a fixed point of the flow after one period, reached rising.
  const bflow::testing::PeriodReturn back = simulate_one_period(j["params"], x, period);
  EXPECT_LE(back.error, 1e-6);
  EXPECT_GT(back.ydot_before, 0.0);

  // Both events cross both feet's surfaces: four pieces, each 5 x 5 on the section.
  ASSERT_EQ(j["events"].size(), 2u);
  for (const Json& e : j["events"]) {
    EXPECT_EQ(e["surfaces"], Json({0, 1}));
    EXPECT_EQ(e["group_size"], 2);
  }
  const Json& map = j["return_map"];
  EXPECT_FALSE(map["is_linear"].get<bool>());
  EXPECT_EQ(map["piece_count"], 4.0);
  ASSERT_EQ(map["pieces"].size(), 4u);
  for (const Json& piece : map["pieces"]) {
    EXPECT_EQ(piece["orders"].size(), 2u);
    ASSERT_EQ(piece["matrix"].size(), 5u);
    EXPECT_EQ(piece["matrix"][0].size(), 5u);
  }
  // B: orthonormal columns orthogonal to the section's normal e_4.
  const Eigen::MatrixXd basis = columns_of(map["tangent_basis"]);
  ASSERT_EQ(basis.rows(), 6);
  ASSERT_EQ(basis.cols(), 5);
  EXPECT_LE((basis.transpose() * basis - Eigen::MatrixXd::Identity(5, 5)).norm(), 1e-14);
  EXPECT_LE(basis.row(4).norm(), 1e-14);

  // The verdict and its bracket.
  const double lower = j["growth_rate_lower"].get<double>();
  const double upper = j["growth_rate_upper"].get<double>();
  EXPECT_EQ(j["stability"], "unstable");
  EXPECT_GT(lower, 1.0);
  EXPECT_LE(lower, upper);
  EXPECT_EQ(j["multipliers"], nullptr);      // piecewise linear: no Floquet multipliers
  EXPECT_EQ(j["decisions"], Json::array());  // every Newton step taken whole

  // The same model, section and guess through the library: the command passes them on.
  BipedParams p = params_of(j["params"]);
  const PeriodicOrbit direct = visit_biped(p, [](const auto& scene) {
    const auto model = adapt(scene);
    Eigen::VectorXd guess(6);
    guess << 0, 0.8, 0, 0, 0, 0;
    return find_periodic_orbit(model, CoordinateSection{4, 0.0, -1.0}, guess);
  });
  ASSERT_TRUE(direct.converged);
  EXPECT_EQ(direct.period, period);
  EXPECT_EQ(j["newton_iterations"], direct.newton_iterations);
  EXPECT_STREQ(to_string(direct.stability), "unstable");

  // One progress line per Newton step, nothing else.
  const std::vector<std::string> lines = lines_of(r.err);
  ASSERT_EQ(lines.size(), j["newton_steps"].size());
  EXPECT_EQ(static_cast<int>(lines.size()), j["newton_iterations"].get<int>() + 1);
  for (const std::string& line : lines) EXPECT_THAT(line, StartsWith("orbit: newton "));
}

TEST(OrbitCommandTest, FamilyAlongThrustConvergesAtEveryValue) {
  OrbitCommandOptions o = biped();
  o.vary_param = "thrust=9:11:3";
  const Outcome r = orbit(o);
  ASSERT_EQ(r.code, kExitOk) << r.err;
  const Json j = Json::parse(r.out);
  EXPECT_EQ(j["vary_param"], Json({{"key", "thrust"}, {"lo", 9.0}, {"hi", 11.0}, {"count", 3}}));
  ASSERT_EQ(j["family"].size(), 3u);
  const double values[] = {9.0, 10.0, 11.0};
  double last_period = 0.0;
  for (std::size_t k = 0; k < 3; ++k) {
    const Json& m = j["family"][k];
    SCOPED_TRACE(k);
    EXPECT_EQ(m["value"], values[k]);
    ASSERT_TRUE(m["converged"].get<bool>()) << m["message"];
    EXPECT_EQ(m["stability"], "unstable");
    EXPECT_LE(m["growth_rate_lower"].get<double>(), m["growth_rate_upper"].get<double>());
    // More thrust, a higher hop: a longer period.
    EXPECT_GT(m["period"].get<double>(), last_period);
    last_period = m["period"].get<double>();
    Json params = j["params"];
    params["thrust"] = values[k];
    const bflow::testing::PeriodReturn back =
        simulate_one_period(params, vector_of(m["x"]), m["period"].get<double>());
    EXPECT_LE(back.error, 1e-6);
  }
  // thrust = 10 is the orbit of the defaults, found again from the orbit at 9.
  EXPECT_NEAR(j["family"][1]["period"].get<double>(), j["period"].get<double>(), 1e-9);
  // The Newton steps of the first orbit, then one line per orbit of the family.
  std::vector<std::string> members;
  for (const std::string& line : lines_of(r.err)) {
    if (line.rfind("orbit: thrust = ", 0) == 0) members.push_back(line);
  }
  ASSERT_EQ(members.size(), 3u);
  EXPECT_THAT(members[2], StartsWith("orbit: thrust = 11 (3/3)  period "));
  EXPECT_THAT(members[2], HasSubstr("unstable"));
}

TEST(OrbitCommandTest, PwconstHasNoOrbitAndFailsWithTheLibrarysMessage) {
  const fs::path file = fs::path(::testing::TempDir()) / "bflow_orbit_pwconst.json";
  fs::remove(file);
  OrbitCommandOptions o;
  o.scene = "pwconst";
  o.output = file.string();
  const Outcome r = orbit(o);
  EXPECT_EQ(r.code, kExitFailure);
  EXPECT_EQ(r.out, "");  // the JSON went to --output
  std::ifstream in(file);
  const Json j = Json::parse(in);
  EXPECT_EQ(j["section"], "x0=1");
  EXPECT_FALSE(j["converged"].get<bool>());
  const std::string message = j["message"];
  EXPECT_THAT(message, HasSubstr("no crossing of the section from s < 0 to s > 0"));
  EXPECT_EQ(j["period"], nullptr);
  EXPECT_EQ(j["return_map"], nullptr);
  EXPECT_EQ(j["stability"], nullptr);
  EXPECT_EQ(r.err, "error: orbit: no periodic orbit found: " + message + "\n");
  fs::remove(file);
}

TEST(OrbitCommandTest, SectionStartingWithMinusIsReadAsTheValue) {
  const Outcome r =
      command_line({"orbit", "--scene", "pwconst", "--section", "-x1=0.3", "--quiet", "--compact"});
  EXPECT_EQ(r.code, kExitFailure);
  EXPECT_EQ(Json::parse(r.out)["section"], "-x1=0.3");
}

TEST(OrbitCommandTest, MalformedOptionsExitTwoWithOneLineNamingThem) {
  const std::string section_syntax =
      " (write x4, -x4, x1=0.3 or -x1=0.3: s = +-(x_i - value), crossed from s < 0 to s > 0)";
  struct Case {
    std::vector<std::string> args;
    std::string line;
  };
  const std::vector<Case> cases = {
      {{"--section", "y4"},
       "--section: section \"y4\": expected x followed by a state index" + section_syntax},
      {{"--section", "x6"},
       "--section: section \"x6\": state index 6 is not below the 6 states" + section_syntax},
      {{"--vary-param", "thrust=1:2"},
       "--vary-param: \"thrust=1:2\" is not KEY=LO:HI:COUNT (three fields after '=', separated "
       "by ':')"},
      {{"--vary-param", "nokey=1:2:3"},
       "--vary-param: \"nokey=1:2:3\": unknown biped parameter \"nokey\" (known: m, J, g, "
       "leg_length, psi, kappa, beta, thrust, thrust_speed, variant)"},
      {{"--vary-param", "thrust=1:2:1"},
       "--vary-param: \"thrust=1:2:1\": COUNT must be >= 2 (a family of orbits from LO to HI), "
       "got 1"},
      {{"--vary-param", "thrust=one:2:3"}, "--vary-param thrust LO: \"one\" is not a number"},
      {{"--vary-param", "thrust=-1:2:3"},
       "--vary-param: \"thrust=-1:2:3\": biped parameter \"thrust\" must be >= 0, got -1"},
      {{"--param", "thrust=5", "--vary-param", "thrust=1:2:3"},
       "--vary-param: thrust is also fixed by --param \"thrust=5\"; give it either fixed or "
       "varied"},
      {{"--x0", "1,2"}, "--x0: has 2 numbers, expected d = 6 (comma-separated)"},
      {{"--tol", "0"}, "--tol: Newton's tolerance must be finite and > 0, got 0"},
      {{"--max-iterations", "-1"}, "--max-iterations: \"-1\" is too small (at least 0)"},
      {{"--param", "kappa=-1"}, "--param: biped parameter \"kappa\" must be > 0, got -1"},
      {{"--section", ""}, "--section: the value is empty"},
      {{"--section", "-x4=1e-400"},
       "--section: section \"-x4=1e-400\": \"1e-400\" underflows (its magnitude is below "
       "2.2250738585072014e-308)" +
           section_syntax},
      {{"--vary-param", "thrust=1e-320:1e-300:5"},
       "--vary-param thrust LO: \"1e-320\" underflows: a nonzero number must be at least "
       "2.2250738585072014e-308 (the smallest normal double) in magnitude"},
      // Both ends valid; HI - LO is beyond the double range, the values are not.
      {{"--vary-param", "thrust=-1e308:1e308:2"},
       "--vary-param: \"thrust=-1e308:1e308:2\": biped parameter \"thrust\" must be >= 0, got "
       "-1e+308"},
      // 1e-20 is the least atol; 1e-300 made every step tiny (75 s for the orbit).
      {{"--atol", "1e-300"},
       "--atol: must be >= 1e-20 (below that the field's rounding alone makes the steps tiny), got "
       "1e-300"},
  };
  for (const Case& c : cases) {
    std::vector<std::string> args = {"orbit", "--scene", "biped"};
    args.insert(args.end(), c.args.begin(), c.args.end());
    SCOPED_TRACE(::testing::PrintToString(args));
    const Outcome r = command_line(args);
    EXPECT_EQ(r.code, kExitBadInput);
    EXPECT_EQ(r.out, "");
    EXPECT_EQ(r.err, "error: " + c.line + "\n");
  }
  const Outcome pwconst = command_line({"orbit", "--scene", "pwconst", "--vary-param", "d=2:3:2"});
  EXPECT_EQ(pwconst.code, kExitBadInput);
  EXPECT_EQ(pwconst.err,
            "error: --vary-param: d changes the dimension of the state (d = 2 to 3); it cannot "
            "vary along a family\n");
  const Outcome none = command_line({"orbit"});
  EXPECT_EQ(none.err, "error: --scene: required; the scenes are pwconst, biped and pronk\n");
}

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// A guard against the runs without end these inputs used to cause, not a speed target: each run
// takes well under a second in Release and about 2 s under the sanitizers on a loaded machine.
constexpr double kNoHangSeconds = 30.0;

// Ends in 5e-310 at the third of five values: refused before the first orbit (it used to stop the
// family at its third orbit, through --param, which was never given, with the JSON lost).
TEST(OrbitCommandTest, EveryValueOfTheFamilyIsCheckedBeforeTheFirstOrbit) {
  const Outcome r =
      command_line({"orbit", "--scene", "biped", "--vary-param", "g=-1e-307:1.01e-307:5"});
  EXPECT_EQ(r.code, kExitBadInput);
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(r.err,
            "error: --vary-param: \"g=-1e-307:1.01e-307:5\": value 3 of 5, g = "
            "5.00000000000003e-310, underflows: a nonzero number must be at least "
            "2.2250738585072014e-308 (the smallest normal double) in magnitude; move LO or HI away "
            "from 0 or change COUNT\n");
}

// HI - LO = 2e308 is beyond the double range; the values are -1e308, 0 and 1e308 (they were NaN).
TEST(OrbitCommandTest, RangeWiderThanTheDoubleRangeHasFiniteValues) {
  const auto start = std::chrono::steady_clock::now();
  const Outcome r = command_line(
      {"orbit", "--scene", "biped", "--vary-param", "g=-1e308:1e308:3", "--quiet", "--compact"});
  EXPECT_LT(seconds_since(start), kNoHangSeconds);
  EXPECT_EQ(r.code, kExitFailure);  // no orbit at these g: a result, not bad input
  const Json j = Json::parse(r.out);
  ASSERT_EQ(j["family"].size(), 3u);
  EXPECT_EQ(j["family"][0]["value"], -1e308);
  EXPECT_EQ(j["family"][1]["value"], 0.0);
  EXPECT_EQ(j["family"][2]["value"], 1e308);
  EXPECT_THAT(r.err, StartsWith("error: orbit: "));
  EXPECT_THAT(r.err, ::testing::Not(HasSubstr("nan")));
}

// A guess 1e306 below the ground (its contact forces are inf - inf) and the least atol: each
// ends within its bound with a named result. Both used to run without end or for minutes.
TEST(OrbitCommandTest, FarGuessAndSmallestAtolEndQuickly) {
  auto start = std::chrono::steady_clock::now();
  const Outcome far = command_line(
      {"orbit", "--scene", "biped", "--x0", "0,-1e306,0,0,0,0", "--quiet", "--compact"});
  EXPECT_LT(seconds_since(start), kNoHangSeconds);
  EXPECT_EQ(far.code, kExitFailure);
  const Json j = Json::parse(far.out);
  EXPECT_FALSE(j["converged"].get<bool>());
  EXPECT_EQ(far.err,
            "error: orbit: no periodic orbit found: " + j["message"].get<std::string>() + "\n");

  start = std::chrono::steady_clock::now();
  const Outcome tight =
      command_line({"orbit", "--scene", "biped", "--atol", "1e-20", "--quiet", "--compact"});
  EXPECT_LT(seconds_since(start), kNoHangSeconds);
  ASSERT_EQ(tight.code, kExitOk) << tight.err;
  EXPECT_EQ(Json::parse(tight.out)["atol"], 1e-20);
}

// 100 000 characters of input give an error line of at most a few hundred.
TEST(OrbitCommandTest, LongInputIsQuotedShort) {
  const std::string huge(100000, 'k');
  const std::vector<std::vector<std::string>> cases = {
      {"--section", "-x4=" + huge},
      {"--section", huge},
      {"--vary-param", huge + "=1:2:3"},
      {"--vary-param", huge + "=x:2:3"},
      {"--vary-param", "thrust=" + huge + ":2:3"},
      {"--vary-param", "thrust=1:2:" + huge},
      {"--output", huge, "--plot", huge},
      {"--output", huge, "--plot", huge + "/x"},
  };
  for (const std::vector<std::string>& c : cases) {
    std::vector<std::string> args = {"orbit", "--scene", "biped"};
    args.insert(args.end(), c.begin(), c.end());
    SCOPED_TRACE(c[0] + " " + c[1].substr(0, 20));
    const Outcome r = command_line(args);
    EXPECT_EQ(r.code, kExitBadInput);
    EXPECT_EQ(r.out, "");
    EXPECT_LT(r.err.size(), 500u) << r.err.substr(0, 200);
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1);
  }
}

// --output that --plot needs (the directory, one above it, a file drawn there) is refused before
// anything is created or computed.
TEST(OrbitCommandTest, OutputThatThePlotNeedsIsRefusedFirst) {
  const fs::path dir = fs::path(::testing::TempDir()) / "bflow_orbit_clash";
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string d = (dir / "D").string();
  struct Case {
    std::vector<std::string> args;
    std::string line;
  };
  const std::vector<Case> cases = {
      {{"--plot", d, "--output", d},
       "--output: \"" + d + "\" is also the --plot directory \"" + d + "\"; name another file"},
      {{"--plot", d + "/", "--output", d},
       "--output: \"" + d + "\" is also the --plot directory \"" + d + "/\"; name another file"},
      {{"--plot", d + "/sub", "--output", d},
       "--output: \"" + d + "\" is a directory above the --plot directory \"" + d +
           "/sub\"; name another file"},
      {{"--plot", d, "--output", d + "/orbit.csv"},
       "--output: \"" + d + "/orbit.csv\" is also the plot's orbit.csv (--plot); " +
           "name another file"},
      {{"--plot", d, "--output", d + "/x/../growth_rate.png", "--vary-param", "thrust=10:11:2"},
       "--output: \"" + d + "/x/../growth_rate.png\" is also the plot's " +
           "growth_rate.png (--plot); name another file"},
  };
  for (const Case& c : cases) {
    std::vector<std::string> args = {"orbit", "--scene", "biped"};
    args.insert(args.end(), c.args.begin(), c.args.end());
    SCOPED_TRACE(::testing::PrintToString(args));
    const Outcome r = command_line(args);
    EXPECT_EQ(r.code, kExitBadInput);
    EXPECT_EQ(r.out, "");
    EXPECT_EQ(r.err, "error: " + c.line + "\n");
    EXPECT_FALSE(fs::exists(dir / "D"));
  }
  // A directory of that name already there: the same refusal, and it stays empty.
  fs::create_directories(dir / "D");
  const Outcome again = command_line({"orbit", "--scene", "biped", "--plot", d, "--output", d});
  EXPECT_EQ(again.code, kExitBadInput);
  EXPECT_TRUE(fs::is_empty(dir / "D"));
  fs::remove_all(dir);
}

// An --output whose directory is missing, is a file or refuses files (/proc, even to root) is
// refused before the first Newton step (no progress line) with one line naming it, and nothing
// is created.
TEST(OrbitCommandTest, OutputThatCannotBeWrittenIsRefusedBeforeAnyOrbit) {
  const fs::path dir = fs::path(::testing::TempDir()) / "bflow_orbit_unwritable";
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream(dir / "file") << "x";
  const std::string missing = (dir / "missing" / "orbit.json").string();
  const std::string under_file = (dir / "file" / "orbit.json").string();
  struct Case {
    std::string output;
    std::string line;
  };
  const std::vector<Case> cases = {
      {missing, "orbit: cannot write \"" + missing + "\": its directory \"" +
                    (dir / "missing").string() + "\" does not exist"},
      {under_file, "orbit: cannot write \"" + under_file + "\": its directory \"" +
                       (dir / "file").string() + "\" is not a directory"},
      {"/proc/bflow-orbit.json", "orbit: cannot write in directory \"/proc\": "},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.output);
    const Outcome r = command_line({"orbit", "--scene", "biped", "--output", c.output});
    EXPECT_EQ(r.code, kExitFailure);
    EXPECT_EQ(r.out, "");
    EXPECT_THAT(r.err, StartsWith("error: " + c.line));
    EXPECT_EQ(lines_of(r.err).size(), 1u) << r.err;
  }
  EXPECT_FALSE(fs::exists(dir / "missing"));
  EXPECT_FALSE(fs::exists("/proc/bflow-orbit.json"));
  std::vector<fs::path> left;
  for (const auto& entry : fs::directory_iterator(dir)) left.push_back(entry.path());
  EXPECT_EQ(left, std::vector<fs::path>{dir / "file"});
  fs::remove_all(dir);
}

TEST(OrbitCommandTest, PlotDrawsTheOrbitAndTheGrowthRate) {
  if (!gnuplot_on_path()) GTEST_SKIP() << "gnuplot is not installed";
  const fs::path dir = fs::path(::testing::TempDir()) / "bflow_orbit_plot";
  fs::remove_all(dir);
  OrbitCommandOptions o = biped();
  o.quiet = true;
  o.vary_param = "thrust=10:11:2";
  o.plot = (dir / "nested").string();
  const Outcome r = orbit(o);
  ASSERT_EQ(r.code, kExitOk) << r.err;
  EXPECT_EQ(r.err, "");
  for (const char* png : {"orbit.png", "growth_rate.png"}) {
    const fs::path file = dir / "nested" / png;
    ASSERT_TRUE(fs::exists(file)) << file;
    EXPECT_GT(fs::file_size(file), 1000u) << file;
  }
  // orbit.csv: one period from the fixed point back to it.
  const Json j = Json::parse(r.out);
  const Eigen::VectorXd x = vector_of(j["x"]);
  std::ifstream csv(dir / "nested" / "orbit.csv");
  std::string line;
  std::getline(csv, line);
  EXPECT_EQ(line, "t,x,y,theta,xdot,ydot,thetadot");
  std::vector<Eigen::VectorXd> rows;
  while (std::getline(csv, line)) {
    std::replace(line.begin(), line.end(), ',', ' ');
    std::istringstream numbers(line);
    Eigen::VectorXd row(7);
    for (int i = 0; i < 7; ++i) numbers >> row[i];
    rows.push_back(row);
  }
  ASSERT_GE(rows.size(), 100u);
  EXPECT_EQ(rows.front()[0], 0.0);
  EXPECT_EQ(rows.front().tail(6), x);
  EXPECT_EQ(rows.back()[0], j["period"].get<double>());
  EXPECT_LE((rows.back().tail(6) - x).lpNorm<Eigen::Infinity>(), 1e-6);
  // family.csv: a header and one row per orbit.
  std::ifstream family(dir / "nested" / "family.csv");
  std::vector<std::string> family_lines;
  while (std::getline(family, line)) family_lines.push_back(line);
  ASSERT_EQ(family_lines.size(), 3u);
  EXPECT_THAT(family_lines[0],
              StartsWith("thrust,converged,period,growth_rate_lower,growth_rate_upper,stability"));
  EXPECT_THAT(family_lines[2], StartsWith("11,1,"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace bflow::cli

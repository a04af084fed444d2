// The pronking body on the command line: `bflow orbit --scene pronk` with no other option finds
// its stable hop (the fixed point checked by one period of bflow::simulate on a pronk built from
// the JSON's parameters); a family along J keeps the orbit and moves the verdict across 1; a
// family along thrust stays stable; `bflow flow --scene pronk` lands both feet together when
// free fall says; bad parameters are one line naming them; --plot draws the orbit.
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

#include "bflow/core/pronk.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
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

using bflow::testing::gnuplot_on_path;
using bflow::testing::rows_of;
using bflow::testing::vector_of;

Outcome orbit(const OrbitCommandOptions& options) {
  return bflow::testing::run_orbit_command(options);
}

// One period of the pronk of `params` by a plain simulation (orbit_json.h).
bflow::testing::PeriodReturn simulate_one_period(const Json& params, const Eigen::VectorXd& x,
                                                 double period) {
  return bflow::testing::one_period(
      adapt(make_pronk(bflow::testing::params_from_json<PronkParams>(params))), x, period);
}

OrbitCommandOptions pronk() {
  OrbitCommandOptions o;
  o.scene = "pronk";
  o.compact = true;
  return o;
}

TEST(PronkCommandTest, OrbitWithNoOptionIsTheStableHop) {
  const Outcome r = orbit(pronk());
  ASSERT_EQ(r.code, kExitOk) << r.err;
  const Json j = Json::parse(r.out);
  // The scene's own defaults, all printed; the apex section; the guess at rest at height 1.
  EXPECT_EQ(j["scene"], "pronk");
  EXPECT_EQ(j["params"],
            Json::parse(R"({"m":1.0,"J":0.25,"g":9.8,"hip":0.5,"leg_length":0.5,"kappa":300.0,
                            "beta":4.0,"thrust":10.0,"thrust_speed":0.1,"tether":1.0,
                            "tether_damping":1.0})"));
  EXPECT_EQ(j["section"], "-x4");
  EXPECT_EQ(vector_of(j["x0"]), (Eigen::VectorXd(6) << 0, 1, 0, 0, 0, 0).finished());

  ASSERT_TRUE(j["converged"].get<bool>()) << j["message"];
  EXPECT_EQ(j["message"], "");
  const Eigen::VectorXd x = vector_of(j["x"]);
  const double period = j["period"].get<double>();
  EXPECT_EQ(x[4], 0.0);  // on the section
  EXPECT_LE(j["residual"].get<double>(), 1e-8 * (1.0 + x.lpNorm<Eigen::Infinity>()));
  EXPECT_LE(j["newton_iterations"].get<int>(), 4);
  // The hop of core/pronk.h (and tests/orbits/pronk_orbit_test.cc's hand hop).
  EXPECT_NEAR(x[1], 0.977396, 1e-6);
  EXPECT_NEAR(period, 0.764871, 1e-6);

  // Independent: x is a fixed point of the flow after one period, reached rising.
  const bflow::testing::PeriodReturn back = simulate_one_period(j["params"], x, period);
  EXPECT_LE(back.error, 1e-6);
  EXPECT_GT(back.ydot_before, 0.0);

  // Both events cross both feet: four pieces, 5 x 5 on the section, all different.
  ASSERT_EQ(j["events"].size(), 2u);
  for (const Json& e : j["events"]) {
    EXPECT_EQ(e["surfaces"], Json({0, 1}));
    EXPECT_EQ(e["group_size"], 2);
  }
  const Json& map = j["return_map"];
  EXPECT_FALSE(map["is_linear"].get<bool>());
  EXPECT_EQ(map["piece_count"], 4.0);
  ASSERT_EQ(map["pieces"].size(), 4u);
  std::vector<Eigen::MatrixXd> pieces;
  for (const Json& piece : map["pieces"]) {
    EXPECT_EQ(piece["orders"].size(), 2u);
    pieces.push_back(rows_of(piece["matrix"]));
    ASSERT_EQ(pieces.back().rows(), 5);
    ASSERT_EQ(pieces.back().cols(), 5);
  }
  for (std::size_t a = 0; a < pieces.size(); ++a) {
    for (std::size_t b = a + 1; b < pieces.size(); ++b) {
      EXPECT_GT((pieces[a] - pieces[b]).norm(), 1e-2 * pieces[a].norm()) << a << " " << b;
    }
  }

  // The verdict: stable with a clear margin.
  const double lower = j["growth_rate_lower"].get<double>();
  const double upper = j["growth_rate_upper"].get<double>();
  EXPECT_EQ(j["stability"], "stable");
  EXPECT_GT(lower, 0.0);
  EXPECT_LE(lower, upper);
  EXPECT_LT(upper, 0.8);
  EXPECT_EQ(j["multipliers"], nullptr);  // piecewise linear: no Floquet multipliers
  EXPECT_EQ(j["decisions"], Json::array());
  EXPECT_EQ(j["notices"], Json::array());

  // One progress line per Newton step, each naming the two surfaces crossed at once.
  std::istringstream lines(r.err);
  int count = 0;
  for (std::string line; std::getline(lines, line); ++count) {
    EXPECT_THAT(line, StartsWith("orbit: newton "));
    EXPECT_THAT(line, HasSubstr("(up to 2 surfaces at once)"));
  }
  EXPECT_EQ(count, j["newton_iterations"].get<int>() + 1);
}

// The section y = 0.9 crossed downwards, from the scene's guess at rest at height 1, and the
// apex at a loose Newton tolerance: both find the stable hop (apex 0.977396, period 0.764871).
// Through 0.9 the body falls at -sqrt(2 g (apex - 0.9)) = -1.231.
TEST(PronkCommandTest, DownwardSectionAndLooseToleranceFindTheHop) {
  OrbitCommandOptions down = pronk();
  down.section = "-x1=0.9";
  down.quiet = true;
  const Outcome r = orbit(down);
  ASSERT_EQ(r.code, kExitOk) << r.err;
  const Json j = Json::parse(r.out);
  ASSERT_TRUE(j["converged"].get<bool>()) << j["message"];
  const Eigen::VectorXd x = vector_of(j["x"]);
  EXPECT_NEAR(x[1], 0.9, 1e-14);
  EXPECT_NEAR(x[4], -std::sqrt(2.0 * 9.8 * (0.977396 - 0.9)), 1e-5);
  EXPECT_NEAR(j["period"].get<double>(), 0.764871, 1e-6);
  EXPECT_EQ(j["stability"], "stable");

  for (const char* tol : {"2e-3", "1e-2"}) {
    OrbitCommandOptions loose = pronk();
    loose.tol = tol;
    loose.quiet = true;
    const Outcome l = orbit(loose);
    ASSERT_EQ(l.code, kExitOk) << tol << ": " << l.err;
    const Json k = Json::parse(l.out);
    ASSERT_TRUE(k["converged"].get<bool>()) << k["message"];
    EXPECT_NEAR(vector_of(k["x"])[1], 0.977396, 10.0 * std::stod(tol));
  }
}

TEST(PronkCommandTest, FamilyAlongJKeepsTheOrbitAndCrossesTheVerdict) {
  OrbitCommandOptions o = pronk();
  o.quiet = true;
  o.vary_param = "J=0.22:0.26:3";
  const Outcome r = orbit(o);
  ASSERT_EQ(r.code, kExitOk) << r.err;
  EXPECT_EQ(r.err, "");
  const Json j = Json::parse(r.out);
  EXPECT_EQ(j["vary_param"], Json({{"key", "J"}, {"lo", 0.22}, {"hi", 0.26}, {"count", 3}}));
  ASSERT_EQ(j["family"].size(), 3u);
  // J does not enter the vertical hop: the same orbit, found at once from the last one.
  const char* verdicts[] = {"unstable", "stable", "stable"};
  for (std::size_t k = 0; k < 3; ++k) {
    const Json& m = j["family"][k];
    SCOPED_TRACE(k);
    ASSERT_TRUE(m["converged"].get<bool>()) << m["message"];
    EXPECT_NEAR(m["period"].get<double>(), j["period"].get<double>(), 1e-9);
    EXPECT_EQ(m["stability"], verdicts[k]);
    EXPECT_LE(m["growth_rate_lower"].get<double>(), m["growth_rate_upper"].get<double>());
  }
  EXPECT_GT(j["family"][0]["growth_rate_lower"].get<double>(), 1.0);
  EXPECT_LT(j["family"][2]["growth_rate_upper"].get<double>(), 1.0);
  EXPECT_EQ(j["family"][2]["newton_iterations"], 0);
}

TEST(PronkCommandTest, FamilyAlongThrustStaysStable) {
  OrbitCommandOptions o = pronk();
  o.vary_param = "thrust=8:12:3";
  const Outcome r = orbit(o);
  ASSERT_EQ(r.code, kExitOk) << r.err;
  const Json j = Json::parse(r.out);
  ASSERT_EQ(j["family"].size(), 3u);
  double last_period = 0.0;
  for (std::size_t k = 0; k < 3; ++k) {
    const Json& m = j["family"][k];
    SCOPED_TRACE(k);
    ASSERT_TRUE(m["converged"].get<bool>()) << m["message"];
    EXPECT_EQ(m["stability"], "stable");
    EXPECT_LT(m["growth_rate_upper"].get<double>(), 0.8);
    // More thrust, a higher hop: a longer period.
    EXPECT_GT(m["period"].get<double>(), last_period);
    last_period = m["period"].get<double>();
    Json params = j["params"];
    params["thrust"] = m["value"];
    const bflow::testing::PeriodReturn back =
        simulate_one_period(params, vector_of(m["x"]), m["period"].get<double>());
    EXPECT_LE(back.error, 1e-6);
  }
  EXPECT_NEAR(j["family"][1]["period"].get<double>(), j["period"].get<double>(), 1e-9);
  // The Newton steps of the first orbit, then one line per orbit of the family.
  std::vector<std::string> members;
  std::istringstream lines(r.err);
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind("orbit: thrust = ", 0) == 0) members.push_back(line);
  }
  ASSERT_EQ(members.size(), 3u);
  EXPECT_THAT(members[2], StartsWith("orbit: thrust = 12 (3/3)  period "));
  EXPECT_THAT(members[2], HasSubstr("stable"));
}

TEST(PronkCommandTest, FlowLandsBothFeetWhenFreeFallSays) {
  const Outcome r = command_line({"flow", "--scene", "pronk", "--compact"});
  ASSERT_EQ(r.code, kExitOk) << r.err;
  const Json j = Json::parse(r.out);
  EXPECT_EQ(j["scene"], "pronk");
  EXPECT_EQ(j["t"], 0.6);
  EXPECT_EQ(vector_of(j["x0"]), (Eigen::VectorXd(6) << 0, 1, 0, 0, 0, 0).finished());
  // From rest at height 1 the feet (0.5 below the body) reach the ground after falling 0.5:
  // t = sqrt(2 0.5 / 9.8), both at once; then both lift off together.
  ASSERT_EQ(j["events"].size(), 2u);
  EXPECT_NEAR(j["events"][0]["t"].get<double>(), std::sqrt(1.0 / 9.8), 1e-8);
  EXPECT_EQ(j["events"][0]["surfaces"], Json({0, 1}));
  EXPECT_EQ(j["events"][1]["surfaces"], Json({0, 1}));
  EXPECT_EQ(j["directions"].size(), 6u);
}

TEST(PronkCommandTest, BadParametersAreOneLineNamingThem) {
  struct Case {
    std::vector<std::string> args;
    std::string line;
  };
  const std::vector<Case> cases = {
      {{"orbit", "--scene", "pronk", "--param", "psi=1"},
       "--param: unknown pronk parameter \"psi\" (known: m, J, g, hip, leg_length, kappa, beta, "
       "thrust, thrust_speed, tether, tether_damping)"},
      {{"orbit", "--scene", "pronk", "--param", "J=-1"},
       "--param: pronk parameter \"J\" must be > 0, got -1"},
      {{"orbit", "--scene", "pronk", "--vary-param", "tether=-1:1:3"},
       "--vary-param: \"tether=-1:1:3\": pronk parameter \"tether\" must be >= 0, got -1"},
      {{"flow", "--scene", "pronk", "--param", "hip=wide"},
       "--param: pronk parameter \"hip\" = \"wide\" is not a number"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(::testing::PrintToString(c.args));
    const Outcome r = command_line(c.args);
    EXPECT_EQ(r.code, kExitBadInput);
    EXPECT_EQ(r.out, "");
    EXPECT_EQ(r.err, "error: " + c.line + "\n");
  }
}

TEST(PronkCommandTest, PlotDrawsTheOrbitAndTheFamily) {
  if (!gnuplot_on_path()) GTEST_SKIP() << "gnuplot is not installed";
  const fs::path dir = fs::path(::testing::TempDir()) / "bflow_pronk_plot";
  fs::remove_all(dir);
  OrbitCommandOptions o = pronk();
  o.quiet = true;
  o.vary_param = "J=0.24:0.26:2";
  o.plot = dir.string();
  const Outcome r = orbit(o);
  ASSERT_EQ(r.code, kExitOk) << r.err;
  for (const char* png : {"orbit.png", "growth_rate.png"}) {
    EXPECT_GT(fs::file_size(dir / png), 1000u) << png;
  }
  std::ifstream csv(dir / "orbit.csv");
  std::string line;
  std::getline(csv, line);
  EXPECT_EQ(line, "t,x,y,theta,xdot,ydot,thetadot");
  fs::remove_all(dir);
}

}  // namespace
}  // namespace bflow::cli

// `bflow demo` in-process, both scenes (biped, the default, and pwconst): the printed tables
// and data files hold the library's numbers, and a missing gnuplot, an unusable directory (before
// anything is computed), output that cannot be written or an unknown scene is reported on one
// line with a non-zero code.
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <streambuf>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Core>

#include "bflow/core/biped.h"
#include "bflow/core/flow_derivative.h"
#include "bflow/core/jump_map.h"
#include "bflow/examples/piecewise_constant.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "cli_commands.h"
#include "support/run_command.h"

namespace bflow::cli {
namespace {

using bflow::testing::capture;
using bflow::testing::command_line;
using bflow::testing::Outcome;

using ::testing::EndsWith;
using ::testing::HasSubstr;
using ::testing::Not;
using ::testing::StartsWith;

namespace fs = std::filesystem;

Outcome demo(const fs::path& dir, bool no_plot, const std::string& scene = "pwconst") {
  return capture([&](std::ostream& out, std::ostream& err) {
    return run_demo(DemoOptions{dir.string(), no_plot, scene}, out, err);
  });
}

fs::path fresh_dir(const std::string& name) {
  const fs::path dir = fs::path(::testing::TempDir()) / name;
  fs::remove_all(dir);
  return dir;
}

std::string read(const fs::path& path) {
  std::ifstream file(path);
  std::stringstream text;
  text << file.rdbuf();
  return text.str();
}

// gnuplot's data blocks: two blank lines end an index; comments are skipped.
std::vector<std::vector<std::string>> data_blocks(const std::string& text) {
  std::istringstream dat(text);
  std::vector<std::vector<std::string>> blocks(1);
  std::string line;
  int blank = 0;
  while (std::getline(dat, line)) {
    if (line.empty()) {
      if (++blank == 2) blocks.emplace_back();
      continue;
    }
    blank = 0;
    if (line[0] != '#') blocks.back().push_back(line);
  }
  return blocks;
}

JumpMap planar_jump() {
  const auto model = examples::PiecewiseConstantField::planar_demo();
  return JumpMap(Eigen::MatrixXd::Identity(2, 2), model.limits());
}

TEST(DemoCommandTest, PwconstPrintsTheLibrarysNumbers) {
  const fs::path dir = fresh_dir("demo_table");
  const Outcome o = demo(dir, /*no_plot=*/true);
  ASSERT_EQ(o.code, 0) << o.err;
  EXPECT_EQ(o.err, "");
  // B(1, 0) = M_(0,1) (1, 0) = (0.575, 0.2625): crosses surface 0 at -1, surface 1 at -0.375.
  EXPECT_THAT(o.out, HasSubstr("  0      ( 1.000000,  0.000000)  ( 0.575000,  0.262500)  (0,1)  "
                               "(-1.000000, -0.375000)"));
  // B(0, 1) = M_(1,0) (0, 1) = (4.9/17, 10.9/17).
  EXPECT_THAT(o.out, HasSubstr("  90     ( 0.000000,  1.000000)  ( 0.288235,  0.641176)  (1,0)"));
  // B(F_--) = F_++.
  EXPECT_THAT(o.out, HasSubstr("  F_--   ( 1.000000,  1.000000)  ( 0.700000,  0.700000)"));
  EXPECT_THAT(o.out, HasSubstr("M_(0,1) = [  0.575000  0.125000 ]"));
  EXPECT_THAT(o.out, HasSubstr("M_(1,0) = [  0.411765  0.288235 ]"));
  EXPECT_THAT(o.out, HasSubstr("All checks passed."));
  EXPECT_THAT(o.out, Not(HasSubstr("FAILED")));
  EXPECT_THAT(o.out, Not(HasSubstr("nan")));
  EXPECT_THAT(o.out, HasSubstr("Skipped the plot (--no-plot)"));
  EXPECT_FALSE(fs::exists(dir / "demo_circle.png"));
}

TEST(DemoCommandTest, PwconstDataFileHoldsTheCircleAndItsExactImage) {
  const fs::path dir = fresh_dir("demo_data");
  ASSERT_EQ(demo(dir, /*no_plot=*/true).code, 0);
  const JumpMap jump = planar_jump();
  const auto pieces = jump.pieces();

  const auto blocks = data_blocks(read(dir / "demo_circle.dat"));
  ASSERT_EQ(blocks.size(), 4u);
  EXPECT_EQ(blocks[0].size(), 721u);  // 720 points and the first again
  EXPECT_EQ(blocks[0].front(), blocks[0].back());
  // Two half circles: the 718 samples off the boundary rays, and both rays at the ends of each.
  EXPECT_EQ(blocks[1].size() + blocks[2].size(), 718u + 4u);
  EXPECT_EQ(blocks[3].size(), 2u);
  for (std::size_t b = 0; b < 3; ++b) {
    for (const std::string& row : blocks[b]) {
      std::istringstream fields(row);
      double angle = 0;
      Eigen::Vector2d dx, image;
      int piece = -1;
      fields >> angle >> dx[0] >> dx[1] >> image[0] >> image[1] >> piece;
      ASSERT_TRUE(fields) << row;
      EXPECT_NEAR(dx.norm(), 1.0, 4e-16) << row;
      // Printed round-trip exactly: read back, it is B(dx) to the last bit.
      EXPECT_EQ(image, jump.apply(dx)) << row;
      ASSERT_TRUE(piece == 0 || piece == 1) << row;
      if (b > 0) {
        EXPECT_EQ(piece, static_cast<int>(b) - 1) << row;
        // Arc of piece k: its M_sigma gives B there (ends on the boundary too, B is continuous).
        EXPECT_LE((pieces[static_cast<std::size_t>(piece)].matrix * dx - image).norm(), 1e-15)
            << row;
      } else {
        EXPECT_EQ(pieces[static_cast<std::size_t>(piece)].order, jump.order(dx).order) << row;
      }
    }
  }
  const std::string gp = read(dir / "demo_circle.gp");
  EXPECT_THAT(gp, HasSubstr("set terminal pngcairo size 800,800"));
  EXPECT_THAT(gp,
              HasSubstr("set output (exists('bflow_output') ? bflow_output : 'demo_circle.png')"));
  EXPECT_THAT(gp, HasSubstr("set size ratio -1"));
  EXPECT_THAT(gp, HasSubstr("data = 'demo_circle.dat'"));
}

TEST(DemoCommandTest, PwconstMissingGnuplotIsReportedWithTheCommand) {
  const fs::path dir = fresh_dir("demo_no_gnuplot");
  const fs::path empty_bin = fresh_dir("demo_empty_bin");
  fs::create_directories(empty_bin);
  const char* old_path = std::getenv("PATH");
  const std::string saved = old_path ? old_path : "";
  setenv("PATH", empty_bin.c_str(), 1);
  const Outcome o = demo(dir, /*no_plot=*/false);
  setenv("PATH", saved.c_str(), 1);
  EXPECT_EQ(o.code, 1);
  EXPECT_THAT(o.err, StartsWith("error: demo: cannot run gnuplot demo_circle.gp (in directory \"" +
                                dir.string() + "\"): No such file or directory"));
  EXPECT_THAT(o.err, HasSubstr("--no-plot"));
  EXPECT_THAT(o.err, EndsWith("\n"));
  EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1);
  // The data and the script are there to plot later.
  EXPECT_TRUE(fs::exists(dir / "demo_circle.dat"));
  EXPECT_TRUE(fs::exists(dir / "demo_circle.gp"));
}

TEST(DemoCommandTest, PwconstFailingGnuplotIsReportedWithItsExitStatus) {
  const fs::path dir = fresh_dir("demo_bad_gnuplot");
  const fs::path bin = fresh_dir("demo_fake_bin");
  fs::create_directories(bin);
  std::ofstream(bin / "gnuplot") << "#!/bin/sh\necho 'fake gnuplot: refusing' >&2\nexit 3\n";
  fs::permissions(bin / "gnuplot", fs::perms::owner_all);
  const char* old_path = std::getenv("PATH");
  const std::string saved = old_path ? old_path : "";
  setenv("PATH", bin.c_str(), 1);
  const Outcome o = demo(dir, /*no_plot=*/false);
  setenv("PATH", saved.c_str(), 1);
  EXPECT_EQ(o.code, 1);
  EXPECT_EQ(o.err, "error: demo: gnuplot demo_circle.gp (in directory \"" + dir.string() +
                       "\") failed with exit status 3 (gnuplot's message is above)\n");
  EXPECT_THAT(o.out, Not(HasSubstr("demo_circle.png\n")));
}

TEST(DemoCommandTest, UnusableDirectoryIsReported) {
  const fs::path file = fresh_dir("demo_is_a_file");
  std::ofstream(file) << "not a directory";
  const Outcome o = demo(file, /*no_plot=*/true);
  EXPECT_EQ(o.code, 1);
  EXPECT_THAT(o.err, StartsWith("error: demo: cannot create directory \"" + file.string() + "\""));
  EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1);
}

// The directory is made and probed before anything is computed: nothing is printed. /proc is a
// directory that takes no new file, even for root.
TEST(DemoCommandTest, UnwritableDirectoryIsRefusedBeforeAnythingIsPrinted) {
  for (const std::string scene : {"biped", "pwconst"}) {
    SCOPED_TRACE(scene);
    const Outcome device = demo("/dev/null/x", /*no_plot=*/true, scene);
    EXPECT_EQ(device.code, 1);
    EXPECT_EQ(device.out, "");
    EXPECT_EQ(device.err,
              "error: demo: cannot create directory \"/dev/null/x\": Not a directory\n");
    const Outcome proc = demo("/proc", /*no_plot=*/true, scene);
    EXPECT_EQ(proc.code, 1);
    EXPECT_EQ(proc.out, "");
    EXPECT_THAT(proc.err, StartsWith("error: demo: cannot write in directory \"/proc\": "));
    EXPECT_EQ(std::count(proc.err.begin(), proc.err.end(), '\n'), 1);
  }
}

TEST(DemoCommandTest, ReadOnlyDirectoryIsRefused) {
  if (::geteuid() == 0) GTEST_SKIP() << "root may write in a read-only directory";
  const fs::path dir = fresh_dir("demo_read_only");
  fs::create_directories(dir);
  fs::permissions(dir, fs::perms::owner_read | fs::perms::owner_exec);
  const Outcome o = demo(dir, /*no_plot=*/true);
  fs::permissions(dir, fs::perms::owner_all);
  EXPECT_EQ(o.code, 1);
  EXPECT_EQ(o.out, "");
  EXPECT_EQ(o.err,
            "error: demo: cannot write in directory \"" + dir.string() + "\": Permission denied\n");
  EXPECT_TRUE(fs::is_empty(dir));  // the probe is not left behind
}

// Refuses every write.
class FailingBuffer : public std::streambuf {
 protected:
  int_type overflow(int_type) override { return traits_type::eof(); }
  std::streamsize xsputn(const char*, std::streamsize) override { return 0; }
};

TEST(DemoCommandTest, UnwritableOutputExitsOneWithOneLine) {
  for (const std::string scene : {"biped", "pwconst"}) {
    SCOPED_TRACE(scene);
    const fs::path dir = fresh_dir("demo_unwritable_output_" + scene);
    FailingBuffer failing;
    std::ostream out(&failing);
    std::ostringstream err;
    EXPECT_EQ(run_demo(DemoOptions{dir.string(), /*no_plot=*/true, scene}, out, err), 1);
    EXPECT_EQ(err.str(), "error: stdout: write failed\n");
  }
}

TEST(DemoCommandTest, WritableDirectoryKeepsNoProbe) {
  const fs::path dir = fresh_dir("demo_no_probe");
  const Outcome o = demo(dir, /*no_plot=*/true);
  ASSERT_EQ(o.code, 0) << o.err;
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(dir)) {
    names.push_back(entry.path().filename().string());
  }
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"demo_circle.dat", "demo_circle.gp"}));
}

// ---------------------------------------------------------------------------------------------
// The biped, the default scene.

// The demo's derivative, recomputed: the same scene, start, time and options, so the same bits.
struct BipedRun {
  FlowResult trajectory;
  FlowDerivative derivative{6};
};

BipedRun biped_run() {
  const auto model = adapt(make_biped_mode_damping(BipedParams{}));
  FlowOptions options;
  options.integrator.rtol = 1e-10;
  options.integrator.atol = 1e-12;
  BipedRun run;
  run.derivative = flow_derivative(model, biped_initial_state(), 0.6, options, &run.trajectory);
  return run;
}

std::string row_text(const Eigen::MatrixXd& m, Eigen::Index r) {
  std::string text = "[";
  for (Eigen::Index c = 0; c < m.cols(); ++c) {
    char buffer[32];
    std::snprintf(buffer, sizeof buffer, " %9.5f", std::fabs(m(r, c)) < 5e-7 ? 0.0 : m(r, c));
    text += buffer;
  }
  return text + " ]";
}

TEST(DemoCommandTest, BipedIsTheDefaultScene) {
  EXPECT_EQ(DemoOptions{}.scene, "biped");
  const fs::path dir = fresh_dir("demo_biped_default");
  std::ostringstream out, err;
  DemoOptions options;
  options.output_dir = dir.string();
  options.no_plot = true;
  ASSERT_EQ(run_demo(options, out, err), 0) << err.str();
  EXPECT_THAT(out.str(), HasSubstr("vertical-plane biped"));
  EXPECT_TRUE(fs::exists(dir / "demo_biped.dat"));
  EXPECT_FALSE(fs::exists(dir / "demo_circle.dat"));
}

TEST(DemoCommandTest, BipedPrintsTheEventThePiecesAndTheTable) {
  const fs::path dir = fresh_dir("demo_biped_table");
  const Outcome o = demo(dir, /*no_plot=*/true, "biped");
  ASSERT_EQ(o.code, 0) << o.err;
  EXPECT_EQ(o.err, "");
  const BipedRun run = biped_run();
  ASSERT_EQ(run.trajectory.events.size(), 1u);
  ASSERT_EQ(run.trajectory.events[0].group_size(), 2);
  // Both feet at t = sqrt(2 (1 - y_td)/g) = 0.3968: one event with two surfaces.
  EXPECT_THAT(o.out, HasSubstr("Touchdown: one event, both feet at the same instant (2 surfaces)"));
  EXPECT_THAT(o.out, HasSubstr("  t = 0.396784681600   (closed form sqrt(2 (1 - y_td) / g) = "
                               "0.396784681600)"));
  EXPECT_THAT(o.out, HasSubstr("surfaces (0,1), sides -- -> ++"));
  // The pieces, as the library computes them; they differ in the ydot row.
  const JumpMap& jump = run.derivative.jumps()[0];
  const Eigen::MatrixXd m01 = jump.saltation({0, 1});
  const Eigen::MatrixXd m10 = jump.saltation({1, 0});
  EXPECT_THAT(o.out, HasSubstr("M_(0,1) = " + row_text(m01, 0) + "   foot 0 lands first"));
  EXPECT_THAT(o.out, HasSubstr("M_(1,0) = " + row_text(m10, 0) + "   foot 1 lands first"));
  EXPECT_THAT(o.out, HasSubstr(row_text(m01, 4)));
  EXPECT_THAT(o.out, HasSubstr(row_text(m10, 4)));
  EXPECT_NE(row_text(m01, 4), row_text(m10, 4));
  EXPECT_THAT(o.out, HasSubstr("conservative: |M_(0,1) - M_(1,0)| / |M_(0,1)| = 0.0e+00"));
  // Table rows: +theta lowers foot 1, -theta foot 0; e_y keeps both feet together.
  EXPECT_THAT(o.out, HasSubstr("  e_theta             foot 1 "));
  EXPECT_THAT(o.out, HasSubstr("  -e_theta            foot 0 "));
  EXPECT_THAT(o.out, HasSubstr("  e_y                 =      "));
  EXPECT_THAT(o.out, HasSubstr("foot 0\nlands first on 179 of them, foot 1 on 179, both together "
                               "on 2."));
  EXPECT_THAT(o.out, HasSubstr("All checks passed."));
  EXPECT_THAT(o.out, Not(HasSubstr("FAILED")));
  EXPECT_THAT(o.out, Not(HasSubstr("nan")));
  EXPECT_THAT(o.out, HasSubstr("Skipped the plot (--no-plot)"));
  EXPECT_FALSE(fs::exists(dir / "demo_biped.png"));
}

TEST(DemoCommandTest, BipedDataFileHoldsTheCircleAndItsExactImage) {
  const fs::path dir = fresh_dir("demo_biped_data");
  ASSERT_EQ(demo(dir, /*no_plot=*/true, "biped").code, 0);
  const BipedRun run = biped_run();
  const FlowDerivative& derivative = run.derivative;
  const Eigen::MatrixXd& phi0 = derivative.transitions()[0];
  const Eigen::MatrixXd& phi1 = derivative.transitions()[1];
  const JumpMap& jump = derivative.jumps()[0];
  const Eigen::MatrixXd pieces[2] = {phi1 * jump.saltation({0, 1}) * phi0,
                                     phi1 * jump.saltation({1, 0}) * phi0};
  const auto blocks = data_blocks(read(dir / "demo_biped.dat"));
  ASSERT_EQ(blocks.size(), 4u);
  EXPECT_EQ(blocks[0].size(), 361u);  // 360 points and the first again
  EXPECT_EQ(blocks[0].front(), blocks[0].back());
  // Two half circles: 358 samples off the boundary rays +-e_y, and both rays at the ends of each.
  EXPECT_EQ(blocks[1].size() + blocks[2].size(), 358u + 4u);
  EXPECT_EQ(blocks[3].size(), 2u);
  for (std::size_t b = 0; b < 4; ++b) {
    for (const std::string& row : blocks[b]) {
      std::istringstream fields(row);
      double angle = 0;
      Eigen::Vector2d p, image;
      int piece = -2;
      fields >> angle >> p[0] >> p[1] >> image[0] >> image[1] >> piece;
      ASSERT_TRUE(fields) << row;
      EXPECT_NEAR(p.norm(), 1.0, 4e-16) << row;
      // dx = p_0 e_theta + p_1 e_y; the image is projected on (theta, y), round-trip exact.
      Eigen::VectorXd dx = Eigen::VectorXd::Zero(6);
      dx[2] = p[0];
      dx[1] = p[1];
      const Eigen::VectorXd full = derivative.apply(dx);
      EXPECT_EQ(image, Eigen::Vector2d(full[2], full[1])) << row;
      if (b == 3) {
        EXPECT_EQ(piece, -1);
        EXPECT_NEAR(std::fabs(p[1]), 1.0, 1e-15) << "the cone boundary is +-e_y";
        continue;
      }
      ASSERT_TRUE(piece == 0 || piece == 1) << row;
      if (b > 0) {
        EXPECT_EQ(piece, static_cast<int>(b) - 1) << row;
      }
      // Each point's piece gives B there (at the boundary rays both do).
      EXPECT_LE((pieces[piece] * dx - full).norm(), 1e-12 * std::max(1.0, full.norm())) << row;
      if (b == 0 && std::fabs(p[0]) > 1e-9) {
        // Away from the rays, the piece is the order at the touchdown of Phi_0 dx.
        EXPECT_EQ(piece, jump.order(phi0 * dx).order[0]) << row;
      }
    }
  }
  const std::string gp = read(dir / "demo_biped.gp");
  EXPECT_THAT(gp, HasSubstr("set terminal pngcairo size 800,800"));
  EXPECT_THAT(gp,
              HasSubstr("set output (exists('bflow_output') ? bflow_output : 'demo_biped.png')"));
  EXPECT_THAT(gp, HasSubstr("set size ratio -1"));
  EXPECT_THAT(gp, HasSubstr("data = 'demo_biped.dat'"));
}

TEST(DemoCommandTest, BipedMissingGnuplotIsReportedWithTheCommand) {
  const fs::path dir = fresh_dir("demo_biped_no_gnuplot");
  const fs::path empty_bin = fresh_dir("demo_biped_empty_bin");
  fs::create_directories(empty_bin);
  const char* old_path = std::getenv("PATH");
  const std::string saved = old_path ? old_path : "";
  setenv("PATH", empty_bin.c_str(), 1);
  const Outcome o = demo(dir, /*no_plot=*/false, "biped");
  setenv("PATH", saved.c_str(), 1);
  EXPECT_EQ(o.code, 1);
  EXPECT_THAT(o.err, StartsWith("error: demo: cannot run gnuplot demo_biped.gp (in directory \"" +
                                dir.string() + "\"): No such file or directory"));
  EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1);
  EXPECT_TRUE(fs::exists(dir / "demo_biped.dat"));
  EXPECT_TRUE(fs::exists(dir / "demo_biped.gp"));
}

TEST(DemoCommandTest, UnknownSceneIsBadInput) {
  const Outcome o = demo(fresh_dir("demo_unknown_scene"), /*no_plot=*/true, "pendulum");
  EXPECT_EQ(o.code, 2);
  EXPECT_EQ(o.out, "");
  EXPECT_EQ(o.err,
            "error: --scene: unknown demo scene \"pendulum\"; the demo scenes are biped and "
            "pwconst\n");
}

// An option given '' is refused naming it (CLI11 would take the default scene or directory),
// before any directory is made; a scene name is quoted short and printable.
TEST(DemoCommandTest, EmptyValuesAndOddNamesAreRefusedOnOneLine) {
  const fs::path dir = fresh_dir("demo_empty_values");
  for (const auto& [args, error] : std::vector<std::pair<std::vector<std::string>, std::string>>{
           {{"--scene", "", "--output", dir.string()}, "--scene: the value is empty"},
           {{"--output", ""}, "--output: the value is empty"},
           {{"-o", ""}, "--output: the value is empty"},
           {{"--scene", "\xff\x1b[31m" + std::string(100, 'p'), "--output", dir.string()},
            "--scene: unknown demo scene \"\\xff\\u001b[31m" + std::string(54, 'p') +
                "...\"; the demo scenes are biped and pwconst"}}) {
    std::vector<std::string> all = {"demo", "--no-plot"};
    all.insert(all.end(), args.begin(), args.end());
    const Outcome o = command_line(all);
    SCOPED_TRACE(error);
    EXPECT_EQ(o.code, 2);
    EXPECT_EQ(o.out, "");
    EXPECT_EQ(o.err, "error: " + error + "\n");
  }
  EXPECT_FALSE(fs::exists(dir));
}

}  // namespace
}  // namespace bflow::cli

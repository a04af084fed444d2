// `bflow demo` in-process: its printed table and data file hold the library's numbers, and a
// missing gnuplot or an unusable directory is reported on one line with a non-zero code.
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Core>

#include "bflow/core/jump_map.h"
#include "bflow/examples/piecewise_constant.h"
#include "cli_commands.h"

namespace bflow::cli {
namespace {

using ::testing::EndsWith;
using ::testing::HasSubstr;
using ::testing::Not;
using ::testing::StartsWith;

namespace fs = std::filesystem;

struct Outcome {
  int code;
  std::string out;
  std::string err;
};

Outcome demo(const fs::path& dir, bool no_plot) {
  std::ostringstream out, err;
  const int code = run_demo(DemoOptions{dir.string(), no_plot}, out, err);
  return {code, out.str(), err.str()};
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

JumpMap planar_jump() {
  const auto model = examples::PiecewiseConstantField::planar_demo();
  return JumpMap(Eigen::MatrixXd::Identity(2, 2), model.limits());
}

TEST(DemoCommandTest, PrintsTheLibrarysNumbers) {
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

TEST(DemoCommandTest, DataFileHoldsTheCircleAndItsExactImage) {
  const fs::path dir = fresh_dir("demo_data");
  ASSERT_EQ(demo(dir, /*no_plot=*/true).code, 0);
  const JumpMap jump = planar_jump();
  const auto pieces = jump.pieces();

  std::istringstream dat(read(dir / "demo_circle.dat"));
  std::vector<std::vector<std::string>> blocks(1);
  std::string line;
  int blank = 0;
  while (std::getline(dat, line)) {
    if (line.empty()) {
      if (++blank == 2) blocks.emplace_back();  // gnuplot: two blank lines end an index
      continue;
    }
    blank = 0;
    if (line[0] != '#') blocks.back().push_back(line);
  }
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
  EXPECT_THAT(gp, HasSubstr("set output 'demo_circle.png'"));
  EXPECT_THAT(gp, HasSubstr("set size ratio -1"));
  EXPECT_THAT(gp, HasSubstr("data = 'demo_circle.dat'"));
}

TEST(DemoCommandTest, MissingGnuplotIsReportedWithTheCommand) {
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

TEST(DemoCommandTest, FailingGnuplotIsReportedWithItsExitStatus) {
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

}  // namespace
}  // namespace bflow::cli

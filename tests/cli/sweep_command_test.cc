// `bflow sweep` in-process: its records hold the closed forms of the linear piecewise-constant
// field, the same bytes whatever the number of threads, failed samples in place, and every
// malformed option one precise error line with exit code 2 before anything is written.
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "cli_commands.h"

namespace bflow::cli {
namespace {

using ::testing::HasSubstr;
using Json = nlohmann::json;

struct Outcome {
  int code;
  std::string out;
  std::string err;
};

Outcome command_line(std::vector<std::string> args) {
  args.insert(args.begin(), "bflow");
  std::vector<const char*> argv;
  for (const auto& a : args) argv.push_back(a.c_str());
  std::istringstream in;
  std::ostringstream out, err;
  const int code = run_cli(static_cast<int>(argv.size()), argv.data(), in, out, err);
  return {code, out.str(), err.str()};
}

std::vector<Json> records(const std::string& text) {
  std::vector<Json> list;
  std::istringstream lines(text);
  std::string line;
  while (std::getline(lines, line)) list.push_back(Json::parse(line));
  return list;
}

TEST(SweepCommand, VaryingDeltaGivesTheClosedFormAtTheOriginsSimultaneousCrossing) {
  // From the scene's own x0 = -F_--(0)/2 both planes are crossed at t = 1/2, and at t = 1
  // B = (1 - delta)/(1 + delta) I ([B] (3.2)); the record has the two pieces of that event.
  const Outcome r = command_line({"sweep", "--scene", "pwconst", "--vary-param", "delta=-0.5:0.5:5",
                                  "--dx", "1,0", "--dx", "0.2,-1", "--quiet"});
  ASSERT_EQ(r.code, 0) << r.err;
  const std::vector<Json> list = records(r.out);
  ASSERT_EQ(list.size(), 5u);
  for (std::size_t k = 0; k < list.size(); ++k) {
    const Json& j = list[k];
    EXPECT_EQ(j["index"], k);
    const double delta = -0.5 + 0.25 * static_cast<double>(k);
    EXPECT_DOUBLE_EQ(j["varied"][0].get<double>(), delta);
    EXPECT_EQ(j["status"], "ok");
    const double b = (1.0 - delta) / (1.0 + delta);
    // Event location and the integration of constant fields: rounding only (measured 2.2e-16).
    EXPECT_NEAR(j["images"][0][0].get<double>(), b, 1e-15) << k;
    EXPECT_NEAR(j["images"][0][1].get<double>(), 0.0, 1e-15) << k;
    EXPECT_NEAR(j["images"][1][0].get<double>(), 0.2 * b, 1e-15) << k;
    EXPECT_NEAR(j["images"][1][1].get<double>(), -b, 1e-15) << k;
    ASSERT_EQ(j["events"].size(), 1u);
    EXPECT_EQ(j["events"][0]["surfaces"], Json::parse("[0, 1]"));
    EXPECT_EQ(j["pieces"], 2.0);
    // dx = (1, 0) brings plane 0 first; (0.2, -1) delays plane 1, so plane 0 comes first too.
    EXPECT_EQ(j["orders"][0], Json::parse("[[0, 1]]"));
    EXPECT_EQ(j["orders"][1], Json::parse("[[0, 1]]"));
  }
  EXPECT_EQ(r.err, "sweep: 5 samples, 5 ok\n");
}

TEST(SweepCommand, TheRecordsAreTheSameBytesWithOneTwoOrThreeThreads) {
  const std::vector<std::string> base = {"sweep",         "--scene", "pwconst",     "--vary",
                                         "1=-0.9:0.2:12", "--vary",  "0=-1:-0.1:4", "--dx",
                                         "1,0.5",         "--quiet"};
  std::vector<std::string> outputs;
  for (const char* format : {"jsonl", "csv"}) {
    for (const char* threads : {"1", "2", "3"}) {
      std::vector<std::string> args = base;
      args.insert(args.end(), {"--threads", threads, "--format", format});
      const Outcome r = command_line(args);
      ASSERT_EQ(r.code, 0) << r.err;
      outputs.push_back(r.out);
    }
  }
  EXPECT_EQ(outputs[0], outputs[1]);
  EXPECT_EQ(outputs[0], outputs[2]);
  EXPECT_EQ(outputs[3], outputs[4]);
  EXPECT_EQ(outputs[3], outputs[5]);
  // 48 samples, grid order: x[1] slowest.
  const std::vector<Json> list = records(outputs[0]);
  ASSERT_EQ(list.size(), 48u);
  EXPECT_EQ(list[5]["varied"], Json::parse("[-0.8, -0.7]"));
}

TEST(SweepCommand, SamplesOnASurfaceAreRecordedInPlaceAndCounted) {
  const Outcome r = command_line(
      {"sweep", "--scene", "pwconst", "--x0=-0.5,0", "--vary", "1=-0.2:0.2:5", "--quiet"});
  ASSERT_EQ(r.code, 0) << r.err;
  const std::vector<Json> list = records(r.out);
  ASSERT_EQ(list.size(), 5u);
  EXPECT_EQ(list[2]["status"], "rejected");
  EXPECT_THAT(list[2]["message"].get<std::string>(), HasSubstr("h_1 = 0"));
  EXPECT_EQ(list[2]["pieces"], 0.0);
  EXPECT_EQ(list[3]["status"], "ok");
  EXPECT_EQ(r.err, "sweep: 5 samples, 4 ok, 1 rejected\n");
}

TEST(SweepCommand, ProgressGoesToStderrAndRecordsToTheOutputFile) {
  const std::string path = ::testing::TempDir() + "sweep_command_test.csv";
  std::remove(path.c_str());
  const Outcome r = command_line({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.1:10",
                                  "--format", "csv", "--output", path});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out, "");
  EXPECT_THAT(r.err, HasSubstr("] 10/10 samples"));
  EXPECT_THAT(r.err, HasSubstr("sweep: 10 samples, 10 ok\n"));
  std::ifstream file(path);
  std::string header, line;
  std::getline(file, header);
  EXPECT_EQ(header, "index,x[0],status,message,t_reached,x_t[0],x_t[1],events,orders,pieces");
  int lines = 0;
  while (std::getline(file, line)) ++lines;
  EXPECT_EQ(lines, 10);
}

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

void write_file(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
}

TEST(SweepCommand, AnInterruptedOutputResumedIsTheUninterruptedOne) {
  for (const char* format : {"jsonl", "csv"}) {
    const std::string whole_path = ::testing::TempDir() + "sweep_whole." + format;
    const std::string cut_path = ::testing::TempDir() + "sweep_cut." + format;
    const std::vector<std::string> args = {"sweep",         "--scene", "pwconst",     "--vary",
                                           "1=-0.9:0.2:12", "--vary",  "0=-1:-0.1:4", "--dx",
                                           "1,0.5",         "--quiet", "--format",    format};
    std::vector<std::string> whole_args = args;
    whole_args.insert(whole_args.end(), {"--output", whole_path});
    ASSERT_EQ(command_line(whole_args).code, 0);
    const std::string whole = read_file(whole_path);
    // A run killed in the middle of its 18th line (what a crash or a lost node leaves).
    std::size_t cut = 0;
    for (int lines = 0; lines < 17; ++lines) cut = whole.find('\n', cut) + 1;
    write_file(cut_path, whole.substr(0, cut + 25));
    std::vector<std::string> resume_args = args;
    resume_args.insert(resume_args.end(), {"--output", cut_path, "--resume", "--threads", "3"});
    const Outcome r = command_line(resume_args);
    ASSERT_EQ(r.code, 0) << r.err;
    const int kept = std::string(format) == "csv" ? 16 : 17;  // the CSV header is a line
    EXPECT_THAT(r.err, HasSubstr("sweep: " + std::to_string(kept) + " of 48 samples kept"));
    EXPECT_THAT(r.err, HasSubstr("sweep: " + std::to_string(48 - kept) + " samples, "));
    EXPECT_EQ(read_file(cut_path), whole) << format;
    // Resuming a finished output changes nothing.
    ASSERT_EQ(command_line(resume_args).code, 0);
    EXPECT_EQ(read_file(cut_path), whole) << format;
  }
}

TEST(SweepCommand, AnotherSweepsOutputIsNotResumedAndNotTouched) {
  const std::string path = ::testing::TempDir() + "sweep_other.jsonl";
  ASSERT_EQ(command_line({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.1:4", "--quiet",
                          "--output", path})
                .code,
            0);
  const std::string before = read_file(path);
  const Outcome r = command_line({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.2:4", "--quiet",
                                  "--output", path, "--resume"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("error: --resume: \"" + path +
                               "\": the output to resume is not from this sweep: line 2 has "
                               "index and varied values [1, -0.7], expected [1, -0.733"));
  EXPECT_EQ(read_file(path), before);
}

TEST(SweepCommand, TheAtlasOfThePiecewiseConstantFieldHasItsThreeCones) {
  // 21 x 21 starts over [-1, -0.05]^2: plane 0 first below the diagonal, plane 1 first above
  // it, both at once on it (dx = (1, 0) then brings plane 0 first): [B] Section 3.1.
  const std::string png = ::testing::TempDir() + "sweep_atlas_test.png";
  const Outcome r =
      command_line({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.05:21", "--vary",
                    "1=-1:-0.05:21", "--dx", "1,0", "--quiet", "--atlas", png});
  if (r.code == 1 && r.err.find("install gnuplot") != std::string::npos) {
    GTEST_SKIP() << "gnuplot is not installed: " << r.err;
  }
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("sweep: wrote"));
  EXPECT_GT(read_file(png).size(), 1000u);
  const std::string gp = read_file(::testing::TempDir() + "sweep_atlas_test.gp");
  std::ifstream data(::testing::TempDir() + "sweep_atlas_test.dat");
  std::string line;
  std::getline(data, line);
  EXPECT_EQ(line, "# x[0] x[1] structure grouped failed");
  std::map<int, int> count;
  int grouped = 0;
  double x = 0, y = 0;
  int id = 0, group = 0, failed = 0;
  while (data >> x >> y >> id >> group >> failed) {
    ++count[id];
    grouped += group;
    EXPECT_EQ(failed, 0);
  }
  // Ids in order of first appearance: sample 0 is (-1, -1), on the diagonal.
  EXPECT_THAT(gp, HasSubstr("title '0+1 (0>1)'"));
  EXPECT_THAT(gp, HasSubstr("title '1 | 0'"));
  EXPECT_THAT(gp, HasSubstr("title '0 | 1'"));
  EXPECT_EQ(count, (std::map<int, int>{{0, 21}, {1, 210}, {2, 210}}));
  EXPECT_EQ(grouped, 21);
}

TEST(SweepCommand, BadOptionsAreRefusedBeforeAnythingIsWritten) {
  const auto refused = [](std::vector<std::string> extra, const std::string& message) {
    std::vector<std::string> args = {"sweep", "--scene", "pwconst", "--quiet"};
    args.insert(args.end(), extra.begin(), extra.end());
    const Outcome r = command_line(args);
    EXPECT_EQ(r.code, 2) << message;
    EXPECT_EQ(r.out, "") << message;
    EXPECT_EQ(r.err, "error: " + message + "\n");
  };
  refused({"--vary", "2=0:1:3"}, "--vary[0]: state index 2 is outside x0 (d = 2)");
  refused({"--vary", "0=0:1"},
          "--vary[0]: \"0=0:1\" is not KEY=LO:HI:COUNT (three fields after '=')");
  refused({"--vary", "0=0:1:0"}, "--vary[0]: 0 count must be >= 1, got 0");
  refused({"--vary", "0=0:x:3"}, "--vary[0] 0 hi: \"x\" is not a number");
  refused({"--vary-param", "d=2:3:2"},
          "--vary-param[0]: d changes the dimension of the state (d = 2 to 3); it cannot vary in "
          "a sweep");
  refused({"--vary-param", "delta=0:1.5:3"},
          "--vary-param[0]: pwconst parameter \"delta\" must be in (-1, 1) (every component of "
          "Delta(b) = -delta b must exceed -1), got \"1.5\"");
  refused({"--vary-param", "mass=0:1:3"},
          "--vary-param[0]: unknown pwconst parameter \"mass\" (known: d, delta, seed)");
  refused({"--threads", "0"}, "--threads: must be >= 1, got 0");
  refused({"--format", "xml"}, "--format: unknown format \"xml\"; the formats are jsonl and csv");
  refused({"--dx", "1,2,3"}, "--dx[0]: has 3 numbers, expected d = 2 (comma-separated)");
  refused({"--resume"}, "--resume: needs --output FILE");
  refused({"--vary", "0=-1:0:3", "--dx", "1,0", "--atlas", "a.png"},
          "--atlas: needs a grid of exactly two axes (--vary, --vary-param), got 1");
  refused({"--vary", "0=-1:0:3", "--vary", "1=-1:0:3", "--atlas", "a.png"},
          "--atlas: needs a --dx: the direction whose crossing orders it maps");
  refused({"--vary", "0=0:1:3", "--output", "/nonexistent-dir/out.jsonl"},
          "--output: cannot write \"/nonexistent-dir/out.jsonl\": No such file or directory");
}

}  // namespace
}  // namespace bflow::cli

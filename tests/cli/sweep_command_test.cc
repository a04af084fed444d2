// `bflow sweep` in-process: its records hold the closed forms of the linear piecewise-constant
// field, the same bytes whatever the number of threads, failed samples in place, and every
// malformed option one precise error line with exit code 2 before anything is written.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "cli_commands.h"
#include "support/run_command.h"

namespace bflow::cli {
namespace {

using bflow::testing::command_line;
using bflow::testing::Outcome;

using ::testing::HasSubstr;
using Json = nlohmann::json;

// The records of a JSON-lines output, after its identity line {"sweep": {...}}.
std::vector<Json> records(const std::string& text) {
  std::vector<Json> list;
  std::istringstream lines(text);
  std::string line;
  if (!std::getline(lines, line)) return list;
  const Json identity = Json::parse(line);
  EXPECT_TRUE(identity.contains("sweep")) << line;
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
  std::string identity, header, line;
  std::getline(file, identity);
  EXPECT_EQ(identity.substr(0, 16), "# bflow sweep {\"");
  EXPECT_THAT(identity, HasSubstr("\"scene\":\"pwconst\""));
  EXPECT_THAT(identity, HasSubstr("\"format\":\"csv\""));
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
    // The identity line, and for CSV the column header, come before the records.
    const int kept = std::string(format) == "csv" ? 15 : 16;
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
  EXPECT_EQ(r.err, "error: --resume: \"" + path +
                       "\": the output to resume is from another sweep: its \"axes\" is "
                       "[{\"name\":\"x[0]\",\"lo\":-1.0,\"hi\":-0.1,\"count\":4}], this "
                       "sweep's is [{\"name\":\"x[0]\",\"lo\":-1.0,\"hi\":-0.2,\"count\":4}]\n");
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

// --resume keeps only what an earlier run of the very same sweep wrote: anything else is
// refused with exit code 2 and the file is left byte for byte as it was.
TEST(SweepCommand, ResumeRefusesEverythingButThisSweepsOutputAndTouchesNothing) {
  const std::string dir = ::testing::TempDir();
  const std::vector<std::string> sweep = {"sweep",       "--scene", "pwconst", "--vary",
                                          "0=-1:-0.1:4", "--dx",    "1,0",     "--quiet"};
  const auto run = [&](std::vector<std::string> extra) {
    std::vector<std::string> args = sweep;
    args.insert(args.end(), extra.begin(), extra.end());
    return command_line(args);
  };
  const std::string good = dir + "sweep_resume_good.jsonl";
  ASSERT_EQ(run({"--output", good}).code, 0);
  const std::string whole = read_file(good);
  const std::string first_line = whole.substr(0, whole.find('\n') + 1);
  // Other sweeps' outputs, from the same command with one option changed.
  const auto other = [&](std::vector<std::string> args) {
    const std::string path = dir + "sweep_resume_other.jsonl";
    std::remove(path.c_str());
    args.insert(args.end(), {"--output", path, "--quiet"});
    EXPECT_EQ(command_line(args).code, 0);
    return read_file(path);
  };
  struct Case {
    std::string name, content, message;
  };
  const std::vector<Case> cases = {
      {"text without a newline", "important notes",
       "is not a bflow sweep output (its first line is \"important notes\")"},
      {"binary",
       std::string("\x7f"
                   "ELF\x02\x01\x01\0\0\xff\xfe",
                   12),
       "is not a bflow sweep output (its first line is \"\\u007fELF"},
      {"text with lines", "line one\nline two\n", "is not a bflow sweep output"},
      {"another time",
       other({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.1:4", "--dx", "1,0", "--t", "0.9"}),
       "is from another sweep: its \"t\" is 0.9, this sweep's is 1.0"},
      {"another parameter",
       other({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.1:4", "--dx", "1,0", "--param",
              "delta=0.5"}),
       "is from another sweep: its \"params\" is {\"d\":2,\"delta\":0.5}, this sweep's is "
       "{\"d\":2,\"delta\":0.25}"},
      {"another direction",
       other({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.1:4", "--dx", "0,1"}),
       "is from another sweep: its \"dx\" is [[0.0,1.0]], this sweep's is [[1.0,0.0]]"},
      {"another start",
       other({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.1:4", "--dx", "1,0", "--x0=-1,-1"}),
       "is from another sweep: its \"x0\" is [-1.0,-1.0], this sweep's is null"},
      {"another tolerance",
       other({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.1:4", "--dx", "1,0", "--rtol",
              "1e-6"}),
       "is from another sweep: its \"rtol\" is 1e-06, this sweep's is 1e-08"},
      {"another grouping",
       other({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.1:4", "--dx", "1,0", "--grouping",
              "none"}),
       "is from another sweep: its \"grouping\" is \"none\", this sweep's is \"auto\""},
      {"another scene", other({"sweep", "--scene", "biped", "--vary", "0=-1:-0.1:4"}),
       "is from another sweep: its \"scene\" is \"biped\", this sweep's is \"pwconst\""},
      {"another format",
       other({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.1:4", "--dx", "1,0", "--format",
              "csv"}),
       "is from another sweep: its \"format\" is \"csv\", this sweep's is \"jsonl\""},
      {"a record that is not one", first_line + "{\"index\":0}\n",
       "is not from this sweep: line 2 is not a JSON-lines record"},
      {"a cut line that is not a record", first_line + "garbage",
       "is not from this sweep: line 2 is an incomplete line that is not the start of record 0"},
      {"a misspelt key",
       [&] {
         std::string text = whole;
         text.replace(text.find("\"x_t\""), 5, "\"x_T\"");
         return text;
       }(),
       "is not from this sweep: line 2 is not a whole JSON-lines record (a key is missing or "
       "misspelt)"},
      {"records beyond the grid", whole + whole.substr(first_line.size()),
       "is not from this sweep: line 6 is a record beyond the grid's samples"},
  };
  const std::string path = dir + "sweep_resume_case.jsonl";
  for (const Case& c : cases) {
    write_file(path, c.content);
    const Outcome r = run({"--output", path, "--resume"});
    EXPECT_EQ(r.code, 2) << c.name;
    EXPECT_EQ(r.out, "") << c.name;
    EXPECT_THAT(r.err,
                HasSubstr("error: --resume: \"" + path + "\": the output to resume " + c.message))
        << c.name;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << c.name << ": " << r.err;
    EXPECT_EQ(read_file(path), c.content) << c.name;
  }
  // Not a regular file: an endless device and a directory.
  for (const std::string& special : {std::string("/dev/zero"), dir}) {
    const Outcome r = run({"--output", special, "--resume"});
    EXPECT_EQ(r.code, 2);
    EXPECT_EQ(r.err, "error: --resume: \"" + special +
                         "\" is not a regular file; only a file an earlier run of this sweep "
                         "wrote can be resumed\n");
  }
  // What may be resumed: nothing, the start of the identity line, whole records and a cut one.
  for (const std::size_t cut : {std::size_t{0}, std::size_t{5}, first_line.size() - 1,
                                first_line.size(), first_line.size() + 9, whole.size() - 1}) {
    write_file(path, whole.substr(0, cut));
    const Outcome r = run({"--output", path, "--resume"});
    EXPECT_EQ(r.code, 0) << "cut at " << cut << ": " << r.err;
    EXPECT_EQ(read_file(path), whole) << "cut at " << cut;
  }
}

TEST(SweepCommand, NoOutputReplacesAnother) {
  const std::string dir = ::testing::TempDir() + "sweep_collisions/";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const std::vector<std::string> sweep = {"sweep",       "--scene", "pwconst",     "--vary",
                                          "0=-1:-0.1:3", "--vary",  "1=-1:-0.1:3", "--dx",
                                          "1,0",         "--quiet"};
  for (const char* name : {"A.dat", "A.gp", "A.png"}) {
    const std::string output = dir + name;
    write_file(output, "keep me");
    std::vector<std::string> args = sweep;
    args.insert(args.end(), {"--output", output, "--atlas", dir + "A.png"});
    const Outcome r = command_line(args);
    EXPECT_EQ(r.code, 2) << name;
    EXPECT_THAT(r.err, HasSubstr("error: --output: \"" + output + "\" is also "));
    EXPECT_EQ(read_file(output), "keep me") << name;
  }
  // Through a link whose target does not exist yet: the records would go where the atlas's
  // data goes.
  std::filesystem::remove(dir + "C.dat");
  std::filesystem::create_symlink("C.dat", dir + "link.jsonl");
  {
    std::vector<std::string> args = sweep;
    args.insert(args.end(), {"--output", dir + "link.jsonl", "--atlas", dir + "C.png"});
    const Outcome r = command_line(args);
    EXPECT_EQ(r.code, 2);
    EXPECT_THAT(r.err, HasSubstr("error: --output: \"" + dir +
                                 "link.jsonl\" is also the atlas's "
                                 "data (--atlas)"));
    EXPECT_FALSE(std::filesystem::exists(dir + "C.dat"));
  }
  // An empty directory named like the atlas's PNG (or its data) is not replaced.
  for (const char* name : {"B.png", "B.dat"}) {
    std::filesystem::create_directories(dir + name);
    std::vector<std::string> args = sweep;
    args.insert(args.end(), {"--atlas", dir + "B.png"});
    const Outcome r = command_line(args);
    EXPECT_EQ(r.code, 2) << name;
    EXPECT_EQ(r.err, "error: --atlas: \"" + dir + name +
                         "\" exists and is not a regular file; it is not replaced (remove it or "
                         "name another output)\n");
    EXPECT_TRUE(std::filesystem::is_directory(dir + name)) << name;
    std::filesystem::remove(dir + name);
  }
}

TEST(SweepCommand, ARecordThatOverflowsIsNotOk) {
  // delta = -0.5: B = (1 - delta)/(1 + delta) I = 3 I, so the image of dx = (1e308, 0) is 3e308,
  // beyond the double range; `bflow flow` exits 1 on it, a sweep records the overflow.
  for (const char* format : {"jsonl", "csv"}) {
    const Outcome r =
        command_line({"sweep", "--scene", "pwconst", "--param", "delta=-0.5", "--dx", "1e308,0",
                      "--vary", "1=-0.5:-0.2:2", "--format", format, "--quiet"});
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(r.err, "sweep: 2 samples, 2 overflow\n");
    EXPECT_EQ(r.out.find("null", r.out.find('\n')), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find("inf"), std::string::npos) << r.out;
    EXPECT_THAT(r.out, HasSubstr("the computation overflowed: images[0] is not finite"));
  }
  // bflow flow on the first sample's start: exit code 1, "status": "overflow".
  const Outcome flow = command_line({"flow", "--scene", "pwconst", "--param", "delta=-0.5", "--dx",
                                     "1e308,0", "--x0=-0.25,-0.5", "--compact"});
  EXPECT_EQ(flow.code, 1) << flow.err;
  EXPECT_THAT(flow.out, HasSubstr("\"status\":\"overflow\""));
}

TEST(SweepCommand, ARejectionThatFollowsAnOverflowIsAnOverflowAsInFlow) {
  // A downward speed of 1e100: the state stays finite through the touchdown, the tangents do
  // not, and the library then ends flow_derivative with an InvalidArgument.
  const std::vector<std::string> start = {"--scene", "biped", "--x0", "0,1,0,0,-1e100,0"};
  std::vector<std::string> args = {"sweep", "--vary", "2=0:0:1", "--dx", "1,0,0,0,0,0", "--quiet"};
  args.insert(args.end(), start.begin(), start.end());
  const Outcome r = command_line(args);
  ASSERT_EQ(r.code, 0) << r.err;
  const std::vector<Json> list = records(r.out);
  ASSERT_EQ(list.size(), 1u);
  EXPECT_EQ(list[0]["status"], "overflow");
  EXPECT_THAT(list[0]["message"].get<std::string>(),
              ::testing::StartsWith("the computation overflowed: F_++ or its derivative on the "
                                    "tangents is not finite"));
  std::vector<std::string> flow = {"flow", "--compact"};
  flow.insert(flow.end(), start.begin(), start.end());
  const Outcome f = command_line(flow);
  EXPECT_EQ(f.code, 1);
  EXPECT_EQ(Json::parse(f.out)["status"], "overflow");
}

TEST(SweepCommand, GridValuesStayFiniteAcrossTheWholeDoubleRange) {
  const std::string path = ::testing::TempDir() + "sweep_wide.jsonl";
  std::remove(path.c_str());
  const std::vector<std::string> args = {
      "sweep", "--scene", "pwconst", "--vary", "0=-1e308:1e308:3", "--quiet", "--output", path};
  ASSERT_EQ(command_line(args).code, 0);
  const std::string whole = read_file(path);
  const std::vector<Json> list = records(whole);
  ASSERT_EQ(list.size(), 3u);
  EXPECT_EQ(list[0]["varied"][0].get<double>(), -1e308);
  EXPECT_EQ(list[1]["varied"][0].get<double>(), 0.0);
  EXPECT_EQ(list[2]["varied"][0].get<double>(), 1e308);
  // Cut in the middle record and resumed.
  write_file(path, whole.substr(0, whole.rfind('\n', whole.size() - 2) - 10));
  std::vector<std::string> resume = args;
  resume.push_back("--resume");
  const Outcome r = command_line(resume);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(read_file(path), whole);
}

TEST(SweepCommand, AxesAndParametersGivenTwiceOrInvalidInsideTheirRangeAreRefused) {
  const auto refused = [](std::vector<std::string> extra, const std::string& message) {
    std::vector<std::string> args = {"sweep", "--scene", "pwconst", "--quiet"};
    args.insert(args.end(), extra.begin(), extra.end());
    const Outcome r = command_line(args);
    EXPECT_EQ(r.code, 2) << message;
    EXPECT_EQ(r.out, "") << message;
    EXPECT_EQ(r.err, "error: " + message + "\n");
  };
  refused({"--vary", "0=-1:-0.1:3", "--vary", "0=-2:-1:3"},
          "--vary[1]: x[0] is already varied by --vary[0]; vary each once");
  refused({"--vary-param", "delta=0:0.5:3", "--vary-param", "delta=-0.5:0:3"},
          "--vary-param[1]: delta is already varied by --vary-param[0]; vary each once");
  refused({"--param", "delta=0.1", "--vary-param", "delta=0:0.5:3"},
          "--vary-param[0]: delta is also fixed by --param delta=\"0.1\"; give it either fixed or "
          "varied");
  refused({"--vary-param", "seed=0:1:3"},
          "--vary-param[0]: pwconst parameter \"seed\" must be an integer in [0, 2^64), got "
          "\"0.5\"");
  refused({"--param", "seed=3", "--vary-param", "delta=0:0.5:3"},
          "--vary-param[0]: give delta (the linear case) or seed (a random Delta), not both");
  // Whole seeds vary.
  const Outcome r =
      command_line({"sweep", "--scene", "pwconst", "--vary-param", "seed=0:4:5", "--quiet"});
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(records(r.out).size(), 5u);
}

TEST(SweepCommand, AWriteThatFailsSaysWhy) {
  const Outcome r = command_line({"sweep", "--scene", "pwconst", "--vary", "0=-1:-0.1:2000",
                                  "--quiet", "--output", "/dev/full"});
  EXPECT_EQ(r.code, 1);
  EXPECT_EQ(r.err, "error: --output: cannot write \"/dev/full\": No space left on device\n");
}

}  // namespace
}  // namespace bflow::cli

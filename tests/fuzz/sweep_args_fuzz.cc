// libFuzzer harness: the command line of `bflow sweep`. The input is split into argv words at
// '\0' and '\n' and run as "bflow sweep <words...>" (bflow::cli::run_cli). Checks the output
// contract (fuzz_contract.h) for a sweep: with exit code 0 the records (stdout, or the --output
// file) are whole lines, JSON documents unless --format is given (CSV), at least one per
// sample of the grid, and stdout is empty with --output; the progress bar ("\r[...") and the
// "sweep: " lines (resumed records, the count by status, the atlas written) may precede the
// outcome; a failure is one "error: " line, after any records already written with exit code 1.
//
// Per-input cost: a sample is one flow and its B-derivative, milliseconds under the sanitizers,
// so the harness caps the grid and each sample. It counts the samples as the command does
// (the product of the COUNTs of every --vary I=LO:HI:COUNT and --vary-param KEY=LO:HI:COUNT)
// and skips (returns -1: not added to the corpus) grids of more than kMaxSamples samples, unless
// the command must refuse them before any sample runs: an axis that is not KEY=LO:HI:COUNT, a
// COUNT that is not a whole decimal number in [1, 2^53], or more than 2^53 samples in all. It
// skips --t above kMaxTime and --max-steps above kMaxSteps, adds "--max-steps kMaxSteps" when
// none is given (a start that makes the steps tiny runs the default 10^6 steps: a minute per
// sample here), skips --threads above 2 and adds "--threads 1" when none is given (the default,
// one per core, depends on the machine; the output does not).
//
// Files: every --output and --atlas value is confined to the harness's scratch directory
// (fuzz_scratch.h), emptied before each input and removed at exit. It holds "file", a regular
// file (--output file/x, --atlas file/a.png: a directory that cannot be created), and "dir", a
// directory (--output dir: not a file).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include "fuzz/fuzz_args.h"
#include "fuzz/fuzz_scratch.h"

namespace {

constexpr double kMaxSamples = 50;
constexpr double kMaxTime = 2.0;
constexpr double kMaxSteps = 2000;
constexpr double kMaxThreads = 2;
constexpr double kRefusedSamples = 9007199254740992.0;  // 2^53: the grid's limit

std::string trimmed(const std::string& text) {
  const auto first = text.find_first_not_of(" \t");
  if (first == std::string::npos) return "";
  return text.substr(first, text.find_last_not_of(" \t") - first + 1);
}

/** The COUNT of an axis "KEY=LO:HI:COUNT" as the command reads it (sweep_command.cc,
    parse_axis), or 0 when the command refuses the axis for its shape or its count. */
double axis_count(const std::string& text) {
  const auto equals = text.find('=');
  if (equals == std::string::npos || equals == 0) return 0.0;
  const std::string range = text.substr(equals + 1);
  const auto first = range.find(':');
  const auto second = first == std::string::npos ? first : range.find(':', first + 1);
  if (second == std::string::npos || range.find(':', second + 1) != std::string::npos) return 0;
  const std::string count = trimmed(range.substr(second + 1));
  if (count.empty() || count.find_first_not_of("0123456789") != std::string::npos) return 0.0;
  const double value = std::strtod(count.c_str(), nullptr);
  return value > kRefusedSamples ? 0.0 : value;
}

/** The number of samples of the grid the words ask for; 0 when the command refuses an axis,
    above kRefusedSamples when it refuses the whole grid. */
double samples_of(const std::vector<std::string>& words) {
  double samples = 1.0;
  for (const char* option : {"--vary", "--vary-param"}) {
    for (const std::string& axis : bflow::fuzz::values_of(words, option)) {
      samples *= axis_count(axis);
    }
  }
  return samples;
}

/** Whether some value given to `option` reads (strtod, leading blanks skipped) above `limit`. */
bool any_above(const std::vector<std::string>& words, const std::string& option, double limit) {
  for (const std::string& text : bflow::fuzz::values_of(words, option)) {
    if (std::strtod(text.c_str(), nullptr) > limit) return true;  // also inf; nan compares false
  }
  return false;
}

/** The number of newline-terminated lines of `text`. */
std::size_t line_count(const std::string& text) {
  std::size_t count = 0;
  for (char c : text) count += c == '\n' ? 1 : 0;
  return count;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::vector<std::string> words = bflow::fuzz::split_words(data, size);
  const double samples = samples_of(words);
  if (samples > kMaxSamples && samples <= kRefusedSamples) return -1;
  if (any_above(words, "--t", kMaxTime) || any_above(words, "--max-steps", kMaxSteps) ||
      any_above(words, "--threads", kMaxThreads)) {
    return -1;
  }
  if (!bflow::fuzz::has_option(words, "--max-steps")) {
    words.push_back("--max-steps");
    words.push_back(std::to_string(static_cast<int>(kMaxSteps)));
  }
  if (!bflow::fuzz::has_option(words, "--threads")) {
    words.push_back("--threads");
    words.push_back("1");
  }

  bflow::fuzz::ScratchDir& scratch = bflow::fuzz::scratch_dir("sweep_args");
  scratch.clear();
  scratch.write("file", "not a directory\n");
  std::filesystem::create_directory(scratch.path() + "/dir");
  const auto confine = [&](const std::string& value) { return scratch.confine(value); };
  bflow::fuzz::map_values(words, "--output", confine);
  bflow::fuzz::map_values(words, "--atlas", confine);

  bool jsonl = true;
  for (const std::string& format : bflow::fuzz::values_of(words, "--format")) {
    jsonl = jsonl && format == "jsonl";
  }
  bflow::fuzz::Contract contract;
  contract.output = jsonl ? bflow::fuzz::Output::kJsonLines : bflow::fuzz::Output::kTextLines;
  contract.record_on_failure = true;
  contract.progress_prefixes = {"\r", "sweep: "};
  const bflow::fuzz::RunResult r = bflow::fuzz::run_and_check("sweep", words, contract);

  if (r.code == 0 && !bflow::fuzz::asks_for_text(words)) {
    // Every sample has its record, in the file or on stdout.
    std::string records = r.out;
    const std::vector<std::string> outputs = bflow::fuzz::values_of(words, "--output");
    if (!outputs.empty()) {
      if (!r.out.empty()) {
        bflow::fuzz::violation("exit code 0 with --output and stdout is not empty", r.code, r.out,
                               r.err);
      }
      bool exists = false;
      records = bflow::fuzz::read_file(outputs.back(), &exists);
      if (!exists) {
        bflow::fuzz::violation(
            "exit code 0 and the --output file " + outputs.back() + " does not exist", r.code,
            r.out, r.err);
      }
      if (!bflow::fuzz::output_is(records, contract.output)) {
        bflow::fuzz::violation("exit code 0 and the --output file is not whole lines of records",
                               r.code, records.substr(0, 4000), r.err);
      }
    }
    if (static_cast<double>(line_count(records)) < samples) {
      bflow::fuzz::violation("exit code 0 and fewer lines of records than samples (" +
                                 std::to_string(static_cast<long long>(samples)) + ")",
                             r.code, records.substr(0, 4000), r.err);
    }
  }
  scratch.clear();
  return 0;
}

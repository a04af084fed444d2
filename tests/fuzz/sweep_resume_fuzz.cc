// libFuzzer harness: the file that `bflow sweep --output F --resume` resumes. The first byte of
// the input chooses the sweep (odd, e.g. 'c': CSV; even, e.g. 'j': JSON lines), the other bytes
// are written to F; an empty input leaves F absent. The harness then runs one fixed sweep of
// four samples,
//
//   bflow sweep --scene pwconst --vary 0=-1:-0.1:4 --dx 1,0 --quiet --threads 1
//               [--format csv] --output F --resume
//
// and checks the contract of --resume, whatever the format of the file:
//   exit 0: F is byte for byte the output of the same sweep run uninterrupted (computed once per
//           format, by the same command without --resume into a fresh file); stdout is empty;
//           stderr holds only "sweep: " lines;
//   exit 2: F is byte for byte what the harness wrote (absent if it was): a refused file loses
//           nothing; stderr is one "error: " line; stdout is empty;
//   any other exit code (1 included), a crash or a hang is a violation.
// F lives in the harness's scratch directory (fuzz_scratch.h), emptied before each input and
// removed at exit. The seeds (tests/fuzz/corpus/sweep_resume) come from make_resume_seeds.sh.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "fuzz/fuzz_args.h"
#include "fuzz/fuzz_scratch.h"

namespace {

/** The fixed sweep writing to `path`, resuming it when `resume`. */
std::vector<std::string> sweep_words(bool csv, const std::string& path, bool resume) {
  std::vector<std::string> words = {"--scene", "pwconst",   "--vary", "0=-1:-0.1:4", "--dx", "1,0",
                                    "--quiet", "--threads", "1"};
  if (csv) {
    words.push_back("--format");
    words.push_back("csv");
  }
  words.push_back("--output");
  words.push_back(path);
  if (resume) words.push_back("--resume");
  return words;
}

/** Where two byte strings first differ, for the report. */
std::string first_difference(const std::string& a, const std::string& b) {
  std::size_t i = 0;
  while (i < a.size() && i < b.size() && a[i] == b[i]) ++i;
  return "sizes " + std::to_string(a.size()) + " and " + std::to_string(b.size()) +
         ", first difference at byte " + std::to_string(i);
}

/** The uninterrupted sweep's output in each format, computed at the first call. */
const std::string& reference(bool csv) {
  static const std::vector<std::string> outputs = [] {
    bflow::fuzz::ScratchDir& scratch = bflow::fuzz::scratch_dir("sweep_resume");
    std::vector<std::string> result;
    for (const bool c : {false, true}) {
      scratch.clear();
      const std::string path = scratch.path() + "/reference";
      const bflow::fuzz::RunResult r = bflow::fuzz::run_words("sweep", sweep_words(c, path, false));
      bool exists = false;
      result.push_back(bflow::fuzz::read_file(path, &exists));
      if (r.code != 0 || !exists || result.back().empty()) {
        bflow::fuzz::violation("the uninterrupted sweep (the reference) failed", r.code, r.out,
                               r.err);
      }
    }
    scratch.clear();
    return result;
  }();
  return outputs[csv ? 1 : 0];
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const bool csv = size > 0 && (data[0] & 1) != 0;
  const std::string& expected = reference(csv);
  bflow::fuzz::ScratchDir& scratch = bflow::fuzz::scratch_dir("sweep_resume");
  scratch.clear();
  const std::string path = scratch.path() + (csv ? "/out.csv" : "/out.jsonl");
  const bool existed = size > 0;
  const std::string before =
      existed ? std::string(reinterpret_cast<const char*>(data) + 1, size - 1) : std::string();
  if (existed) scratch.write(csv ? "out.csv" : "out.jsonl", before);

  const bflow::fuzz::RunResult r = bflow::fuzz::run_words("sweep", sweep_words(csv, path, true));
  bool exists = false;
  const std::string after = bflow::fuzz::read_file(path, &exists);
  if (r.code != 0 && r.code != 2) {
    bflow::fuzz::violation("--resume: exit code " + std::to_string(r.code) + ", expected 0 or 2",
                           r.code, r.out, r.err);
  }
  bflow::fuzz::Contract contract;
  contract.output = csv ? bflow::fuzz::Output::kTextLines : bflow::fuzz::Output::kJsonLines;
  contract.progress_prefixes = {"sweep: "};
  bflow::fuzz::check(r.code, r.out, r.err, contract);
  if (!r.out.empty()) {
    bflow::fuzz::violation("--resume with --output and stdout is not empty", r.code, r.out, r.err);
  }
  if (r.code == 0 && (!exists || after != expected)) {
    bflow::fuzz::violation(
        "--resume: exit code 0 and the file is not the uninterrupted sweep's output (" +
            (exists ? first_difference(after, expected) : std::string("the file is gone")) +
            ")\n--- file after the run ---\n" + after.substr(0, 2000) + "\n--- expected ---\n" +
            expected.substr(0, 2000),
        r.code, r.out, r.err);
  }
  if (r.code == 2 && (exists != existed || after != before)) {
    bflow::fuzz::violation(
        "--resume: exit code 2 and the file is not as it was (" +
            (exists ? first_difference(after, before) : std::string("the file is gone")) + ")",
        r.code, r.out, r.err);
  }
  scratch.clear();
  return 0;
}

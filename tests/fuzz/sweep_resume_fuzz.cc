// libFuzzer harness: the file that `bflow sweep --output F --resume` resumes. The first byte of
// the input chooses the sweep (odd, e.g. 'c': CSV; even, e.g. 'j': JSON lines), the other bytes
// are written to F; an empty input leaves F absent. The harness then runs one fixed sweep of
// four samples,
//
//   bflow sweep --scene pwconst --vary 0=-1:-0.1:4 --dx 1,0 --quiet --threads 1
//               [--format csv] --output F --resume
//
// and checks the contract of --resume, whatever the format of the file:
//   exit 0: stderr says "sweep: K of 4 samples kept"; F is the first lines of what the harness
//           wrote, the identity line (and CSV header) and K records, untouched, followed by the
//           uninterrupted output of the same sweep (computed once per format, by the same command
//           without --resume into a fresh file) from its record K on; with K = 0, F is that whole
//           output (kept records are the file's own bytes: --resume checks their shape, index and
//           varied values, not every number); stdout is empty; stderr holds only "sweep: " lines;
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
  // Where the first `lines` lines of `text` end.
  const auto line_end = [](const std::string& text, std::size_t lines) {
    std::size_t at = 0;
    for (std::size_t k = 0; k < lines; ++k) {
      const std::size_t newline = text.find('\n', at);
      if (newline == std::string::npos) return std::string::npos;
      at = newline + 1;
    }
    return at;
  };
  std::string wanted = expected;
  if (r.code == 0) {
    const std::string marker = "sweep: ";
    const std::size_t at = r.err.find(" of 4 samples kept");
    const std::size_t from = at == std::string::npos ? at : r.err.rfind(marker, at);
    const std::size_t kept =
        from == std::string::npos ? 0 : std::stoul(r.err.substr(from + marker.size()));
    if (kept > 0) {
      const std::size_t header = csv ? 2 : 1;
      const std::size_t mine = line_end(before, header + kept);
      const std::size_t theirs = line_end(expected, header + kept);
      if (mine == std::string::npos || theirs == std::string::npos) {
        bflow::fuzz::violation(
            "--resume: kept " + std::to_string(kept) + " records the file does not hold", r.code,
            r.out, r.err);
      }
      wanted = before.substr(0, mine) + expected.substr(theirs);
    }
  }
  if (r.code == 0 && (!exists || after != wanted)) {
    bflow::fuzz::violation(
        "--resume: exit code 0 and the file is not its kept records followed by the uninterrupted "
        "sweep's output (" +
            (exists ? first_difference(after, wanted) : std::string("the file is gone")) +
            ")\n--- file after the run ---\n" + after.substr(0, 2000) + "\n--- expected ---\n" +
            wanted.substr(0, 2000),
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

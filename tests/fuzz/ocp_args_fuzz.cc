// libFuzzer harness: the command line of `bflow ocp`. The input is split into argv words at
// '\0' and '\n' and run as "bflow ocp <words...>" (bflow::cli::run_cli). Checks the output
// contract (fuzz_contract.h): progress lines "ocp: ..." may come before the outcome, "warning: "
// lines may accompany it, and an optimal control problem not solved (exit code 1) prints its
// JSON record.
//
// Per-input cost: an OCP solve is a homotopy of IPOPT NLPs, each up to 3000 iterations of about
// 1 ms natively even for the smallest problems, and bflow's derivatives cost about 100 times more
// under the sanitizers. The braking block solves any small instance in 10-170 ms natively; the
// turbo car does not: with one or two control stages it cannot reach q = 200 at rest in a
// reasonable time, and IPOPT spends its 3000 iterations per NLP and the homotopy its retries
// (turbo-car --N 1 --nfe 2 --stages 1 --sigma0 1 --sigma-final 0.001: 13.7 s natively; --N 5,
// docs/cli.md: 2.3 s); the monoped takes minutes to hours. The harness therefore solves only
// what it can read as a small braking block: no word mentions turbo-car or monoped (so the
// example is the braking block or is refused), --N given, every --N, --nfe and --stages a plain
// decimal integer with N * N_FE * n_s <= kWorkBudget, every --sigma0, --sigma-final and --tol a
// number, with sigma0 <= kMaxSigma0, at most kMaxNlps NLPs in the homotopy (sigma falls tenfold
// per NLP) and tol >= kMinTol. Any other command line (the turbo car, the monoped, larger
// sizes) is checked but not solved: the harness points --plot (replacing every value given, or
// appended) at a path under a regular file of its scratch directory. The command checks every
// option, the NLP's size against its limits and then the plot directory before it solves
// anything, so every word is still parsed and validated, and the command stops with exit code 1
// and one line "error: ocp: cannot create directory ..." instead of solving. A command line the
// harness misreads as small costs time, not correctness: libFuzzer's -timeout reports it.
//
// Files: every --plot value of a solved command line is confined to the harness's scratch
// directory (fuzz_scratch.h), which also holds "file", a regular file (--plot file: the
// directory cannot be created); it is emptied before each input and removed at exit.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include "fuzz/fuzz_args.h"
#include "fuzz/fuzz_scratch.h"

namespace {

constexpr long long kWorkBudget = 4;
constexpr int kMaxNlps = 14;
constexpr double kMaxSigma0 = 1e4;
constexpr double kMinTol = 1e-14;

/** `word` as a plain decimal integer (an optional '-', then digits; at most 9 of them). */
bool read_decimal(const std::string& word, long long& value) {
  const std::size_t start = !word.empty() && word[0] == '-' ? 1 : 0;
  if (word.size() == start || word.size() - start > 9 ||
      word.find_first_not_of("0123456789", start) != std::string::npos) {
    return false;
  }
  value = std::strtoll(word.c_str(), nullptr, 10);
  return true;
}

/** `word` as a whole number for strtod. */
bool read_number(const std::string& word, double& value) {
  if (word.empty()) return false;
  char* end = nullptr;
  value = std::strtod(word.c_str(), &end);
  return end == word.c_str() + word.size() && std::isfinite(value);
}

/** The largest value given to the integer option `name`, or `fallback` when none is given;
    false when a value is not a plain decimal integer. */
bool largest_int(const std::vector<std::string>& words, const std::string& name, long long fallback,
                 long long& result) {
  result = fallback;
  bool first = true;
  for (const std::string& text : bflow::fuzz::values_of(words, name)) {
    long long value = 0;
    if (!read_decimal(text, value)) return false;
    if (first || value > result) result = value;
    first = false;
  }
  return true;
}

/** Every value given to the real option `name` (or `fallback` when none is given), in
    [lo, hi]; false when a value is not a number or lies outside. `extreme` gets the smallest
    (`smallest`) or the largest value. */
bool reals_within(const std::vector<std::string>& words, const std::string& name, double fallback,
                  double lo, double hi, bool smallest, double& extreme) {
  std::vector<std::string> texts = bflow::fuzz::values_of(words, name);
  extreme = fallback;
  bool first = true;
  for (const std::string& text : texts) {
    double value = 0.0;
    if (!read_number(text, value) || !(value >= lo && value <= hi)) return false;
    if (first || (smallest ? value < extreme : value > extreme)) extreme = value;
    first = false;
  }
  return true;
}

/** Whether the harness can read `words` as a small problem of the braking block (see the
    header). */
bool small_solve(const std::vector<std::string>& words) {
  for (const std::string& w : words) {
    if (w.find("turbo-car") != std::string::npos || w.find("monoped") != std::string::npos) {
      return false;
    }
  }
  if (bflow::fuzz::values_of(words, "--N").empty()) return false;  // the default N is 10
  long long n = 0, nfe = 0, stages = 0;
  if (!largest_int(words, "--N", 10, n) || !largest_int(words, "--nfe", 3, nfe) ||
      !largest_int(words, "--stages", 2, stages)) {
    return false;
  }
  if (n > kWorkBudget || nfe > kWorkBudget || stages > kWorkBudget ||
      std::max(n, 1LL) * std::max(nfe, 1LL) * std::max(stages, 1LL) > kWorkBudget) {
    return false;
  }
  double sigma0 = 0.0, sigma_final = 0.0, tol = 0.0;
  if (!reals_within(words, "--sigma0", 100.0, 0.0, kMaxSigma0, false, sigma0) ||
      !reals_within(words, "--sigma-final", 1e-10, 0.0, kMaxSigma0, true, sigma_final) ||
      !reals_within(words, "--tol", 1e-10, kMinTol, 1.0, true, tol)) {
    return false;
  }
  if (sigma0 > 0.0 && sigma_final > 0.0 && sigma_final < sigma0 &&
      std::log10(sigma0 / sigma_final) + 1.0 > kMaxNlps) {
    return false;
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  bflow::fuzz::ScratchDir& scratch = bflow::fuzz::scratch_dir("ocp_args");
  scratch.clear();
  scratch.write("file", "not a directory\n");
  std::vector<std::string> words = bflow::fuzz::split_words(data, size);
  if (small_solve(words)) {
    // An empty name is kept: the command refuses it before touching the file system.
    bflow::fuzz::map_values(words, "--plot", [&](const std::string& value) {
      return value.empty() ? value : scratch.confine(value);
    });
  } else {
    const std::string blocked = scratch.path() + "/file/plot";
    if (bflow::fuzz::has_option(words, "--plot")) {
      bflow::fuzz::map_values(words, "--plot", [&](const std::string&) { return blocked; });
    } else {
      words.push_back("--plot");
      words.push_back(blocked);
    }
  }
  bflow::fuzz::Contract contract;
  contract.warnings_on_success = true;
  contract.warnings_on_failure = true;
  contract.record_on_failure = true;
  contract.progress_prefixes = {"ocp: "};
  bflow::fuzz::run_and_check("ocp", words, contract);
  scratch.clear();
  return 0;
}

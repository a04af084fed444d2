// libFuzzer harness: the command line of `bflow fesd`. The input is split into argv words at
// '\0' and '\n' and run as "bflow fesd <words...>" (bflow::cli::run_cli). Checks the output
// contract (fuzz_contract.h): "warning: " lines may accompany exit code 0 (a step IPOPT
// solved only to its acceptable level), and a failed step (exit code 1) may print the JSON
// record.
//
// Per-input cost: under ASan and UBSan a run costs about 100 times its native time, and the
// runs that fall back on IPOPT's homotopy take seconds to minutes (IRMA's default run 8 s;
// --standard, --scheme gauss or a single step of sliding-leave 20-60 s; crossing with one
// finite element per step 1.2 s natively, over 10 s here). The harness therefore simulates
// only the switching cases with the step or Stewart formulation, Radau IIA, switch detection,
// N_sim != 1, N_FE != 1 and N_sim * N_FE * n_s * max(1, n_d) <= kWorkBudget; any other
// command line gets "--sizes" appended, so that CLI11 still parses every word and the contract
// is still checked, but only the size table is computed. Command lines whose work exceeds
// kWorkRefused (e.g. --nfe 1073741824) run as given: no one needs such sizes from the
// command, which must refuse them promptly; a timeout or an out-of-memory report there is a
// finding.
#include <climits>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "fuzz/fuzz_args.h"
#include "scene_setup.h"

namespace {

constexpr double kWorkBudget = 1000.0;
constexpr double kWorkRefused = 1e8;

/** `word` as the command reads an int option (bflow::cli::parse_integer, in int range); false
    where the command refuses it. */
bool read_int(const std::string& word, long long& value) {
  try {
    value = bflow::cli::parse_integer(word, "--fuzz", INT_MIN, INT_MAX);
    return true;
  } catch (const bflow::cli::InputError&) {
    return false;
  }
}

/** The largest value given to `name` ("--name V" or "--name=V"), or `fallback`. */
long long option_value(const std::vector<std::string>& words, const std::string& name,
                       long long fallback) {
  long long result = fallback;
  bool given = false;
  for (std::size_t i = 0; i < words.size(); ++i) {
    long long value = 0;
    bool read = false;
    if (words[i] == name && i + 1 < words.size()) {
      read = read_int(words[i + 1], value);
    } else if (words[i].compare(0, name.size() + 1, name + "=") == 0) {
      read = read_int(words[i].substr(name.size() + 1), value);
    }
    if (read && (!given || value > result)) {
      result = value;
      given = true;
    }
  }
  return result;
}

/** Whether some value given to `name` ("--name V" or "--name=V") is not an integer read_int()
    takes: such a command line is not costed, only parsed (what the command reads there is not
    known here). */
bool unreadable(const std::vector<std::string>& words, const std::string& name) {
  for (std::size_t i = 0; i < words.size(); ++i) {
    long long value = 0;
    if (words[i] == name && i + 1 < words.size() && !read_int(words[i + 1], value)) return true;
    if (words[i].compare(0, name.size() + 1, name + "=") == 0 &&
        !read_int(words[i].substr(name.size() + 1), value)) {
      return true;
    }
  }
  return false;
}

/** Whether `words` hold `flag` (also as "--flag=VALUE"). */
bool has_flag(const std::vector<std::string>& words, const std::string& flag) {
  for (const std::string& w : words) {
    if (w == flag || w.compare(0, flag.size() + 1, flag + "=") == 0) return true;
  }
  return false;
}

/** Whether some value given to `name` ("--name V" or "--name=V") is `value`. */
bool has_value(const std::vector<std::string>& words, const std::string& name,
               const std::string& value) {
  for (std::size_t i = 0; i < words.size(); ++i) {
    if ((words[i] == name && i + 1 < words.size() && words[i + 1] == value) ||
        words[i] == name + "=" + value) {
      return true;
    }
  }
  return false;
}

/** N_sim * N_FE * n_s * max(1, n_d) as the command would use them (N_sim 0: IRMA's 20), 0
    when the values are refused before any work. */
double work_of(const std::vector<std::string>& words) {
  long long nsim = option_value(words, "--nsim", 0);
  if (nsim == 0) nsim = 20;
  const long long nfe = option_value(words, "--nfe", 3);
  const long long stages = option_value(words, "--stages", 2);
  const long long lifting = option_value(words, "--lifting", 0);
  if (nsim < 1 || nfe < 1 || stages < 1) return 0.0;
  return static_cast<double>(nsim) * static_cast<double>(nfe) * static_cast<double>(stages) *
         static_cast<double>(lifting > 1 ? lifting : 1);
}

/** Whether the simulation `words` ask for may take seconds under the sanitizers. */
bool expensive(const std::vector<std::string>& words) {
  for (const char* name : {"--nsim", "--nfe", "--stages", "--lifting"}) {
    if (unreadable(words, name)) return true;
  }
  return has_value(words, "--example", "irma") || has_value(words, "--scheme", "gauss") ||
         has_flag(words, "--standard") || option_value(words, "--nsim", 0) == 1 ||
         option_value(words, "--nfe", 3) == 1 || work_of(words) > kWorkBudget;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::vector<std::string> words = bflow::fuzz::split_words(data, size);
  if (work_of(words) <= kWorkRefused && expensive(words) && !has_flag(words, "--sizes")) {
    words.push_back("--sizes");
  }
  bflow::fuzz::Contract contract;
  contract.warnings_on_success = true;
  contract.record_on_failure = true;
  bflow::fuzz::run_and_check("fesd", words, contract);
  return 0;
}

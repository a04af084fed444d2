// libFuzzer harness: the command line of `bflow flow`. The input is split into argv words at
// '\0' and '\n' and run as "bflow flow <words...>" (bflow::cli::run_cli); every accepted
// command line runs its simulation. Checks the output contract (fuzz_contract.h): "warning: "
// lines may accompany exit code 0, and a run that stops early (exit code 1) may print its
// partial JSON record.
//
// Per-input cost: a simulation takes milliseconds natively and about 100 times that under the
// sanitizers; the biped's bounces make a long horizon expensive (--t 1e6: 12 s). Command lines
// with a final time above kMaxTime are skipped (return -1: not added to the corpus). A start that
// makes the steps tiny (--x0 0,1,8,0,-1e10,0) runs the default 10^6 steps in 0.65 s natively,
// a minute under the sanitizers: without --max-steps the harness adds --max-steps kMaxSteps, and
// command lines asking for more are skipped. The other options are fuzzed as they come.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include "fuzz/fuzz_args.h"

namespace {

constexpr double kMaxTime = 10.0;
constexpr double kMaxSteps = 20000;

/** The value given to `option` ("--opt V" or "--opt=V"), or "" when it is not given. */
std::string value_of(const std::vector<std::string>& words, const std::string& option) {
  std::string value;
  for (std::size_t i = 0; i < words.size(); ++i) {
    if (words[i] == option && i + 1 < words.size()) value = words[i + 1];
    if (words[i].compare(0, option.size() + 1, option + "=") == 0) {
      value = words[i].substr(option.size() + 1);
    }
  }
  return value;
}

/** Whether some value given to --t ("--t T" or "--t=T") reads as a number above kMaxTime. */
bool long_horizon(const std::vector<std::string>& words) {
  for (std::size_t i = 0; i < words.size(); ++i) {
    std::string value;
    if (words[i] == "--t" && i + 1 < words.size()) {
      value = words[i + 1];
    } else if (words[i].compare(0, 4, "--t=") == 0) {
      value = words[i].substr(4);
    } else {
      continue;
    }
    const double t = std::strtod(value.c_str(), nullptr);
    if (t > kMaxTime) return true;  // also inf; nan compares false
  }
  return false;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::vector<std::string> words = bflow::fuzz::split_words(data, size);
  if (long_horizon(words)) return -1;
  const std::string steps = value_of(words, "--max-steps");
  if (steps.empty()) {
    words.push_back("--max-steps");
    words.push_back(std::to_string(static_cast<int>(kMaxSteps)));
  } else if (std::strtod(steps.c_str(), nullptr) > kMaxSteps) {
    return -1;
  }
  bflow::fuzz::Contract contract;
  contract.warnings_on_success = true;
  contract.record_on_failure = true;
  bflow::fuzz::run_and_check("flow", words, contract);
  return 0;
}

// The output contract of the `bflow` command, checked by the fuzz harnesses on every input;
// a violation prints what was broken and aborts, so that libFuzzer reports the input.
//
//   exit 0:    stdout is one JSON document; stderr is empty (or, where allowed, only lines
//              starting "warning: ");
//   exit 1, 2: stderr is exactly one line "error: ..." that is not "error: internal: ...";
//              stdout is empty (or, where allowed with exit 1, the JSON record of a run that
//              stopped early);
//   any other exit code is a violation.
#ifndef BFLOW_TESTS_FUZZ_FUZZ_CONTRACT_H_
#define BFLOW_TESTS_FUZZ_FUZZ_CONTRACT_H_

#include <cstdio>
#include <cstdlib>
#include <string>

#include <nlohmann/json.hpp>

namespace bflow::fuzz {

struct Contract {
  /** With exit code 0, stderr may hold "warning: ..." lines. */
  bool warnings_on_success = false;
  /** With exit code 1, stdout may hold a JSON record (a simulation that stopped early). */
  bool record_on_failure = false;
  /** With exit code 0, stdout may be the help ("Usage: bflow ...") or the version ("bflow
      0.1.0") instead of JSON. */
  bool text_on_success = false;
};

[[noreturn]] inline void violation(const std::string& what, int code, const std::string& out,
                                   const std::string& err) {
  constexpr std::size_t kShown = 4000;
  std::fprintf(stderr,
               "bflow contract violation: %s\nexit code: %d\n--- stdout (%zu bytes) ---\n%s\n"
               "--- stderr (%zu bytes) ---\n%s\n--- end ---\n",
               what.c_str(), code, out.size(), out.substr(0, kShown).c_str(), err.size(),
               err.substr(0, kShown).c_str());
  std::abort();
}

inline bool is_json(const std::string& text) { return nlohmann::json::accept(text); }

/** Every line of `text` ends with '\n' and starts with `prefix`. */
inline bool all_lines_start_with(const std::string& text, const std::string& prefix) {
  if (text.empty() || text.back() != '\n') return false;
  for (std::size_t begin = 0; begin < text.size();) {
    const std::size_t end = text.find('\n', begin);
    if (text.compare(begin, prefix.size(), prefix) != 0) return false;
    begin = end + 1;
  }
  return true;
}

/** Aborts unless (code, out, err) keep the contract. */
inline void check(int code, const std::string& out, const std::string& err,
                  const Contract& contract) {
  if (code == 0) {
    const bool text = contract.text_on_success && (out.find("Usage: bflow") != std::string::npos ||
                                                   out.compare(0, 6, "bflow ") == 0);
    if (!text && !is_json(out)) {
      violation("exit code 0 and stdout is not valid JSON", code, out, err);
    }
    if (!err.empty() && !(contract.warnings_on_success && all_lines_start_with(err, "warning: "))) {
      violation(contract.warnings_on_success
                    ? "exit code 0 and stderr holds a line not starting \"warning: \""
                    : "exit code 0 and stderr is not empty",
                code, out, err);
    }
    return;
  }
  if (code != 1 && code != 2) violation("exit code is not 0, 1 or 2", code, out, err);
  if (err.empty() || err.back() != '\n' || err.find('\n') != err.size() - 1) {
    violation("stderr is not exactly one line", code, out, err);
  }
  if (err.compare(0, 7, "error: ") != 0) {
    violation("stderr does not start with \"error: \"", code, out, err);
  }
  if (err.compare(0, 16, "error: internal:") == 0) {
    violation("an internal error (an exception the command did not expect)", code, out, err);
  }
  if (!out.empty() && !(code == 1 && contract.record_on_failure && is_json(out))) {
    violation(contract.record_on_failure && code == 1
                  ? "exit code 1 and stdout is neither empty nor valid JSON"
                  : "failure and stdout is not empty",
              code, out, err);
  }
}

}  // namespace bflow::fuzz

#endif  // BFLOW_TESTS_FUZZ_FUZZ_CONTRACT_H_

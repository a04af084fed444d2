// The output contract of the `bflow` command, checked by the fuzz harnesses on every input;
// a violation prints what was broken and aborts, so that libFuzzer reports the input (and a
// replay test, tests/fuzz/replay_main.cc, dies of SIGABRT).
//
//   exit 0:    stdout is one JSON document (sweep: lines of records, JSON lines or CSV); stderr
//              is empty (or, where allowed, only lines starting "warning: " and progress lines);
//   exit 1, 2: stderr is exactly one line "error: ..." of at most 500 characters that is not
//              "error: internal: ...";
//              with exit code 1 progress lines (and, where allowed, "warning: " lines) may come
//              before it; stdout is empty (or, where allowed with exit 1, the JSON record of a
//              run that stopped early, or the records a sweep wrote before it failed);
//   any other exit code is a violation.
#ifndef BFLOW_TESTS_FUZZ_FUZZ_CONTRACT_H_
#define BFLOW_TESTS_FUZZ_FUZZ_CONTRACT_H_

#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace bflow::fuzz {

/** What stdout holds after exit code 0. */
enum class Output {
  kJsonDocument,  ///< one JSON document
  kJsonLines,     ///< nothing, or lines each ending in '\n' and each a JSON document
  kTextLines,     ///< nothing, or lines each ending in '\n' (CSV)
};

struct Contract {
  Output output = Output::kJsonDocument;
  /** With exit code 0, stderr may hold "warning: ..." lines. */
  bool warnings_on_success = false;
  /** With exit code 1, "warning: ..." lines may come before the error line. */
  bool warnings_on_failure = false;
  /** With exit code 1, stdout may hold a record: a JSON document (a simulation that stopped
      early) or, for the line outputs, the lines written before the failure. */
  bool record_on_failure = false;
  /** With exit code 0, stdout may be the help ("Usage: bflow ...") or the version ("bflow
      0.1.0") instead of JSON. */
  bool text_on_success = false;
  /** With exit code 0 or 1, lines of stderr that start with one of these (progress lines, a
      summary) may come before the outcome. */
  std::vector<std::string> progress_prefixes;
};

/** The longest error line, in characters (code points) without its newline. */
inline constexpr std::size_t kMaxErrorLine = 500;

/** Called before a violation aborts: a harness removes its scratch directory there. */
inline std::function<void()> before_abort;

[[noreturn]] inline void violation(const std::string& what, int code, const std::string& out,
                                   const std::string& err) {
  constexpr std::size_t kShown = 4000;
  std::fprintf(stderr,
               "bflow contract violation: %s\nexit code: %d\n--- stdout (%zu bytes) ---\n%s\n"
               "--- stderr (%zu bytes) ---\n%s\n--- end ---\n",
               what.c_str(), code, out.size(), out.substr(0, kShown).c_str(), err.size(),
               err.substr(0, kShown).c_str());
  if (before_abort) before_abort();
  std::abort();
}

inline bool is_json(const std::string& text) { return nlohmann::json::accept(text); }

/** The lines of `text`, without their '\n'; a last line without one is kept as it is. */
inline std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> lines;
  for (std::size_t begin = 0; begin < text.size();) {
    std::size_t end = text.find('\n', begin);
    if (end == std::string::npos) end = text.size();
    lines.push_back(text.substr(begin, end - begin));
    begin = end + 1;
  }
  return lines;
}

/** Every line of `text` ends with '\n' and starts with `prefix`. */
inline bool all_lines_start_with(const std::string& text, const std::string& prefix) {
  if (text.empty() || text.back() != '\n') return false;
  for (const std::string& line : lines_of(text)) {
    if (line.compare(0, prefix.size(), prefix) != 0) return false;
  }
  return true;
}

/** Whether `out` is what `output` allows: one JSON document, or whole lines (each a JSON
    document for kJsonLines). */
inline bool output_is(const std::string& out, Output output) {
  if (output == Output::kJsonDocument) return is_json(out);
  if (out.empty()) return true;
  if (out.back() != '\n') return false;
  if (output == Output::kTextLines) return true;
  for (const std::string& line : lines_of(out)) {
    if (!is_json(line)) return false;
  }
  return true;
}

/** Aborts unless (code, out, err) keep the contract. */
inline void check(int code, const std::string& out, const std::string& err,
                  const Contract& contract) {
  // Progress lines are set aside first (exit codes 0 and 1 only); the rest is checked.
  std::string rest = err;
  if (!contract.progress_prefixes.empty() && (code == 0 || code == 1) && !err.empty()) {
    if (err.back() != '\n') violation("stderr does not end with a newline", code, out, err);
    rest.clear();
    for (const std::string& line : lines_of(err)) {
      bool progress = false;
      for (const std::string& prefix : contract.progress_prefixes) {
        progress = progress || line.compare(0, prefix.size(), prefix) == 0;
      }
      if (!progress) rest += line + '\n';
    }
  }
  if (code == 0) {
    const bool text = contract.text_on_success && (out.find("Usage: bflow") != std::string::npos ||
                                                   out.compare(0, 6, "bflow ") == 0);
    if (!text && !output_is(out, contract.output)) {
      violation(contract.output == Output::kJsonDocument
                    ? "exit code 0 and stdout is not valid JSON"
                    : "exit code 0 and stdout is not whole lines of records",
                code, out, err);
    }
    if (!rest.empty() &&
        !(contract.warnings_on_success && all_lines_start_with(rest, "warning: "))) {
      violation(contract.warnings_on_success
                    ? "exit code 0 and stderr holds a line not starting \"warning: \""
                : contract.progress_prefixes.empty()
                    ? "exit code 0 and stderr is not empty"
                    : "exit code 0 and stderr holds more than progress lines",
                code, out, err);
    }
    return;
  }
  if (code != 1 && code != 2) violation("exit code is not 0, 1 or 2", code, out, err);
  if (code == 1 && contract.warnings_on_failure) {
    while (rest.compare(0, 9, "warning: ") == 0 && rest.find('\n') != std::string::npos) {
      rest.erase(0, rest.find('\n') + 1);
    }
  }
  if (rest.empty() || rest.back() != '\n' || rest.find('\n') != rest.size() - 1) {
    violation("stderr is not exactly one line (besides progress lines)", code, out, err);
  }
  if (!contract.progress_prefixes.empty() &&
      err.compare(err.size() - rest.size(), rest.size(), rest) != 0) {
    violation("the error line is not the last line of stderr", code, out, err);
  }
  if (rest.compare(0, 7, "error: ") != 0) {
    violation("stderr does not start with \"error: \"", code, out, err);
  }
  // Bounded whatever the input: user text is quoted at a bounded length in every message.
  std::size_t characters = 0;
  for (char c : rest) characters += (static_cast<unsigned char>(c) & 0xc0) != 0x80 ? 1 : 0;
  if (characters - 1 > kMaxErrorLine) {
    violation("the error line is longer than 500 characters", code, out, err);
  }
  // "error: internal: ..." (run_cli) or "error: <command>: internal: ..." (a command's own).
  const std::size_t colon = rest.find(": ", 7);
  const bool internal = rest.compare(7, 9, "internal:") == 0 ||
                        (colon != std::string::npos && rest.find(' ', 7) == colon + 1 &&
                         rest.compare(colon + 2, 9, "internal:") == 0);
  if (internal) {
    violation("an internal error (an exception the command did not expect)", code, out, err);
  }
  const bool record_allowed =
      code == 1 && contract.record_on_failure && output_is(out, contract.output);
  if (!out.empty() && !record_allowed) {
    violation(contract.record_on_failure && code == 1
                  ? "exit code 1 and stdout is neither empty nor a record"
                  : "failure and stdout is not empty",
              code, out, err);
  }
}

}  // namespace bflow::fuzz

#endif  // BFLOW_TESTS_FUZZ_FUZZ_CONTRACT_H_

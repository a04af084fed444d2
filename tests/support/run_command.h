// Runs the `bflow` command in-process and keeps what it wrote: the command-line tests of
// tests/cli and the fuzz harnesses of tests/fuzz share it, so that every one of them calls
// run_cli exactly as main() does (argv[0] = "bflow", a given standard input).
#ifndef BFLOW_TESTS_SUPPORT_RUN_COMMAND_H_
#define BFLOW_TESTS_SUPPORT_RUN_COMMAND_H_

#include <istream>
#include <ostream>
#include <sstream>
#include <string>
#include <vector>

#include "cli_commands.h"

namespace bflow::testing {

/** A run's exit code and everything it wrote to stdout and stderr. */
struct Outcome {
  int code = 0;
  std::string out;
  std::string err;
};

/** Calls run(out, err), which returns the exit code, with fresh string streams. */
template <typename Run>
Outcome capture(Run&& run) {
  std::ostringstream out, err;
  const int code = run(static_cast<std::ostream&>(out), static_cast<std::ostream&>(err));
  return {code, out.str(), err.str()};
}

/** "bflow <args...>" in-process, with `stdin_text` as its standard input. */
inline Outcome command_line(const std::vector<std::string>& args,
                            const std::string& stdin_text = "") {
  std::vector<const char*> argv = {"bflow"};
  for (const std::string& a : args) argv.push_back(a.c_str());
  std::istringstream in(stdin_text);
  return capture([&](std::ostream& out, std::ostream& err) {
    return cli::run_cli(static_cast<int>(argv.size()), argv.data(), in, out, err);
  });
}

}  // namespace bflow::testing

#endif  // BFLOW_TESTS_SUPPORT_RUN_COMMAND_H_

// The `bflow` command, callable in-process (the tests do) as well as from main().
//
// Every entry point writes results to `out`, diagnostics to `err`, and returns the exit code:
//   0  success;
//   1  the computation or its output failed (a non-finite result, a file that cannot be
//      written, gnuplot missing or failing, an unexpected internal error);
//   2  bad input or usage (malformed JSON, a field with the wrong shape or type, an unknown key,
//      input the core rejects such as non-transversal limits, an unknown option, an
//      unreadable input file).
// On failure `err` receives exactly one line, "error: <field>: <problem>", naming the offending
// field ("normals", "tangents[3]", "field_limits", "input", ...).
//
//   std::istringstream in(R"({"normals": [[1]], "field_limits": {"-": [1], "+": [2]},
//                             "tangents": [[-1]]})");
//   std::ostringstream out, err;
//   int code = bflow::cli::run_jump(in, out, err);  // 0; out holds {"n": 1, "d": 1, ...}
#ifndef BFLOW_CLI_CLI_COMMANDS_H_
#define BFLOW_CLI_CLI_COMMANDS_H_

#include <iosfwd>
#include <string>

namespace bflow::cli {

inline constexpr int kExitOk = 0;
inline constexpr int kExitFailure = 1;
inline constexpr int kExitBadInput = 2;

/** The version string printed by `bflow --version` ("bflow 0.1.0"). */
std::string version_string();

struct JumpOptions {
  /** One line of JSON instead of the indented form. */
  bool compact = false;
};

/** `bflow jump`: reads the JSON document from `in` (see docs/cli.md), writes the JSON result
    to `out`. Never throws. */
int run_jump(std::istream& in, std::ostream& out, std::ostream& err,
             const JumpOptions& options = {});

/** `bflow jump --input PATH`: as run_jump, reading PATH, or `stdin` when PATH is "-". An
    unreadable file is bad input (exit code 2). Never throws. */
int run_jump_file(const std::string& path, std::istream& stdin_stream, std::ostream& out,
                  std::ostream& err, const JumpOptions& options = {});

struct DemoOptions {
  /** Directory for demo_circle.{dat,gp,png}; created if missing. */
  std::string output_dir = "bflow-demo";
  /** Skip running gnuplot (the .dat and .gp files are still written). */
  bool no_plot = false;
};

/** `bflow demo`: the piecewise-constant field of [B] Section 3.1 at rho = 0, d = 2 (see
    docs/cli.md). Prints the table, the pieces and self-checks, writes the files, runs
    gnuplot. Returns 1 when a self-check fails, a file cannot be written, or gnuplot fails.
    Never throws. */
int run_demo(const DemoOptions& options, std::ostream& out, std::ostream& err);

/** The whole command line (argv[0] is ignored): parses it and dispatches. Never throws. */
int run_cli(int argc, const char* const* argv, std::istream& in, std::ostream& out,
            std::ostream& err);

}  // namespace bflow::cli

#endif  // BFLOW_CLI_CLI_COMMANDS_H_

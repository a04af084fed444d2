// Command-line parsing for `bflow` (CLI11) and dispatch to the commands.
#include <exception>
#include <istream>
#include <ostream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "cli_commands.h"
#include "cli_util.h"

#ifndef BFLOW_VERSION
#error "BFLOW_VERSION must be defined (the CMake project version)"
#endif

namespace bflow::cli {
namespace {

constexpr const char* kMainFooter = R"(Exit codes:
  0  success
  1  the computation or its output failed (a non-finite result, a file that cannot be
     written, gnuplot missing or failing)
  2  bad input or usage: the one line on stderr, "error: <field>: <problem>", names it

Run 'bflow jump --help' for the JSON format. Documentation: docs/cli.md.)";

constexpr const char* kJumpFooter =
    R"(Input, one JSON object (n surfaces meet at a point rho in d dimensions):
  "normals":       [[eta_0...], ...]        n rows of d numbers, oriented so that every
                                            eta_j . F_b > 0 (full row rank, n <= d)
  "field_limits":  {"--": [d numbers], ...} Gamma(b) = F_b(rho) for every sign word b of
                                            n characters; character j is surface j
  "tangents":      [[d numbers], ...]       directions dx before the event (may be [])
  "pieces":        true | false             optional: all n! pieces (n <= 10)
  "triangulation": true | false             optional: the triangulation of [B] Section 5
Any other key is an error.

Output, one JSON object (numbers print in the shortest form that reads back exactly):
  "n", "d"
  "results":  one per tangent, in order:
     "image"             B(dx) by Algorithm 2.1
     "order"             surfaces in the order dx crosses them (surface indices from 0)
     "crossing_times"    when each is crossed (time 0: dx itself on the F_{-...-} line)
     "jacobian"          M_sigma for that order, rows of the d x d matrix
     "barycentric_image" B(dx) by the triangulation (with "triangulation": true)
  "pieces":        [{"order": [...], "matrix": [[...], ...]}, ...]  (with "pieces": true)
  "triangulation": {"zeta": {word: [...]}, "zeta_image": {word: [...]},
                    "lineality_basis": [[...], ...] (columns), "simplices":
                    [{"order": [...], "words": ["--", ...]}, ...]}

Example (one surface, x_0 = 0, in d = 2):
  $ echo '{"normals": [[1, 0]], "field_limits": {"-": [1, 0], "+": [2, 1]},
           "tangents": [[-1, 0]]}' | bflow jump --input -
  {"n": 1, "d": 2, "results": [{"image": [-2.0, -1.0], "order": [0],
    "crossing_times": [1.0], "jacobian": [[2.0, 0.0], [1.0, 1.0]]}]}   (printed indented)

Bad input exits with code 2 and one line on stderr, e.g.
  error: tangents[0]: has 3 numbers, expected d = 2)";

constexpr const char* kDemoFooter =
    R"(The field xdot = 1 + Delta(sign(x)) of [B] Section 3.1 with d = 2 and a non-linear
Delta: its flow through rho = 0 has a B-derivative with two pieces. Prints B on unit
vectors every 45 degrees and on F_--, the pieces M_(0,1) and M_(1,0), and checks against
the triangulation and one-sided differences of the exact flow. Writes DIR/demo_circle.dat
(the unit circle at 720 points and its image under B, a piecewise ellipse),
DIR/demo_circle.gp, and runs gnuplot on it to draw DIR/demo_circle.png. Exits with code 1
if a check fails, a file cannot be written, or gnuplot is missing or fails.)";

}  // namespace

std::string version_string() { return std::string("bflow ") + BFLOW_VERSION; }

int run_cli(int argc, const char* const* argv, std::istream& in, std::ostream& out,
            std::ostream& err) {
  try {
    CLI::App app(
        "bflow: B-derivatives (first-order sensitivities) of flows of nonsmooth vector fields "
        "at points where switching surfaces meet.",
        "bflow");
    app.set_version_flag("--version", version_string(), "Print the version and exit");
    app.require_subcommand(1);
    app.footer(kMainFooter);

    std::string input;
    JumpOptions jump_options;
    CLI::App* jump = app.add_subcommand(
        "jump",
        "Evaluate the jump map B at one event: normals, field limits, tangents in; images, "
        "crossing orders, Jacobians out (JSON)");
    jump->add_option("-i,--input", input, "JSON input file, or - for the standard input")
        ->required()
        ->type_name("FILE|-");
    jump->add_flag("--compact", jump_options.compact, "Print the result on one line");
    jump->footer(kJumpFooter);

    DemoOptions demo_options;
    CLI::App* demo = app.add_subcommand(
        "demo", "Table and plot of B for the piecewise-constant field of [B] Section 3.1 in d = 2");
    demo->add_option("-o,--output", demo_options.output_dir,
                     "Directory for demo_circle.{dat,gp,png}; created if missing")
        ->type_name("DIR")
        ->capture_default_str();
    demo->add_flag("--no-plot", demo_options.no_plot,
                   "Write the data and the gnuplot script but do not run gnuplot");
    demo->footer(kDemoFooter);

    if (argc <= 1) {
      report_error(err, "a command is required: jump or demo (see 'bflow --help')");
      return kExitBadInput;
    }
    if (argv[1][0] != '-' && std::string(argv[1]) != "jump" && std::string(argv[1]) != "demo") {
      report_error(err, "unknown command " + quote(argv[1]) +
                            "; the commands are jump and demo (see 'bflow --help')");
      return kExitBadInput;
    }
    std::vector<std::string> args;
    for (int i = argc - 1; i >= 1; --i) args.emplace_back(argv[i]);  // CLI11 wants them reversed
    try {
      app.parse(args);
    } catch (const CLI::ParseError& e) {
      if (e.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) {
        return app.exit(e, out, err);  // --help, --version
      }
      std::string message = e.what();
      if (message.empty()) message = e.get_name();
      const std::string where = jump->parsed() ? "jump: " : demo->parsed() ? "demo: " : "";
      const std::string help = jump->parsed()   ? "bflow jump --help"
                               : demo->parsed() ? "bflow demo --help"
                                                : "bflow --help";
      report_error(err, where + message + " (see '" + help + "')");
      return kExitBadInput;
    }
    if (jump->parsed()) return run_jump_file(input, in, out, err, jump_options);
    return run_demo(demo_options, out, err);
  } catch (const std::exception& e) {
    report_error(err, std::string("internal: ") + e.what());
    return kExitFailure;
  }
}

}  // namespace bflow::cli

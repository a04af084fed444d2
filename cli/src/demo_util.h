// Helpers shared by the scenes of `bflow demo` (and the plots and files of `bflow ocp`, `orbit`
// and `sweep`): formatted text, files and paths, checks and gnuplot.
#ifndef BFLOW_CLI_DEMO_UTIL_H_
#define BFLOW_CLI_DEMO_UTIL_H_

#include <cstdio>
#include <filesystem>
#include <ostream>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "cli_commands.h"

namespace bflow::cli {

/** A failure of the demo or of a plot (a file, gnuplot); run_demo() and run_ocp() print it and
    return 1. */
class DemoError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/** snprintf into a string (at most 255 characters). */
template <typename... Args>
std::string formatted(const char* format, Args... args) {
  char buffer[256];
  std::snprintf(buffer, sizeof buffer, format, args...);
  return buffer;
}

/** "( 1.000000,  0.500000)"; entries below 5e-7 in magnitude print as 0 (rounding noise such
    as cos(90 deg) = 6e-17 would print as "-0.000000"). */
std::string vector_text(const Eigen::Ref<const Eigen::VectorXd>& v);

/** "(0,1)". */
std::string order_text(const std::vector<int>& order);

/** A self-check: passed when value <= bound, or value >= bound for a lower bound. */
struct Check {
  std::string what;
  double value;
  double bound;
  bool lower_bound = false;
};

/** Prints one line per check and a verdict; returns true when all passed. */
bool print_checks(std::ostream& out, const std::vector<Check>& checks);

/** Creates `dir` (and its parents) and checks that a file can be created in it, so that the
    command is refused before it computes anything. @throws DemoError "<command>: ..." naming
    the directory and the reason (errno's text). */
void prepare_output_directory(const std::filesystem::path& dir,
                              const std::string& command = "demo");

/** @throws DemoError "<command>: ..." when `path` exists and is not a regular file (a
    directory, a device): the commands never replace one. */
void check_replaceable_file(const std::filesystem::path& path, const std::string& command = "demo");

/** Checks, before anything is computed, that write_file(path) can succeed: `path` does not
    exist or is a regular file, and its directory exists and accepts a new file (a probe file,
    removed at once). Creates nothing. @throws DemoError "<command>: ..." naming the file, the
    directory and the reason. */
void check_writable_file(const std::filesystem::path& path, const std::string& command = "demo");

/** `path` made absolute, its links followed (also one whose target does not exist yet, which a
    write would create), and normalised. */
std::filesystem::path resolved(const std::filesystem::path& path);

/** Whether a and b name one file: the same path once resolved, or one file by two names (a hard
    link). */
bool same_file(const std::filesystem::path& a, const std::filesystem::path& b);

/** Writes `contents` to `path`: to a temporary file beside it, renamed onto `path` once whole,
    so that a failure leaves any earlier `path` as it was. @throws DemoError "<command>: ..."
    naming the file and the reason, also when `path` exists and is not a regular file. */
void write_file(const std::filesystem::path& path, const std::string& contents,
                const std::string& command = "demo");

/** Runs `gnuplot SCRIPT` in `dir` with bflow_output set to a temporary file, checks that gnuplot
    wrote it, non-empty, and renames it onto `png`: a failed plot leaves an earlier `png` as it
    was. The script sets its output with gnuplot_output(png). @throws DemoError "<command>: ..."
    naming the gnuplot command on failure, or `png` when it exists and is not a regular file;
    when gnuplot cannot be started, the message ends with "install gnuplot (Debian:
    gnuplot-nox) or <without_plot>". */
void run_gnuplot(const std::filesystem::path& dir, const std::string& script,
                 const std::string& png, const std::string& command = "demo",
                 const std::string& without_plot = "pass --no-plot");

/** "set output (exists('bflow_output') ? bflow_output : 'PNG')\n": a script's output line, the
    PNG when a user runs the script, the temporary file when run_gnuplot() does. */
std::string gnuplot_output(const std::string& png);

/** The two demo scenes (run_demo() prepares the output directory, dispatches and catches). */
int demo_pwconst(const DemoOptions& options, std::ostream& out, std::ostream& err);
int demo_biped(const DemoOptions& options, std::ostream& out, std::ostream& err);

/** A point of a circle of perturbations, its image (projected on the plotted plane) and the
    index of the piece active there. */
struct Sample {
  double angle_deg;
  Eigen::Vector2d dx;
  Eigen::Vector2d image;
  int piece;
};

/** One line per sample; numbers in shortest round-trip form, exactly what the library gave. */
void write_samples(std::ostream& out, const std::vector<Sample>& samples);

/** Fill colour of piece 0 or 1 in the demo plots. */
inline std::string gnuplot_color(int piece) { return piece == 0 ? "#DAA520" : "#2E8B57"; }

}  // namespace bflow::cli

#endif  // BFLOW_CLI_DEMO_UTIL_H_

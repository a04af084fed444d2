// The `bflow` command, callable in-process (the tests do) as well as from main().
//
// Every entry point writes results to `out`, diagnostics to `err`, and returns the exit code:
//   0  success;
//   1  the computation or its output failed (a non-finite result, a simulation that stops
//      early, an optimal control problem not solved, a failed self-check of the demo, a file
//      that cannot be written, gnuplot missing or failing, an unexpected internal error);
//   2  bad input or usage (malformed JSON, a field with the wrong shape or type, an unknown key,
//      input the library rejects such as non-transversal limits or sliding, a malformed option
//      value, an unknown option or scene, an unreadable input file).
// On failure `err` receives exactly one line, "error: <field>: <problem>", naming the offending
// field or option ("normals", "tangents[3]", "--dx[1]", "--param", "flow", ...).
//
//   std::istringstream in(R"({"normals": [[1]], "field_limits": {"-": [1], "+": [2]},
//                             "tangents": [[-1]]})");
//   std::ostringstream out, err;
//   int code = bflow::cli::run_jump(in, out, err);  // 0; out holds {"n": 1, "d": 1, ...}
//
//   bflow::cli::FlowCommandOptions flow;
//   flow.scene = "pwconst";
//   flow.params = {"d=3", "delta=0.25"};
//   code = bflow::cli::run_flow(flow, out, err);    // 0; every "image" is 0.6 dx
#ifndef BFLOW_CLI_CLI_COMMANDS_H_
#define BFLOW_CLI_CLI_COMMANDS_H_

#include <iosfwd>
#include <optional>
#include <string>
#include <vector>

namespace bflow {
class MpiSession;
}  // namespace bflow

namespace bflow::cli {

inline constexpr int kExitOk = 0;
inline constexpr int kExitFailure = 1;
inline constexpr int kExitBadInput = 2;

/** The version string printed by `bflow --version` ("bflow 0.1.0"). */
std::string version_string();

/** Default of JumpOptions::max_input_bytes: 64 MiB. */
inline constexpr long long kJumpDefaultMaxInputBytes = 64LL << 20;
/** Default of JumpOptions::max_output_bytes: 1 GiB. */
inline constexpr long long kJumpDefaultMaxOutputBytes = 1LL << 30;

struct JumpOptions {
  /** One line of JSON instead of the indented form. */
  bool compact = false;
  /** Longest input read, in bytes (--max-input-bytes); a longer input is refused (exit 2)
      after reading one byte more, so an endless stream such as /dev/zero ends at once. */
  long long max_input_bytes = kJumpDefaultMaxInputBytes;
  /** Largest output, in bytes, as estimated before anything is computed (--max-output-bytes):
      a request above it (n! pieces for large n) is refused (exit 2) with the estimate. Pieces
      are streamed, one at a time, so memory stays O(n d^2) whatever this limit. */
  long long max_output_bytes = kJumpDefaultMaxOutputBytes;
};

/** `bflow jump`: reads the JSON document from `in` (see docs/cli.md), writes the JSON result
    to `out`. Never throws. */
int run_jump(std::istream& in, std::ostream& out, std::ostream& err,
             const JumpOptions& options = {});

/** `bflow jump --input PATH`: as run_jump, reading PATH, or `stdin` when PATH is "-". An
    unreadable file is bad input (exit code 2). Never throws. */
int run_jump_file(const std::string& path, std::istream& stdin_stream, std::ostream& out,
                  std::ostream& err, const JumpOptions& options = {});

/** `bflow flow`: the options as given on the command line. Numbers stay text so that
    run_flow() validates them and names the option in its message. */
struct FlowCommandOptions {
  /** "pwconst", "biped" or "pronk"; required. */
  std::string scene;
  /** "key=value", each key at most once: pwconst d, delta, seed; biped and pronk as
      bflow::set_param. */
  std::vector<std::string> params;
  /** Final time (default 1 for pwconst, 0.6 for biped and pronk), >= 0. */
  std::optional<std::string> t;
  /** "a,b,..." with d numbers (default: rho- = -F_--(0)/2 for pwconst, biped_initial_state(),
      pronk_initial_state()). */
  std::optional<std::string> x0;
  /** Directions "a,b,..." with d numbers each (default: the unit vectors e_0 ... e_{d-1}). */
  std::vector<std::string> dx;
  std::optional<std::string> rtol;
  std::optional<std::string> atol;
  /** "auto", "dopri5", "dop853", "cvodes-bdf" or "cvodes-adams" (bflow::parse_backend). */
  std::string integrator = "auto";
  /** "auto", "window" or "none" (bflow::parse_grouping); default auto. */
  std::optional<std::string> grouping;
  /** With --grouping window: the window in time, >= 0 (FlowOptions::simultaneity_window). */
  std::optional<std::string> window;
  /** Steps per smooth segment before the run stops (bflow::IntegratorOptions::max_steps). */
  std::optional<std::string> max_steps;
  /** Also finite differences of the simulated flow for every direction (bflow::fd::compare). */
  bool fd = false;
  /** One line of JSON instead of the indented form. */
  bool compact = false;
};

/** `bflow flow`: simulates the scene to t, computes the B-derivative of its flow once
    (bflow::flow_derivative) and prints, as JSON, x(t), the events and, for every direction,
    the image D phi_t(x0; dx), the crossing orders and the active Jacobian (see docs/cli.md).
    Exit code 2 for a bad option or input the library rejects (sliding, grazing, x0 on a
    surface), 1 when the simulation stops early (the JSON then has "status" and "message").
    Every notice of the run (near-simultaneous crossings not grouped, near grazing) is in the
    JSON's "notices" and printed as one "warning: ..." line on `err`.
    Never throws. */
int run_flow(const FlowCommandOptions& options, std::ostream& out, std::ostream& err);

/** `bflow sweep`: the flow of a scene and its B-derivative for every sample of a grid of initial
    states and scene parameters, on threads, one record per sample in grid order
    (bflow/sweep/sweep.h has the record formats, docs/sweep.md the command). */
struct SweepCommandOptions {
  /** The scene, parameters, t, x0, directions (dx), tolerances, integrator and grouping, as for
      `bflow flow` (fd and compact are not used). Without --dx no direction is evaluated. */
  FlowCommandOptions flow;
  /** "I=lo:hi:count": x0[I] takes count values from lo to hi; repeat for more axes. */
  std::vector<std::string> vary;
  /** "key=lo:hi:count": the scene parameter key (a real-valued one) does the same. */
  std::vector<std::string> vary_param;
  /** Worker threads, >= 1 (default: one per core; under MPI, per rank: the cores divided by the
      ranks on the machine). */
  std::optional<std::string> threads;
  /** "jsonl" (default) or "csv". */
  std::string format = "jsonl";
  /** Write the records to this file instead of `out`. */
  std::optional<std::string> output;
  /** Also draw the atlas of crossing orders of a two-axis grid to this PNG (gnuplot): a colour
      per event structure along the first --dx (bflow::event_structure); the grouped events and
      the failed samples marked. Its data and script are written beside it (.dat, .gp). */
  std::optional<std::string> atlas;
  /** With --output: keep the whole records an earlier run of the same sweep left in the file
      and compute the rest (bflow::find_resume_point). */
  bool resume = false;
  /** No progress bar on `err`. */
  bool quiet = false;
};
int run_sweep(const SweepCommandOptions& options, std::ostream& out, std::ostream& err);
/** The MPI world `bflow sweep` shares its samples with (main() sets it; nullptr or one rank: a
    single process). On ranks other than 0 the command writes nothing. */
void set_mpi_session(const MpiSession* session);

struct DemoOptions {
  /** Directory for the demo's .dat, .gp and .png files; created if missing. */
  std::string output_dir = "bflow-demo";
  /** Skip running gnuplot (the .dat and .gp files are still written). */
  bool no_plot = false;
  /** "biped" (the mode-damping biped of [B] Section 3.2.4, files demo_biped.*) or "pwconst"
      (the planar piecewise-constant field of [B] Section 3.1, files demo_circle.*). */
  std::string scene = "biped";
};

/** `bflow demo`: with scene "biped", the B-derivative of the mode-damping biped's flow through
    the touchdown of both feet: the event, the two pieces of its jump, a table of B against
    one-sided differences, and the image of a circle of (theta, thetadot) perturbations (a
    piecewise ellipse, [B] Figure 3.2). With scene "pwconst", the piecewise-constant field of
    [B] Section 3.1 at rho = 0, d = 2. Prints the tables and self-checks, writes the files, runs
    gnuplot (see docs/cli.md). Returns 2 for an unknown scene or an empty directory name, 1
    when a self-check fails, a file cannot be written, or gnuplot fails. Never throws. */
int run_demo(const DemoOptions& options, std::ostream& out, std::ostream& err);

/** The solver options `bflow fesd` and `bflow ocp` share (their help's "Solver" group), as
    given; the same fields of bflow::FesdOptions and bflow::OcpOptions. A linear solver that is
    unknown or whose library cannot be loaded, or blas_threads < 0: exit code 2 before computing. */
struct SolverCommandOptions {
  /** --linear-solver: IPOPT's, one of bflow::kLinearSolvers (mumps, spral, HSL's ma27 ... ma97
      from Coin-HSL, pardiso, pardisomkl). */
  std::string linear_solver = "mumps";
  /** --linear-solver-library: the HSL or PARDISO library file ("": libcoinhsl.so, then
      libhsl.so; libpardiso.so). */
  std::string linear_solver_library;
  /** --blas-threads: OpenBLAS's threads during the NLPs, >= 0 (0: OpenBLAS's own count). */
  int blas_threads = 1;
  /** --jet-derivatives: SolverOptions::derivative_programs false (Jets at every evaluation). */
  bool jet_derivatives = false;
};

/** `bflow fesd`: the options as given on the command line. run_fesd() checks every range and
    names the option in its message. */
struct FesdCommandOptions {
  /** irma, crossing, sliding-enter, sliding-leave or spontaneous; required. */
  std::string example;
  std::string formulation = "step";  ///< step or stewart
  std::string scheme = "radau";      ///< radau or gauss
  int stages = 2;                    ///< n_s, 1..9
  /** Finite elements per integration step, >= 1 and within bflow::kFesdMaxIndex and
      bflow::kFesdMaxMemoryBytes (bflow::fesd_problem_size). */
  int nfe = 3;
  /** Integration steps, >= 1 (the run's results within the memory bound); not given: the
      example's default. */
  std::optional<int> nsim;
  /** Horizon, finite and > 0; not given: the example's default. */
  std::optional<double> t;
  bool standard = false;       ///< standard time-stepping, no switch detection
  bool exact_hessian = false;  ///< IPOPT with exact Hessians instead of limited-memory
  bool trajectory = false;     ///< add the grid, states, step sizes and active sets
  bool sizes = false;          ///< print [F] Table 4 and the NLP size for the example instead
  /** Lifting depth n_d: 0 (none) or 2..max(2, n_c), also for --sizes. */
  int lifting = 0;
  SolverCommandOptions solver;
  bool compact = false;
};

/** `bflow fesd`: simulates a built-in Filippov example by FESD (bflow::fesd_simulate) and
    prints the horizon and steps used, x(T), the switch times, the complementarity residual, the
    CPU time and the sensitivity dx(T)/dx0 as JSON (see docs/cli.md); with `sizes`, the problem
    sizes of Stewart's and the step reformulation ([F] Table 4) and of one step's NLP. Exit code
    2 for a bad option (out of range, a problem above the size limits, a linear solver whose
    library cannot be loaded), 1 when an integration step does not converge (the JSON then holds
    what was reached, and `err` one "error: fesd:" line). Never throws. */
int run_fesd(const FesdCommandOptions& options, std::ostream& out, std::ostream& err);

/** `bflow ocp`: the options as given on the command line. run_ocp() checks every range and
    names the option in its message. */
struct OcpCommandOptions {
  /** turbo-car or braking-block (bflow/examples/ocp_examples.h), monoped
      (bflow/examples/monoped_ocp.h) or hopper (bflow/examples/hopper.h); required. */
  std::string example;
  /** --N: control stages, >= 1; not given: 10, 30 for the monoped, 50 for the hopper. */
  std::optional<int> n;
  int nfe = 3;                   ///< finite elements per control stage, >= 1
  int stages = 2;                ///< n_s, 1..9
  std::string scheme = "radau";  ///< radau or gauss
  /** integral or derivative (bflow::CollocationForm). */
  std::string collocation_form = "integral";
  /** step or stewart; not given: stewart for the hopper, else step. */
  std::optional<std::string> formulation;
  bool standard = false;                ///< standard time-stepping, no switch detection
  std::string relaxation = "scholtes";  ///< scholtes or l1
  /** --cross: element-sums or point-pairs (bflow::CrossComplementarity); not given: the
      example's (point-pairs for the monoped with stewart, else element-sums). */
  std::optional<std::string> cross;
  /** The monoped's setup (examples::MonopedSetup): nosnoc (not given) or strict. */
  std::optional<std::string> setup;
  /** Relaxation parameters and IPOPT's tolerance of the last NLP, finite and > 0 with
      sigma_final <= sigma0; not given: the defaults of bflow::OcpOptions. */
  std::optional<double> sigma0, sigma_final, tol;
  /** --early-polish-sigma: bflow::OcpHomotopyOptions::early_polish_sigma, finite and >= 0 (0: only
      the final polish); not given: the example's. */
  std::optional<double> early_polish_sigma;
  /** --monotone-mu-down-to: bflow::OcpHomotopyOptions::monotone_mu_down_to, >= 0 (inf: IPOPT's
      adaptive mu strategy for every NLP); not given: the example's. */
  std::optional<double> monotone_mu_down_to;
  /** --max-iterations: IPOPT iterations of the whole homotopy, >= 0 (0: no limit but IPOPT's
      per NLP); not given: bflow::OcpHomotopyOptions::max_total_iterations of the example. */
  std::optional<int> max_iterations;
  /** --lifting: the step formulation's lifting depth (OcpOptions::lifting_depth); not given:
      the example's (2 for the monoped's nosnoc setup, else 0). */
  std::optional<int> lifting;
  SolverCommandOptions solver;
  bool trajectory = false;  ///< add every element boundary, the states there, h, active sets
  /** Directory (created if missing) for ocp_states.png, ocp_controls.png, ocp_switching.png
      and their data and gnuplot scripts; not given: no plots. */
  std::optional<std::string> plot;
  bool compact = false;
  bool quiet = false;  ///< no progress lines on `err`
};

/** `bflow ocp`: solves the example's optimal control problem (bflow::ocp_solve) and prints the
    status, the optimal cost, T, the states and controls on the stages, the switch times, the
    homotopy, the counters and the errors against the example's exact optimum as JSON (see
    docs/cli.md). Unless `quiet`, one progress line per NLP of the homotopy goes to `err` while
    it runs. Exit code 2 for a bad option (a --linear-solver whose library cannot be loaded
    included), 1 when the status is not "solved" (the JSON is still printed, and `err` gets one
    "error: ocp: <status>: <message>" line), when the plot directory cannot be written or
    gnuplot fails. Never throws. */
int run_ocp(const OcpCommandOptions& options, std::ostream& out, std::ostream& err);

/** `bflow orbit`: the options as given on the command line. Numbers stay text so that
    run_orbit() validates them and names the option in its message. */
struct OrbitCommandOptions {
  /** "pwconst", "biped" or "pronk"; required. */
  std::string scene;
  /** "key=value", each key at most once, as for `bflow flow`. For the biped they override the
      orbit's defaults variant=mode-damping, kappa=1000, beta=4, thrust=10, thrust_speed=0.1 (a
      hopping biped), each key on its own. */
  std::vector<std::string> params;
  /** The guess, "a,b,..." with d numbers (default: biped (0, 0.8, 0, 0, 0, 0), at rest at the
      apex; pronk (0, 1, 0, 0, 0, 0); pwconst rho- = -F_--(0)/2). */
  std::optional<std::string> x0;
  /** The Poincare section as bflow::parse_coordinate_section() reads it: "x4", "-x4", "x1=0.3",
      "-x1=0.3" (default: biped and pronk "-x4", the apex; pwconst "x0=1"). */
  std::optional<std::string> section;
  /** Newton's tolerance (OrbitOptions::tolerance), finite and > 0; default 1e-8. */
  std::optional<std::string> tol;
  /** Newton iterations (OrbitOptions::max_newton_iterations), >= 0; default 40. */
  std::optional<std::string> max_iterations;
  /** Integration tolerances, as for `bflow flow`; default 1e-10 and 1e-12
      (bflow::default_orbit_flow_options), or rtol / 100 when only rtol is given. */
  std::optional<std::string> rtol;
  std::optional<std::string> atol;
  /** "key=lo:hi:count", count >= 2: a family of orbits by natural-parameter continuation over
      count values of the real-valued scene parameter key, from lo to hi, each orbit from the
      last one found. */
  std::optional<std::string> vary_param;
  /** Directory (created if missing) for orbit.png (one period of the orbit) and, with
      vary_param, growth_rate.png, with their CSV data and gnuplot scripts. */
  std::optional<std::string> plot;
  /** Write the JSON to this file instead of `out`. */
  std::optional<std::string> output;
  bool compact = false;
  bool quiet = false;  ///< no progress lines on `err`
};

/** `bflow orbit`: the periodic orbit of a scene through a Poincare section
    (bflow::find_periodic_orbit): its fixed point, period, events, the return map's pieces
    restricted to the section, the growth-rate bracket and the verdict, as JSON (see
    docs/cli.md); with vary_param also the family. Unless `quiet`, one progress line per Newton
    step of the orbit and one per orbit of the family go to `err`. Exit code 2 for a bad option,
    1 when an orbit is not found (Newton's method does not converge, or the guess never returns
    to the section; the JSON is still printed, and `err` ends with one "error: orbit: ..."
    line), when a plot or the output file cannot be written. Never throws. */
int run_orbit(const OrbitCommandOptions& options, std::ostream& out, std::ostream& err);

/** The whole command line (argv[0] is ignored): parses it and dispatches. Never throws. */
int run_cli(int argc, const char* const* argv, std::istream& in, std::ostream& out,
            std::ostream& err);

}  // namespace bflow::cli

#endif  // BFLOW_CLI_CLI_COMMANDS_H_

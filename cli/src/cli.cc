// Command-line parsing for `bflow` (CLI11) and dispatch to the commands.
#include <algorithm>
#include <exception>
#include <istream>
#include <limits>
#include <optional>
#include <ostream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "cli_commands.h"
#include "cli_util.h"
#include "scene_setup.h"

#ifndef BFLOW_VERSION
#error "BFLOW_VERSION must be defined (the CMake project version)"
#endif

namespace bflow::cli {
namespace {

constexpr const char* kMainFooter = R"(Exit codes:
  0  success
  1  the computation or its output failed (a non-finite result or an overflow, a
     simulation that stops early, an optimal control problem not solved, a periodic orbit
     not found, a failed self-check of the demo, a file or the standard output that cannot
     be written, gnuplot missing or failing)
  2  bad input or usage: the one line on stderr, "error: <field>: <problem>", names it

Run 'bflow jump --help', 'bflow flow --help', 'bflow fesd --help', 'bflow ocp --help' and
'bflow orbit --help' for the formats. Documentation: docs/cli.md.)";

constexpr const char* kJumpFooter =
    R"(Input, one JSON object (n surfaces meet at a point rho in d dimensions):
  "normals":       [[eta_0...], ...]        n rows of d numbers, oriented so that every
                                            eta_j . F_b > 0 (full row rank, n <= d)
  "field_limits":  {"--": [d numbers], ...} Gamma(b) = F_b(rho) for every sign word b of
                                            n characters; character j is surface j
  "tangents":      [[d numbers], ...]       directions dx before the event (may be [])
  "pieces":        true | false             optional: all n! pieces (n <= 10; refused when
                                            the output would exceed --max-output-bytes)
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

constexpr const char* kSweepFooter =
    R"(The scenes and their parameters are those of 'bflow flow'. Samples are every combination
of the --vary and --vary-param values, in grid order (index 0 first; the first axis given
varies slowest); the records come out in that order whatever the number of threads, as soon as
each is ready, and a progress bar on stderr shows the samples done, the rate and the time left.

The first line identifies the sweep: {"sweep": {"bflow", "scene", "params", "integrator",
"rtol", "atol", "grouping", "t", "max_steps", "x0", "dx", "format", "states", "directions",
"axes"}} (CSV: "# bflow sweep {...}" before the column header).
A JSON-lines record (one line per sample):
  {"index", "varied" (the values, in the order of the options), "status", "message" (when not
   ok), "t_reached", "x_t", "events": [{"t", "surfaces"}], "images" (one per --dx),
   "orders" (per --dx, per event: the crossing order that direction takes), "pieces" (the
   number of linear pieces: the product over events of (surfaces crossed together)!)}
CSV has the same columns: index, one per axis, status, message, t_reached, x_t[i],
image<k>[i], events (t:s1+s2;...), orders (events ';', surfaces '>', directions '|'), pieces.
status is "ok" (every number finite), an integration status that stopped the sample early
("too many steps", "step-size underflow", ...), "overflow" (a number beyond the double range),
"rejected" (the engine refused the start: on a surface, grazing,
sliding; the message says which) or "error". A failed sample never stops the sweep; the exit
code is 0 and the last stderr line counts the samples by status. --atlas PNG (two axes and a
--dx) maps the event structure of every sample: the surfaces of each event in time order, and
for surfaces crossed together the order the first --dx takes, e.g. 0+1 (1>0). With
--output FILE --resume,
the whole records an interrupted run of the same sweep left in FILE are kept (its first line
must be this sweep's identity, its records this grid's) and the sweep goes on from the first
missing sample; the file then holds exactly what an uninterrupted run writes. Anything else
(another sweep's output, a file that is not one, a device) is refused with exit code 2 and left
as it was.

Example: the piecewise-constant field over a line of starts through the origin's cone
  $ bflow sweep --scene pwconst --vary 1=-0.9:-0.1:9 --x0=-0.5,0 --dx 1,0 --quiet
  {"index":0,"varied":[-0.9],"status":"ok","t_reached":1.0,"x_t":[...],"events":[...],...})";

constexpr const char* kFlowFooter =
    R"(Scenes (--param key=value, each key at most once):
  pwconst  xdot = 1 + Delta(sign(x)), h(x) = x, of [B] Section 3.1: all d surfaces meet at
           rho = 0, reached at t = 1/2 from the default x0 = rho- = -F_--(0)/2.
           d (default 2, at most 16); delta: the linear case Delta(b) = -delta b, |delta| < 1,
           B = (1-delta)/(1+delta) I at t = 1 (default delta = 0.25); or seed: a random Delta
           with entries in (-0.7, 1.5) (fixed generator), B piecewise linear. Default --t 1.
  biped    the vertical-plane biped of [B] Section 3.2.4 (d = 6, x = (x, y, theta, xdot, ydot,
           thetadot), 2 feet): variant (conservative | dissipative | mode-damping, the
           default), m, J, g, leg_length, psi, kappa, beta, thrust, thrust_speed (an energy
           source, 0 by default: see bflow orbit). Default x0 = (0,1,0,0,0,0), from
           which both feet touch together at t = 0.3968; default --t 0.6.
  pronk    a body on two vertical legs at its hips on flat ground, with the legs' thrust and
           a soft horizontal tether (d = 6, same x, 2 feet; bflow/core/pronk.h): m, J, g, hip,
           leg_length, kappa, beta, thrust, thrust_speed, tether, tether_damping (defaults:
           its stable hop, see bflow orbit). Default x0 = (0,1,0,0,0,0), from which both
           feet touch together at t = 0.3194; default --t 0.6.

Output, one JSON object (numbers print in the shortest form that reads back exactly):
  "scene", "params", "integrator" (as asked), "rtol", "atol", "grouping", "t", "x0"
  "backend"     the integrator that ran (for --integrator auto, the one it chose)
  "x_t"         phi_t(x0)
  "events"      [{"t", "surfaces" (crossed together), "crossing_times" (located, per surface),
                  "spread", "window" (grouping), "gap" (to the nearest crossing not grouped,
                  null if none), "rho", "sides_before", "sides_after",
                  "margins": [{"before", "after"}] (eta . F / (|eta| |F|) per surface)}]
  "notices"     [{"kind" (near-simultaneous | near-grazing), "surfaces", "times", "gap",
                  "band", "message"}], each also one warning line on stderr
  "directions"  one per --dx, in order (default e_0 ... e_{d-1}):
     "dx", "image" (D phi_t(x0; dx)), "orders" (crossing order at each event),
     "jacobian" (the piece active at dx, rows), and with --fd "fd": {"one_sided", "central"
     (at the alpha of the smallest one-sided error), "alpha", "rows": [{"alpha",
     "one_sided_error", "central_error"}] for alpha = 1e-2 ... 1e-10}
If the simulation stops early (too many steps, step-size underflow, ...) the output has
"status", "message", "t_reached" and the events so far, and the exit code is 1.

Example ([B] (3.2): B = (1 - delta)/(1 + delta) I = 0.6 I; the rounding is the simulation's):
  $ bflow flow --scene pwconst --param d=3 --dx 1,0,0 --compact
  {..."events":[{"t":0.4999999999999999,"surfaces":[0,1,2],...}],"directions":[{"dx":
  [1.0,0.0,0.0],"image":[0.6000000000000001,0.0,0.0],"orders":[[0,1,2]],"jacobian":[[0.6,
  0.0,0.0],[0.0,0.6,0.0],[0.0,0.0,0.6]]}]}

Bad input exits with code 2 and one line on stderr, e.g.
  error: --dx[0]: has 2 numbers, expected d = 3 (comma-separated))";

constexpr const char* kDemoFooter =
    R"(--scene biped (the default): the vertical-plane biped of [B] Section 3.2.4 with
mode-dependent damping, falling from (0,1,0,0,0,0) to t = 0.6; both feet touch at the same
instant (t = 0.3968), one event with two surfaces whose jump has two pieces. Prints the event,
the pieces M_(0,1) and M_(1,0), B = D phi_0.6 on a table of directions against one-sided
differences, and checks. Writes DIR/demo_biped.dat (a circle of (theta, y) perturbations
and its image under B, projected on (theta, y): a piecewise ellipse), DIR/demo_biped.gp, and
runs gnuplot to draw DIR/demo_biped.png.

--scene pwconst: the field xdot = 1 + Delta(sign(x)) of [B] Section 3.1 with d = 2 and a
non-linear Delta: B on unit vectors every 45 degrees and on F_--, the pieces, checks against
the triangulation and one-sided differences of the exact flow; DIR/demo_circle.{dat,gp,png}.

DIR is created if missing and must be writable: otherwise the demo stops with code 1 before
computing anything. Exits with code 1 if a check fails, a file or the standard output cannot be
written, or gnuplot is missing or fails; the last line printed is the path of the PNG.)";

constexpr const char* kOcpFooter =
    R"(Examples (bflow/examples/ocp_examples.h), the first two with their exact optima:
  turbo-car      q' = v, v' = u for v < 10 and 3 u for v > 10, |u| <= 5, |v| <= 20, from
                 (0, 0) to q = 200, v = 0 in least time: T* = 40/3, v = 10 at t = 2, 34/3
  braking-block  p' = v, v' in u - sign(v), from (0, 2), T = 3, minimising the integral of
                 v^2 + u^2: J* = 2 sqrt5 + asinh 2 - 4, at rest from t = asinh 2 (sliding)
  monoped        the two-link hopping robot of [F] Section 7.2 by time-freezing
                 (bflow/examples/monoped_ocp.h): from (0, 0.4) to q = (3, 0.4, 0, 0) at rest
                 in T = 3 along a reference with two hops; x = (q, v, clock), u = (hip and
                 knee torques, speed of time). --setup nosnoc (default): the benchmark of
                 the paper's Figure 10, sigma 1 to 1e-4 (step; Stewart: x 0.4, 15 NLPs)
                 stopping at complementarity 1e-5, --tol 1e-5 (IPOPT's acceptable level
                 too). --setup strict: sigma 1 to 1e-7, --tol 1e-6, complementarity 1e-6,
                 the foot at most 5 mm below the ground. Adds "setup", "hops" (flight phases
                 that start from the ground) and "t_physical_end" (the clock at T); "exact"
                 gives the target and the errors against it. --plot also draws
                 monoped_frames.png, monoped_states.png and monoped_controls.png.
  hopper         the hopping robot of nosnoc's Python package by time-freezing
                 (bflow/examples/hopper.h): a body on a telescopic leg, five jumps from
                 x = 0.1 to x = 5 in T = 5 along a reference, N = 50 (a multiple of 5),
                 Stewart's formulation on the eight base sets, the package's settings
                 (sigma 100 x 0.1 for at most six NLPs, stopping at complementarity 1e-9,
                 IPOPT tol 1e-8). x = (x, y, angle, leg length, their velocities, clock),
                 u = (torque, leg force, slack, speed of time). Adds "hops" and
                 "t_physical_end"; "exact" gives the target and the errors against it.
                 --plot also draws hopper_frames.png, hopper_states.png and
                 hopper_controls.png.

Output, one JSON object: "example", "N", "nfe", "status", "message", "ipopt_status" and
"kkt_error" (how IPOPT ended the result's NLP; "solved" needs kkt_error <= --tol either way),
"notes", "objective",
"T", "t" (stage boundaries), "x" (state at each), "u" (control per stage), "switch_times",
"max_complementarity", "polished", "homotopy" [{"sigma", "objective", "complementarity",
"product_multipliers", "largest_product_multiplier" (the relaxed products' multipliers: their
sum is -d objective / d sigma), "iterations", "cpu_seconds", "status", "kkt_error", "polish",
"worst_rows" (only when IPOPT did not solve it: the rows it violates most)}],
"ipopt_iterations", "cpu_seconds",
"cpu_per_iteration", "exact" (the optimum and this run's errors against it); with
--trajectory also "grid", "x_grid", "step_sizes", "active_sets".

While the homotopy runs, one progress line per NLP goes to stderr (not with --quiet).
Exit code 1 when the status is not "solved": the JSON is still printed, and stderr ends with
one line "error: ocp: <status>: <message>". A solved run far from the known optimum (the
turbo car at an N that is a multiple of 5 off 40/3, the braking block more than (T/N)^2 above
J*) ended at another stationary point: the exit code stays 0, and the notice ends "notes" and
is printed as one "warning: ocp: ..." line on stderr.

"ipopt", "linear_solver" and "blas" in the JSON name the solver stack: "IPOPT 3.14.19",
IPOPT's linear solver with its version or library, "mumps 5.8.2" by default (--linear-solver),
and the BLAS under it with its threads, "OpenBLAS 0.3.24, 1 thread" and the library
(--blas-threads).
HSL's solvers come from Coin-HSL's library, which no package ships (docs/ocp.md, "Linear
solvers"): when it cannot be loaded, the command exits with code 2 before solving, with one
line "error: --linear-solver: ..." naming the file and the loader's reason.)";

constexpr const char* kOrbitFooter =
    R"(The section (--section TEXT): s(x) = 0, crossed from s < 0 to s > 0
(bflow::parse_coordinate_section):
  x4        s = x_4, crossed upwards        -x4       s = -x_4: x_4 from + to -
  x1=0.3    s = x_1 - 0.3                   -x1=0.3   s = 0.3 - x_1

Scenes and defaults:
  biped    (d = 6, x = (x, y, theta, xdot, ydot, thetadot)) hopping on its legs' thrust: unless
           --param sets them, variant=mode-damping, kappa=1000, beta=4, thrust=10,
           thrust_speed=0.1. Section -x4 (the apex: vertical speed from + to -), guess
           --x0 0,0.8,0,0,0,0 (at rest at height 0.8). Both feet land and lift off together:
           every event crosses two surfaces, and the return map has four linear pieces.
  pronk    (d = 6, same x) the pronking body on its own defaults (J = m hip^2, kappa=300,
           beta=4, thrust=10, tether=1, tether_damping=1): section -x4, guess --x0
           0,1,0,0,0,0. Both feet land and lift off together, and the hop is stable: growth
           rate in [0.555, 0.746]; vary J (stable for J in about [0.235, 0.27]) or thrust.
  pwconst  the field of 'bflow flow --scene pwconst': it crosses every plane once and has no
           periodic orbit (section x0=1, guess rho-): the run reports converged false.
Newton's method: --tol 1e-8 (|P(x) - x|_inf <= tol (1 + |x|_inf)), --max-iterations 40;
integration --rtol 1e-10 --atol 1e-12 (with --rtol alone, atol = rtol / 100).

Output, one JSON object (numbers print in the shortest form that reads back exactly):
  "scene", "params" (all, defaults included), "section", "rtol", "atol", "tolerance",
  "max_iterations", "x0" (the guess)
  "converged", "message" (why not), "x" (the fixed point, on the section), "period",
  "newton_iterations", "residual" (|P(x) - x|_inf), "newton_steps" [{"iteration",
  "residual", "period", "step_length"}], "events" [{"t", "surfaces", "group_size"}]
  "return_map": {"is_linear", "tangent_basis" (the columns of B, an orthonormal basis of
     the section's tangent space), "piece_count", "pieces": [{"orders" (per event, the order
     its surfaces are crossed in), "matrix" (B^T M B: the piece on the section)}]}
  "growth_rate_lower", "growth_rate_upper" (a bracket on the growth rate of the return map on
  the section), "stability" (stable: upper < 1; unstable: lower > 1; else undecided),
  "bracket": {"pieces", "upper_length", "lower_period"}, "multipliers" ([{"real", "imag"}],
  when the map is linear; else null), "notices", "decisions" (Newton steps the solver
  shortened because the return map could not be evaluated further, with the reason)
  with --vary-param: "vary_param" {"key", "lo", "hi", "count"} and "family": [{"value",
  "converged", "message", "x", "period", "newton_iterations", "residual",
  "growth_rate_lower", "growth_rate_upper", "stability"}], each orbit from the last one found
  (the first from --x0)
The return map's keys are null when no orbit was found.

Progress on stderr (not with --quiet): one line per Newton step, and one per orbit of a family.
--plot DIR draws DIR/orbit.png (the states over one period, the events dashed, and the phase
plot of the two components that vary most) and, with --vary-param, DIR/growth_rate.png; the data
(orbit.csv, family.csv) and gnuplot scripts stay beside them.
Exit code 1 when an orbit is not found (the JSON is still printed; stderr ends with one line
"error: orbit: ..."), or a plot or the output cannot be written; 2 for a bad option.

Example: the hopping biped's orbit, unstable sideways on the ground's hump y = -x^2
  $ bflow orbit --scene biped --quiet --compact
  {"scene":"biped",...,"converged":true,"message":"","x":[2.2e-19,0.7246129768688343,...],
   "period":0.7100100108250474,"newton_iterations":3,...,"growth_rate_lower":5.59235815...,
   "growth_rate_upper":5.59235818...,"stability":"unstable",...})";

// The numeric options of jump, fesd and ocp as typed, before read_numbers() checks them.
struct NumericTexts {
  std::optional<std::string> max_input_bytes, max_output_bytes;
  std::optional<std::string> fesd_stages, fesd_nfe, fesd_nsim, fesd_t, fesd_lifting;
  std::optional<std::string> ocp_n, ocp_nfe, ocp_stages, ocp_sigma0, ocp_sigma_final, ocp_tol,
      ocp_max_iterations, ocp_lifting, ocp_early_polish_sigma, ocp_monotone_mu_down_to;
  std::optional<std::string> fesd_blas_threads, ocp_blas_threads;
};

// The help groups of fesd and ocp, as their options are grouped (fesd/homotopy_options.h): the
// problem, its discretisation, the relaxation homotopy, IPOPT with its linear solver, and what is
// printed.
constexpr const char* kProblemGroup = "Problem";
constexpr const char* kDiscretisationGroup = "Discretisation (FESD)";
constexpr const char* kHomotopyGroup = "Homotopy (the relaxation's sigma and the NLPs' tolerances)";
constexpr const char* kSolverGroup = "Solver (IPOPT and its linear solver)";
constexpr const char* kOutputGroup = "Output";

// The "Solver" group of fesd and ocp: the options both pass to IPOPT (SolverCommandOptions);
// --blas-threads as typed, read by read_numbers.
void add_solver_options(CLI::App* command, SolverCommandOptions& s,
                        std::optional<std::string>& blas_threads) {
  const char* group = kSolverGroup;
  command
      ->add_option("--linear-solver", s.linear_solver,
                   "IPOPT's linear solver: mumps (MUMPS with METIS), spral, HSL's ma27, ma57, "
                   "ma77, ma86, ma97 (from Coin-HSL's library), pardiso (pardiso-project.org's) or "
                   "pardisomkl (where IPOPT has MKL); see docs/ocp.md, \"Linear solvers\"")
      ->type_name("NAME")
      ->capture_default_str()
      ->group(group);
  command
      ->add_option("--linear-solver-library", s.linear_solver_library,
                   "the library of an HSL solver or of PARDISO, a file name the loader finds or a "
                   "path (default: libcoinhsl.so, then libhsl.so; libpardiso.so)")
      ->type_name("FILE")
      ->group(group);
  command
      ->add_option("--blas-threads", blas_threads,
                   "OpenBLAS's threads while IPOPT solves, >= 0; 0: OpenBLAS's own count "
                   "(OPENBLAS_NUM_THREADS, else one per core). FESD's KKT matrices are too small "
                   "for threads (default 1); \"blas\" in the JSON names the BLAS and the count")
      ->type_name("N")
      ->group(group);
  command
      ->add_flag("--jet-derivatives", s.jet_derivatives,
                 "the Jacobian and exact Hessian by Jets at every evaluation instead of as "
                 "programs traced once (the same numbers to rounding; docs/ocp.md, \"The "
                 "derivatives as programs\")")
      ->group(group);
}

int read_int(const std::string& text, const char* option) {
  return static_cast<int>(parse_integer(text, option, std::numeric_limits<int>::min(),
                                        std::numeric_limits<int>::max()));
}

// The options given into the commands' structs. The ranges fesd and ocp accept are their own
// checks (run_fesd, run_ocp), so that the in-process API refuses the same values with the same
// words; the byte limits are whole numbers from 1 to 2^63 - 1.
// @throws InputError naming the option.
void read_numbers(const NumericTexts& t, JumpOptions& jump, FesdCommandOptions& fesd,
                  OcpCommandOptions& ocp) {
  constexpr long long kMax = std::numeric_limits<long long>::max();
  if (t.max_input_bytes) {
    jump.max_input_bytes = parse_integer(*t.max_input_bytes, "--max-input-bytes", 1, kMax);
  }
  if (t.max_output_bytes) {
    jump.max_output_bytes = parse_integer(*t.max_output_bytes, "--max-output-bytes", 1, kMax);
  }
  if (t.fesd_stages) fesd.stages = read_int(*t.fesd_stages, "--stages");
  if (t.fesd_nfe) fesd.nfe = read_int(*t.fesd_nfe, "--nfe");
  if (t.fesd_nsim) fesd.nsim = read_int(*t.fesd_nsim, "--nsim");
  if (t.fesd_t) fesd.t = read_double(*t.fesd_t, "--T");
  if (t.fesd_lifting) fesd.lifting = read_int(*t.fesd_lifting, "--lifting");
  if (t.ocp_n) ocp.n = read_int(*t.ocp_n, "--N");
  if (t.ocp_nfe) ocp.nfe = read_int(*t.ocp_nfe, "--nfe");
  if (t.ocp_stages) ocp.stages = read_int(*t.ocp_stages, "--stages");
  if (t.ocp_sigma0) ocp.sigma0 = read_double(*t.ocp_sigma0, "--sigma0");
  if (t.ocp_sigma_final) ocp.sigma_final = read_double(*t.ocp_sigma_final, "--sigma-final");
  if (t.ocp_tol) ocp.tol = read_double(*t.ocp_tol, "--tol");
  if (t.ocp_max_iterations)
    ocp.max_iterations = read_int(*t.ocp_max_iterations, "--max-iterations");
  if (t.ocp_lifting) ocp.lifting = read_int(*t.ocp_lifting, "--lifting");
  if (t.fesd_blas_threads)
    fesd.solver.blas_threads = read_int(*t.fesd_blas_threads, "--blas-threads");
  if (t.ocp_blas_threads) ocp.solver.blas_threads = read_int(*t.ocp_blas_threads, "--blas-threads");
  if (t.ocp_early_polish_sigma) {
    ocp.early_polish_sigma = read_double(*t.ocp_early_polish_sigma, "--early-polish-sigma");
  }
  if (t.ocp_monotone_mu_down_to) {
    ocp.monotone_mu_down_to = read_double(*t.ocp_monotone_mu_down_to, "--monotone-mu-down-to");
  }
}

// Refuses an option of `command` given with an empty value ("--N ''"), which CLI11 would take
// as the option's default; with `only`, just the options named there.
// @throws InputError naming the option.
void refuse_empty_values(const CLI::App& command, const std::vector<std::string>& only = {}) {
  for (const CLI::Option* option : command.get_options()) {
    if (option->get_type_size_max() == 0 || option->count() == 0) continue;  // a flag, or not given
    const std::string name = option->get_name();
    if (!only.empty() && std::find(only.begin(), only.end(), name) == only.end()) continue;
    for (const std::string& value : option->results()) refuse_empty(value, name);
  }
}

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

    // Numeric options are kept as text and read after parsing by one checked reader
    // (read_numbers() below), which refuses what CLI11's conversions let through: an empty
    // value (which they take as the default), a value beyond the type (which they clamp) and a
    // number that underflows.
    NumericTexts numbers;
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
    jump->add_option("--max-input-bytes", numbers.max_input_bytes,
                     "Refuse an input longer than this, 1 .. 2^63 - 1 (default 64 MiB)")
        ->type_name("BYTES");
    jump->add_option("--max-output-bytes", numbers.max_output_bytes,
                     "Refuse a request whose output is estimated above this, e.g. all n! pieces "
                     "for large n, 1 .. 2^63 - 1 (default 1 GiB)")
        ->type_name("BYTES");
    jump->footer(kJumpFooter);

    FlowCommandOptions flow_options;
    CLI::App* flow = app.add_subcommand(
        "flow",
        "Simulate a scene (pwconst, biped or pronk) across its switching surfaces and print the "
        "B-derivative of its flow on directions (JSON)");
    flow->add_option("--scene", flow_options.scene, "pwconst, biped or pronk (required)")
        ->type_name("NAME");
    flow->add_option("--param", flow_options.params,
                     "A scene parameter, key=value; repeat for several")
        ->type_name("KEY=VALUE")
        ->allow_extra_args(false);
    flow->add_option("--t", flow_options.t, "Final time, >= 0 (pwconst: 1, biped, pronk: 0.6)")
        ->type_name("T");
    flow->add_option("--x0", flow_options.x0,
                     "Initial state, d comma-separated numbers (default: the scene's)")
        ->type_name("A,B,...");
    flow->add_option("--dx", flow_options.dx,
                     "A direction, d comma-separated numbers; repeat for several (default: the "
                     "unit vectors)")
        ->type_name("A,B,...")
        ->allow_extra_args(false);
    flow->add_option("--rtol", flow_options.rtol, "Relative tolerance, > 0 (default 1e-8)")
        ->type_name("R");
    flow->add_option("--atol", flow_options.atol,
                     "Absolute tolerance, >= 1e-20 (default: rtol / 100)")
        ->type_name("A");
    flow->add_option("--grouping", flow_options.grouping,
                     "How crossings become one event: auto (a window from the tolerances and "
                     "the normal speeds; default), window (--window T) or none")
        ->type_name("POLICY");
    flow->add_option("--window", flow_options.window,
                     "With --grouping window: crossings closer than T in time are one event")
        ->type_name("T");
    flow->add_option("--integrator", flow_options.integrator,
                     "auto (dopri5 at loose tolerances on small models with surfaces, else dop853: "
                     "bflow::choose_backend), dopri5, dop853, cvodes-bdf or cvodes-adams")
        ->type_name("NAME")
        ->capture_default_str();
    flow->add_option("--max-steps", flow_options.max_steps,
                     "Steps per smooth segment before the run stops (default 1000000)")
        ->type_name("N");
    flow->add_flag("--fd", flow_options.fd,
                   "Also one-sided and central finite differences of the simulated flow, "
                   "alpha = 1e-2 ... 1e-10");
    flow->add_flag("--compact", flow_options.compact, "Print the result on one line");
    flow->footer(kFlowFooter);

    DemoOptions demo_options;
    CLI::App* demo = app.add_subcommand(
        "demo",
        "Table and plot of a B-derivative: the biped of [B] Section 3.2.4 (default) or the "
        "piecewise-constant field of Section 3.1");
    demo->add_option("--scene", demo_options.scene, "biped or pwconst")
        ->type_name("NAME")
        ->capture_default_str();
    demo->add_option("-o,--output", demo_options.output_dir,
                     "Directory for the demo's .dat, .gp and .png; created if missing")
        ->type_name("DIR")
        ->capture_default_str();
    demo->add_flag("--no-plot", demo_options.no_plot,
                   "Write the data and the gnuplot script but do not run gnuplot");
    demo->footer(kDemoFooter);

    FesdCommandOptions fesd_options;
    CLI::App* fesd = app.add_subcommand(
        "fesd",
        "Simulate a Filippov example with sliding by Finite Elements with Switch Detection "
        "(IPOPT) and print x(T), switch times and dx(T)/dx0 (JSON)");
    fesd->add_option("--example", fesd_options.example,
                     "irma, crossing, sliding-enter, sliding-leave or spontaneous (required)")
        ->type_name("NAME")
        ->group(kProblemGroup);
    fesd->add_option("--formulation", fesd_options.formulation, "step or stewart")
        ->type_name("NAME")
        ->capture_default_str()
        ->group(kDiscretisationGroup);
    fesd->add_option("--scheme", fesd_options.scheme, "radau (Radau IIA) or gauss (Gauss-Legendre)")
        ->type_name("NAME")
        ->capture_default_str()
        ->group(kDiscretisationGroup);
    fesd->add_option("--stages", numbers.fesd_stages, "Runge-Kutta stages n_s, 1..9")
        ->type_name("S")
        ->default_str(std::to_string(fesd_options.stages))
        ->group(kDiscretisationGroup);
    fesd->add_option("--nfe", numbers.fesd_nfe,
                     "Finite elements per integration step, >= 1 (at most what the size limits "
                     "of docs/fesd.md allow)")
        ->type_name("N")
        ->default_str(std::to_string(fesd_options.nfe))
        ->group(kDiscretisationGroup);
    fesd->add_option("--nsim", numbers.fesd_nsim,
                     "Integration steps over [0, T], >= 1 (default: irma 20, the others 4)")
        ->type_name("M")
        ->group(kProblemGroup);
    fesd->add_option("--T", numbers.fesd_t,
                     "Horizon, finite and > 0 (default: irma 100, sliding-leave 2, the others 1)")
        ->type_name("T")
        ->group(kProblemGroup);
    fesd->add_flag(
            "--exact-hessian", fesd_options.exact_hessian,
            "IPOPT with the exact Hessian (second-order AD by pieces) instead of limited-memory")
        ->group(kSolverGroup);
    add_solver_options(fesd, fesd_options.solver, numbers.fesd_blas_threads);
    fesd->add_flag("--standard", fesd_options.standard,
                   "Standard time-stepping: fixed steps, no switch detection")
        ->group(kDiscretisationGroup);
    fesd->add_flag("--trajectory", fesd_options.trajectory,
                   "Add the grid, the states, the step sizes and the active sets")
        ->group(kOutputGroup);
    fesd->add_flag("--sizes", fesd_options.sizes,
                   "Print the problem sizes of Stewart's and the step reformulation ([F] Table 4) "
                   "and of one integration step's NLP")
        ->group(kOutputGroup);
    fesd->add_option("--lifting", numbers.fesd_lifting,
                     "Step formulation: lifting depth n_d of Algorithm 1, 2..max(2, n_c) (theta "
                     "and beta as unknowns; 0: none)")
        ->type_name("ND")
        ->group(kDiscretisationGroup);
    fesd->add_flag("--compact", fesd_options.compact, "Print the result on one line")
        ->group(kOutputGroup);

    OcpCommandOptions ocp_options;
    CLI::App* ocp = app.add_subcommand(
        "ocp",
        "Solve an optimal control problem of a nonsmooth example through FESD (IPOPT) and "
        "print the optimum, the switch times and the errors against the exact optimum (JSON)");
    ocp->add_option("--example", ocp_options.example,
                    "turbo-car, braking-block, monoped or hopper (required)")
        ->type_name("NAME")
        ->group(kProblemGroup);
    ocp->add_option("--N", numbers.ocp_n,
                    "Control stages N, >= 1 (default 10; 30 for the monoped, 50 for the hopper)")
        ->type_name("N")
        ->group(kProblemGroup);
    ocp->add_option("--nfe", numbers.ocp_nfe, "Finite elements per control stage, >= 1")
        ->type_name("N_FE")
        ->default_str(std::to_string(ocp_options.nfe))
        ->group(kDiscretisationGroup);
    ocp->add_option("--stages", numbers.ocp_stages, "Runge-Kutta stages n_s, 1..9")
        ->type_name("S")
        ->default_str(std::to_string(ocp_options.stages))
        ->group(kDiscretisationGroup);
    ocp->add_option("--scheme", ocp_options.scheme, "radau (Radau IIA) or gauss (Gauss-Legendre)")
        ->type_name("NAME")
        ->capture_default_str()
        ->group(kDiscretisationGroup);
    ocp->add_option("--collocation-form", ocp_options.collocation_form,
                    "integral (X = x_n + h A F) or derivative (D (X - x_n) = h F, nosnoc's; "
                    "sparser KKT matrices, the same solutions)")
        ->type_name("NAME")
        ->capture_default_str()
        ->group(kDiscretisationGroup);
    ocp->add_option("--formulation", ocp_options.formulation,
                    "step or stewart (default step; stewart for the hopper)")
        ->type_name("NAME")
        ->group(kDiscretisationGroup);
    ocp->add_flag("--standard", ocp_options.standard,
                  "Standard time-stepping: equal fixed elements, no switch detection")
        ->group(kDiscretisationGroup);
    ocp->add_option("--setup", ocp_options.setup,
                    "The monoped's setup: nosnoc (its benchmark behind the paper's Figure 10, the "
                    "default) or strict (tighter tolerances, a foot path constraint)")
        ->group(kProblemGroup);
    ocp->add_option("--relaxation", ocp_options.relaxation,
                    "scholtes (products <= sigma), l1 (penalty 1/sigma times the products) or "
                    "elastic (products <= s, s >= 0 one slack with penalty s/sigma)")
        ->type_name("NAME")
        ->capture_default_str()
        ->group(kHomotopyGroup);
    ocp->add_option("--cross", ocp_options.cross,
                    "Cross complementarity rows: element-sums (one product of sums per element "
                    "and pair), point-pairs (every product of two points on its own row) or "
                    "point-sums (each point against the sum over the element's points, nosnoc's "
                    "Python default); default point-pairs for the monoped with stewart "
                    "(nosnoc's), else element-sums")
        ->type_name("NAME")
        ->group(kDiscretisationGroup);
    ocp->add_option("--sigma0", numbers.ocp_sigma0,
                    "Initial relaxation sigma, > 0 (default 100; 1 for the monoped)")
        ->type_name("X")
        ->group(kHomotopyGroup);
    ocp->add_option("--sigma-final", numbers.ocp_sigma_final,
                    "Final relaxation sigma, > 0 and <= --sigma0 (default 1e-10; monoped: 1e-4 for "
                    "--setup nosnoc, 0.4^14 with stewart, 1e-7 for --setup strict)")
        ->type_name("X")
        ->group(kHomotopyGroup);
    ocp->add_option("--early-polish-sigma", numbers.ocp_early_polish_sigma,
                    "From the first NLP at sigma <= X on, try the polish after every NLP with a "
                    "new active set and end the homotopy at the first one kept, >= 0 (default "
                    "1e-4; 0: only the final polish after --sigma-final; the monoped and the "
                    "hopper do not polish)")
        ->type_name("X")
        ->group(kHomotopyGroup);
    ocp->add_option(
           "--monotone-mu-down-to", numbers.ocp_monotone_mu_down_to,
           "The NLPs warm-started from the one before, at sigma >= X, run IPOPT's "
           "monotone mu strategy, the others its adaptive one, >= 0 (default 1e-2; inf: "
           "adaptive throughout; the monoped warm-starts without multipliers and the hopper "
           "starts cold: adaptive); "
           "the JSON's \"homotopy\" names each NLP's \"mu_strategy\"")
        ->type_name("X")
        ->group(kHomotopyGroup);
    ocp->add_option("--tol", numbers.ocp_tol,
                    "IPOPT's tolerance for the last NLP, >= 1e-14 (default 1e-10; monoped: 1e-5 "
                    "for --setup nosnoc, 1e-6 for --setup strict)")
        ->type_name("X")
        ->group(kHomotopyGroup);
    ocp->add_option("--lifting", numbers.ocp_lifting,
                    "Step formulation: lifting depth n_d of Algorithm 1, 0 (none) or 2.."
                    "max(2, n_c) (default 0; 2 for the monoped's nosnoc setup)")
        ->type_name("ND")
        ->group(kDiscretisationGroup);
    ocp->add_option("--max-iterations", numbers.ocp_max_iterations,
                    "IPOPT iterations of the whole homotopy, >= 0; when they run out the status "
                    "is budget_exhausted with the last solved NLP's result (default 0: no limit "
                    "but 3000 per NLP, 10000 for the monoped)")
        ->type_name("K")
        ->group(kHomotopyGroup);
    add_solver_options(ocp, ocp_options.solver, numbers.ocp_blas_threads);
    ocp->add_flag("--trajectory", ocp_options.trajectory,
                  "Add every element boundary, the states there, the step sizes and active sets")
        ->group(kOutputGroup);
    ocp->add_option("--plot", ocp_options.plot,
                    "Draw DIR/ocp_states.png, ocp_controls.png and ocp_switching.png (gnuplot)")
        ->type_name("DIR")
        ->group(kOutputGroup);
    ocp->add_flag("--compact", ocp_options.compact, "Print the result on one line")
        ->group(kOutputGroup);
    ocp->add_flag("--quiet", ocp_options.quiet, "No progress lines on stderr")->group(kOutputGroup);
    ocp->footer(kOcpFooter);

    OrbitCommandOptions orbit_options;
    CLI::App* orbit = app.add_subcommand(
        "orbit",
        "Find a periodic orbit of a scene through a Poincare section by a nonsmooth Newton "
        "method: fixed point, period, the return map's pieces and a stability verdict (JSON)");
    orbit->add_option("--scene", orbit_options.scene, "pwconst, biped or pronk (required)")
        ->type_name("NAME");
    orbit
        ->add_option("--param", orbit_options.params,
                     "A scene parameter, key=value; repeat for several (they override the "
                     "biped's orbit defaults one by one)")
        ->type_name("KEY=VALUE")
        ->allow_extra_args(false);
    orbit
        ->add_option("--x0", orbit_options.x0,
                     "The guess, d comma-separated numbers, projected onto the section "
                     "(biped: 0,0.8,0,0,0,0; pronk: 0,1,0,0,0,0)")
        ->type_name("A,B,...");
    orbit
        ->add_option("--section", orbit_options.section,
                     "The Poincare section, e.g. x4, -x4, x1=0.3 (below; biped, pronk: -x4, the "
                     "apex)")
        ->type_name("TEXT");
    orbit->add_option("--tol", orbit_options.tol, "Newton's tolerance, > 0 (default 1e-8)")
        ->type_name("X");
    orbit
        ->add_option("--max-iterations", orbit_options.max_iterations,
                     "Newton iterations, >= 0 (default 40)")
        ->type_name("N");
    orbit
        ->add_option("--vary-param", orbit_options.vary_param,
                     "A family: COUNT >= 2 values of a real scene parameter from LO to HI, each "
                     "orbit from the last one found")
        ->type_name("KEY=LO:HI:COUNT");
    orbit->add_option("--rtol", orbit_options.rtol, "Relative tolerance, > 0 (default 1e-10)")
        ->type_name("R");
    orbit
        ->add_option("--atol", orbit_options.atol,
                     "Absolute tolerance, >= 1e-20 (default 1e-12, or rtol / 100 with --rtol)")
        ->type_name("A");
    orbit
        ->add_option("--plot", orbit_options.plot,
                     "Draw DIR/orbit.png and, with --vary-param, DIR/growth_rate.png (gnuplot)")
        ->type_name("DIR");
    orbit
        ->add_option("-o,--output", orbit_options.output,
                     "Write the JSON to FILE instead of stdout")
        ->type_name("FILE");
    orbit->add_flag("--compact", orbit_options.compact, "Print the result on one line");
    orbit->add_flag("--quiet", orbit_options.quiet, "No progress lines on stderr");
    orbit->footer(kOrbitFooter);

    SweepCommandOptions sweep_options;
    CLI::App* sweep = app.add_subcommand(
        "sweep",
        "The flow of a scene and its B-derivative over a grid of initial states and parameters, "
        "on threads: one record per sample (JSON lines or CSV), in grid order");
    sweep->add_option("--scene", sweep_options.flow.scene, "pwconst, biped or pronk (required)")
        ->type_name("NAME");
    sweep
        ->add_option("--param", sweep_options.flow.params,
                     "A scene parameter, key=value; repeat for several")
        ->type_name("KEY=VALUE")
        ->allow_extra_args(false);
    sweep
        ->add_option("--t", sweep_options.flow.t,
                     "Final time, >= 0 (pwconst: 1, biped, pronk: 0.6)")
        ->type_name("T");
    sweep
        ->add_option("--x0", sweep_options.flow.x0,
                     "The initial state the varied entries start from, d comma-separated numbers "
                     "(default: the scene's)")
        ->type_name("A,B,...");
    sweep
        ->add_option("--vary", sweep_options.vary,
                     "Vary x0[I] over COUNT values from LO to HI (both included); repeat for a "
                     "grid, the first given varies slowest")
        ->type_name("I=LO:HI:COUNT")
        ->allow_extra_args(false);
    sweep
        ->add_option("--vary-param", sweep_options.vary_param,
                     "Vary a real-valued scene parameter the same way")
        ->type_name("KEY=LO:HI:COUNT")
        ->allow_extra_args(false);
    sweep
        ->add_option("--dx", sweep_options.flow.dx,
                     "A direction, d comma-separated numbers: its image and crossing orders in "
                     "every record; repeat for several (default: none)")
        ->type_name("A,B,...")
        ->allow_extra_args(false);
    sweep
        ->add_option("--threads", sweep_options.threads,
                     "Worker threads (default: one per core; under mpirun, the cores of a "
                     "machine shared among its ranks)")
        ->type_name("K");
    sweep->add_option("--format", sweep_options.format, "jsonl or csv")
        ->type_name("FORMAT")
        ->capture_default_str();
    sweep
        ->add_option("--output", sweep_options.output,
                     "Write the records to FILE instead of stdout")
        ->type_name("FILE");
    sweep
        ->add_option("--atlas", sweep_options.atlas,
                     "Also draw the atlas of crossing orders of a two-axis grid to this PNG "
                     "(a colour per event structure along the first --dx; gnuplot)")
        ->type_name("PNG");
    sweep->add_flag("--resume", sweep_options.resume,
                    "With --output: keep the whole records an interrupted run of the same sweep "
                    "left in FILE and compute the rest");
    sweep->add_flag("--quiet", sweep_options.quiet, "No progress bar on stderr");
    sweep->add_option("--rtol", sweep_options.flow.rtol, "Relative tolerance, > 0 (default 1e-8)")
        ->type_name("R");
    sweep
        ->add_option("--atol", sweep_options.flow.atol,
                     "Absolute tolerance, >= 1e-20 (default: rtol / 100)")
        ->type_name("A");
    sweep
        ->add_option("--grouping", sweep_options.flow.grouping,
                     "How crossings become one event: auto (default), window (--window T) or "
                     "none")
        ->type_name("POLICY");
    sweep
        ->add_option("--window", sweep_options.flow.window,
                     "With --grouping window: crossings closer than T in time are one event")
        ->type_name("T");
    sweep
        ->add_option("--integrator", sweep_options.flow.integrator,
                     "auto (dopri5 at loose tolerances on small models with surfaces, else dop853: "
                     "bflow::choose_backend), dopri5, dop853, cvodes-bdf or cvodes-adams")
        ->type_name("NAME")
        ->capture_default_str();
    sweep
        ->add_option("--max-steps", sweep_options.flow.max_steps,
                     "Steps per smooth segment before a sample stops (default 1000000)")
        ->type_name("N");
    sweep->footer(kSweepFooter);

    if (argc <= 1) {
      report_error(err,
                   "a command is required: jump, flow, demo, fesd, ocp, sweep or orbit (see "
                   "'bflow --help')");
      return kExitBadInput;
    }
    const std::string command = argv[1];
    if (command[0] != '-' && command != "jump" && command != "flow" && command != "demo" &&
        command != "fesd" && command != "ocp" && command != "sweep" && command != "orbit") {
      report_error(err, "unknown command " + quote(command) +
                            "; the commands are jump, flow, demo, fesd, ocp, sweep and orbit (see "
                            "'bflow --help')");
      return kExitBadInput;
    }
    std::vector<std::string> args;
    for (int i = argc - 1; i >= 1; --i) args.emplace_back(argv[i]);  // CLI11 wants them reversed
    try {
      app.parse(args);
    } catch (const CLI::ParseError& e) {
      if (e.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) {
        return finish_output(out, err, app.exit(e, out, err));  // --help, --version
      }
      // CLI11 quotes what it did not expect as given: keep a bounded, printable prefix.
      std::string message = escaped(e.what(), 200, false);
      if (message.empty()) message = e.get_name();
      std::string name;
      for (const CLI::App* sub : {jump, flow, demo, fesd, ocp, sweep, orbit}) {
        if (sub->parsed()) name = sub->get_name();
      }
      const std::string where = name.empty() ? "" : name + ": ";
      const std::string help = name.empty() ? "bflow --help" : "bflow " + name + " --help";
      report_error(err, where + message + " (see '" + help + "')");
      return kExitBadInput;
    }
    try {
      for (const CLI::App* sub : {jump, flow, demo, fesd, ocp, orbit}) {
        if (sub->parsed()) refuse_empty_values(*sub);
      }
      // The sweep checks its own options; those it shares with flow are checked as flow's.
      if (sweep->parsed()) {
        std::vector<std::string> scene_options;
        for (const CLI::Option* option : flow->get_options()) {
          scene_options.push_back(option->get_name());
        }
        refuse_empty_values(*sweep, scene_options);
      }
      read_numbers(numbers, jump_options, fesd_options, ocp_options);
    } catch (const InputError& e) {
      report_error(err, e.what());
      return kExitBadInput;
    }
    // Every command ends here: a result that could not be written is a failure (exit code 1).
    if (jump->parsed()) {
      return finish_output(out, err, run_jump_file(input, in, out, err, jump_options));
    }
    if (flow->parsed()) return finish_output(out, err, run_flow(flow_options, out, err));
    if (fesd->parsed()) return finish_output(out, err, run_fesd(fesd_options, out, err));
    if (ocp->parsed()) return finish_output(out, err, run_ocp(ocp_options, out, err));
    if (sweep->parsed()) return finish_output(out, err, run_sweep(sweep_options, out, err));
    if (orbit->parsed()) return finish_output(out, err, run_orbit(orbit_options, out, err));
    return finish_output(out, err, run_demo(demo_options, out, err));
  } catch (const std::exception& e) {
    report_error(err, std::string("internal: ") + e.what());
    return kExitFailure;
  }
}

}  // namespace bflow::cli

// The problems bflow is compared on with other tools (scripts/peers, bench/peers/, docs/peers.md),
// each solved once with every homotopy and IPOPT setting taken from the command line, so that a
// peer's settings can be reproduced exactly. Prints one JSON object on stdout.
//
//   peer_problems --problem braking-block --stages 10 --cross point-pairs --no-polish ...
//
// Problems (all with exact solutions, examples/include/bflow/examples/):
//   braking-block   the braking block (ocp_examples.h): fixed horizon 3, an optimum that slides,
//                   J* = 2 sqrt 5 + asinh 2 - 4
//   turbo-car       the time-optimal turbo car (ocp_examples.h): T* = 40 / 3
//   irma            IRMA (irma.h) from its x0 over [0, --horizon] (default 100 min) in --steps
//                   integration steps; exact x(T) by exact_irma
//   sliding-enter   x' in -sign(x) + 0.2 sin 5t from 0.5 over [0, 1] (switching_cases.h): it
//                   reaches x = 0 at 0.5206 and slides; exact x(T) = (0, 1)
//
// --solver ocp (default) runs ocp_solve: the OCPs once, a simulation once per integration step as
// a one-stage OCP without cost (a dummy control fixed at 0), starting from the neutral guess with
// x at the step's start, the way nosnoc's simulation loop solves one step. --solver fesd runs
// fesd_simulate with its own rules (Newton on guessed active sets first, its homotopy otherwise);
// only the FesdOptions flags below apply then.
//
// The JSON: the problem and settings; status; the optimum (objective, T) or x(T) and the exact
// value with the error; the NLP as IPOPT sees it (variables, equality and inequality constraints,
// Jacobian and Hessian nonzeros, from IPOPT's problem statistics; for a simulation one step's
// NLP) and as bflow counts it; every NLP of the homotopy (sigma, IPOPT iterations, status,
// complementarity, CPU); the CPU time of the run (cpu_s: the tool's calls, ocp_solve or
// fesd_simulate, as nosnoc's is its problem's construction and solve; process_cpu_s: everything
// after the flags, harness_cpu_s the difference: reading IPOPT's logs, the exact solutions, the
// JSON) and of the NLP solves alone; the split of IPOPT's time from its timing statistics
// (bench/ipopt_flags.h): function and derivative evaluations, KKT factorisations and the rest; x at
// every stage boundary (every integration step's end for a simulation), u per stage, and the switch
// times.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bflow/core/errors.h"
#include "bflow/examples/irma.h"
#include "bflow/examples/ocp_examples.h"
#include "bflow/examples/switching_cases.h"
#include "bflow/fesd/fesd.h"
#include "bflow/ocp/ocp.h"
#include "ipopt_flags.h"
#include "peer_common.h"

namespace {

using bflow_bench::process_cpu_seconds;
using bflow_bench::vector_json;
using nlohmann::ordered_json;

// The process CPU seconds spent in the tool's own calls (timed_call), the run's cpu_s.
double tool_cpu = 0.0;
template <typename Call>
auto timed_call(Call call) {
  const double start = process_cpu_seconds();
  auto result = call();
  tool_cpu += process_cpu_seconds() - start;
  return result;
}

// A step inclusion x' in f(x, a) as an OCP model with one control that does not enter: the
// integration step of a simulation as ocp_solve's problem (the control is fixed by its bounds).
template <typename Model>
struct SimulationAsOcp {
  static constexpr int kStates = Model::kStates, kControls = 1, kSwitches = Model::kSwitches;
  Model model;
  template <typename T>
  void switching(const T* x, T* c) const {
    model.switching(x, c);
  }
  template <typename T>
  void field(const T* x, const T*, const T* a, T* xdot) const {
    model.field(x, a, xdot);
  }
};

struct Flags {
  std::string problem, solver = "ocp", formulation = "step", cross = "element-sums";
  std::string warm_start = "primal-dual";
  int stages = 10, elements = 3, collocation_stages = 2, steps = 0;
  double horizon = 0.0;
  double sigma_initial = -1.0, sigma_final = -1.0, sigma_factor = -1.0;
  double early_polish_sigma = -1.0;
  bool superlinear = false, linear = false;
  double complementarity_tolerance = -1.0, nlp_tolerance = -1.0;
  double intermediate_tolerance_factor = -1.0, step_deviation_weight = 0.0;
  double equilibration_weight = 0.0, later_mu_init = 0.0, acceptable_tolerance = 0.0;
  std::optional<double> monotone_mu_down_to;  // not given: the default
  int acceptable_iterations = 15, max_nlp_iterations = -1;
  bool no_polish = false, stop_at_complementarity = false, continue_after_failure = false;
  bool first_from_zero_multipliers = false, neutral_guess = false, nosnoc_guess = false;
  bool no_newton = false;
  bool probe_sparsity = false, no_mumps_amalgamation = false, jet_derivatives = false;
  std::string collocation_form = "integral";
  bool x_bounds_at_stage_points = false;
};

bool is_simulation(const std::string& problem) {
  return problem == "irma" || problem == "sliding-enter";
}

bflow::OcpOptions ocp_options(const Flags& f) {
  bflow::OcpOptions o;
  o.stages = is_simulation(f.problem) ? 1 : f.stages;
  o.elements = f.elements;
  o.collocation_stages = f.collocation_stages;
  o.formulation = bflow::parse_dcs_formulation(f.formulation);
  o.cross_complementarity = f.cross == "point-pairs" ? bflow::CrossComplementarity::kPointPairs
                                                     : bflow::CrossComplementarity::kElementSums;
  if (f.sigma_initial > 0.0) o.homotopy.sigma_initial = f.sigma_initial;
  if (f.sigma_final > 0.0) o.homotopy.sigma_final = f.sigma_final;
  if (f.early_polish_sigma >= 0.0) o.homotopy.early_polish_sigma = f.early_polish_sigma;
  if (f.sigma_factor > 0.0) o.homotopy.sigma_factor = f.sigma_factor;
  o.homotopy.superlinear = f.superlinear;
  if (f.complementarity_tolerance > 0.0)
    o.homotopy.complementarity_tolerance = f.complementarity_tolerance;
  if (f.nlp_tolerance > 0.0) o.homotopy.nlp_tolerance = f.nlp_tolerance;
  if (f.intermediate_tolerance_factor >= 0.0) {
    o.homotopy.intermediate_tolerance_factor = f.intermediate_tolerance_factor;
  }
  o.step_deviation_weight = f.step_deviation_weight;
  o.equilibration_weight = f.equilibration_weight;
  o.homotopy.polish = !f.no_polish;
  o.homotopy.stop_at_complementarity = f.stop_at_complementarity;
  o.homotopy.continue_after_failure = f.continue_after_failure;
  o.homotopy.warm_start = f.warm_start != "cold";
  o.homotopy.warm_start_multipliers = f.warm_start == "primal-dual";
  o.homotopy.first_from_zero_multipliers = f.first_from_zero_multipliers;
  o.homotopy.later_mu_init = f.later_mu_init;
  if (f.monotone_mu_down_to) o.homotopy.monotone_mu_down_to = *f.monotone_mu_down_to;
  o.homotopy.acceptable_tolerance = f.acceptable_tolerance;
  o.homotopy.acceptable_iterations = f.acceptable_iterations;
  if (f.max_nlp_iterations > 0) o.homotopy.max_nlp_iterations = f.max_nlp_iterations;
  o.algebraic_guess = f.nosnoc_guess    ? bflow::AlgebraicGuess::kNosnoc
                      : f.neutral_guess ? bflow::AlgebraicGuess::kNeutral
                                        : bflow::AlgebraicGuess::kSides;
  o.probe_sparsity = f.probe_sparsity;
  o.collocation_form = bflow::parse_collocation_form(f.collocation_form);
  o.solver.mumps_amalgamation = !f.no_mumps_amalgamation;
  o.solver.derivative_programs = !f.jet_derivatives;
  return o;
}

bflow::FesdOptions fesd_options(const Flags& f, int steps) {
  bflow::FesdOptions o;
  o.solver.mumps_amalgamation = !f.no_mumps_amalgamation;
  o.solver.derivative_programs = !f.jet_derivatives;
  o.stages = f.collocation_stages;
  o.elements = f.elements;
  o.steps = steps;
  o.formulation = bflow::parse_dcs_formulation(f.formulation);
  if (f.sigma_initial > 0.0) o.homotopy.sigma_initial = f.sigma_initial;
  if (f.sigma_final > 0.0) o.homotopy.sigma_final = f.sigma_final;
  if (f.sigma_factor > 0.0) o.homotopy.sigma_factor = f.sigma_factor;
  if (f.linear) o.homotopy.superlinear = false;
  if (f.nlp_tolerance > 0.0) o.homotopy.nlp_tolerance = f.nlp_tolerance;
  if (f.max_nlp_iterations > 0) o.homotopy.max_nlp_iterations = f.max_nlp_iterations;
  o.newton = !f.no_newton;
  o.sensitivities = false;
  return o;
}

// IPOPT's log (timing statistics, problem statistics) and the command line's IPOPT flags, on
// either kind of options.
template <typename Options>
void add_ipopt_options(Options& o, const bflow_bench::IpoptLog& log,
                       const bflow_bench::IpoptFlags& flags) {
  o.solver.ipopt_string_options.emplace_back("output_file", log.path());
  o.solver.ipopt_integer_options.emplace_back("file_print_level", 6);
  o.solver.ipopt_string_options.emplace_back("print_timing_statistics", "yes");
  o.solver.ipopt_string_options.insert(o.solver.ipopt_string_options.end(), flags.strings.begin(),
                                       flags.strings.end());
  o.solver.ipopt_numeric_options.insert(o.solver.ipopt_numeric_options.end(), flags.numbers.begin(),
                                        flags.numbers.end());
  o.solver.ipopt_integer_options.insert(o.solver.ipopt_integer_options.end(),
                                        flags.integers.begin(), flags.integers.end());
}

// Sums of IPOPT's logs over the solves of a run (a simulation's steps each have their own log);
// the problem statistics of the first.
struct LogTotals {
  bflow_bench::IpoptCounts counts;
  bool any = false;
  void add(const bflow_bench::IpoptCounts& c) {
    if (c.nlps == 0) return;
    if (!any) {
      counts = c;
      any = true;
      return;
    }
    counts.nlps += c.nlps;
    counts.trial_factorizations += c.trial_factorizations;
    counts.factorizations += c.factorizations;
    counts.factorization += c.factorization;
    counts.back_solve += c.back_solve;
    counts.symbolic += c.symbolic;
    counts.hessian += c.hessian;
    counts.functions += c.functions;
    counts.overall += c.overall;
  }
  // Without any IPOPT solve (every step by Newton) only the iterations, 0.
  ordered_json json(double solve_cpu, int iterations) const {
    ordered_json j;
    const auto count = [this](long c) { return any && c >= 0 ? ordered_json(c) : ordered_json(); };
    j["variables"] = count(counts.variables);
    j["equalities"] = count(counts.equalities);
    j["inequalities"] = count(counts.inequalities);
    j["jacobian_nonzeros"] = count(counts.jacobian_nonzeros);
    j["hessian_nonzeros"] = count(counts.hessian_nonzeros);
    j["iterations"] = iterations;
    if (!any) return j;
    j["ipopt_cpu_s"] = counts.overall;
    j["functions_cpu_s"] = counts.functions;
    j["hessian_cpu_s"] = counts.hessian;
    j["factorization_cpu_s"] = counts.factorization;
    j["back_solve_cpu_s"] = counts.back_solve;
    j["factorizations"] = counts.factorizations;
    j["trial_factorizations"] = counts.trial_factorizations;
    j["rest_cpu_s"] = solve_cpu - counts.functions - counts.factorization - counts.back_solve;
    return j;
  }
};

ordered_json nlp_json(const bflow::OcpHomotopyStep& s, int step) {
  ordered_json j;
  if (step >= 0) j["step"] = step;
  j["sigma"] = s.sigma;
  j["iterations"] = s.iterations;
  j["status"] = s.ipopt_status;
  j["complementarity"] = s.complementarity;
  j["objective"] = s.objective;
  j["cpu_s"] = s.cpu_seconds;
  j["polish"] = s.polish;
  j["mu_strategy"] = s.mu_strategy;
  return j;
}

// x(t) of sliding-enter: 0.54 - t - 0.04 cos 5t until it reaches 0, then 0 (and the clock t).
Eigen::VectorXd sliding_enter_exact(double t) {
  const double ts = bflow::examples::sliding_enter_time();
  return Eigen::Vector2d(t < ts ? 0.54 - t - 0.04 * std::cos(5.0 * t) : 0.0, t);
}

// An OCP with an exact optimum, once.
template <typename Example>
ordered_json run_ocp(const Flags& f, const bflow_bench::IpoptFlags& ipopt_flags) {
  const auto model = bflow::adapt_ocp(Example{});
  bflow::OcpProblem problem = Example::problem();
  problem.x_bounds_at_stage_points = f.x_bounds_at_stage_points;
  bflow::OcpOptions o = ocp_options(f);
  const bflow_bench::IpoptLog log;
  add_ipopt_options(o, log, ipopt_flags);
  const bflow::OcpResult r = timed_call([&] { return bflow::ocp_solve(model, problem, o); });
  ordered_json j;
  j["status"] = bflow::to_string(r.status);
  j["message"] = r.message;
  j["objective"] = r.objective;
  j["T"] = r.T;
  j["max_complementarity"] = r.max_complementarity;
  j["polished"] = r.polished;
  j["unknowns"] = r.unknowns;
  j["constraints"] = r.constraints;
  j["jacobian_nonzeros_bflow"] = r.jacobian_nonzeros;
  j["hessian_nonzeros_bflow"] = r.hessian_nonzeros;
  double solve_cpu = 0.0;
  j["nlps"] = ordered_json::array();
  for (const bflow::OcpHomotopyStep& s : r.homotopy) {
    j["nlps"].push_back(nlp_json(s, -1));
    solve_cpu += s.cpu_seconds;
  }
  j["solve_cpu_s"] = solve_cpu;
  LogTotals totals;
  totals.add(log.read());
  j["ipopt"] = totals.json(solve_cpu, r.ipopt_iterations);
  j["stage_times"] = r.stage_times;
  j["x_stages"] = ordered_json::array();
  for (Eigen::Index k = 0; k < r.x_stages.cols(); ++k) {
    j["x_stages"].push_back(vector_json(r.x_stages.col(k)));
  }
  j["u"] = ordered_json::array();
  for (Eigen::Index k = 0; k < r.u.cols(); ++k) j["u"].push_back(vector_json(r.u.col(k)));
  j["switch_times"] = r.switch_times;
  return j;
}

// A simulation, one integration step at a time as a one-stage OCP (--solver ocp), or by
// fesd_simulate (--solver fesd).
template <typename Model>
ordered_json run_simulation(const Flags& f, const bflow_bench::IpoptFlags& ipopt_flags,
                            const Model& model, const Eigen::VectorXd& x0, double horizon,
                            int steps) {
  const double H = horizon / steps;
  ordered_json j;
  j["stage_times"] = ordered_json::array();
  j["x_stages"] = ordered_json::array();
  j["switch_times"] = ordered_json::array();
  j["nlps"] = ordered_json::array();
  for (int k = 0; k <= steps; ++k) j["stage_times"].push_back(k * H);
  LogTotals totals;
  if (f.solver == "fesd") {
    bflow::FesdOptions o = fesd_options(f, steps);
    const bflow_bench::IpoptLog log;
    add_ipopt_options(o, log, ipopt_flags);
    const auto step_model = bflow::adapt_step(model);
    const bflow::FesdResult r =
        timed_call([&] { return bflow::fesd_simulate(step_model, x0, horizon, o); });
    totals.add(log.read());
    const bflow::FesdProblemSize size = bflow::fesd_problem_size(step_model, o);
    j["status"] = bflow::to_string(r.status);
    j["message"] = r.message;
    j["unknowns"] = size.unknowns;
    j["constraints"] = size.constraints;
    j["newton_steps"] = r.newton_steps;
    j["halved_steps"] = r.halved_steps;
    j["max_complementarity"] = r.max_complementarity;
    int iterations = 0;
    for (std::size_t s = 0; s < r.nlp_iterations.size(); ++s) {
      ordered_json n;
      n["step"] = static_cast<int>(s);
      n["iterations"] = r.nlp_iterations[s];
      j["nlps"].push_back(n);
      iterations += r.nlp_iterations[s];
    }
    // x at the ends of the integration steps (the grid has N_FE elements per step unless one
    // was halved, so look the times up).
    for (int k = 0; k <= steps; ++k) {
      std::size_t best = 0;
      for (std::size_t g = 0; g < r.grid.size(); ++g) {
        if (std::abs(r.grid[g] - k * H) < std::abs(r.grid[best] - k * H)) best = g;
      }
      j["x_stages"].push_back(vector_json(r.states.col(static_cast<Eigen::Index>(best))));
    }
    j["switch_times"] = r.switch_times;
    j["x_T"] = vector_json(r.x_end);
    j["solve_cpu_s"] = nullptr;
    j["ipopt"] = totals.json(totals.counts.overall, iterations);
    return j;
  }
  const auto ocp_model = bflow::adapt_ocp(SimulationAsOcp<Model>{model});
  bflow::OcpProblem problem;
  problem.horizon = H;
  problem.u_lower = problem.u_upper = Eigen::VectorXd::Zero(1);
  Eigen::VectorXd x = x0;
  std::string status = "solved", message;
  double solve_cpu = 0.0, max_complementarity = 0.0;
  int iterations = 0;
  j["x_stages"].push_back(vector_json(x));
  for (int k = 0; k < steps; ++k) {
    problem.x0 = x;
    bflow::OcpOptions o = ocp_options(f);
    const bflow_bench::IpoptLog log;
    add_ipopt_options(o, log, ipopt_flags);
    const bflow::OcpResult r = timed_call([&] { return bflow::ocp_solve(ocp_model, problem, o); });
    totals.add(log.read());
    if (k == 0) {
      j["unknowns"] = r.unknowns;
      j["constraints"] = r.constraints;
      j["jacobian_nonzeros_bflow"] = r.jacobian_nonzeros;
      j["hessian_nonzeros_bflow"] = r.hessian_nonzeros;
    }
    for (const bflow::OcpHomotopyStep& s : r.homotopy) {
      j["nlps"].push_back(nlp_json(s, k));
      solve_cpu += s.cpu_seconds;
    }
    iterations += r.ipopt_iterations;
    max_complementarity = std::max(max_complementarity, r.max_complementarity);
    for (double t : r.switch_times) j["switch_times"].push_back(k * H + t);
    if (!r.ok() && status == "solved") {
      status = bflow::to_string(r.status);
      message = "step " + std::to_string(k) + ": " + r.message;
    }
    x = r.x_stages.col(r.x_stages.cols() - 1);
    j["x_stages"].push_back(vector_json(x));
  }
  j["status"] = status;
  j["message"] = message;
  j["max_complementarity"] = max_complementarity;
  j["x_T"] = vector_json(x);
  j["solve_cpu_s"] = solve_cpu;
  j["ipopt"] = totals.json(solve_cpu, iterations);
  return j;
}

double max_abs_difference(const ordered_json& a, const Eigen::VectorXd& b) {
  double d = 0.0;
  for (Eigen::Index i = 0; i < b.size(); ++i) {
    d = std::max(d, std::abs(a.at(static_cast<std::size_t>(i)).get<double>() - b[i]));
  }
  return d;
}

}  // namespace

int main(int argc, char** argv) {
  const bflow_bench::IpoptFlags ipopt_flags = bflow_bench::take_ipopt_flags(argc, argv);
  Flags f;
  CLI::App app(
      "One run of a problem bflow is compared on with other tools (scripts/peers), every setting "
      "from the flags; prints one JSON object. IPOPT options: --ipopt-int=name=value, "
      "--ipopt-num=..., --ipopt-str=... (repeatable, applied after bflow's own).");
  app.add_option("--problem", f.problem, "braking-block, turbo-car, irma or sliding-enter")
      ->required()
      ->check(CLI::IsMember({"braking-block", "turbo-car", "irma", "sliding-enter"}));
  app.add_option("--solver", f.solver,
                 "ocp: ocp_solve (a simulation one step at a time); fesd: fesd_simulate")
      ->check(CLI::IsMember({"ocp", "fesd"}));
  app.add_option("--formulation", f.formulation, "step or stewart")
      ->check(CLI::IsMember({"step", "stewart"}));
  app.add_option("--stages", f.stages, "N control stages (OCPs)")->check(CLI::PositiveNumber);
  app.add_option("--elements", f.elements, "N_FE per stage or integration step")
      ->check(CLI::PositiveNumber);
  app.add_option("--collocation-form", f.collocation_form,
                 "integral or derivative (OcpOptions::collocation_form)");
  app.add_option("--collocation-stages", f.collocation_stages, "n_s of Radau IIA")
      ->check(CLI::Range(1, 9));
  app.add_option("--steps", f.steps,
                 "N_sim integration steps (simulations; default irma 20, "
                 "sliding-enter 4)");
  app.add_option("--horizon", f.horizon, "T of a simulation (default irma 100, sliding-enter 1)");
  app.add_option("--cross", f.cross, "element-sums or point-pairs")
      ->check(CLI::IsMember({"element-sums", "point-pairs"}));
  app.add_option("--sigma-initial", f.sigma_initial);
  app.add_option("--sigma-final", f.sigma_final);
  app.add_option("--early-polish-sigma", f.early_polish_sigma,
                 "OcpHomotopyOptions::early_polish_sigma (0: only the final polish)");
  app.add_option("--sigma-factor", f.sigma_factor);
  app.add_flag("--superlinear", f.superlinear, "sigma <- min(factor sigma, sigma^1.5) (ocp)");
  app.add_flag("--linear", f.linear, "sigma <- factor sigma (fesd; its default is superlinear)");
  app.add_option("--complementarity-tolerance", f.complementarity_tolerance);
  app.add_flag("--stop-at-complementarity", f.stop_at_complementarity);
  app.add_option("--nlp-tolerance", f.nlp_tolerance);
  app.add_option("--intermediate-tolerance-factor", f.intermediate_tolerance_factor);
  app.add_option("--step-deviation-weight", f.step_deviation_weight);
  app.add_option("--equilibration-weight", f.equilibration_weight);
  app.add_flag("--no-polish", f.no_polish);
  app.add_option("--warm-start", f.warm_start,
                 "primal-dual (bflow's default), primal (multipliers from 0) or cold (IPOPT's own "
                 "initialisation from the previous point)")
      ->check(CLI::IsMember({"primal-dual", "primal", "cold"}));
  app.add_flag("--first-from-zero-multipliers", f.first_from_zero_multipliers);
  app.add_option("--later-mu-init", f.later_mu_init);
  app.add_option("--monotone-mu-down-to", f.monotone_mu_down_to,
                 "OcpHomotopyOptions::monotone_mu_down_to (inf: the adaptive strategy throughout)");
  app.add_option("--acceptable-tolerance", f.acceptable_tolerance);
  app.add_option("--acceptable-iterations", f.acceptable_iterations);
  app.add_option("--max-nlp-iterations", f.max_nlp_iterations);
  app.add_flag("--continue-after-failure", f.continue_after_failure);
  app.add_flag("--neutral-guess", f.neutral_guess,
               "algebraic guess a = lambda = 1/2, Stewart theta = 1/n_f, lambda = 1, mu = 0");
  app.add_flag(
      "--nosnoc-guess", f.nosnoc_guess,
      "nosnoc's algebraic guess: a = lambda = 1/2, Stewart theta = lambda = 1/n_f, mu = 1");
  app.add_flag(
      "--no-mumps-amalgamation", f.no_mumps_amalgamation,
      "MUMPS without its small-front amalgamation (OcpOptions::solver.mumps_amalgamation)");
  app.add_flag("--jet-derivatives", f.jet_derivatives,
               "Jets and HessianJet at every derivative evaluation instead of traced programs "
               "(SolverOptions::derivative_programs false)");
  app.add_flag("--probe-sparsity", f.probe_sparsity,
               "only the Jacobian and Hessian entries found nonzero at random points declared to "
               "IPOPT (OcpOptions::probe_sparsity)");
  app.add_flag("--x-bounds-at-stage-points", f.x_bounds_at_stage_points,
               "the state bounds (turbo car: |v| <= 20) on every collocation stage, not only at "
               "the element boundaries");
  app.add_flag("--no-newton", f.no_newton, "fesd_simulate without its Newton attempts");
  CLI11_PARSE(app, argc, argv);
  if (f.solver == "fesd" && !is_simulation(f.problem)) {
    std::fprintf(stderr, "error: --solver fesd: %s is not a simulation\n", f.problem.c_str());
    return 2;
  }

  const double cpu_start = process_cpu_seconds();
  const auto wall_start = std::chrono::steady_clock::now();
  ordered_json out;
  out["tool"] = "bflow";
  out["problem"] = f.problem;
  out["solver"] = f.solver;
  out["formulation"] = f.formulation;
  try {
    if (f.problem == "braking-block") {
      out.update(run_ocp<bflow::examples::BrakingBlock>(f, ipopt_flags));
      out["exact"] = bflow::examples::BrakingBlock::optimal_cost();
      out["error"] = std::abs(out["objective"].get<double>() - out["exact"].get<double>());
    } else if (f.problem == "turbo-car") {
      out.update(run_ocp<bflow::examples::TurboCar>(f, ipopt_flags));
      out["exact"] = bflow::examples::TurboCar::kOptimalTime;
      out["error"] = std::abs(out["T"].get<double>() - out["exact"].get<double>());
    } else if (f.problem == "irma") {
      const double T = f.horizon > 0.0 ? f.horizon : 100.0;
      const int steps = f.steps > 0 ? f.steps : 20;
      const bflow::examples::Irma irma;
      const Eigen::VectorXd x0 = bflow::examples::Irma::initial_state();
      out.update(run_simulation(f, ipopt_flags, irma, x0, T, steps));
      const bflow::examples::IrmaSolution exact =
          bflow::examples::exact_irma(irma, bflow::examples::Irma::initial_state(), T);
      Eigen::VectorXd x_exact = exact.x;
      out["exact"] = vector_json(x_exact);
      out["error"] = max_abs_difference(out["x_T"], x_exact);
      out["exact_switch_times"] = ordered_json::array();
      for (const bflow::examples::IrmaSwitch& s : exact.switches) {
        out["exact_switch_times"].push_back(s.t);
      }
      ordered_json exact_stages = ordered_json::array();
      for (int k = 0; k <= steps; ++k) {
        exact_stages.push_back(vector_json(
            bflow::examples::exact_irma(irma, bflow::examples::Irma::initial_state(), k * T / steps)
                .x));
      }
      out["exact_x_stages"] = exact_stages;
    } else {
      const double T = f.horizon > 0.0 ? f.horizon : 1.0;
      const int steps = f.steps > 0 ? f.steps : 4;
      const Eigen::VectorXd x0 = Eigen::Vector2d(0.5, 0.0);
      out.update(run_simulation(f, ipopt_flags, bflow::examples::SlidingEnterCase{}, x0, T, steps));
      out["exact"] = vector_json(sliding_enter_exact(T));
      out["error"] = max_abs_difference(out["x_T"], sliding_enter_exact(T));
      out["exact_switch_times"] = {bflow::examples::sliding_enter_time()};
      ordered_json exact_stages = ordered_json::array();
      for (int k = 0; k <= steps; ++k) {
        exact_stages.push_back(vector_json(sliding_enter_exact(k * T / steps)));
      }
      out["exact_x_stages"] = exact_stages;
    }
  } catch (const bflow::InvalidArgument& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 2;
  }
  const double process_cpu = process_cpu_seconds() - cpu_start;
  out["cpu_s"] = tool_cpu;
  out["process_cpu_s"] = process_cpu;
  out["harness_cpu_s"] = process_cpu - tool_cpu;
  out["wall_s"] =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  out["ipopt_options"] = ipopt_flags.describe();
  out["blas"] = bflow_bench::loaded_library("libblas.so");
  out["lapack"] = bflow_bench::loaded_library("liblapack.so");
  std::cout << out.dump() << "\n";
  return 0;
}

// The hopping monoped of [F] Section 7.2 (monoped_ocp.h, docs/ocp.md): one whole ocp_solve
// with the options of `bflow ocp --example monoped` (nosnoc's setup,
// examples::MonopedTask::options), against the number N of control stages, in the Heaviside
// step formulation (three regions) and in Stewart's (eight base sets): the paper's Figure 10.
//
//   BM_Monoped/<formulation>/<N>   N = 30, 40, ..., 90, both formulations at each N in turn
//
// Each solve runs once. The reported time is the CPU time per IPOPT iteration (manual time); the
// CPU column is the CPU time of the whole homotopy. Counters: IPOPT iterations, the distance of
// q(T) to the target, the clock at the end, the hops, the complementarity residual, the
// objective, IPOPT's KKT error, acceptable_stop (1 when IPOPT stopped at its acceptable level)
// and "solved" (1 or 0); the label is "solved" or the status and its message (a failed solve keeps
// its row: its cost is part of the figure).
//
//   BM_MonopedIteration/<formulation>/<N>   the cost of an IPOPT iteration alone: the first NLP
//       (sigma = sigma_initial) of the same problem, stopped after kIterations iterations; the
//       reported time is its CPU time per iteration (the performance target at N = 60 in the
//       step formulation, and its growth in N). A minute for all 14 rows. From IPOPT's own log
//       (bench/ipopt_flags.h: output_file at file_print_level 6 with print_timing_statistics)
//       also factorizations_per_iteration (IPOPT's trial factorizations of the KKT matrix;
//       mumps_factorizations_per_iteration counts every MUMPS factorization, one more per NLP),
//       seconds_per_factorization (the CPU time of MUMPS's factorizations over their number),
//       hessian_seconds_per_iteration (the Lagrangian Hessian's evaluations) and
//       rest_seconds_per_iteration (cpu_per_iteration minus those two).
//
//   BM_MonopedFirstNlp/<formulation>/30   the first NLP of the homotopy (sigma = 1, IPOPT's tol
//       1e-2 as in the homotopy) solved to its end: iterations, objective, IPOPT's status (the
//       label) and the same counters: whether IPOPT options change its path.
//
// IPOPT options for every row: --ipopt-int=name=value, --ipopt-num=..., --ipopt-str=...
// (repeatable; bench/ipopt_flags.h); the context records them and the BLAS and LAPACK loaded.
// --budget=K bounds each BM_Monoped row's homotopy to K IPOPT iterations in all
// (OcpHomotopyOptions::max_total_iterations; counter "budget"). --no-mumps-amalgamation solves
// every row with MUMPS as it comes (OcpOptions::solver.mumps_amalgamation false; the context says
// which). A row's label is its status (and message) and, after " | ", its homotopy: "sigma
// objective complementarity iterations status" per NLP, "; " between them.
//
//   build-bench/bench/monoped_benchmark   (scripts/bench --monoped stores the JSON and draws
//                                          docs/monoped_cpu.png; scripts/bench
//                                          --monoped-iteration runs the second family only)
#include <benchmark/benchmark.h>

#include <cstdio>
#include <string>

#include <Eigen/Core>

#include "bflow/examples/monoped_ocp.h"
#include "bflow/ocp/ocp.h"
#include "ipopt_flags.h"

namespace {

bflow_bench::IpoptFlags g_ipopt_flags;  // from the command line, for every row
int g_budget = 0;  // --budget=K: OcpHomotopyOptions::max_total_iterations of every BM_Monoped row
bool g_amalgamation = true;  // false with --no-mumps-amalgamation

// Takes --budget=K out of argv (before benchmark::Initialize).
// Also takes --no-mumps-amalgamation.
int take_budget(int& argc, char** argv) {
  int budget = 0, kept = 1;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg.rfind("--budget=", 0) == 0) {
      budget = std::stoi(arg.substr(9));
    } else if (arg == "--no-mumps-amalgamation") {
      g_amalgamation = false;
    } else {
      argv[kept++] = argv[i];
    }
  }
  argc = kept;
  return budget;
}

// The homotopy as "sigma objective complementarity iterations status" per NLP, "; " between.
std::string homotopy_path(const bflow::OcpResult& r) {
  std::string path;
  char line[160];
  for (const bflow::OcpHomotopyStep& s : r.homotopy) {
    std::snprintf(line, sizeof line, "%s%.3g %.6g %.2g %d %s", path.empty() ? "" : "; ",
                  s.polish ? 0.0 : s.sigma, s.objective, s.complementarity, s.iterations,
                  s.ipopt_status.c_str());
    path += line;
  }
  return path;
}

// The counters read from IPOPT's log of the solve (`iterations` IPOPT iterations, `cpu` seconds).
void log_counters(benchmark::State& state, const bflow_bench::IpoptCounts& c, int iterations,
                  double cpu) {
  if (iterations <= 0) return;
  bflow_bench::split_counters(state, c, iterations, cpu);
  state.counters["symbolic_seconds"] = c.symbolic;
  state.counters["ipopt_overall_seconds"] = c.overall;
}

using bflow::OcpResult;
using bflow::examples::MonopedTask;

template <bflow::TimeFreezingRegions kRegions>
void BM_Monoped(benchmark::State& state, bflow::DcsFormulation formulation) {
  const auto model = bflow::adapt_ocp(bflow::examples::monoped_free_model<kRegions>());
  const MonopedTask task;  // nosnoc's setup
  const int stages = static_cast<int>(state.range(0));
  const bflow::OcpProblem problem = task.problem(stages);
  bflow::OcpOptions o = task.options(stages, formulation);
  g_ipopt_flags.apply_to(o);
  o.solver.mumps_amalgamation = g_amalgamation;
  o.homotopy.max_total_iterations = g_budget;
  OcpResult r;
  for (auto _ : state) {
    r = bflow::ocp_solve(model, problem, o);
    state.SetIterationTime(r.cpu_per_iteration);
  }
  state.counters["ipopt_iterations"] = r.ipopt_iterations;
  state.counters["cpu_total"] = r.cpu_seconds;
  state.counters["cpu_per_iteration"] = r.cpu_per_iteration;
  state.counters["unknowns"] = r.unknowns;
  state.counters["nlps"] = static_cast<double>(r.homotopy.size());
  if (r.x_stages.cols() > 0) {
    const Eigen::VectorXd end = r.x_stages.col(r.x_stages.cols() - 1);
    state.counters["q_error"] = MonopedTask::target_error(end);
    state.counters["t_physical_end"] = end[8];
    state.counters["hops"] = MonopedTask::hops(r.x_grid);
  }
  state.counters["complementarity"] = r.max_complementarity;
  state.counters["objective"] = r.objective;
  state.counters["kkt_error"] = r.kkt_error;
  state.counters["acceptable_stop"] = r.ipopt_status == "Solved_To_Acceptable_Level" ? 1.0 : 0.0;
  state.counters["solved"] = r.ok() ? 1.0 : 0.0;
  state.counters["budget"] = g_budget;
  state.SetLabel((r.ok() ? std::string("solved")
                         : std::string(bflow::to_string(r.status)) + ": " + r.message) +
                 " | " + homotopy_path(r));
}

constexpr int kIterations = 40;

// The monoped's first NLP (sigma = sigma_initial) with `configure` applied to its options, timed
// per IPOPT iteration; false (the state skipped) when IPOPT took no iteration.
template <bflow::TimeFreezingRegions kRegions, typename Configure>
bool first_nlp(benchmark::State& state, bflow::DcsFormulation formulation, Configure configure,
               OcpResult& r) {
  const auto model = bflow::adapt_ocp(bflow::examples::monoped_model<kRegions>());
  MonopedTask task;  // the strict setup, as the iteration's cost was first measured
  task.setup = bflow::examples::MonopedSetup::kStrict;
  const int stages = static_cast<int>(state.range(0));
  const bflow::OcpProblem problem = task.problem(stages);
  bflow::OcpOptions o = task.options(stages, formulation);
  o.homotopy.sigma_final = o.homotopy.sigma_initial;  // one NLP
  o.homotopy.polish = false;
  configure(o);
  const bflow_bench::IpoptLog log;
  log.apply_to(o);
  g_ipopt_flags.apply_to(o);
  o.solver.mumps_amalgamation = g_amalgamation;
  for (auto _ : state) {
    r = bflow::ocp_solve(model, problem, o);
    if (r.homotopy.empty() || r.homotopy.front().iterations == 0) {
      state.SkipWithError(("no IPOPT iteration: " + r.message).c_str());
      return false;
    }
    state.SetIterationTime(r.homotopy.front().cpu_seconds / r.homotopy.front().iterations);
  }
  const bflow::OcpHomotopyStep& nlp = r.homotopy.front();
  state.counters["ipopt_iterations"] = nlp.iterations;
  state.counters["cpu_per_iteration"] = nlp.cpu_seconds / nlp.iterations;
  state.counters["unknowns"] = r.unknowns;
  log_counters(state, log.read(), nlp.iterations, nlp.cpu_seconds);
  state.SetLabel(nlp.ipopt_status);
  return true;
}

// The first kIterations IPOPT iterations of the sigma = 1 NLP.
template <bflow::TimeFreezingRegions kRegions>
void BM_MonopedIteration(benchmark::State& state, bflow::DcsFormulation formulation) {
  OcpResult r;
  if (!first_nlp<kRegions>(
          state, formulation,
          [](bflow::OcpOptions& o) { o.homotopy.max_nlp_iterations = kIterations; }, r)) {
    return;
  }
  state.counters["constraints"] = r.constraints;
  state.counters["jacobian_nonzeros"] = r.jacobian_nonzeros;
  state.counters["hessian_nonzeros"] = r.hessian_nonzeros;
}

// The first NLP (sigma = sigma_initial) to its end, with the tolerances the homotopy gives it
// (tol = 1e-2 sigma; ocp_solve's last NLP gets nlp_tolerance, so that is set to it).
template <bflow::TimeFreezingRegions kRegions>
void BM_MonopedFirstNlp(benchmark::State& state, bflow::DcsFormulation formulation) {
  OcpResult r;
  if (!first_nlp<kRegions>(
          state, formulation,
          [](bflow::OcpOptions& o) { o.homotopy.nlp_tolerance = 1e-2 * o.homotopy.sigma_initial; },
          r)) {
    return;
  }
  const bflow::OcpHomotopyStep& nlp = r.homotopy.front();
  state.counters["cpu_total"] = nlp.cpu_seconds;
  state.counters["objective"] = nlp.objective;
  state.counters["complementarity"] = nlp.complementarity;
}
}  // namespace

// Rows by N, the two formulations next to each other, so that a run stopped early (each row
// takes minutes) still compares them.
int main(int argc, char** argv) {
  g_ipopt_flags = bflow_bench::take_ipopt_flags(argc, argv);
  g_budget = take_budget(argc, argv);
  for (int n = 30; n <= 90; n += 10) {
    for (const bool stewart : {false, true}) {
      const std::string name =
          std::string("BM_Monoped/") + (stewart ? "stewart" : "step") + "/" + std::to_string(n);
      benchmark::internal::Benchmark* b =
          stewart ? benchmark::RegisterBenchmark(name.c_str(),
                                                 BM_Monoped<bflow::TimeFreezingRegions::kBaseSets>,
                                                 bflow::DcsFormulation::kStewart)
                  : benchmark::RegisterBenchmark(name.c_str(),
                                                 BM_Monoped<bflow::TimeFreezingRegions::kUnions>,
                                                 bflow::DcsFormulation::kStep);
      b->Arg(n)->Iterations(1)->UseManualTime()->MeasureProcessCPUTime()->Unit(
          benchmark::kMillisecond);
    }
  }
  for (int n = 30; n <= 90; n += 10) {
    for (const bool stewart : {false, true}) {
      const std::string name = std::string("BM_MonopedIteration/") +
                               (stewart ? "stewart" : "step") + "/" + std::to_string(n);
      benchmark::internal::Benchmark* b =
          stewart ? benchmark::RegisterBenchmark(
                        name.c_str(), BM_MonopedIteration<bflow::TimeFreezingRegions::kBaseSets>,
                        bflow::DcsFormulation::kStewart)
                  : benchmark::RegisterBenchmark(
                        name.c_str(), BM_MonopedIteration<bflow::TimeFreezingRegions::kUnions>,
                        bflow::DcsFormulation::kStep);
      b->Arg(n)->Iterations(1)->UseManualTime()->MeasureProcessCPUTime()->Unit(
          benchmark::kMillisecond);
    }
  }
  for (const bool stewart : {false, true}) {
    const std::string name =
        std::string("BM_MonopedFirstNlp/") + (stewart ? "stewart" : "step") + "/30";
    benchmark::internal::Benchmark* b =
        stewart ? benchmark::RegisterBenchmark(
                      name.c_str(), BM_MonopedFirstNlp<bflow::TimeFreezingRegions::kBaseSets>,
                      bflow::DcsFormulation::kStewart)
                : benchmark::RegisterBenchmark(
                      name.c_str(), BM_MonopedFirstNlp<bflow::TimeFreezingRegions::kUnions>,
                      bflow::DcsFormulation::kStep);
    b->Arg(30)->Iterations(1)->UseManualTime()->MeasureProcessCPUTime()->Unit(
        benchmark::kMillisecond);
  }
  benchmark::AddCustomContext("ipopt_options", g_ipopt_flags.describe());
  benchmark::AddCustomContext("mumps_amalgamation", g_amalgamation ? "on" : "off");
  benchmark::AddCustomContext("blas", bflow_bench::loaded_library("libblas.so"));
  benchmark::AddCustomContext("lapack", bflow_bench::loaded_library("liblapack.so"));
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}

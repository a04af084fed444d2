// The hopping monoped of [F] Section 7.2 (monoped_ocp.h, docs/ocp.md): one whole ocp_solve,
// homotopy and polish, with the options of `bflow ocp --example monoped`
// (examples::MonopedTask::options), against the number N of control stages, in the Heaviside
// step formulation (three regions) and in Stewart's (eight base sets): the paper's Figure 10.
//
//   BM_Monoped/<formulation>/<N>   N = 30, 40, ..., 90, both formulations at each N in turn
//
// Each solve runs once. The reported time is the CPU time per IPOPT iteration (manual time); the
// CPU column is the CPU time of the whole homotopy. Counters: IPOPT iterations, the distance of
// q(T) to the target, the clock at the end, the hops, the complementarity residual and
// "solved" (1 or 0); the label is "solved" or the status and its message (a failed solve keeps
// its row: its cost is part of the figure).
//
//   BM_MonopedIteration/<formulation>/<N>   the cost of an IPOPT iteration alone: the first NLP
//       (sigma = sigma_initial) of the same problem, stopped after kIterations iterations; the
//       reported time is its CPU time per iteration (the performance target at N = 60 in the
//       step formulation, and its growth in N). A minute for all 14 rows.
//
//   build-bench/bench/monoped_benchmark   (scripts/bench --monoped stores the JSON and draws
//                                          docs/monoped_cpu.png; scripts/bench
//                                          --monoped-iteration runs the second family only)
#include <benchmark/benchmark.h>

#include <string>

#include <Eigen/Core>

#include "bflow/examples/monoped_ocp.h"
#include "bflow/ocp/ocp.h"

namespace {

using bflow::OcpResult;
using bflow::examples::MonopedTask;

template <bflow::TimeFreezingRegions kRegions>
void BM_Monoped(benchmark::State& state, bflow::DcsFormulation formulation) {
  const auto model = bflow::adapt_ocp(bflow::examples::monoped_model<kRegions>());
  const MonopedTask task;
  const bflow::OcpProblem problem = task.problem();
  bflow::OcpOptions o = MonopedTask::options(static_cast<int>(state.range(0)));
  o.formulation = formulation;
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
  state.counters["solved"] = r.ok() ? 1.0 : 0.0;
  state.SetLabel(r.ok() ? "solved" : std::string(bflow::to_string(r.status)) + ": " + r.message);
}

constexpr int kIterations = 40;

template <bflow::TimeFreezingRegions kRegions>
void BM_MonopedIteration(benchmark::State& state, bflow::DcsFormulation formulation) {
  const auto model = bflow::adapt_ocp(bflow::examples::monoped_model<kRegions>());
  const MonopedTask task;
  const bflow::OcpProblem problem = task.problem();
  bflow::OcpOptions o = MonopedTask::options(static_cast<int>(state.range(0)));
  o.formulation = formulation;
  o.sigma_final = o.sigma_initial;  // one NLP
  o.max_nlp_iterations = kIterations;
  o.polish = false;
  OcpResult r;
  for (auto _ : state) {
    r = bflow::ocp_solve(model, problem, o);
    if (r.homotopy.empty() || r.homotopy.front().iterations == 0) {
      state.SkipWithError(("no IPOPT iteration: " + r.message).c_str());
      return;
    }
    state.SetIterationTime(r.homotopy.front().cpu_seconds / r.homotopy.front().iterations);
  }
  const bflow::OcpHomotopyStep& nlp = r.homotopy.front();
  state.counters["ipopt_iterations"] = nlp.iterations;
  state.counters["cpu_per_iteration"] = nlp.cpu_seconds / nlp.iterations;
  state.counters["unknowns"] = r.unknowns;
  state.counters["constraints"] = r.constraints;
  state.counters["jacobian_nonzeros"] = r.jacobian_nonzeros;
  state.counters["hessian_nonzeros"] = r.hessian_nonzeros;
}
}  // namespace

// Rows by N, the two formulations next to each other, so that a run stopped early (each row
// takes minutes) still compares them.
int main(int argc, char** argv) {
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
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}

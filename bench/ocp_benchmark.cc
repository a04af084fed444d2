// Optimal control through FESD (ocp.h, docs/ocp.md): one whole ocp_solve, homotopy and polish,
// of the two problems with exact optima (ocp_examples.h) against the number N of control stages
// (N_FE = 3 elements of Radau IIA, n_s = 2, per stage; the default options).
//
//   BM_OcpBrakingBlock/<formulation>/<N>  the braking block (fixed horizon, an optimum that
//                                         slides), step and Stewart formulations
//   BM_OcpTurboCar/step/<N>               the time-optimal turbo car
//
// No benchmark::DoNotOptimize: the solve cannot be optimised away (IPOPT's side effects), and
// Google Benchmark 1.7.1's DoNotOptimize on a double lvalue made GCC 12 -O3 read that double back
// as 0 afterwards (its "+m,r" asm constraint).
//
// Each solve runs once (a solve takes from about 1 s to several seconds). The reported time is the
// CPU time per IPOPT iteration (manual time), so that the BigO line of each family is the linear
// fit of the cost of an iteration in N; the CPU column is the CPU time of the whole solve, and
// its BigO coefficient the fit of a solve. A solve whose status is not "solved" is reported as
// an error with its message.
//
// From IPOPT's own log over the whole solve (bench/ipopt_flags.h): factorizations_per_iteration,
// seconds_per_factorization, hessian_seconds_per_iteration and rest_seconds_per_iteration.
// IPOPT options for every row: --ipopt-int=name=value, --ipopt-num=..., --ipopt-str=...
// (repeatable); the context records them and the BLAS and LAPACK loaded.
//
//   build-bench/bench/ocp_benchmark     (scripts/bench --ocp stores the JSON)
#include <benchmark/benchmark.h>

#include <cmath>
#include <string>

#include "bflow/examples/ocp_examples.h"
#include "bflow/ocp/ocp.h"
#include "ipopt_flags.h"

namespace {

bflow_bench::IpoptFlags g_ipopt_flags;  // from the command line, for every row

using bflow::OcpOptions;
using bflow::OcpResult;

// N = 10, 20, 40, 80 (up to `largest`), one solve each, timed per IPOPT iteration.
void stages_up_to(benchmark::internal::Benchmark* b, int largest) {
  for (int n = 10; n <= largest; n *= 2) b->Arg(n);
  b->Iterations(1)
      ->UseManualTime()
      ->MeasureProcessCPUTime()
      ->Complexity(benchmark::oN)
      ->Unit(benchmark::kMillisecond);
}
void up_to_80(benchmark::internal::Benchmark* b) { stages_up_to(b, 80); }
void up_to_40(benchmark::internal::Benchmark* b) { stages_up_to(b, 40); }

// The counters every solve reports; false if the solve failed (the state is then skipped).
bool report(benchmark::State& state, const OcpResult& r) {
  if (!r.ok()) {
    state.SkipWithError((std::string(bflow::to_string(r.status)) + ": " + r.message).c_str());
    return false;
  }
  state.counters["ipopt_iterations"] = r.ipopt_iterations;
  state.counters["cpu_per_iteration"] = r.cpu_per_iteration;
  state.counters["objective"] = r.objective;
  state.counters["unknowns"] = r.unknowns;
  state.counters["jacobian_nonzeros"] = r.jacobian_nonzeros;
  state.counters["hessian_nonzeros"] = r.hessian_nonzeros;
  state.counters["polished"] = r.polished ? 1.0 : 0.0;
  return true;
}

// Solves the example with N = state.range(0); the manual time is the CPU per IPOPT iteration.
template <typename Example>
OcpResult solve(benchmark::State& state, bflow::DcsFormulation formulation) {
  const auto model = bflow::adapt_ocp(Example{});
  const bflow::OcpProblem problem = Example::problem();
  OcpOptions o;
  o.stages = static_cast<int>(state.range(0));
  o.formulation = formulation;
  const bflow_bench::IpoptLog log;
  log.apply_to(o);
  g_ipopt_flags.apply_to(o);
  OcpResult r;
  for (auto _ : state) {
    r = bflow::ocp_solve(model, problem, o);
    state.SetIterationTime(r.cpu_per_iteration);
  }
  state.SetComplexityN(state.range(0));
  const bflow_bench::IpoptCounts c = log.read();
  double nlp_cpu = 0.0;
  for (const bflow::OcpHomotopyStep& s : r.homotopy) nlp_cpu += s.cpu_seconds;
  bflow_bench::split_counters(state, c, r.ipopt_iterations, nlp_cpu);
  state.counters["cpu_total"] = r.cpu_seconds;
  state.counters["nlps"] = static_cast<double>(r.homotopy.size());
  return r;
}

void BM_OcpBrakingBlock(benchmark::State& state, bflow::DcsFormulation formulation) {
  const OcpResult r = solve<bflow::examples::BrakingBlock>(state, formulation);
  if (!report(state, r)) return;
  state.counters["objective_error"] =
      std::abs(r.objective - bflow::examples::BrakingBlock::optimal_cost());
  // The stop time: the first element boundary from which the block sticks (sliding, side 0).
  double stop = r.T;
  for (std::size_t e = r.active_sets.size(); e-- > 0;) {
    if (r.active_sets[e][0] != 0) break;
    stop = r.grid[e];
  }
  state.counters["stop_time_error"] = std::abs(stop - bflow::examples::BrakingBlock::stop_time());
}
BENCHMARK_CAPTURE(BM_OcpBrakingBlock, step, bflow::DcsFormulation::kStep)->Apply(up_to_80);
BENCHMARK_CAPTURE(BM_OcpBrakingBlock, stewart, bflow::DcsFormulation::kStewart)->Apply(up_to_80);

void BM_OcpTurboCar(benchmark::State& state, bflow::DcsFormulation formulation) {
  const OcpResult r = solve<bflow::examples::TurboCar>(state, formulation);
  if (!report(state, r)) return;
  state.counters["T"] = r.T;
  state.counters["T_error"] = std::abs(r.T - bflow::examples::TurboCar::kOptimalTime);
}
BENCHMARK_CAPTURE(BM_OcpTurboCar, step, bflow::DcsFormulation::kStep)->Apply(up_to_40);

}  // namespace

int main(int argc, char** argv) {
  g_ipopt_flags = bflow_bench::take_ipopt_flags(argc, argv);
  benchmark::AddCustomContext("ipopt_options", g_ipopt_flags.describe());
  benchmark::AddCustomContext("blas", bflow_bench::loaded_library("libblas.so"));
  benchmark::AddCustomContext("lapack", bflow_bench::loaded_library("liblapack.so"));
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}

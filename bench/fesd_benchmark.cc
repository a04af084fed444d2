// FESD cost ([F] Section 7.1): one integration step of IRMA (Radau IIA, n_s = 2, N_FE = 3) as a
// homotopy of IPOPT solves, with the IPOPT iterations it took, and the same for the scalar
// crossing case. The step is the one from x0 (no switch) and the one across IRMA's first switch
// (c_5 at t = 25.54, from the exact state at t = 25).
//
//   build-accuracy/bench/fesd_benchmark --benchmark_repetitions=5
#include <benchmark/benchmark.h>

#include "bflow/examples/irma.h"
#include "bflow/examples/switching_cases.h"
#include "bflow/integrators/fesd.h"

namespace {

using bflow::FesdOptions;
using bflow::FesdResult;

void report(benchmark::State& state, const FesdResult& r) {
  if (!r.ok()) {
    state.SkipWithError(r.message.c_str());
    return;
  }
  state.counters["ipopt_iterations"] = r.nlp_iterations.empty() ? 0 : r.nlp_iterations[0];
  state.counters["switches"] = static_cast<double>(r.switch_times.size());
}

void BM_FesdIrmaStep(benchmark::State& state) {
  const bflow::examples::Irma irma;
  const auto model = bflow::adapt_step(irma);
  const bool across_switch = state.range(0) == 1;
  const Eigen::VectorXd x0 =
      across_switch
          ? Eigen::VectorXd(
                bflow::examples::exact_irma(irma, bflow::examples::Irma::initial_state(), 25.0).x)
          : Eigen::VectorXd(bflow::examples::Irma::initial_state());
  FesdOptions o;
  o.stages = 2;
  o.elements = 3;
  o.steps = 1;
  o.sensitivities = false;
  FesdResult r;
  for (auto _ : state) {
    r = bflow::fesd_simulate(model, x0, 5.0, o);
    benchmark::DoNotOptimize(r.x_end.data());
  }
  report(state, r);
}
BENCHMARK(BM_FesdIrmaStep)
    ->Arg(0)
    ->Arg(1)
    ->ArgNames({"across_switch"})
    ->Unit(benchmark::kMillisecond);

void BM_FesdCrossingStep(benchmark::State& state) {
  const auto model = bflow::adapt_step(bflow::examples::CrossingCase{});
  FesdOptions o;
  o.steps = 1;
  o.sensitivities = false;
  FesdResult r;
  for (auto _ : state) {
    r = bflow::fesd_simulate(model, Eigen::VectorXd::Constant(1, -0.1), 0.25, o);
    benchmark::DoNotOptimize(r.x_end.data());
  }
  report(state, r);
}
BENCHMARK(BM_FesdCrossingStep)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();

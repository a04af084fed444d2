// FESD cost ([F] Section 7.1): one integration step of IRMA (Radau IIA, n_s = 2, N_FE = 3), the
// one from x0 (no switch) and the one across IRMA's first switch (c_6 at t = 25.54, from the
// exact state at t = 25), solved as the engine does (Newton's method on guessed active sets) and
// as a homotopy of IPOPT solves only (newton = false), with the IPOPT iterations it took; the
// whole first 100 minutes (N_sim = 20); and the scalar crossing case.
//
//   build-accuracy/bench/fesd_benchmark --benchmark_repetitions=5
#include <benchmark/benchmark.h>

#include "bflow/examples/irma.h"
#include "bflow/examples/switching_cases.h"
#include "bflow/fesd/fesd.h"

namespace {

using bflow::FesdOptions;
using bflow::FesdResult;

void report(benchmark::State& state, const FesdResult& r) {
  if (!r.ok()) {
    state.SkipWithError(r.message.c_str());
    return;
  }
  int iterations = 0;
  for (int k : r.nlp_iterations) iterations += k;
  state.counters["ipopt_iterations"] = iterations;
  state.counters["newton_steps"] = r.newton_steps;
  state.counters["switches"] = static_cast<double>(r.switch_times.size());
}

void BM_FesdIrmaStep(benchmark::State& state) {
  const bflow::examples::Irma irma;
  const auto model = bflow::adapt_step(irma);
  const bool across_switch = state.range(0) == 1;
  const bool homotopy_only = state.range(1) == 1;
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
  o.newton = !homotopy_only;
  FesdResult r;
  for (auto _ : state) {
    r = bflow::fesd_simulate(model, x0, 5.0, o);
    benchmark::DoNotOptimize(r.x_end.data());
  }
  report(state, r);
}
BENCHMARK(BM_FesdIrmaStep)
    ->Args({0, 0})
    ->Args({1, 0})
    ->Args({0, 1})
    ->Args({1, 1})
    ->ArgNames({"across_switch", "homotopy_only"})
    ->Unit(benchmark::kMillisecond);

// IRMA over its first 100 minutes, N_sim = 20 (two switches), with dx(T)/dx0.
void BM_FesdIrma100(benchmark::State& state) {
  const bflow::examples::Irma irma;
  const auto model = bflow::adapt_step(irma);
  FesdOptions o;
  o.steps = 20;
  FesdResult r;
  for (auto _ : state) {
    r = bflow::fesd_simulate(model, bflow::examples::Irma::initial_state(), 100.0, o);
    benchmark::DoNotOptimize(r.x_end.data());
  }
  report(state, r);
}
BENCHMARK(BM_FesdIrma100)->Unit(benchmark::kMillisecond);

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

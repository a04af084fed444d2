// Throughput of a sweep (bflow/sweep/parallel.h, sweep.h): samples per second with 1 and 2
// worker threads, each sample a whole flow_derivative with its images written as a JSON line.
//
//   BM_Sweep/biped/<threads>     the biped of [B] Section 3.2.4 (mode-damping) from its double
//                                touchdown start, theta0 over [-0.05, 0.05] (400 samples,
//                                t = 0.6, dx = e_theta): two feet touching in either order
//   BM_Sweep/pwconst/<threads>   the piecewise-constant field, d = 4, x0[0] over [-1, -0.1]
//                                (4000 samples, t = 1, dx = e_0): cheap samples, where the
//                                pool's own cost shows
//
//   BM_SweepCommand/threads/2    (built with BFLOW_MPI) the command over 200000 biped samples,
//   BM_SweepCommand/mpi/2        2 threads in one process against mpirun -np 2 of 1 thread each
//
// The time is wall-clock (UseRealTime); items_per_second is samples per second. The parallel
// efficiency is rate(2 threads) / (2 rate(1 thread)), and MPI's rate(2 ranks) / rate(2 threads);
// scripts/bench --sweep prints both.
#include <benchmark/benchmark.h>

#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <ostream>
#include <sstream>
#include <streambuf>
#include <string>
#include <utility>

#include <Eigen/Core>

#include "bflow/core/biped.h"
#include "bflow/examples/piecewise_constant.h"
#include "bflow/integrators/model_adapter.h"
#include "bflow/sweep/parallel.h"
#include "bflow/sweep/sweep.h"

namespace {

// Counts the bytes written and drops them: the records are formatted as for a file.
class CountingBuffer : public std::streambuf {
 public:
  std::uint64_t bytes = 0;

 protected:
  std::streamsize xsputn(const char*, std::streamsize n) override {
    bytes += static_cast<std::uint64_t>(n);
    return n;
  }
  int overflow(int c) override {
    ++bytes;
    return c;
  }
};

void run_sweep(benchmark::State& state, const bflow::SegmentModel& model, const Eigen::VectorXd& x0,
               const bflow::SweepGrid& grid, const bflow::FlowSweepRequest& request) {
  bflow::SweepRunOptions o;
  o.threads = static_cast<int>(state.range(0));
  std::uint64_t ok = 0, bytes = 0;
  for (auto _ : state) {
    CountingBuffer buffer;
    std::ostream out(&buffer);
    bflow::SweepWriter writer(out, bflow::SweepFormat::kJsonLines, grid, model.states(),
                              static_cast<int>(request.directions.size()));
    ok = 0;
    // As `bflow sweep` does: each worker formats its records, the writing thread copies lines.
    bflow::run_ordered<std::pair<bool, std::string>>(
        0, grid.samples(),
        [&](std::uint64_t i) {
          Eigen::VectorXd start = x0;
          grid.apply_states(i, start);
          const bflow::FlowSampleRecord r =
              bflow::evaluate_flow_sample(model, start, request, i, grid.values(i));
          return std::make_pair(r.ok(), writer.line(r));
        },
        [&](std::uint64_t i, const std::string& what) {
          return std::make_pair(
              false, writer.line(bflow::FlowSampleRecord::error(i, grid.values(i), what)));
        },
        [&](std::pair<bool, std::string>&& r) {
          ok += r.first ? 1 : 0;
          out << r.second;
        },
        o);
    bytes = buffer.bytes;
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * grid.samples()));
  state.counters["samples"] = static_cast<double>(grid.samples());
  state.counters["ok"] = static_cast<double>(ok);
  state.counters["bytes"] = static_cast<double>(bytes);
}

void BM_SweepBiped(benchmark::State& state) {
  const bflow::BipedParams params;
  bflow::visit_biped(params, [&](const auto& scene) {
    const auto model = bflow::adapt(scene);
    const Eigen::VectorXd x0 = bflow::biped_initial_state();
    const bflow::SweepGrid grid({bflow::SweepAxis::state_axis(2, -0.05, 0.05, 400)});
    bflow::FlowSweepRequest request;
    request.t = 0.6;
    request.directions = {Eigen::VectorXd::Unit(6, 2)};
    run_sweep(state, model, x0, grid, request);
  });
}

void BM_SweepPwconst(benchmark::State& state) {
  const bflow::examples::PiecewiseConstantField field =
      bflow::examples::PiecewiseConstantField::linear(4, 0.25);
  const auto model = bflow::adapt(field);
  const Eigen::VectorXd x0 = -0.5 * field.limits().col(0);
  const bflow::SweepGrid grid({bflow::SweepAxis::state_axis(0, -1.0, -0.1, 4000)});
  bflow::FlowSweepRequest request;
  request.t = 1.0;
  request.directions = {Eigen::VectorXd::Unit(4, 0)};
  run_sweep(state, model, x0, grid, request);
}

#ifdef BFLOW_SWEEP_MPIRUN
// The command itself, `bflow sweep` over 200000 biped samples to /dev/null: with 2 threads in one
// process, and with 2 MPI ranks of 1 thread each (mpirun --oversubscribe -np 2). Wall-clock time
// of the whole command, start-up included; items_per_second is samples per second.
constexpr int kCommandSamples = 200000;

void BM_SweepCommand(benchmark::State& state, bool mpi) {
  const std::string sweep =
      std::string(BFLOW_SWEEP_COMMAND) +
      " sweep --scene biped --vary 2=-0.05:0.05:" + std::to_string(kCommandSamples) +
      " --dx 0,0,1,0,0,0 --quiet --output /dev/null";
  const std::string command =
      mpi ? "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 "
            "OMPI_MCA_btl_vader_single_copy_mechanism=none " BFLOW_SWEEP_MPIRUN
            " --oversubscribe -np 2 " +
                sweep + " --threads 1 2>/dev/null"
          : sweep + " --threads 2 2>/dev/null";
  for (auto _ : state) {
    const auto start = std::chrono::steady_clock::now();
    const int code = std::system(command.c_str());
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (code != 0) {
      state.SkipWithError(("the command failed: " + command).c_str());
      return;
    }
    state.SetIterationTime(seconds);
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()) * kCommandSamples);
}
BENCHMARK_CAPTURE(BM_SweepCommand, threads2, false)
    ->Name("BM_SweepCommand/threads/2")
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_SweepCommand, mpi2, true)
    ->Name("BM_SweepCommand/mpi/2")
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond);
#endif

// find_resume_point over a whole output of 4000 biped samples (what `bflow sweep --resume`
// reads before it goes on): bytes per second, each line checked as a record of the sweep.
void BM_FindResumePoint(benchmark::State& state) {
  const auto format =
      state.range(0) == 0 ? bflow::SweepFormat::kJsonLines : bflow::SweepFormat::kCsv;
  const bflow::BipedParams params;
  std::string text;
  const bflow::SweepGrid grid({bflow::SweepAxis::state_axis(2, -0.05, 0.05, 4000)});
  std::ostringstream out;
  bflow::SweepWriter writer(out, format, grid, 6, 1, R"({"scene":"biped"})");
  bflow::visit_biped(params, [&](const auto& scene) {
    const auto model = bflow::adapt(scene);
    bflow::FlowSweepRequest request;
    request.t = 0.6;
    request.directions = {Eigen::VectorXd::Unit(6, 2)};
    writer.header();
    for (std::uint64_t i = 0; i < grid.samples(); ++i) {
      Eigen::VectorXd start = bflow::biped_initial_state();
      grid.apply_states(i, start);
      writer.write(bflow::evaluate_flow_sample(model, start, request, i, grid.values(i)));
    }
  });
  text = out.str();
  std::uint64_t kept = 0;
  for (auto _ : state) {
    std::istringstream in(text);
    kept = bflow::find_resume_point(in, writer).records;
    benchmark::DoNotOptimize(kept);
  }
  if (kept != grid.samples()) state.SkipWithError("not every record was kept");
  state.SetBytesProcessed(static_cast<std::int64_t>(state.iterations() * text.size()));
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * grid.samples()));
}

}  // namespace

BENCHMARK(BM_FindResumePoint)
    ->Name("BM_FindResumePoint/jsonl")
    ->Arg(0)
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FindResumePoint)
    ->Name("BM_FindResumePoint/csv")
    ->Arg(1)
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SweepBiped)
    ->Name("BM_Sweep/biped")
    ->Arg(1)
    ->Arg(2)
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SweepPwconst)
    ->Name("BM_Sweep/pwconst")
    ->Arg(1)
    ->Arg(2)
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();

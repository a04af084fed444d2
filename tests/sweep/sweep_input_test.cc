// Sweep input checked where it enters: the grid refuses a coordinate on two axes, and the pool
// starts no more workers than samples, turns a thread the system cannot start into an
// InvalidArgument after joining the workers that started, and stops when its cancellation hook
// says so.
#include <sys/resource.h>

#include <atomic>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/core/errors.h"
#include "bflow/sweep/parallel.h"
#include "bflow/sweep/sweep.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;

TEST(SweepGridInput, TheSameCoordinateOnTwoAxesIsRefused) {
  EXPECT_THAT(testing::message_of([] {
                SweepGrid({SweepAxis::state_axis(1, 0.0, 1.0, 3),
                           SweepAxis::parameter_axis("delta", 0.1, 0.2, 2),
                           SweepAxis::state_axis(1, 2.0, 3.0, 4)});
              }),
              HasSubstr("x[1] is varied by axes 0 and 2"));
  EXPECT_THAT(testing::message_of([] {
                SweepGrid({SweepAxis::parameter_axis("delta", 0.1, 0.2, 2),
                           SweepAxis::parameter_axis("delta", 0.3, 0.4, 2)});
              }),
              HasSubstr("delta is varied by axes 0 and 1"));
  // A state and a parameter of the same spelling are different coordinates.
  EXPECT_EQ(SweepGrid({SweepAxis::state_axis(0, 0.0, 1.0, 2),
                       SweepAxis::parameter_axis("x0", 0.0, 1.0, 3)})
                .samples(),
            6u);
}

// The address space limited to what the process uses plus 256 MiB: each thread reserves its
// stack (8 MiB by default), so 600 threads cannot all start.
void limit_address_space() {
  long pages = 0;
  if (FILE* f = std::fopen("/proc/self/statm", "r")) {
    if (std::fscanf(f, "%ld", &pages) != 1) pages = 0;
    std::fclose(f);
  }
  const rlim_t limit = static_cast<rlim_t>(pages) * 4096 + (rlim_t{256} << 20);
  const rlimit r{limit, limit};
  setrlimit(RLIMIT_AS, &r);
}

int run_with_threads(int threads, std::uint64_t samples) {
  SweepRunOptions options;
  options.threads = threads;
  std::uint64_t sum = 0, count = 0;
  try {
    run_ordered<std::uint64_t>(
        0, samples, [](std::uint64_t i) { return i; },
        [](std::uint64_t, const std::string&) { return std::uint64_t{0}; },
        [&](std::uint64_t&& v) {
          sum += v;
          ++count;
        },
        options);
  } catch (const InvalidArgument& e) {
    const std::string what = e.what();
    return what.find("could not start worker thread") != std::string::npos ? 2 : 3;
  }
  return count == samples && sum == samples * (samples - 1) / 2 ? 0 : 1;
}

// The child of a "threadsafe" death test runs this program again from its start. OpenBLAS (in
// the process through IPOPT) starts a worker thread per core when it loads, and a worker
// allocates its buffers when it first runs, which on a loaded machine can come after the child
// has limited its address space: ASan then aborts the child in that allocation. With one BLAS
// thread OpenBLAS starts no worker.
void one_blas_thread_in_children() { setenv("OPENBLAS_NUM_THREADS", "1", 1); }

TEST(SweepPoolDeathTest, AThreadThatCannotStartIsAnErrorNotAnAbort) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  one_blas_thread_in_children();
  EXPECT_EXIT(
      {
        limit_address_space();
        std::exit(run_with_threads(600, 100000));
      },
      ::testing::ExitedWithCode(2), "");
}

TEST(SweepPoolDeathTest, NoMoreWorkersThanSamples) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  one_blas_thread_in_children();
  // Three samples need three workers, which fit; the 597 others are not started.
  EXPECT_EXIT(
      {
        limit_address_space();
        std::exit(run_with_threads(600, 3));
      },
      ::testing::ExitedWithCode(0), "");
}

// A hook that cancels once the sink has taken k records: the run says it was cancelled, the
// sink saw exactly 0 .. k - 1, and the workers stopped (samples evaluated <= k + the records
// that may wait for the sink + one in hand per worker, far below the 10^6 of the grid).
TEST(SweepPoolCancel, AHookThatCancelsAfterKSamplesStopsTheRun) {
  for (const int threads : {1, 2, 4}) {
    constexpr std::uint64_t kSamples = 1000000, kStopAfter = 37;
    SweepRunOptions options;
    options.threads = threads;
    options.window = 8;
    options.cancel_interval = 0.0;  // polled before every record
    std::vector<std::uint64_t> seen;
    std::atomic<std::uint64_t> evaluated{0};
    options.cancelled = [&] { return seen.size() >= kStopAfter; };
    const SweepRunResult r = run_ordered<std::uint64_t>(
        0, kSamples,
        [&](std::uint64_t i) {
          ++evaluated;
          return i;
        },
        [](std::uint64_t, const std::string&) { return std::uint64_t{0}; },
        [&](std::uint64_t&& v) { seen.push_back(v); }, options);
    EXPECT_TRUE(r.cancelled) << threads;
    EXPECT_EQ(r.done, kStopAfter) << threads;
    EXPECT_EQ(r.threads, threads);
    ASSERT_EQ(seen.size(), kStopAfter);
    for (std::uint64_t k = 0; k < kStopAfter; ++k) EXPECT_EQ(seen[k], k);
    EXPECT_LE(evaluated.load(), kStopAfter + options.window + static_cast<std::uint64_t>(threads));
  }
}

// Without a hook, or with one that never fires, the run is whole and says so; the thread count
// it reports is capped by the samples.
TEST(SweepPoolCancel, AnUncancelledRunReportsEverySampleAndItsThreads) {
  SweepRunOptions options;
  options.threads = 16;
  options.cancelled = [] { return false; };
  std::uint64_t sum = 0;
  const SweepRunResult r = run_ordered<std::uint64_t>(
      0, 5, [](std::uint64_t i) { return i; },
      [](std::uint64_t, const std::string&) { return std::uint64_t{0}; },
      [&](std::uint64_t&& v) { sum += v; }, options);
  EXPECT_FALSE(r.cancelled);
  EXPECT_EQ(r.done, 5u);
  EXPECT_EQ(r.threads, 5);
  EXPECT_EQ(sum, 10u);
}

}  // namespace
}  // namespace bflow

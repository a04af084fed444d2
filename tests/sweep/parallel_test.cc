#include "bflow/sweep/parallel.h"

#include <atomic>
#include <chrono>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "bflow/core/errors.h"

namespace bflow {
namespace {

struct Item {
  std::uint64_t index = 0;
  double value = 0.0;
  std::string error;
};

// A value that depends on the index alone, with uneven work: every 7th sample sleeps, so that
// with several threads later indices finish before earlier ones.
Item slow_square(std::uint64_t i) {
  if (i % 7 == 3) std::this_thread::sleep_for(std::chrono::milliseconds(2));
  return {i, static_cast<double>(i) * static_cast<double>(i), ""};
}

Item failed(std::uint64_t i, const std::string& what) { return {i, -1.0, what}; }

std::vector<Item> run(std::uint64_t first, std::uint64_t end, int threads,
                      std::uint64_t window = 0) {
  std::vector<Item> out;
  SweepRunOptions o;
  o.threads = threads;
  o.window = window;
  run_ordered<Item>(
      first, end, slow_square, failed, [&](Item&& r) { out.push_back(r); }, o);
  return out;
}

TEST(RunOrdered, TheSinkSeesEveryIndexOnceInOrderWhateverTheThreads) {
  for (int threads : {1, 2, 3, 8}) {
    const std::vector<Item> out = run(5, 205, threads);
    ASSERT_EQ(out.size(), 200u) << threads << " threads";
    for (std::size_t k = 0; k < out.size(); ++k) {
      EXPECT_EQ(out[k].index, 5 + k) << threads << " threads";
      EXPECT_EQ(out[k].value, static_cast<double>((5 + k) * (5 + k)));
    }
  }
}

TEST(RunOrdered, AnEmptyRangeCallsNothing) { EXPECT_TRUE(run(4, 4, 2).empty()); }

TEST(RunOrdered, AFailingSampleBecomesItsRecordAndTheRunGoesOn) {
  std::vector<Item> out;
  SweepRunOptions o;
  o.threads = 3;
  run_ordered<Item>(
      0, 50,
      [](std::uint64_t i) -> Item {
        if (i == 17) throw std::runtime_error("sample 17 is bad");
        return slow_square(i);
      },
      failed, [&](Item&& r) { out.push_back(r); }, o);
  ASSERT_EQ(out.size(), 50u);
  EXPECT_EQ(out[17].error, "sample 17 is bad");
  EXPECT_EQ(out[17].value, -1.0);
  EXPECT_EQ(out[18].value, 18.0 * 18.0);
  EXPECT_EQ(out[49].value, 49.0 * 49.0);
}

TEST(RunOrdered, NoWorkerRunsMoreThanTheWindowAheadOfTheSink) {
  // A sink that is slow for the first record: the workers must wait instead of computing
  // everything; the evaluations started before the sink took record 0 are at most the window.
  std::atomic<std::uint64_t> written{0};
  std::atomic<std::uint64_t> furthest_ahead{0};
  SweepRunOptions o;
  o.threads = 2;
  o.window = 4;
  std::uint64_t count = 0;
  run_ordered<Item>(
      0, 100,
      [&](std::uint64_t i) {
        const std::uint64_t ahead = i - written.load();
        std::uint64_t seen = furthest_ahead.load();
        while (ahead > seen && !furthest_ahead.compare_exchange_weak(seen, ahead)) {
        }
        return Item{i, 0.0, ""};
      },
      failed,
      [&](Item&& r) {
        if (r.index == 0) std::this_thread::sleep_for(std::chrono::milliseconds(20));
        ++count;
        written.store(r.index + 1);
      },
      o);
  EXPECT_EQ(count, 100u);
  // index < written + window when the worker passed the gate; `written` read later can only be
  // larger, so ahead <= window - 1.
  EXPECT_LE(furthest_ahead.load(), 3u);
}

TEST(RunOrdered, ASinkExceptionStopsTheRunAndReachesTheCaller) {
  std::uint64_t seen = 0;
  SweepRunOptions o;
  o.threads = 2;
  EXPECT_THROW(run_ordered<Item>(
                   0, 1000, slow_square, failed,
                   [&](Item&& r) {
                     if (r.index == 10) throw std::runtime_error("disk full");
                     ++seen;
                   },
                   o),
               std::runtime_error);
  EXPECT_EQ(seen, 10u);
}

TEST(RunOrdered, AnOnErrorExceptionReachesTheCaller) {
  SweepRunOptions o;
  o.threads = 2;
  EXPECT_THROW(run_ordered<Item>(
                   0, 100,
                   [](std::uint64_t i) -> Item {
                     if (i == 5) throw std::runtime_error("bad sample");
                     return Item{i, 0.0, ""};
                   },
                   [](std::uint64_t, const std::string&) -> Item {
                     throw std::logic_error("cannot record");
                   },
                   [](Item&&) {}, o),
               std::logic_error);
}

TEST(RunOrdered, ProgressEndsWithEverySampleDone) {
  std::vector<SweepProgress> reports;
  SweepRunOptions o;
  o.threads = 2;
  o.progress_interval = 0.0;  // every record
  o.progress = [&](const SweepProgress& p) { reports.push_back(p); };
  run_ordered<Item>(
      0, 30, slow_square, failed, [](Item&&) {}, o);
  ASSERT_EQ(reports.size(), 30u);
  for (std::size_t k = 0; k < reports.size(); ++k) {
    EXPECT_EQ(reports[k].done, k + 1);
    EXPECT_EQ(reports[k].total, 30u);
  }
  EXPECT_EQ(reports.back().seconds_left(), 0.0);
  EXPECT_GT(reports.back().rate(), 0.0);
}

TEST(RunOrdered, BadArgumentsAreRefusedWithTheirValues) {
  SweepRunOptions o;
  o.threads = -2;
  try {
    run_ordered<Item>(
        0, 3, slow_square, failed, [](Item&&) {}, o);
    FAIL() << "threads = -2 was accepted";
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("got -2"), std::string::npos) << e.what();
  }
  try {
    run_ordered<Item>(9, 3, slow_square, failed, [](Item&&) {});
    FAIL() << "first > end was accepted";
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("9"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace bflow

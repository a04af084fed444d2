// An ordered parallel map: the records of samples first, first + 1, ..., end - 1 computed on a
// pool of threads and handed to a sink in index order, as soon as each is ready.
//
//   bflow::SweepRunOptions o;
//   o.threads = 2;
//   bflow::run_ordered<Record>(
//       0, samples,
//       [&](std::uint64_t i) { return evaluate(i); },          // any thread, any order
//       [&](std::uint64_t i, const std::string& what) {       // evaluate threw
//         return Record::failed(i, what);
//       },
//       [&](Record&& r) { write(out, r); },                   // the calling thread, i in order
//       o);
//
// Guarantees:
// - The sink sees every index of [first, end) exactly once, in increasing order, on the calling
//   thread; what it receives does not depend on the number of threads (evaluate must depend on
//   its index only).
// - Workers take the next index from a shared counter (dynamic scheduling: a slow sample holds
//   up one worker, not a share of the samples fixed in advance).
// - At most `window` records wait for the sink at any time (the memory does not grow with the
//   number of samples): a worker whose index is `window` ahead of the sink waits.
// - An exception from evaluate becomes that sample's record through on_error (its what()); the
//   sweep goes on. An exception from the sink or from on_error stops the workers after the
//   samples they hold and is rethrown, as is a worker's failure to store a record (bad_alloc).
// - At most one worker per sample is started. A worker thread the system cannot start stops
//   the run: the workers that started are joined and InvalidArgument names the thread count.
// - progress (optional) is called on the calling thread after the sink, at most every
//   progress_interval seconds and once after the last sample.
// - cancelled (optional) is polled on the calling thread, at most every cancel_interval
//   seconds, while it waits for a record and before it hands one to the sink. When it returns
//   true the sink takes no more records, the workers stop after the samples they hold (a
//   sample is never cut short) and the run returns with cancelled set: the sink then has seen
//   exactly the indices first .. first + done - 1.
// - The result says how many records the sink took, how many workers ran and whether the run
//   was cancelled.
#ifndef BFLOW_SWEEP_PARALLEL_H_
#define BFLOW_SWEEP_PARALLEL_H_

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

#include "bflow/core/errors.h"

namespace bflow {

/** Where an ordered run stands, for a progress display. */
struct SweepProgress {
  std::uint64_t done = 0;   ///< samples handed to the sink in this run
  std::uint64_t total = 0;  ///< samples of this run (end - first)
  double seconds = 0.0;     ///< wall-clock time since the run started
  /** Samples per second so far (0 before the first). */
  double rate() const { return seconds > 0.0 ? static_cast<double>(done) / seconds : 0.0; }
  /** Estimated seconds left at the rate so far (0 when done, -1 when unknown). */
  double seconds_left() const {
    if (done >= total) return 0.0;
    const double r = rate();
    return r > 0.0 ? static_cast<double>(total - done) / r : -1.0;
  }
};

struct SweepRunOptions {
  /** Worker threads; 0: std::thread::hardware_concurrency() (1 if unknown). */
  int threads = 0;
  /** Records that may wait for the sink; 0: 64 per thread. */
  std::uint64_t window = 0;
  std::function<void(const SweepProgress&)> progress;
  double progress_interval = 0.25;  ///< seconds between progress calls
  /** Polled on the calling thread; true stops the run (see the top of this header). Python's
      binding runs the interpreter's signal handlers here, so Ctrl-C stops a sweep. */
  std::function<bool()> cancelled;
  double cancel_interval = 0.05;  ///< seconds between polls of cancelled (0: before every record)
};

/** What an ordered run did. */
struct SweepRunResult {
  std::uint64_t done = 0;  ///< records the sink took: indices first .. first + done - 1
  int threads = 0;         ///< worker threads started: the threads asked for, capped by samples
  bool cancelled = false;  ///< options.cancelled stopped the run before the last sample
};

/** The number of worker threads `options` asks for (threads, or the hardware's when 0);
    run_ordered starts at most one per sample.
    @throws InvalidArgument for threads < 0. */
inline int sweep_threads(const SweepRunOptions& options) {
  if (options.threads < 0) {
    throw InvalidArgument("sweep: threads must be >= 0 (0: one per core), got " +
                          std::to_string(options.threads));
  }
  if (options.threads > 0) return options.threads;
  const unsigned hardware = std::thread::hardware_concurrency();
  return hardware > 0 ? static_cast<int>(hardware) : 1;
}

/** See the top of this header. @throws InvalidArgument for first > end or threads < 0. */
template <typename Record, typename Evaluate, typename OnError, typename Sink>
SweepRunResult run_ordered(std::uint64_t first, std::uint64_t end, Evaluate evaluate,
                           OnError on_error, Sink sink, const SweepRunOptions& options = {}) {
  if (first > end) {
    throw InvalidArgument("sweep: the first sample " + std::to_string(first) +
                          " is after the end " + std::to_string(end));
  }
  // No more workers than samples: the others would only start and stop.
  const int threads = static_cast<int>(std::min<std::uint64_t>(
      static_cast<std::uint64_t>(sweep_threads(options)), std::max<std::uint64_t>(end - first, 1)));
  const std::uint64_t window =
      options.window > 0 ? options.window : 64 * static_cast<std::uint64_t>(threads);
  using Clock = std::chrono::steady_clock;
  const Clock::time_point start = Clock::now();
  Clock::time_point last_report = start;
  SweepProgress progress;
  progress.total = end - first;

  std::mutex mutex;
  std::condition_variable ready;            // the record the sink waits for arrived
  std::condition_variable room;             // the sink moved on (workers ahead of it wait on it)
  std::map<std::uint64_t, Record> waiting;  // guarded by mutex
  std::atomic<std::uint64_t> next{first};
  // The next index the sink takes; written under mutex, read without it by workers that are
  // within the window (the common case takes no lock before evaluating).
  std::atomic<std::uint64_t> written{first};
  bool stop = false;                  // the sink or on_error failed (guarded by mutex)
  std::exception_ptr worker_failure;  // on_error's exception (guarded by mutex)

  const auto work = [&]() {
    while (true) {
      const std::uint64_t index = next.fetch_add(1);
      if (index >= end) return;
      if (index >= written.load() + window) {
        std::unique_lock<std::mutex> lock(mutex);
        room.wait(lock, [&] { return stop || index < written.load() + window; });
        if (stop) return;
      }
      Record record;
      try {
        try {
          record = evaluate(index);
        } catch (const std::exception& e) {
          record = on_error(index, std::string(e.what()));
        } catch (...) {
          record = on_error(index, std::string("unknown exception"));
        }
      } catch (...) {  // from on_error: the run stops and the caller gets it
        {
          std::lock_guard<std::mutex> lock(mutex);
          if (!worker_failure) worker_failure = std::current_exception();
          stop = true;
        }
        ready.notify_all();
        room.notify_all();
        return;
      }
      bool wanted = false;
      {
        std::lock_guard<std::mutex> lock(mutex);
        if (stop) return;
        try {
          waiting.emplace(index, std::move(record));
        } catch (...) {  // bad_alloc: the caller gets it, never std::terminate in a worker
          if (!worker_failure) worker_failure = std::current_exception();
          stop = true;
        }
        wanted = stop || index == written.load();
      }
      // Only the record the sink waits for wakes it; it then takes every consecutive one.
      if (wanted) ready.notify_one();
      if (wanted && stop) {
        room.notify_all();
        return;
      }
    }
  };

  std::vector<std::thread> pool;
  pool.reserve(static_cast<std::size_t>(threads));
  std::exception_ptr failure;
  std::vector<Record> batch;
  SweepRunResult result;
  result.threads = threads;
  // The wait between polls of cancelled; never 0, which would spin.
  const auto poll_wait = std::chrono::duration<double>(std::max(options.cancel_interval, 1e-3));
  Clock::time_point last_poll = start;
  const auto poll = [&](Clock::time_point now) {
    if (!options.cancelled ||
        std::chrono::duration<double>(now - last_poll).count() < options.cancel_interval) {
      return false;
    }
    last_poll = now;
    return options.cancelled();
  };
  try {
    // A thread the system cannot start (address space, a process limit) stops the run: the
    // workers that started finish the samples they hold and are joined, then the caller gets an
    // InvalidArgument naming the count (never std::terminate from a joinable thread unwound).
    for (int k = 0; k < threads; ++k) {
      try {
        pool.emplace_back(work);
      } catch (const std::exception& e) {  // system_error, or bad_alloc for the thread's state
        throw InvalidArgument("sweep: could not start worker thread " + std::to_string(k + 1) +
                              " of " + std::to_string(threads) + " (" + e.what() +
                              "); ask for fewer threads");
      }
    }
    while (written.load() < end && !result.cancelled) {
      batch.clear();
      bool arrived = true;
      {
        std::unique_lock<std::mutex> lock(mutex);
        const auto has_next = [&] { return stop || waiting.count(written.load()) > 0; };
        if (options.cancelled) {
          arrived = ready.wait_for(lock, poll_wait, has_next);
        } else {
          ready.wait(lock, has_next);
        }
        if (stop) std::rethrow_exception(worker_failure);
        if (arrived) {
          for (auto it = waiting.find(written.load() + batch.size());
               it != waiting.end() && it->first == written.load() + batch.size();
               it = waiting.erase(it)) {
            batch.push_back(std::move(it->second));
          }
        }
      }
      if (!arrived) {  // the cancelled hook is polled without the lock held
        result.cancelled = poll(Clock::now());
        continue;
      }
      for (Record& record : batch) {
        if (poll(Clock::now())) {
          result.cancelled = true;
          break;
        }
        sink(std::move(record));
        ++progress.done;
        {
          std::lock_guard<std::mutex> lock(mutex);
          written.store(written.load() + 1);
        }
        room.notify_all();
        const Clock::time_point now = Clock::now();
        if (options.progress &&
            (written.load() == end || std::chrono::duration<double>(now - last_report).count() >=
                                          options.progress_interval)) {
          progress.seconds = std::chrono::duration<double>(now - start).count();
          options.progress(progress);
          last_report = now;
        }
      }
    }
  } catch (...) {
    failure = std::current_exception();
  }
  if (failure || result.cancelled) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      stop = true;
    }
    room.notify_all();
    next.store(end);
  }
  for (std::thread& t : pool) t.join();
  if (failure) std::rethrow_exception(failure);
  result.done = progress.done;
  return result;
}

}  // namespace bflow

#endif  // BFLOW_SWEEP_PARALLEL_H_

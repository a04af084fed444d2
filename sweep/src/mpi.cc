#include "bflow/sweep/mpi.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "bflow/core/errors.h"

#ifdef BFLOW_HAVE_MPI
#include <dlfcn.h>
#include <mpi.h>
#endif

namespace bflow {
namespace {

// The number of ranks an MPI launcher started (OpenMPI, MPICH/PMI), 1 without one.
int launched_ranks() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE"}) {
    if (const char* value = std::getenv(name)) {
      const int n = std::atoi(value);
      if (n > 0) return n;
    }
  }
  return 1;
}

#ifdef BFLOW_HAVE_MPI
// Debian's sequential MUMPS (linked through IPOPT) exports MPI stubs of its own under the C names
// MPI_Init, MPI_Comm_rank, MPI_Finalize and MPI_Wtime; in a process that loads it and the real
// MPI, those names may bind to the stubs (MPI_Comm_rank then answers 0 on every rank). The two
// this file needs are taken from the library that defines MPI_Comm_size, which MUMPS does not.
struct RealMpi {
  int (*comm_rank)(MPI_Comm, int*) = nullptr;
  int (*finalize)() = nullptr;
};

const RealMpi& real_mpi() {
  static const RealMpi functions = [] {
    RealMpi f;
    Dl_info info{};
    void* library = nullptr;
    if (dladdr(reinterpret_cast<void*>(&MPI_Comm_size), &info) != 0 && info.dli_fname != nullptr)
      library = dlopen(info.dli_fname, RTLD_NOW | RTLD_NOLOAD);
    if (library != nullptr) {
      f.comm_rank = reinterpret_cast<int (*)(MPI_Comm, int*)>(dlsym(library, "MPI_Comm_rank"));
      f.finalize = reinterpret_cast<int (*)()>(dlsym(library, "MPI_Finalize"));
    }
    if (f.comm_rank == nullptr || f.finalize == nullptr) {
      throw InvalidArgument(std::string("sweep: cannot find MPI_Comm_rank and MPI_Finalize in ") +
                            (info.dli_fname != nullptr ? info.dli_fname : "the MPI library"));
    }
    return f;
  }();
  return functions;
}
#endif

}  // namespace

bool MpiSession::available() {
#ifdef BFLOW_HAVE_MPI
  return true;
#else
  return false;
#endif
}

MpiSession::MpiSession(int* argc, char*** argv) {
  const int launched = launched_ranks();
  if (launched <= 1) return;
#ifdef BFLOW_HAVE_MPI
  int provided = 0;
  MPI_Init_thread(argc, argv, MPI_THREAD_FUNNELED, &provided);
  initialised_ = true;
  real_mpi().comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &size_);
#else
  (void)argc;
  (void)argv;
  throw InvalidArgument("started by an MPI launcher with " + std::to_string(launched) +
                        " ranks, but bflow was built without MPI (configure with -DBFLOW_MPI=ON; "
                        "Debian: libopenmpi-dev); each rank would run the whole sweep");
#endif
}

MpiSession::~MpiSession() {
#ifdef BFLOW_HAVE_MPI
  if (initialised_) real_mpi().finalize();
#endif
}

bool MpiSession::agree(bool go) const {
#ifdef BFLOW_HAVE_MPI
  if (size_ > 1) {
    int word = go ? 1 : 0;
    MPI_Bcast(&word, 1, MPI_INT, 0, MPI_COMM_WORLD);
    return word == 1;
  }
#endif
  return go;
}

#ifdef BFLOW_HAVE_MPI
namespace {

constexpr int kTagResult = 1;  // worker -> 0: [first, count, then count (length, bytes)]
constexpr int kTagAssign = 2;  // 0 -> worker: [first, count]; count 0: stop

void append_u64(std::string& buffer, std::uint64_t v) {
  buffer.append(reinterpret_cast<const char*>(&v), sizeof v);
}
std::uint64_t read_u64(const std::string& buffer, std::size_t& at) {
  std::uint64_t v = 0;
  BFLOW_ASSERT(at + sizeof v <= buffer.size());
  std::memcpy(&v, buffer.data() + at, sizeof v);
  at += sizeof v;
  return v;
}

// The records of [a, b) on this rank's threads, in order.
std::vector<std::string> compute_chunk(std::uint64_t a, std::uint64_t b,
                                       const std::function<std::string(std::uint64_t)>& evaluate,
                                       const SweepRunOptions& options) {
  std::vector<std::string> records;
  records.reserve(static_cast<std::size_t>(b - a));
  SweepRunOptions local;
  local.threads = options.threads;
  run_ordered<std::string>(
      a, b, evaluate,
      [](std::uint64_t i, const std::string& what) -> std::string {
        throw std::runtime_error("sweep: sample " + std::to_string(i) + " threw: " + what);
      },
      [&](std::string&& r) { records.push_back(std::move(r)); }, local);
  return records;
}

void send_bytes(const std::string& bytes, int to, int tag) {
  MPI_Send(bytes.data(), static_cast<int>(bytes.size()), MPI_BYTE, to, tag, MPI_COMM_WORLD);
}

std::string receive_bytes(int from, int tag, int* source) {
  MPI_Status status;
  MPI_Probe(from, tag, MPI_COMM_WORLD, &status);
  int count = 0;
  MPI_Get_count(&status, MPI_BYTE, &count);
  std::string bytes(static_cast<std::size_t>(count), '\0');
  MPI_Recv(bytes.data(), count, MPI_BYTE, status.MPI_SOURCE, tag, MPI_COMM_WORLD,
           MPI_STATUS_IGNORE);
  if (source != nullptr) *source = status.MPI_SOURCE;
  return bytes;
}

}  // namespace
#endif

std::vector<std::uint64_t> run_ordered_mpi(
    const MpiSession& mpi, std::uint64_t first, std::uint64_t end,
    const std::function<std::string(std::uint64_t)>& evaluate,
    const std::function<void(std::string&&)>& sink, const SweepRunOptions& options,
    std::uint64_t chunk) {
  if (first > end) {
    throw InvalidArgument("sweep: the first sample " + std::to_string(first) +
                          " is after the end " + std::to_string(end));
  }
  if (mpi.size() <= 1) {
    run_ordered<std::string>(
        first, end, evaluate,
        [](std::uint64_t i, const std::string& what) -> std::string {
          throw std::runtime_error("sweep: sample " + std::to_string(i) + " threw: " + what);
        },
        sink, options);
    return {end - first};
  }
#ifdef BFLOW_HAVE_MPI
  const std::uint64_t ranks = static_cast<std::uint64_t>(mpi.size());
  if (chunk == 0) chunk = std::clamp<std::uint64_t>((end - first) / (16 * ranks), 1, 4096);

  if (mpi.rank() != 0) {
    std::string message;
    append_u64(message, 0);
    append_u64(message, 0);
    send_bytes(message, 0, kTagResult);  // ready
    while (true) {
      const std::string assign = receive_bytes(0, kTagAssign, nullptr);
      std::size_t at = 0;
      const std::uint64_t a = read_u64(assign, at), count = read_u64(assign, at);
      if (count == 0) return {};
      const std::vector<std::string> records = compute_chunk(a, a + count, evaluate, options);
      message.clear();
      append_u64(message, a);
      append_u64(message, count);
      for (const std::string& r : records) {
        append_u64(message, r.size());
        message += r;
      }
      send_bytes(message, 0, kTagResult);
    }
  }

  // Rank 0: hands out chunks, computes some itself on a thread, and writes in order.
  std::mutex mutex;
  std::uint64_t next = first;  // the next index to hand out (guarded by mutex)
  std::map<std::uint64_t, std::vector<std::string>> done;  // by chunk start (guarded)
  std::vector<std::uint64_t> computed(static_cast<std::size_t>(mpi.size()), 0);  // per rank
  const auto take = [&](std::uint64_t* a, std::uint64_t* count) {
    std::lock_guard<std::mutex> lock(mutex);
    *a = next;
    *count = std::min(chunk, end - next);
    next += *count;
  };
  std::exception_ptr local_failure;
  std::thread local([&] {
    try {
      while (true) {
        std::uint64_t a = 0, count = 0;
        take(&a, &count);
        if (count == 0) return;
        std::vector<std::string> records = compute_chunk(a, a + count, evaluate, options);
        std::lock_guard<std::mutex> lock(mutex);
        done.emplace(a, std::move(records));
        computed[0] += count;
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex);
      local_failure = std::current_exception();
    }
  });
  using Clock = std::chrono::steady_clock;
  const Clock::time_point start = Clock::now();
  Clock::time_point last_report = start;
  SweepProgress progress;
  progress.total = end - first;
  std::uint64_t written = first;
  int running = mpi.size() - 1;  // worker ranks not yet told to stop
  std::exception_ptr failure;
  try {
    while (written < end || running > 0) {
      bool busy = false;
      int flag = 0;
      MPI_Status status;
      MPI_Iprobe(MPI_ANY_SOURCE, kTagResult, MPI_COMM_WORLD, &flag, &status);
      if (flag) {
        busy = true;
        int source = 0;
        const std::string message = receive_bytes(status.MPI_SOURCE, kTagResult, &source);
        std::size_t at = 0;
        const std::uint64_t a = read_u64(message, at), count = read_u64(message, at);
        if (count > 0) {
          std::vector<std::string> records;
          records.reserve(static_cast<std::size_t>(count));
          for (std::uint64_t k = 0; k < count; ++k) {
            const std::uint64_t length = read_u64(message, at);
            records.push_back(message.substr(at, static_cast<std::size_t>(length)));
            at += static_cast<std::size_t>(length);
          }
          std::lock_guard<std::mutex> lock(mutex);
          done.emplace(a, std::move(records));
          computed[static_cast<std::size_t>(source)] += count;
        }
        std::uint64_t b = 0, n = 0;
        take(&b, &n);
        std::string assign;
        append_u64(assign, b);
        append_u64(assign, n);
        send_bytes(assign, source, kTagAssign);
        if (n == 0) --running;
      }
      while (true) {
        std::vector<std::string> records;
        {
          std::lock_guard<std::mutex> lock(mutex);
          if (local_failure) std::rethrow_exception(local_failure);
          auto it = done.find(written);
          if (it == done.end()) break;
          records = std::move(it->second);
          done.erase(it);
        }
        busy = true;
        for (std::string& r : records) {
          sink(std::move(r));
          ++written;
          ++progress.done;
          const Clock::time_point now = Clock::now();
          if (options.progress &&
              (written == end || std::chrono::duration<double>(now - last_report).count() >=
                                     options.progress_interval)) {
            progress.seconds = std::chrono::duration<double>(now - start).count();
            options.progress(progress);
            last_report = now;
          }
        }
      }
      if (!busy) std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
  } catch (...) {
    failure = std::current_exception();
  }
  if (failure) {
    // No more chunks: every worker that asks is told to stop, so that all ranks end normally
    // and the caller can report the failure (a sink that could not write, say).
    {
      std::lock_guard<std::mutex> lock(mutex);
      next = end;
    }
    local.join();
    try {
      while (running > 0) {
        int source = 0;
        receive_bytes(MPI_ANY_SOURCE, kTagResult, &source);
        std::string assign;
        append_u64(assign, end);
        append_u64(assign, 0);
        send_bytes(assign, source, kTagAssign);
        --running;
      }
    } catch (...) {
      MPI_Abort(MPI_COMM_WORLD, 1);
    }
    std::rethrow_exception(failure);
  }
  local.join();
  return computed;
#else
  (void)chunk;
  throw InvalidArgument("sweep: bflow was built without MPI");
#endif
}

}  // namespace bflow

// Sweeps across MPI ranks (`mpirun -np K bflow sweep ...`): rank 0 hands out chunks of sample
// indices on request (dynamic: a slow region of the grid holds up one rank, not a share fixed in
// advance), every rank computes its chunks on its threads (run_ordered), and rank 0 receives the
// records and hands them to its sink in index order, so the output is the single-process one,
// byte for byte.
//
// MPI is optional (CMake option BFLOW_MPI, Debian libopenmpi-dev); MPI itself stays private to
// this component. Built without it, MpiSession reports one rank, and a process started by mpirun
// with several ranks is refused (every rank would write the whole sweep).
//
//   bflow::MpiSession mpi(argc, argv);          // MPI_Init only when started by mpirun
//   if (mpi.size() > 1) bflow::run_ordered_mpi(mpi, first, end, evaluate, sink, options);
#ifndef BFLOW_SWEEP_MPI_H_
#define BFLOW_SWEEP_MPI_H_

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "bflow/sweep/parallel.h"

namespace bflow {

/** The MPI world of this process: initialised (MPI_Init_thread, funneled) when the process was
    started by an MPI launcher with more than one rank and bflow was built with MPI; finalised by
    the destructor. Otherwise one rank, and no MPI call is made.
    @throws InvalidArgument when started with several ranks by a launcher but built without MPI
    (names the CMake option). */
class MpiSession {
 public:
  MpiSession(int* argc, char*** argv);
  ~MpiSession();
  MpiSession(const MpiSession&) = delete;
  MpiSession& operator=(const MpiSession&) = delete;
  int rank() const { return rank_; }
  int size() const { return size_; }
  /** Whether this process called MPI_Init (and the destructor MPI_Finalize). */
  bool initialised() const { return initialised_; }
  /** Rank 0 tells every rank whether to go on (after its own checks, e.g. of a file); returns
      rank 0's word on every rank. One rank: returns `go`. */
  bool agree(bool go) const;
  /** Whether bflow was built with MPI. */
  static bool available();

 private:
  int rank_ = 0, size_ = 1;
  bool initialised_ = false;
};

/** run_ordered across the ranks of `mpi`: every rank evaluates chunks of `chunk` indices
    (0: about 1/16 of a rank's share, at most 4096) on options.threads threads; evaluate returns a
    record as bytes (a worker sends it to rank 0 as is) and must not throw (wrap failures into a
    record). On rank 0 the sink receives the records of [first, end) in index order and
    options.progress is called as by run_ordered; other ranks only compute. Every rank calls it
    with the same end (and rank 0 alone decides `first`: the workers compute what it hands out).
    Returns, on rank 0, the samples each rank computed (rank 0's thread included; one entry for
    a single process) and an empty vector on the other ranks. When the sink (or a worker) throws,
    rank 0 stops handing out chunks, tells every worker to stop, and rethrows: all ranks end
    normally. */
std::vector<std::uint64_t> run_ordered_mpi(
    const MpiSession& mpi, std::uint64_t first, std::uint64_t end,
    const std::function<std::string(std::uint64_t)>& evaluate,
    const std::function<void(std::string&&)>& sink, const SweepRunOptions& options = {},
    std::uint64_t chunk = 0);

}  // namespace bflow

#endif  // BFLOW_SWEEP_MPI_H_

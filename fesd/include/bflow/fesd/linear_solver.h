// The sparse symmetric indefinite solver IPOPT factorises its KKT systems with, as FesdOptions
// and OcpOptions name it (linear_solver, with linear_solver_library for the ones IPOPT loads),
// and the solver stack a build has (cmake/BflowIpopt.cmake; docs/ocp.md, "The solver stack").
//
// With IPOPT 3.14 (the default build): MUMPS 5.8.2 with METIS and SPRAL are linked; HSL's
// solvers come from the user's Coin-HSL library, loaded under its own name (IPOPT's option
// hsllib; bflow looks for libcoinhsl.so, then libhsl.so), pardiso-project's PARDISO from
// libpardiso.so (pardisolib), MKL's PARDISO only where IPOPT was built with MKL. With Debian's
// IPOPT 3.11.9 (the fallback): MUMPS 5.5.1 linked, HSL and PARDISO from the fixed names
// libhsl.so and libpardiso.so. A library that lacks the solver makes IPOPT return
// Invalid_Option (MA27, MA57, HSL_MA77, HSL_MA86) or end the whole process (HSL_MA97), so bflow
// loads the file itself first and refuses a solver it cannot find, with the loader's reason:
//
//   check_linear_solver("ma27", "", "ocp");  // without Coin-HSL on the library path:
//   // LinearSolverUnavailable: ocp: linear solver "ma27" needs HSL's libcoinhsl.so (or
//   // libhsl.so), which cannot be loaded (libcoinhsl.so: cannot open shared object file: ...
//
// docs/ocp.md ("Linear solvers") says how to get and install Coin-HSL.
#ifndef BFLOW_FESD_LINEAR_SOLVER_H_
#define BFLOW_FESD_LINEAR_SOLVER_H_

#include <mutex>
#include <string>

#include "bflow/core/errors.h"
#include "bflow/fesd/solver_options.h"

namespace bflow {

/** The values of linear_solver bflow passes to IPOPT: MUMPS (linked into IPOPT, the default);
    SPRAL (linked into IPOPT 3.14); HSL's MA27, MA57, HSL_MA77, HSL_MA86 and HSL_MA97 (from
    Coin-HSL's library); PARDISO (pardiso-project.org's library); MKL's PARDISO ("pardisomkl",
    where IPOPT was built with MKL). IPOPT's wsmp and custom are left out: no build here has
    WSMP, and a custom solver needs code linked into IPOPT. */
inline constexpr const char* kLinearSolvers[] = {"mumps", "spral", "ma27",    "ma57",      "ma77",
                                                 "ma86",  "ma97",  "pardiso", "pardisomkl"};

/** A known linear solver whose shared library cannot be loaded, or lacks the solver, or that
    this build's IPOPT has not. An InvalidArgument, so that callers who treat every refused
    option alike need nothing new. */
class LinearSolverUnavailable : public InvalidArgument {
 public:
  using InvalidArgument::InvalidArgument;
};

/** "mumps, spral, ma27, ma57, ma77, ma86, ma97, pardiso or pardisomkl". */
std::string linear_solver_list();

/** The files IPOPT loads the solver from when the caller names none, in the order tried:
    "libcoinhsl.so libhsl.so" for ma27 ... ma97 with IPOPT 3.14 ("libhsl.so" with 3.11),
    "libpardiso.so" for pardiso, "" for the solvers linked into IPOPT.
    @throws InvalidArgument "<who>: unknown linear solver "<name>"; use mumps, ..." for a name
    not in kLinearSolvers. */
std::string linear_solver_library(const std::string& name, const std::string& who);

/** Loads `library` as IPOPT would (dlopen, RTLD_NOW, by name through LD_LIBRARY_PATH, the
    ld.so cache and the default directories; a path containing '/' as it stands) and looks for
    the routine IPOPT needs first for the solver (ma27ad, ma57ad, ma77_default_control_d,
    ma86_default_control_d, ma97_default_control_d, pardiso, with or without a trailing
    underscore). "" when both succeed (and always for a solver linked into IPOPT), else why
    not: the loader's dlerror() text, or "<library> has no routine ma97_default_control_d (nor
    ma97_default_control_d_): it was built without HSL_MA97". The library is closed again; IPOPT
    opens it itself.
    @throws InvalidArgument for a name not in kLinearSolvers. */
std::string linear_solver_load_error(const std::string& name, const std::string& library);

/** The library file IPOPT is to load the solver from: "" for a solver linked into this build's
    IPOPT; `library` when given (IPOPT 3.14 only: 3.11 loads fixed names) and it loads with the
    solver's routine; else the first of linear_solver_library(name) that does.
    @throws InvalidArgument for a name not in kLinearSolvers, quoting it and listing them, or a
    library named with IPOPT 3.11 or for a solver that loads none.
    @throws LinearSolverUnavailable for spral or pardisomkl where this IPOPT has not the solver
    ("... this build's IPOPT 3.11.9 has no SPRAL; configure with -DBFLOW_IPOPT=wheel ..."), and
    "<who>: linear solver "ma27" needs HSL's libcoinhsl.so (or libhsl.so), which cannot be
    loaded (<linear_solver_load_error>); get Coin-HSL (https://licences.stfc.ac.uk/product/coin-hsl)
    and put the directory holding its library on LD_LIBRARY_PATH or name the file
    (linear_solver_library; docs/ocp.md, "Linear solvers"), or use mumps" (for pardiso without
    the Coin-HSL part). */
std::string check_linear_solver(const std::string& name, const std::string& library,
                                const std::string& who);
/** check_linear_solver(name, "", who). */
std::string check_linear_solver(const std::string& name, const std::string& who);

/** The solver stack of this build: "IPOPT 3.14.19". */
std::string ipopt_description();
/** The linear solver as a result records it: "mumps 5.8.2 (METIS)", "spral (IPOPT 3.14.19's)",
    "ma57 (libcoinhsl.so)", "pardiso (libpardiso.so)". */
std::string linear_solver_description(const std::string& name, const std::string& library);

/** MUMPS's amalgamation of small fronts (KEEP(197) = 1) for the analyses IPOPT runs on this
    thread while the object lives (`on`), or not (`on` false); the previous setting afterwards.

    An FESD NLP's KKT matrix (n of 100 to a few 1000) has many tiny fronts, and the MUMPS 5.5.1
    of Debian 12 pays per front: on the braking block's KKT matrix (n = 1370) its elimination
    tree has 866 nodes, 191 with the amalgamation, and a factorisation takes 1.16 instead of
    1.97 ms, a solve 0.32 instead of 0.77 ms (bench/results/kkt_mumps.json; later MUMPS releases
    amalgamate by default: MUMPS 5.8.2, the default build's, sets KEEP(197) = 1 itself). IPOPT
    3.11 has no option for it, so a build with a MUMPS before 5.8 (Debian's fallback) defines
    MUMPS's entry point dmumps_c (fesd/src/mumps_fronts.cc), sets KEEP(197) = 1 before each
    analysis (MUMPS 5.5 and later; other versions are left alone) and forwards the call to the
    MUMPS library; a build with MUMPS 5.8 has no such interposer and this object does nothing. The
   factorisation is as exact as without (more fill, fewer and larger fronts); the pivots, and with
   them the round-off, differ. HomotopySolver opens one around every NLP
   (IpoptSettings::mumps_amalgamation). */
class ScopedMumpsAmalgamation {
 public:
  explicit ScopedMumpsAmalgamation(bool on);
  ~ScopedMumpsAmalgamation();
  ScopedMumpsAmalgamation(const ScopedMumpsAmalgamation&) = delete;
  ScopedMumpsAmalgamation& operator=(const ScopedMumpsAmalgamation&) = delete;

 private:
  bool previous_;
};

/** The BLAS that MUMPS's dense kernels call, found once: the library that defines the dgemm_
    the dynamic linker gives this process (else IPOPT's dependencies), and OpenBLAS's thread
    control in that same library (openblas_set_num_threads), where it is OpenBLAS. */
struct BlasInfo {
  std::string file;               ///< the library defining dgemm_ ("" when none is found)
  std::string version;            ///< "OpenBLAS 0.3.28" (openblas_get_config), "" for another BLAS
  bool threads_settable = false;  ///< it is OpenBLAS: ScopedBlasThreads can set its threads
};
const BlasInfo& blas_info();

/** OpenBLAS's threads while the object lives (`threads` >= 1), the previous count afterwards;
    `threads` 0, or a BLAS that is not OpenBLAS, leaves it alone.

    FESD's KKT matrices have fronts of some tens of rows, too small for threads: with the default
    build's OpenBLAS (the casadi wheel's, which starts one thread per core) on 2 threads MUMPS took
    0.92 ms per factorisation of the braking block's KKT matrix (step, N = 10, nosnoc's settings),
    on 1 thread 0.65 ms, and the whole iteration 2.8 against 1.9 ms (docs/ocp.md, "The cost of an
    iteration"). HomotopySolver opens one around every NLP (IpoptSettings::blas_threads, default
    1), under ipopt_mutex(): OpenBLAS's count is the process's, so another thread's BLAS calls
    on the same library during an NLP run on that many threads too. */
class ScopedBlasThreads {
 public:
  explicit ScopedBlasThreads(int threads);
  ~ScopedBlasThreads();
  ScopedBlasThreads(const ScopedBlasThreads&) = delete;
  ScopedBlasThreads& operator=(const ScopedBlasThreads&) = delete;

 private:
  int previous_ = 0;  // 0: nothing to restore
};

/** Lets the process keep the memory the linear solver frees between factorisations (glibc's
    malloc: no mmap for large blocks, M_MMAP_MAX 0, and freed memory handed back to the kernel
    only above 512 MiB at the heap's top, M_TRIM_THRESHOLD), instead of unmapping MUMPS's
    workspace after every factorisation and faulting it in again, page by page, in the next.
    The hopper's whole solve (9501 unknowns, 1393 IPOPT iterations, the same iterates): 23
    thousand minor page faults instead of 11 million, 0.1 instead of 24.9 s of system time,
    183 instead of 241 s of CPU, a largest resident size of 95 instead of 90 MB (docs/ocp.md,
    "The cost of an iteration on IPOPT 3.14.19"). malloc's settings are the process's and
    have no way back, so this is done once, at the first solve of an NLP whose
    SolverOptions::keep_freed_memory is true, and stays; returns whether malloc took it (false
    for a C library other than glibc, and under a sanitizer's allocator). */
bool keep_freed_memory();

/** @throws InvalidArgument "<who>: blas_threads = -1 must be >= 0 (0: OpenBLAS's own count)". */
void check_blas_threads(int threads, const std::string& who);

/** Every field of `solver` (solver_options.h), as fesd_simulate and ocp_solve check them before
    anything runs: the print level (IPOPT's 0..12), exact_hessian_scale (finite, and 1 unless
    `exact_hessian`), blas_threads (check_blas_threads) and the linear solver with its library
    (check_linear_solver).
    @throws InvalidArgument (LinearSolverUnavailable for a solver that cannot be loaded), each
    message starting "<who>: " and naming the field and the value. */
void check_solver_options(const SolverOptions& solver, bool exact_hessian, const std::string& who);

/** OpenBLAS's thread count now (openblas_get_num_threads), 0 for another BLAS. */
int blas_threads();

/** The BLAS as a result records it beside the linear solver: "OpenBLAS 0.3.28, 1 thread
    (libcasadi-tp-openblas.so.0)" for `threads` >= 1, "OpenBLAS 0.3.28, 2 threads (its own
    count) (...)" for 0, "libblas.so.3" for another BLAS, "" when none is found. */
std::string blas_description(int threads);

/** The MUMPS analyses of this process that ran with KEEP(197) = 1 set by bflow (always 0 in a
    build without the interposer, mumps_interposed()). */
long mumps_amalgamated_analyses();
/** Whether this build defines dmumps_c to set KEEP(197) (a MUMPS before 5.8). */
bool mumps_interposed();

/** The process's one lock around IPOPT and MUMPS. MUMPS keeps state in Fortran module variables
    shared by all its instances (its load balancing, DMUMPS_LOAD_INIT, allocates them in every
    factorisation), so two factorisations at once corrupt each other, and IPOPT 3.11 does not
    promise more. bflow holds this lock in IpoptApplicationFactory and Initialize, around every
    OptimizeTNLP (one NLP of a homotopy or one polish: solves of other threads interleave
    between them, each thread's results unchanged), when an IpoptApplication is released, in the
    dmumps_c interposer where the build has one (every MUMPS call, whoever makes it) and in
   check_linear_solver's dlopen. It is recursive: the dmumps_c calls inside an OptimizeTNLP take it
   again on the same thread. A single-threaded run pays one uncontended lock per NLP and per MUMPS
   call. Code that calls IPOPT or MUMPS itself, beside bflow, in a program with several threads
   takes it too. */
std::recursive_mutex& ipopt_mutex();

}  // namespace bflow

#endif  // BFLOW_FESD_LINEAR_SOLVER_H_

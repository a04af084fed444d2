// The sparse symmetric indefinite solver IPOPT factorises its KKT systems with, as FesdOptions
// and OcpOptions name it (linear_solver). Debian's IPOPT 3.11.9 links MUMPS; HSL's solvers and
// PARDISO it loads at run time with dlopen from a fixed file name (3.11 has no option naming
// the file), and a solver missing from that file makes IPOPT return Invalid_Option (MA27, MA57,
// HSL_MA77, HSL_MA86) or end the whole process (HSL_MA97). So bflow loads the file itself
// first and refuses a solver it cannot find, with the loader's reason:
//
//   check_linear_solver("ma27", "ocp");  // without libhsl.so on the library path:
//   // LinearSolverUnavailable: ocp: linear solver "ma27" needs HSL's libhsl.so, which cannot be
//   // loaded (libhsl.so: cannot open shared object file: No such file or directory); ...
//
// docs/ocp.md ("Linear solvers: MUMPS and HSL") says how to get and install libhsl.so.
#ifndef BFLOW_FESD_LINEAR_SOLVER_H_
#define BFLOW_FESD_LINEAR_SOLVER_H_

#include <mutex>
#include <string>

#include "bflow/core/errors.h"

namespace bflow {

/** The values of linear_solver bflow passes to IPOPT: MUMPS (linked into IPOPT, the default);
    HSL's MA27, MA57, HSL_MA77, HSL_MA86 and HSL_MA97 (from libhsl.so); PARDISO (from
    libpardiso.so, pardiso-project.org's library, not MKL's). IPOPT 3.11's wsmp and custom are
    left out: Debian's build has no WSMP, and a custom solver needs code linked into IPOPT. */
inline constexpr const char* kLinearSolvers[] = {"mumps", "ma27", "ma57",   "ma77",
                                                 "ma86",  "ma97", "pardiso"};

/** A known linear solver whose shared library cannot be loaded, or lacks the solver. An
    InvalidArgument, so that callers who treat every refused option alike need nothing new. */
class LinearSolverUnavailable : public InvalidArgument {
 public:
  using InvalidArgument::InvalidArgument;
};

/** "mumps, ma27, ma57, ma77, ma86, ma97 or pardiso". */
std::string linear_solver_list();

/** The file IPOPT 3.11 loads the solver from: "libhsl.so" for ma27 ... ma97, "libpardiso.so"
    for pardiso, "" for mumps (linked in).
    @throws InvalidArgument "<who>: unknown linear solver "<name>"; use mumps, ..." for a name
    not in kLinearSolvers. */
std::string linear_solver_library(const std::string& name, const std::string& who);

/** Loads `library` as IPOPT would (dlopen, RTLD_NOW, by name through LD_LIBRARY_PATH, the
    ld.so cache and the default directories; a path containing '/' as it stands) and looks for
    the routine IPOPT 3.11 needs first for the solver (ma27ad, ma57ad, ma77_default_control_d,
    ma86_default_control_d, ma97_default_control_d, pardiso, with or without a trailing
    underscore). "" when both succeed (and always for mumps), else why not: the loader's
    dlerror() text, or "<library> has no routine ma97_default_control_d (nor
    ma97_default_control_d_): it was built without HSL_MA97". The library is closed again; IPOPT
    opens it itself.
    @throws InvalidArgument for a name not in kLinearSolvers. */
std::string linear_solver_load_error(const std::string& name, const std::string& library);

/** Nothing for mumps, nor for a solver whose library loads with its routine.
    @throws InvalidArgument for a name not in kLinearSolvers, quoting it and listing them.
    @throws LinearSolverUnavailable "<who>: linear solver "ma27" needs HSL's libhsl.so, which
    cannot be loaded (<linear_solver_load_error>); get Coin-HSL
    (https://licences.stfc.ac.uk/product/coin-hsl), build libhsl.so and put the directory
    holding libhsl.so on LD_LIBRARY_PATH (docs/ocp.md, "Linear solvers: MUMPS and HSL"), or use
    mumps" (for pardiso without the Coin-HSL part). */
void check_linear_solver(const std::string& name, const std::string& who);

/** MUMPS's amalgamation of small fronts (KEEP(197) = 1) for the analyses IPOPT runs on this
    thread while the object lives (`on`), or not (`on` false); the previous setting afterwards.

    An FESD NLP's KKT matrix (n of 100 to a few 1000) has many tiny fronts, and the MUMPS 5.5.1
    of Debian 12 pays per front: on the braking block's KKT matrix (n = 1370) its elimination
    tree has 866 nodes, 191 with the amalgamation, and a factorisation takes 1.16 instead of
    1.97 ms, a solve 0.32 instead of 0.77 ms (bench/results/kkt_mumps.json; later MUMPS releases
    amalgamate by default). IPOPT 3.11 has no option for it, so bflow defines MUMPS's entry point
    dmumps_c, sets KEEP(197) = 1 before each analysis (MUMPS 5.5 and later; other versions are
    left alone) and forwards the call to the MUMPS library. The factorisation is as exact as
    without (more fill, fewer and larger fronts); the pivots, and with them the round-off, differ.
    HomotopySolver opens one around every NLP (IpoptSettings::mumps_amalgamation). */
class ScopedMumpsAmalgamation {
 public:
  explicit ScopedMumpsAmalgamation(bool on);
  ~ScopedMumpsAmalgamation();
  ScopedMumpsAmalgamation(const ScopedMumpsAmalgamation&) = delete;
  ScopedMumpsAmalgamation& operator=(const ScopedMumpsAmalgamation&) = delete;

 private:
  bool previous_;
};

/** The MUMPS analyses of this process that ran with KEEP(197) = 1 set by bflow. */
long mumps_amalgamated_analyses();

/** The process's one lock around IPOPT and MUMPS. MUMPS keeps state in Fortran module variables
    shared by all its instances (its load balancing, DMUMPS_LOAD_INIT, allocates them in every
    factorisation), so two factorisations at once corrupt each other, and IPOPT 3.11 does not
    promise more. bflow holds this lock in IpoptApplicationFactory and Initialize, around every
    OptimizeTNLP (one NLP of a homotopy or one polish: solves of other threads interleave
    between them, each thread's results unchanged), when an IpoptApplication is released, in the
    dmumps_c interposer (every MUMPS call, whoever makes it) and in check_linear_solver's dlopen.
    It is recursive: the dmumps_c calls inside an OptimizeTNLP take it again on the same thread.
    A single-threaded run pays one uncontended lock per NLP and per MUMPS call. Code that calls
    IPOPT or MUMPS itself, beside bflow, in a program with several threads takes it too. */
std::recursive_mutex& ipopt_mutex();

}  // namespace bflow

#endif  // BFLOW_FESD_LINEAR_SOLVER_H_

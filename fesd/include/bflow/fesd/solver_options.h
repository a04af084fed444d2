// The options of IPOPT and of its linear solver that FESD simulation (FesdOptions::solver) and
// optimal control (OcpOptions::solver) share: one set, with the same defaults for both. What
// differs between the two (the tolerance of the last NLP, the iteration limit per NLP, exact or
// limited-memory Hessians, the homotopy) stays in each one's options.
#ifndef BFLOW_FESD_SOLVER_OPTIONS_H_
#define BFLOW_FESD_SOLVER_OPTIONS_H_

#include <string>
#include <utility>
#include <vector>

namespace bflow {

struct SolverOptions {
  int print_level = 0;  ///< IPOPT's print_level (0 silent)
  /** IPOPT's linear solver for every NLP, one of kLinearSolvers (linear_solver.h): "mumps"
      (linked into IPOPT, MUMPS 5.8.2 with METIS in the default build), "spral" (linked into
      IPOPT 3.14), HSL's "ma27", "ma57", "ma77", "ma86", "ma97" (from Coin-HSL's library),
      "pardiso" (pardiso-project.org's) or "pardisomkl" (where IPOPT has MKL). nosnoc's
      benchmarks use MA27. Checked before anything is computed.
      @throws InvalidArgument (from fesd_simulate and ocp_solve) for another name,
      LinearSolverUnavailable when its library cannot be loaded (docs/ocp.md, "Linear
      solvers"). */
  std::string linear_solver = "mumps";
  /** The library file of an HSL solver or of PARDISO, by name (found as the dynamic loader
      finds libraries) or path: "" tries libcoinhsl.so, then libhsl.so (libpardiso.so for
      pardiso). IPOPT 3.14 only (its hsllib and pardisolib); a build on IPOPT 3.11 loads the
      fixed names and refuses another. */
  std::string linear_solver_library;
  /** With a MUMPS before 5.8 (the IPOPT 3.11 fallback build), its amalgamation of small fronts
      (KEEP(197) = 1, which IPOPT 3.11 cannot set; bflow::ScopedMumpsAmalgamation): about half
      the cost of an IPOPT iteration on FESD's KKT matrices with Debian's MUMPS 5.5.1; other
      round-off, the same solutions. MUMPS 5.8 (the default build) amalgamates by itself, and
      this has no effect there. */
  bool mumps_amalgamation = true;
  /** OpenBLAS's threads while IPOPT solves (bflow::ScopedBlasThreads, linear_solver.h), >= 0:
      FESD's KKT matrices are too small for BLAS threads (one NLP of the braking block took 1.9
      instead of 2.8 ms per iteration on 1 thread than on the 2 the default build's OpenBLAS
      starts on a 2-core machine). 0 leaves OpenBLAS's own count (OPENBLAS_NUM_THREADS, else one
      per core); no effect on a BLAS other than OpenBLAS. The results' `blas` names the BLAS and
      the count.
      @throws InvalidArgument (from fesd_simulate and ocp_solve) for a count below 0. */
  int blas_threads = 1;
  /** The process keeps the memory MUMPS frees between factorisations instead of faulting it
      in again at every one (bflow::keep_freed_memory, linear_solver.h: glibc's malloc
      settings, set once at the first solve that asks and kept for the process): the hopper's
      solve took 183 instead of 241 s of CPU; small KKT matrices stay below malloc's
      thresholds. false leaves malloc as the process has it. */
  bool keep_freed_memory = true;
  /** Further IPOPT options, set after bflow's own (mu_strategy adaptive, bound_relax_factor 0,
      timing_statistics no, and the homotopy's: tol, mu_init, warm_start_*, acceptable_*, set
      before every NLP), once at the start and again before every NLP, so that these win (e.g.
      {"output_file", "ipopt.log"}, {"derivative_test", "second-order"}, {"acceptable_tol",
      1e-2}, {"mumps_pivot_order", 0}: other pivots, and with them other homotopy paths).
      @throws InvalidArgument (from fesd_simulate and ocp_solve) naming an option IPOPT does not
      take. */
  std::vector<std::pair<std::string, std::string>> ipopt_string_options;
  std::vector<std::pair<std::string, double>> ipopt_numeric_options;
  std::vector<std::pair<std::string, int>> ipopt_integer_options;
  /** The exact derivatives as programs (hessian_tape.h): each element's Jacobian rows and
      each block of the exact Hessian (an element's field pieces and algebraic rows, the costs
      and constraints) traced once at its first point and differentiated symbolically, then
      run at every later evaluation, where a branch its model takes otherwise (a comparison,
      abs, fmax, ...) traces it again. Every program is checked against the Jets it replaces
      where it was traced and at its 2nd, 4th, 8th, ... run; one that disagrees is replaced by
      them for good. false: Jets and HessianJet at every evaluation (the same numbers to
      rounding). docs/ocp.md, "The derivatives as programs". */
  bool derivative_programs = true;
  /** For testing derivative checks only: with exact Hessians, the Hessian handed to IPOPT is
      multiplied by this (1 in any real use), so a test can show that IPOPT's second-order
      derivative checker reports a wrong Hessian. */
  double exact_hessian_scale = 1.0;
};

}  // namespace bflow

#endif  // BFLOW_FESD_SOLVER_OPTIONS_H_

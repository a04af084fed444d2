// The one place of bflow that knows IPOPT: an NLP handed to IPOPT through an interface without
// IPOPT's types (NlpProblem), one IPOPT application with bflow's options (IpoptSession), and
// the versions of the IPOPT and MUMPS the build links (cmake/BflowIpopt.cmake). Only
// ipopt_adapter.cc includes IPOPT's headers; the transcription (transcription.cc) and the
// homotopy (homotopy.cc) see this header.
//
// Every IpoptSession call that enters IPOPT or MUMPS holds ipopt_mutex() (linear_solver.h):
// IPOPT's creation, initialisation and release, and each optimize (one NLP).
#ifndef BFLOW_FESD_SRC_IPOPT_ADAPTER_H_
#define BFLOW_FESD_SRC_IPOPT_ADAPTER_H_

#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace bflow {
namespace fesd {

/** An NLP min f(x) s.t. g_l <= g(x) <= g_u, x_l <= x <= x_u, with sparse first derivatives of g
    and the lower triangle of the Lagrangian's Hessian, as IPOPT asks for them (C indices). */
class NlpProblem {
 public:
  virtual ~NlpProblem() = default;
  /** Unknowns, constraints, Jacobian and Hessian nonzeros. */
  virtual void sizes(int& n, int& m, int& nnz_jac, int& nnz_hess) = 0;
  virtual void bounds(int n, double* x_l, double* x_u, int m, double* g_l, double* g_u) = 0;
  /** The starting point; false when the multipliers asked for are not there. */
  virtual bool start(int n, bool init_x, double* x, bool init_z, double* z_l, double* z_u, int m,
                     bool init_lambda, double* lambda) = 0;
  virtual double objective(const double* x) = 0;
  virtual void gradient(int n, const double* x, double* grad) = 0;
  virtual void constraints(const double* x, double* g) = 0;
  virtual void jacobian_structure(int nele, int* rows, int* cols) = 0;
  virtual void jacobian_values(const double* x, int nele, double* values) = 0;
  virtual void hessian_structure(int nele, int* rows, int* cols) = 0;
  /** obj_factor times the objective's Hessian plus lambda_r times each constraint's. */
  virtual void hessian_values(const double* x, double obj_factor, const double* lambda, int nele,
                              double* values) = 0;
  /** The point IPOPT ends at with its multipliers, and its unscaled KKT error and largest
      constraint violation there (infinity when IPOPT stopped before its first iterate). */
  virtual void finish(int n, const double* x, const double* z_l, const double* z_u, int m,
                      const double* lambda, double kkt_error, double constraint_violation) = 0;
  /** Asked after every iteration: false stops the NLP (NlpStatus::kUserStop). */
  virtual bool go_on() = 0;
};

/** IPOPT's outcome of one NLP (its ApplicationReturnStatus). */
enum class NlpStatus {
  kSolved,
  kAcceptable,
  kInfeasible,
  kSearchDirectionTooSmall,
  kDiverging,
  kUserStop,
  kFeasiblePointFound,
  kMaxIterations,
  kRestorationFailed,
  kErrorInStepComputation,
  kMaxCpuTime,
  kTooFewDegreesOfFreedom,
  kInvalidProblem,
  kInvalidOption,
  kInvalidNumber,
  kOther
};

/** IPOPT's name of the status: "Solve_Succeeded", "Maximum_Iterations_Exceeded", ... */
const char* nlp_status_name(NlpStatus status);

/** One IPOPT application: options set by name (a false return: IPOPT does not take it), then
    initialize() once, then any number of optimize() calls, each solving one NLP from the
    problem's start at the options set then. */
class IpoptSession {
 public:
  IpoptSession();
  ~IpoptSession();
  IpoptSession(const IpoptSession&) = delete;
  IpoptSession& operator=(const IpoptSession&) = delete;

  bool set_string(const std::string& name, const std::string& value);
  bool set_numeric(const std::string& name, double value);
  bool set_integer(const std::string& name, int value);
  /** false when the option has not been set. */
  bool get_integer(const std::string& name, int& value) const;

  /** bflow's own options, the same for fesd_simulate's step NLPs and ocp_solve's NLPs (set
      before the caller's, which win): print level, exact or limited-memory Hessians, the linear
      solver, the iteration limit, the adaptive barrier update, no relaxation of the bounds (the
      complementarity pairs sit on them), no timing statistics; for HSL's solvers and
      pardiso-project's PARDISO the library file (`solver_library`, IPOPT 3.14's hsllib and
      pardisolib). */
  void set_defaults(int print_level, bool exact_hessian, int max_iterations,
                    const std::string& linear_solver, const std::string& solver_library);
  /** The caller's options, each by its type.
      @throws InvalidArgument "<who>: IPOPT does not take the <type> option <name> = <value>". */
  void apply(const std::vector<std::pair<std::string, std::string>>& strings,
             const std::vector<std::pair<std::string, double>>& numbers,
             const std::vector<std::pair<std::string, int>>& integers, const std::string& who);
  /** @throws InvalidArgument "<who>: IPOPT failed to initialise". */
  void initialize(const std::string& who);

  struct Outcome {
    NlpStatus status = NlpStatus::kOther;
    int iterations = 0;
  };
  /** One NLP from the problem's start, as a new problem: IPOPT analyses the KKT matrix's
      structure again. (IPOPT's ReOptimizeTNLP with warm_start_same_structure, which keeps that
      analysis between NLPs of one structure, changed the outcomes: docs/ocp.md, "IPOPT
      3.14's options".) */
  Outcome optimize(NlpProblem& problem);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/** Whether this IPOPT takes the value `name` of its option linear_solver (it was built with the
    solver; a solver loaded at run time is taken whether or not its library loads). */
bool ipopt_takes_linear_solver(const std::string& name);
/** The IPOPT the build links ("3.14.19"), from its IpoptConfig.h. */
const char* ipopt_version();
/** The MUMPS IPOPT links ("5.8.2"), from its dmumps_c.h; "" when the build did not find it. */
const char* mumps_version();
/** The file of the IPOPT library this process runs (dladdr), "" when not found. */
const char* ipopt_library_file();
/** Whether this IPOPT was built with SPRAL (linear_solver "spral"). */
bool ipopt_has_spral();
/** Whether IPOPT takes the option hsllib and pardisolib (3.14): the library of HSL's solvers
    and of PARDISO named by file, else IPOPT 3.11's fixed libhsl.so and libpardiso.so. */
bool ipopt_names_solver_libraries();

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_SRC_IPOPT_ADAPTER_H_

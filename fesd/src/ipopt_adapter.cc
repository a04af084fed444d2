// IPOPT's side of ipopt_adapter.h: a TNLP that forwards to an NlpProblem, and the
// IpoptApplication behind IpoptSession. The only source that includes IPOPT's headers.
#include "ipopt_adapter.h"

#include <IpoptConfig.h>
#include <IpIpoptApplication.hpp>
#include <IpIpoptCalculatedQuantities.hpp>
#include <IpIpoptData.hpp>
#include <IpSolveStatistics.hpp>
#include <IpTNLP.hpp>

#include <dlfcn.h>

#include <limits>
#include <mutex>
#include <string>

#include "bflow/core/errors.h"
#include "bflow/core/text.h"
#include "bflow/fesd/linear_solver.h"
#include "bflow/fesd/transcription.h"

namespace bflow {
namespace fesd {

static_assert(std::numeric_limits<Ipopt::Index>::max() == kFesdMaxIndex,
              "kFesdMaxIndex must be IPOPT's largest index");
static_assert(sizeof(Ipopt::Index) == sizeof(int) && sizeof(Ipopt::Number) == sizeof(double),
              "NlpProblem passes IPOPT's indices as int and its numbers as double");

namespace {

NlpStatus from_ipopt(Ipopt::ApplicationReturnStatus status) {
  switch (status) {
    case Ipopt::Solve_Succeeded:
      return NlpStatus::kSolved;
    case Ipopt::Solved_To_Acceptable_Level:
      return NlpStatus::kAcceptable;
    case Ipopt::Infeasible_Problem_Detected:
      return NlpStatus::kInfeasible;
    case Ipopt::Search_Direction_Becomes_Too_Small:
      return NlpStatus::kSearchDirectionTooSmall;
    case Ipopt::Diverging_Iterates:
      return NlpStatus::kDiverging;
    case Ipopt::User_Requested_Stop:
      return NlpStatus::kUserStop;
    case Ipopt::Feasible_Point_Found:
      return NlpStatus::kFeasiblePointFound;
    case Ipopt::Maximum_Iterations_Exceeded:
      return NlpStatus::kMaxIterations;
    case Ipopt::Restoration_Failed:
      return NlpStatus::kRestorationFailed;
    case Ipopt::Error_In_Step_Computation:
      return NlpStatus::kErrorInStepComputation;
    case Ipopt::Maximum_CpuTime_Exceeded:
      return NlpStatus::kMaxCpuTime;
    case Ipopt::Not_Enough_Degrees_Of_Freedom:
      return NlpStatus::kTooFewDegreesOfFreedom;
    case Ipopt::Invalid_Problem_Definition:
      return NlpStatus::kInvalidProblem;
    case Ipopt::Invalid_Option:
      return NlpStatus::kInvalidOption;
    case Ipopt::Invalid_Number_Detected:
      return NlpStatus::kInvalidNumber;
    default:
      return NlpStatus::kOther;
  }
}

// The TNLP IPOPT solves: every call forwarded to the NlpProblem.
class Forward final : public Ipopt::TNLP {
 public:
  explicit Forward(NlpProblem& problem) : p_(problem) {}

  bool get_nlp_info(Ipopt::Index& n, Ipopt::Index& m, Ipopt::Index& nnz_jac, Ipopt::Index& nnz_hess,
                    IndexStyleEnum& style) override {
    p_.sizes(n, m, nnz_jac, nnz_hess);
    style = C_STYLE;
    return true;
  }
  bool get_bounds_info(Ipopt::Index n, Ipopt::Number* x_l, Ipopt::Number* x_u, Ipopt::Index m,
                       Ipopt::Number* g_l, Ipopt::Number* g_u) override {
    p_.bounds(n, x_l, x_u, m, g_l, g_u);
    return true;
  }
  bool get_starting_point(Ipopt::Index n, bool init_x, Ipopt::Number* x, bool init_z,
                          Ipopt::Number* z_l, Ipopt::Number* z_u, Ipopt::Index m, bool init_lambda,
                          Ipopt::Number* lambda) override {
    return p_.start(n, init_x, x, init_z, z_l, z_u, m, init_lambda, lambda);
  }
  bool eval_f(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Number& value) override {
    value = p_.objective(x);
    return true;
  }
  bool eval_grad_f(Ipopt::Index n, const Ipopt::Number* x, bool, Ipopt::Number* grad) override {
    p_.gradient(n, x, grad);
    return true;
  }
  bool eval_g(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Index, Ipopt::Number* g) override {
    p_.constraints(x, g);
    return true;
  }
  bool eval_jac_g(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Index, Ipopt::Index nele,
                  Ipopt::Index* rows, Ipopt::Index* cols, Ipopt::Number* values) override {
    if (values == nullptr) {
      p_.jacobian_structure(nele, rows, cols);
    } else {
      p_.jacobian_values(x, nele, values);
    }
    return true;
  }
  bool eval_h(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Number obj_factor, Ipopt::Index,
              const Ipopt::Number* lambda, bool, Ipopt::Index nele, Ipopt::Index* rows,
              Ipopt::Index* cols, Ipopt::Number* values) override {
    if (values == nullptr) {
      p_.hessian_structure(nele, rows, cols);
    } else {
      p_.hessian_values(x, obj_factor, lambda, nele, values);
    }
    return true;
  }
  bool intermediate_callback(Ipopt::AlgorithmMode, Ipopt::Index, Ipopt::Number, Ipopt::Number,
                             Ipopt::Number, Ipopt::Number, Ipopt::Number, Ipopt::Number,
                             Ipopt::Number, Ipopt::Number, Ipopt::Index, const Ipopt::IpoptData*,
                             Ipopt::IpoptCalculatedQuantities*) override {
    return p_.go_on();
  }
  void finalize_solution(Ipopt::SolverReturn status, Ipopt::Index n, const Ipopt::Number* x,
                         const Ipopt::Number* z_l, const Ipopt::Number* z_u, Ipopt::Index m,
                         const Ipopt::Number*, const Ipopt::Number* lambda, Ipopt::Number,
                         const Ipopt::IpoptData* data,
                         Ipopt::IpoptCalculatedQuantities* cq) override {
    double kkt_error = std::numeric_limits<double>::infinity();
    double violation = std::numeric_limits<double>::infinity();
    // When IPOPT stops before its first iterate is complete (a function or derivative not
    // finite at the start, too few degrees of freedom, ...), its quantities are not computed,
    // and asking for them reads vectors that hold no values (SIGSEGV in IpBlasDasum).
    const bool stopped_at_start = status == Ipopt::INVALID_NUMBER_DETECTED ||
                                  status == Ipopt::TOO_FEW_DEGREES_OF_FREEDOM ||
                                  status == Ipopt::INTERNAL_ERROR ||
                                  status == Ipopt::INVALID_OPTION || status == Ipopt::OUT_OF_MEMORY;
    if (cq != nullptr && data != nullptr && Ipopt::IsValid(data->curr()) && !stopped_at_start) {
      kkt_error = cq->curr_nlp_error();
      violation = cq->unscaled_curr_nlp_constraint_violation(Ipopt::NORM_MAX);
    }
    p_.finish(n, x, z_l, z_u, m, lambda, kkt_error, violation);
  }

 private:
  NlpProblem& p_;
};

}  // namespace

const char* nlp_status_name(NlpStatus status) {
  switch (status) {
    case NlpStatus::kSolved:
      return "Solve_Succeeded";
    case NlpStatus::kAcceptable:
      return "Solved_To_Acceptable_Level";
    case NlpStatus::kInfeasible:
      return "Infeasible_Problem_Detected";
    case NlpStatus::kSearchDirectionTooSmall:
      return "Search_Direction_Becomes_Too_Small";
    case NlpStatus::kDiverging:
      return "Diverging_Iterates";
    case NlpStatus::kUserStop:
      return "User_Requested_Stop";
    case NlpStatus::kFeasiblePointFound:
      return "Feasible_Point_Found";
    case NlpStatus::kMaxIterations:
      return "Maximum_Iterations_Exceeded";
    case NlpStatus::kRestorationFailed:
      return "Restoration_Failed";
    case NlpStatus::kErrorInStepComputation:
      return "Error_In_Step_Computation";
    case NlpStatus::kMaxCpuTime:
      return "Maximum_CpuTime_Exceeded";
    case NlpStatus::kTooFewDegreesOfFreedom:
      return "Not_Enough_Degrees_Of_Freedom";
    case NlpStatus::kInvalidProblem:
      return "Invalid_Problem_Definition";
    case NlpStatus::kInvalidOption:
      return "Invalid_Option";
    case NlpStatus::kInvalidNumber:
      return "Invalid_Number_Detected";
    case NlpStatus::kOther:
      break;
  }
  return "IPOPT_error";
}

struct IpoptSession::Impl {
  Ipopt::SmartPtr<Ipopt::IpoptApplication> app;
};

IpoptSession::IpoptSession() : impl_(new Impl) {
  const std::lock_guard<std::recursive_mutex> lock(ipopt_mutex());
  impl_->app = IpoptApplicationFactory();
  impl_->app->RethrowNonIpoptException(false);
}

IpoptSession::~IpoptSession() {
  // Releasing the application ends its MUMPS instance (dmumps_c with JOB = -2).
  const std::lock_guard<std::recursive_mutex> lock(ipopt_mutex());
  impl_->app = nullptr;
}

bool IpoptSession::set_string(const std::string& name, const std::string& value) {
  return impl_->app->Options()->SetStringValue(name, value);
}
bool IpoptSession::set_numeric(const std::string& name, double value) {
  return impl_->app->Options()->SetNumericValue(name, value);
}
bool IpoptSession::set_integer(const std::string& name, int value) {
  return impl_->app->Options()->SetIntegerValue(name, value);
}
bool IpoptSession::get_integer(const std::string& name, int& value) const {
  Ipopt::Index v = 0;
  if (!impl_->app->Options()->GetIntegerValue(name, v, "")) return false;
  value = v;
  return true;
}

void IpoptSession::set_defaults(int print_level, bool exact_hessian, int max_iterations,
                                const std::string& linear_solver,
                                const std::string& solver_library) {
  set_integer("print_level", print_level);
  set_string("linear_solver", linear_solver);
  set_string("sb", "yes");
  set_string("hessian_approximation", exact_hessian ? "exact" : "limited-memory");
  set_integer("max_iter", max_iterations);
  set_string("mu_strategy", "adaptive");
  set_numeric("bound_relax_factor", 0.0);
#if IPOPT_VERSION_MAJOR > 3 || (IPOPT_VERSION_MAJOR == 3 && IPOPT_VERSION_MINOR >= 14)
  // No CPU clock read around each of IPOPT's tasks (3.11 always reads it, about 100 getrusage
  // calls per iteration).
  set_string("timing_statistics", "no");
  if (!solver_library.empty()) {
    const bool hsl = linear_solver.rfind("ma", 0) == 0;
    set_string(hsl ? "hsllib" : "pardisolib", solver_library);
  }
#else
  (void)solver_library;  // IPOPT 3.11 loads libhsl.so and libpardiso.so by those names
#endif
}

void IpoptSession::apply(const std::vector<std::pair<std::string, std::string>>& strings,
                         const std::vector<std::pair<std::string, double>>& numbers,
                         const std::vector<std::pair<std::string, int>>& integers,
                         const std::string& who) {
  for (const auto& [name, value] : strings) {
    if (!set_string(name, value)) {
      throw InvalidArgument(who + ": IPOPT does not take the string option " + name + " = " +
                            value);
    }
  }
  for (const auto& [name, value] : numbers) {
    if (!set_numeric(name, value)) {
      throw InvalidArgument(who + ": IPOPT does not take the numeric option " + name + " = " +
                            format_number(value));
    }
  }
  for (const auto& [name, value] : integers) {
    if (!set_integer(name, value)) {
      throw InvalidArgument(who + ": IPOPT does not take the integer option " + name + " = " +
                            std::to_string(value));
    }
  }
}

void IpoptSession::initialize(const std::string& who) {
  const std::lock_guard<std::recursive_mutex> lock(ipopt_mutex());
  if (impl_->app->Initialize() != Ipopt::Solve_Succeeded) {
    throw InvalidArgument(who + ": IPOPT failed to initialise");
  }
}

IpoptSession::Outcome IpoptSession::optimize(NlpProblem& problem) {
  const std::lock_guard<std::recursive_mutex> lock(ipopt_mutex());
  Ipopt::SmartPtr<Ipopt::TNLP> forward = new Forward(problem);
  Outcome out;
  out.status = from_ipopt(impl_->app->OptimizeTNLP(forward));
  out.iterations =
      Ipopt::IsValid(impl_->app->Statistics()) ? impl_->app->Statistics()->IterationCount() : 0;
  return out;
}

bool ipopt_takes_linear_solver(const std::string& name) {
  const std::lock_guard<std::recursive_mutex> lock(ipopt_mutex());
  // An option value IPOPT did not register (a solver it was built without) is refused here.
  const Ipopt::SmartPtr<Ipopt::IpoptApplication> app = IpoptApplicationFactory();
  app->Jnlst()->DeleteAllJournals();  // no message on stdout for a refused value
  return app->Options()->SetStringValue("linear_solver", name);
}

const char* ipopt_version() { return IPOPT_VERSION; }
const char* mumps_version() { return BFLOW_MUMPS_VERSION; }
const char* ipopt_library_file() {
  Dl_info where{};
  const auto factory = &IpoptApplicationFactory;
  if (dladdr(reinterpret_cast<void*>(factory), &where) == 0 || where.dli_fname == nullptr)
    return "";
  return where.dli_fname;
}
bool ipopt_has_spral() { return BFLOW_IPOPT_HAS_SPRAL != 0; }
bool ipopt_names_solver_libraries() {
  return IPOPT_VERSION_MAJOR > 3 || (IPOPT_VERSION_MAJOR == 3 && IPOPT_VERSION_MINOR >= 14);
}

}  // namespace fesd

bool mumps_interposed() { return BFLOW_MUMPS_INTERPOSER != 0; }

}  // namespace bflow

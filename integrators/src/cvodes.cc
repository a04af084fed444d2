// SUNDIALS CVODES behind SegmentIntegrator. Every SUNDIALS object is owned by an RAII handle;
// every CVODES return code becomes a status or a message here and nowhere else.
#include "bflow/integrators/cvodes.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <exception>
#include <limits>
#include <new>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <cvodes/cvodes.h>
#include <nvector/nvector_serial.h>
#include <sunlinsol/sunlinsol_dense.h>
#include <sunmatrix/sunmatrix_dense.h>

#include "bflow/core/errors.h"

namespace bflow {

static_assert(std::is_same_v<sunrealtype, double>, "bflow needs SUNDIALS built with double");

const char* to_string(CvodesMethod method) {
  return method == CvodesMethod::kBdf ? "bdf" : "adams";
}

namespace {

// ---------------------------------------------------------------------------------------------
// RAII for the SUNDIALS objects.

struct ContextFree {
  void operator()(SUNContext context) const { SUNContext_Free(&context); }
};
struct VectorFree {
  void operator()(N_Vector vector) const { N_VDestroy(vector); }
};
struct MatrixFree {
  void operator()(SUNMatrix matrix) const { SUNMatDestroy(matrix); }
};
struct SolverFree {
  void operator()(SUNLinearSolver solver) const { SUNLinSolFree(solver); }
};
struct CvodeFree {
  void operator()(void* memory) const { CVodeFree(&memory); }
};

using ContextHandle = std::unique_ptr<std::remove_pointer_t<SUNContext>, ContextFree>;
using VectorHandle = std::unique_ptr<std::remove_pointer_t<N_Vector>, VectorFree>;
using MatrixHandle = std::unique_ptr<std::remove_pointer_t<SUNMatrix>, MatrixFree>;
using SolverHandle = std::unique_ptr<std::remove_pointer_t<SUNLinearSolver>, SolverFree>;
using CvodeHandle = std::unique_ptr<void, CvodeFree>;

// k vectors cloned from a template (the tangents).
class VectorArray {
 public:
  VectorArray() = default;
  VectorArray(int count, N_Vector like) : count_(count) {
    if (count_ > 0) {
      vectors_ = N_VCloneVectorArray(count_, like);
      if (vectors_ == nullptr) throw std::bad_alloc();
    }
  }
  VectorArray(VectorArray&& other) noexcept
      : vectors_(std::exchange(other.vectors_, nullptr)), count_(std::exchange(other.count_, 0)) {}
  VectorArray& operator=(VectorArray&& other) noexcept {
    if (this != &other) {
      release();
      vectors_ = std::exchange(other.vectors_, nullptr);
      count_ = std::exchange(other.count_, 0);
    }
    return *this;
  }
  VectorArray(const VectorArray&) = delete;
  VectorArray& operator=(const VectorArray&) = delete;
  ~VectorArray() { release(); }

  N_Vector* data() const { return vectors_; }
  double* column(int c) const { return N_VGetArrayPointer(vectors_[c]); }

 private:
  void release() {
    if (vectors_ != nullptr) N_VDestroyVectorArray(vectors_, count_);
    vectors_ = nullptr;
  }
  N_Vector* vectors_ = nullptr;
  int count_ = 0;
};

template <typename T>
T* checked(T* pointer) {
  if (pointer == nullptr) throw std::bad_alloc();
  return pointer;
}

// Name of a CVODES return flag, e.g. "CV_CONV_FAILURE" (CVodeGetReturnFlagName mallocs it).
std::string flag_name(int flag) {
  char* name = CVodeGetReturnFlagName(flag);
  std::string text = name != nullptr ? name : "CV_UNKNOWN(" + std::to_string(flag) + ")";
  std::free(name);
  return text;
}

// A CVODES set-up call failed (only for a bug or exhausted memory): becomes kSolverFailure.
struct SetupFailure {
  std::string message;
};

bool is_field_failure(int flag) {
  switch (flag) {
    case CV_RHSFUNC_FAIL:
    case CV_FIRST_RHSFUNC_ERR:
    case CV_REPTD_RHSFUNC_ERR:
    case CV_UNREC_RHSFUNC_ERR:
    case CV_SRHSFUNC_FAIL:
    case CV_FIRST_SRHSFUNC_ERR:
    case CV_REPTD_SRHSFUNC_ERR:
    case CV_UNREC_SRHSFUNC_ERR:
    case CV_RTFUNC_FAIL:
    case CV_LSETUP_FAIL:
      return true;
    default:
      return false;
  }
}

// ---------------------------------------------------------------------------------------------
// The segment as the callbacks see it (their user_data). Callbacks never let an exception
// through the C frames of CVODES: they store it and return -1 (unrecoverable); integrate()
// rethrows it once CVode has returned. A non-finite number is recorded and returned as a
// recoverable error (1), so that CVODES first retries with a smaller step.

// Segments shorter than kEulerSpan ulps of t, or than kEulerAbsoluteSpan, are one explicit
// Euler step.
constexpr double kEulerSpan = 128.0;
constexpr double kEulerAbsoluteSpan = 1e-100;

constexpr int kRecoverable = 1;
constexpr int kUnrecoverable = -1;

struct Problem {
  const SegmentModel* model = nullptr;
  Signs sides;
  int d = 0;
  int n = 0;
  int k = 0;
  Eigen::VectorXd f;         // d: F_b(x) from field_tangents (CVODES has it already)
  Eigen::MatrixXd v;         // d x k: the tangents S handed to the sensitivity right-hand side
  Eigen::MatrixXd fv;        // d x k: DF_b(x) S
  Eigen::MatrixXd identity;  // d x d: directions for the Jacobian
  std::vector<double> h;     // n surface values

  std::exception_ptr exception;
  bool nonfinite = false;
  double nonfinite_t = 0.0;
  std::string nonfinite_what;
  // Time of the last evaluation of the field, its tangents or its Jacobian: tn + h inside the
  // step CVODES is attempting, so it gives the size of a step that failed.
  double last_t = 0.0;
  std::string solver_message;

  void reset(const SegmentModel& segment_model, Signs segment_sides, int states, int surfaces,
             int tangents) {
    model = &segment_model;
    sides = segment_sides;
    d = states;
    n = surfaces;
    k = tangents;
    f.resize(d);
    v.resize(d, k);
    fv.resize(d, k);
    if (identity.rows() != d) identity = Eigen::MatrixXd::Identity(d, d);
    h.resize(static_cast<std::size_t>(n));
    exception = nullptr;
    nonfinite = false;
    nonfinite_t = 0.0;
    nonfinite_what.clear();
    last_t = 0.0;
    solver_message.clear();
  }

  std::string where(double t, const double* x) const {
    std::string text = " at t = " + format_number(t) +
                       ", x = " + format_vector(Eigen::Map<const Eigen::VectorXd>(x, d));
    if (n > 0) text += " (b = \"" + sides.str() + "\")";
    return text;
  }

  int record_nonfinite(double t, std::string what) {
    nonfinite = true;
    nonfinite_t = t;
    nonfinite_what = std::move(what);
    return kRecoverable;
  }

  // 0 if x is finite, else records it.
  int check_state(double t, const double* x) {
    for (int i = 0; i < d; ++i) {
      if (!std::isfinite(x[i])) {
        return record_nonfinite(t, "the state is non-finite (entry " + std::to_string(i) + " is " +
                                       format_number(x[i]) + ")" + where(t, x));
      }
    }
    return 0;
  }

  // xdot = F_b(x) with doubles.
  int field(double t, const double* x, double* xdot) {
    last_t = t;
    if (int r = check_state(t, x); r != 0) return r;
    model->field(x, sides, xdot);
    for (int i = 0; i < d; ++i) {
      if (!std::isfinite(xdot[i])) {
        return record_nonfinite(t, "F_b(x) row " + std::to_string(i) + " is non-finite (" +
                                       format_number(xdot[i]) + ")" + where(t, x));
      }
    }
    return 0;
  }

  // out = DF_b(x) w for the d x m block w, by Jets in chunks (SegmentModel::field_tangents).
  int tangents(double t, const double* x, const Eigen::Ref<const Eigen::MatrixXd>& w,
               Eigen::Ref<Eigen::MatrixXd> out) {
    last_t = t;
    if (int r = check_state(t, x); r != 0) return r;
    for (Eigen::Index c = 0; c < w.cols(); ++c) {
      for (Eigen::Index i = 0; i < d; ++i) {
        if (!std::isfinite(w(i, c))) {
          return record_nonfinite(t, "tangent " + std::to_string(c) + " is non-finite (entry " +
                                         std::to_string(i) + " is " + format_number(w(i, c)) + ")" +
                                         where(t, x));
        }
      }
    }
    const Eigen::Map<const Eigen::VectorXd> xv(x, d);
    try {
      model->field_tangents(xv, sides, w, f, out);
    } catch (const InvalidArgument&) {
      // field_tangents throws InvalidArgument for a non-finite value or derivative too; tell
      // those apart from an exception of the model itself by looking for the non-finite
      // number one direction at a time. A throwing model throws again here, or is rethrown.
      std::string what = find_nonfinite(t, x, w);
      if (what.empty()) throw;
      return record_nonfinite(t, std::move(what));
    }
    return 0;
  }

  // First non-finite entry of F_b(x) or DF_b(x) w (one Jet1 pass per column), or "".
  std::string find_nonfinite(double t, const double* x,
                             const Eigen::Ref<const Eigen::MatrixXd>& w) {
    std::vector<double> value(static_cast<std::size_t>(d));
    model->field(x, sides, value.data());
    for (int i = 0; i < d; ++i) {
      if (!std::isfinite(value[static_cast<std::size_t>(i)])) {
        return "F_b(x) row " + std::to_string(i) + " is non-finite (" +
               format_number(value[static_cast<std::size_t>(i)]) + ")" + where(t, x);
      }
    }
    std::vector<Jet1> in(static_cast<std::size_t>(d)), out(static_cast<std::size_t>(d));
    for (Eigen::Index c = 0; c < w.cols(); ++c) {
      for (int i = 0; i < d; ++i) {
        in[static_cast<std::size_t>(i)] = Jet1(x[i]);
        in[static_cast<std::size_t>(i)].v[0] = w(i, c);
      }
      model->field(in.data(), sides, out.data());
      for (int i = 0; i < d; ++i) {
        const Jet1& y = out[static_cast<std::size_t>(i)];
        if (!std::isfinite(y.a) || !std::isfinite(y.v[0])) {
          return "row " + std::to_string(i) + " of DF_b(x) * V is non-finite (column " +
                 std::to_string(c) + " is " + format_number(y.v[0]) + ")" + where(t, x);
        }
      }
    }
    return "";
  }

  // g_j = s_j h_j(x).
  int surfaces(double t, const double* x, double* g) {
    model->surface_values(x, h.data());
    for (int j = 0; j < n; ++j) {
      const double hj = h[static_cast<std::size_t>(j)];
      if (!std::isfinite(hj)) {
        record_nonfinite(t, "h(x) row " + std::to_string(j) + " is non-finite (" +
                                format_number(hj) + ")" + where(t, x));
        return kUnrecoverable;  // CVODES has no recoverable failure of the root function
      }
      g[j] = sides.plus(j) ? hj : -hj;
    }
    return 0;
  }
};

template <typename Body>
int guarded(void* user_data, Body&& body) noexcept {
  Problem& problem = *static_cast<Problem*>(user_data);
  try {
    return body(problem);
  } catch (...) {
    problem.exception = std::current_exception();
    return kUnrecoverable;
  }
}

int field_callback(sunrealtype t, N_Vector y, N_Vector ydot, void* user_data) {
  return guarded(user_data, [&](Problem& p) {
    return p.field(t, N_VGetArrayPointer(y), N_VGetArrayPointer(ydot));
  });
}

// All k tangents in one call (CVodeSensInit, not CVodeSensInit1), one chunked Jet pass.
int tangent_callback(int ns, sunrealtype t, N_Vector y, N_Vector /*ydot*/, N_Vector* ys,
                     N_Vector* ysdot, void* user_data, N_Vector /*tmp1*/, N_Vector /*tmp2*/) {
  return guarded(user_data, [&](Problem& p) {
    for (int c = 0; c < ns; ++c) {
      p.v.col(c) = Eigen::Map<const Eigen::VectorXd>(N_VGetArrayPointer(ys[c]), p.d);
    }
    if (int r = p.tangents(t, N_VGetArrayPointer(y), p.v, p.fv); r != 0) return r;
    for (int c = 0; c < ns; ++c) {
      Eigen::Map<Eigen::VectorXd>(N_VGetArrayPointer(ysdot[c]), p.d) = p.fv.col(c);
    }
    return 0;
  });
}

// The Newton matrix needs DF_b(x): Jets with V = I, written into the column-major dense matrix.
int jacobian_callback(sunrealtype t, N_Vector y, N_Vector /*fy*/, SUNMatrix jacobian,
                      void* user_data, N_Vector /*tmp1*/, N_Vector /*tmp2*/, N_Vector /*tmp3*/) {
  return guarded(user_data, [&](Problem& p) {
    Eigen::Map<Eigen::MatrixXd> out(SUNDenseMatrix_Data(jacobian), p.d, p.d);
    return p.tangents(t, N_VGetArrayPointer(y), p.identity, out);
  });
}

int surface_callback(sunrealtype t, N_Vector y, sunrealtype* g, void* user_data) {
  return guarded(user_data, [&](Problem& p) { return p.surfaces(t, N_VGetArrayPointer(y), g); });
}

void error_callback(int code, const char* /*module*/, const char* function, char* message,
                    void* user_data) {
  try {
    Problem& p = *static_cast<Problem*>(user_data);
    p.solver_message = std::string(code == CV_WARNING ? "warning in " : "") +
                       (function != nullptr ? function : "CVODES") + ": " +
                       (message != nullptr ? message : "");
  } catch (...) {
    // Losing the text of a message is better than an exception through C frames.
  }
}

// ---------------------------------------------------------------------------------------------
// Input checks.

void check_request(const SegmentModel& model, const SegmentRequest& request,
                   const IntegratorOptions& options) {
  const std::string who = "CvodesIntegrator::integrate: ";
  const int d = model.states();
  const int n = model.surfaces();
  if (d < 1) throw InvalidArgument(who + "the model has d = " + std::to_string(d) + " states");
  if (request.x0.size() != d) {
    throw InvalidArgument(who + "x0 has " + std::to_string(request.x0.size()) +
                          " entries, the model has d = " + std::to_string(d) + " states");
  }
  if (request.v0.cols() > 0 && request.v0.rows() != d) {
    throw InvalidArgument(who + "v0 is " + std::to_string(request.v0.rows()) + " x " +
                          std::to_string(request.v0.cols()) + ", expected " + std::to_string(d) +
                          " rows (d)");
  }
  if (request.sides.size() != n) {
    throw InvalidArgument(who + "sides \"" + request.sides.str() + "\" name " +
                          std::to_string(request.sides.size()) +
                          " surfaces, the model has n = " + std::to_string(n));
  }
  if (!request.x0.allFinite()) {
    throw InvalidArgument(who + "x0 is not finite: x0 = " + format_vector(request.x0));
  }
  if (!request.v0.allFinite()) throw InvalidArgument(who + "v0 has a non-finite entry");
  if (!std::isfinite(request.t0) || !std::isfinite(request.t_end)) {
    throw InvalidArgument(who + "t0 and t_end must be finite, got t0 = " +
                          format_number(request.t0) + ", t_end = " + format_number(request.t_end));
  }
  if (!(options.rtol >= IntegratorOptions::kMinRtol) || !std::isfinite(options.rtol) ||
      !(options.absolute_tolerance() >= IntegratorOptions::kMinAtol) ||
      !std::isfinite(options.absolute_tolerance())) {
    throw InvalidArgument(who +
                          "need a finite rtol >= " + format_number(IntegratorOptions::kMinRtol) +
                          " and a finite atol >= " + format_number(IntegratorOptions::kMinAtol) +
                          ", got rtol = " + format_number(options.rtol) +
                          ", atol = " + format_number(options.absolute_tolerance()));
  }
  if (!(options.initial_step >= 0.0) || !(options.min_step >= 0.0) || !(options.max_step > 0.0) ||
      !std::isfinite(options.initial_step) || !std::isfinite(options.min_step)) {
    throw InvalidArgument(who + "need initial_step >= 0, min_step >= 0 and max_step > 0, got " +
                          format_number(options.initial_step) + ", " +
                          format_number(options.min_step) + ", " + format_number(options.max_step));
  }
  if (options.max_steps < 1) {
    throw InvalidArgument(who + "max_steps must be positive, got " +
                          std::to_string(options.max_steps));
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------

class CvodesIntegrator::Impl {
 public:
  explicit Impl(CvodesMethod method) : method_(method) {
    SUNContext context = nullptr;
    if (SUNContext_Create(nullptr, &context) != 0 || context == nullptr) throw std::bad_alloc();
    context_.reset(context);
  }

  CvodesMethod method() const { return method_; }
  const CvodesStatistics& statistics() const { return statistics_; }

  SegmentResult integrate(const SegmentModel& model, const SegmentRequest& request,
                          const IntegratorOptions& options) {
    check_request(model, request, options);
    const int d = model.states();
    const int n = model.surfaces();
    const int k = static_cast<int>(request.v0.cols());
    statistics_ = CvodesStatistics{};
    problem_.reset(model, request.sides, d, n, k);

    SegmentResult result;
    result.t = request.t0;
    result.x = request.x0;
    result.v = k > 0 ? request.v0 : Eigen::MatrixXd(d, 0);
    const double span = request.t_end - request.t0;
    if (span == 0.0) return result;
    const double t_scale = std::max(std::abs(request.t0), std::abs(request.t_end));
    // CVODES refuses |t_end - t0| < 2 eps |t| (CV_TOO_CLOSE), below its time fuzz of
    // 100 eps |t| it stops after one step of any length and extrapolates to t_end, and its
    // initial step estimate underflows for spans of ~1e-150.
    if (std::abs(span) <= kEulerSpan * std::numeric_limits<double>::epsilon() * t_scale ||
        std::abs(span) <= kEulerAbsoluteSpan) {
      euler_step(request, result);
      return result;
    }
    try {
      run(request, options, result);
    } catch (const SetupFailure& failure) {
      result.status = IntegrationStatus::kSolverFailure;
      result.message = "CVODES (" + std::string(to_string(method_)) + "): " + failure.message;
    }
    return result;
  }

 private:
  std::string name() const { return "CVODES (" + std::string(to_string(method_)) + ")"; }

  void check(int flag, const char* call) const {
    if (flag < 0) {
      throw SetupFailure{std::string(call) + " returned " + flag_name(flag) +
                         (problem_.solver_message.empty() ? "" : ": " + problem_.solver_message)};
    }
  }

  // Vectors, Newton matrix and linear solver outlive a call; they are rebuilt when d or k
  // changes. The CVODES memory itself is created fresh for every segment (see run()).
  void prepare(int d, int k) {
    SUNContext context = context_.get();
    if (d != d_) {
      ys_ = VectorArray();
      solver_.reset();
      matrix_.reset();
      y_.reset(checked(N_VNew_Serial(d, context)));
      matrix_.reset(checked(SUNDenseMatrix(d, d, context)));
      solver_.reset(checked(SUNLinSol_Dense(y_.get(), matrix_.get(), context)));
      d_ = d;
      k_ = -1;
    }
    if (k != k_) {
      ys_ = VectorArray(k, y_.get());
      k_ = k;
    }
  }

  void run(const SegmentRequest& request, const IntegratorOptions& options, SegmentResult& result) {
    Problem& p = problem_;
    const int d = p.d;
    const int n = p.n;
    const int k = p.k;
    prepare(d, k);
    N_Vector y = y_.get();
    Eigen::Map<Eigen::VectorXd>(N_VGetArrayPointer(y), d) = request.x0;

    // A fresh CVODES memory per segment rather than CVodeReInit: the root finder keeps
    // per-surface state (surfaces deactivated at t0) that CVodeReInit and CVodeRootInit with
    // the same number of surfaces do not reset, and the sizes change between segments anyway.
    // The cost is a few dozen small allocations per segment.
    CvodeHandle memory(
        CVodeCreate(method_ == CvodesMethod::kBdf ? CV_BDF : CV_ADAMS, context_.get()));
    if (!memory) throw std::bad_alloc();
    void* mem = memory.get();
    check(CVodeSetErrHandlerFn(mem, &error_callback, &p), "CVodeSetErrHandlerFn");
    check(CVodeInit(mem, &field_callback, request.t0, y), "CVodeInit");
    check(CVodeSetUserData(mem, &p), "CVodeSetUserData");
    check(CVodeSStolerances(mem, options.rtol, options.absolute_tolerance()), "CVodeSStolerances");
    check(CVodeSetLinearSolver(mem, solver_.get(), matrix_.get()), "CVodeSetLinearSolver");
    check(CVodeSetJacFn(mem, &jacobian_callback), "CVodeSetJacFn");
    const double direction = request.t_end > request.t0 ? 1.0 : -1.0;
    if (options.initial_step > 0.0) {
      check(CVodeSetInitStep(mem, direction * options.initial_step), "CVodeSetInitStep");
    }
    if (std::isfinite(options.max_step)) {
      check(CVodeSetMaxStep(mem, options.max_step), "CVodeSetMaxStep");
    }
    // One minimum step for the whole segment: relative to the largest |t| in it, the finest
    // step that still moves t there.
    const double t_scale = std::max({1.0, std::abs(request.t0), std::abs(request.t_end)});
    const double min_step = options.min_step * t_scale;
    if (min_step > options.max_step) {
      // CVODES would refuse hmin > hmax; no step is allowed, as for any other backend.
      result.status = IntegrationStatus::kStepSizeUnderflow;
      result.message = name() + ": the minimum step " + format_number(min_step) + " (min_step " +
                       format_number(options.min_step) +
                       " relative to max(1, |t0|, |t_end|)) exceeds max_step = " +
                       format_number(options.max_step);
      return;
    }
    check(CVodeSetMinStep(mem, min_step), "CVodeSetMinStep");
    check(CVodeSetStopTime(mem, request.t_end), "CVodeSetStopTime");
    if (n > 0) {
      check(CVodeRootInit(mem, n, &surface_callback), "CVodeRootInit");
      std::vector<int> decreasing(static_cast<std::size_t>(n), -1);
      check(CVodeSetRootDirection(mem, decreasing.data()), "CVodeSetRootDirection");
      check(CVodeSetNoInactiveRootWarn(mem), "CVodeSetNoInactiveRootWarn");
    }
    if (k > 0) {
      for (int c = 0; c < k; ++c) {
        Eigen::Map<Eigen::VectorXd>(ys_.column(c), d) = request.v0.col(c);
      }
      check(CVodeSensInit(mem, k, CV_STAGGERED, &tangent_callback, ys_.data()), "CVodeSensInit");
      std::vector<double> atol(static_cast<std::size_t>(k), options.absolute_tolerance());
      check(CVodeSensSStolerances(mem, options.rtol, atol.data()), "CVodeSensSStolerances");
      check(CVodeSetSensErrCon(mem, options.tangents_in_error_norm ? SUNTRUE : SUNFALSE),
            "CVodeSetSensErrCon");
      // No parameters: the sensitivity right-hand side is ours, so CVODES needs neither p
      // (only its difference quotients use it) nor pbar (scales of its estimated tolerances).
      check(CVodeSetSensParams(mem, nullptr, nullptr, nullptr), "CVodeSetSensParams");
    }

    // CVodeSetMaxNumSteps limits the steps of one CVode call; the budget is for the segment.
    // Bounded: a call is repeated only after it took steps, and never past max_steps in all.
    double t_reached = request.t0;
    long steps = 0;
    int flag = CV_SUCCESS;
    while (true) {
      const long before = steps;
      check(CVodeSetMaxNumSteps(mem, options.max_steps - steps), "CVodeSetMaxNumSteps");
      flag = CVode(mem, request.t_end, y, &t_reached, CV_NORMAL);
      if (p.exception) std::rethrow_exception(std::exchange(p.exception, nullptr));
      check(CVodeGetNumSteps(mem, &steps), "CVodeGetNumSteps");
      if (flag == CV_TOO_MUCH_WORK && steps < options.max_steps && steps > before) continue;
      break;
    }

    collect_statistics(mem, k);
    result.steps = statistics_.steps;
    result.rejected_steps = statistics_.error_test_failures;
    result.field_evaluations = statistics_.field_evaluations;
    result.t = t_reached;
    result.x = Eigen::Map<const Eigen::VectorXd>(N_VGetArrayPointer(y), d);
    if (k > 0 && steps > 0) read_tangents(mem, result);

    switch (flag) {
      case CV_SUCCESS:
      case CV_TSTOP_RETURN:
        result.status = IntegrationStatus::kReachedEnd;
        result.t = request.t_end;
        break;
      case CV_ROOT_RETURN: {
        result.status = IntegrationStatus::kCrossing;
        std::vector<int> found(static_cast<std::size_t>(n), 0);
        check(CVodeGetRootInfo(mem, found.data()), "CVodeGetRootInfo");
        for (int j = 0; j < n; ++j) {
          if (found[static_cast<std::size_t>(j)] != 0) result.crossed.push_back(j);
        }
        break;
      }
      case CV_TOO_MUCH_WORK:
        result.status = IntegrationStatus::kTooManySteps;
        result.message = name() + ": max_steps = " + std::to_string(options.max_steps) +
                         " steps taken, stopped at t = " + format_number(t_reached) +
                         " before t_end = " + format_number(request.t_end) + " (CV_TOO_MUCH_WORK)";
        break;
      default:
        classify_failure(flag, t_reached, direction, options.min_step, t_scale, result);
        break;
    }
    const bool stopped_well = result.status == IntegrationStatus::kReachedEnd ||
                              result.status == IntegrationStatus::kCrossing;
    if (stopped_well && (!result.x.allFinite() || !result.v.allFinite())) {
      result.status = IntegrationStatus::kNonFinite;
      result.message = name() +
                       ": the state or a tangent is non-finite at t = " + format_number(result.t) +
                       ": x = " + format_vector(result.x);
    }
  }

  // The tangents where CVode returned (after at least one step; before it they are v0).
  void read_tangents(void* mem, SegmentResult& result) {
    double t_sens = 0.0;
    check(CVodeGetSens(mem, &t_sens, ys_.data()), "CVodeGetSens");
    for (int c = 0; c < problem_.k; ++c) {
      result.v.col(c) = Eigen::Map<const Eigen::VectorXd>(ys_.column(c), problem_.d);
    }
  }

  void classify_failure(int flag, double t_reached, double direction, double relative_min_step,
                        double t_scale, SegmentResult& result) const {
    const double min_step = relative_min_step * t_scale;
    const Problem& p = problem_;
    const std::string solver =
        flag_name(flag) + (p.solver_message.empty() ? "" : ": " + p.solver_message);
    // A non-finite number counts when CVODES failed in a callback, or when it was met inside
    // the step that failed (times beyond t_reached); an earlier one CVODES recovered from.
    const bool nonfinite_now =
        p.nonfinite && (is_field_failure(flag) || (p.nonfinite_t - t_reached) * direction > 0.0);
    if (nonfinite_now) {
      result.status = IntegrationStatus::kNonFinite;
      result.message = name() + ": " + p.nonfinite_what +
                       "; stopped at t = " + format_number(t_reached) + " (" + solver + ")";
      return;
    }
    const double attempted = std::abs(p.last_t - t_reached);
    const double fuzz =
        4.0 * std::numeric_limits<double>::epsilon() * std::max(1.0, std::abs(t_reached));
    const bool at_min_step = (flag == CV_ERR_FAILURE || flag == CV_CONV_FAILURE) &&
                             attempted <= min_step * (1.0 + 1e-6) + fuzz;
    if (at_min_step || flag == CV_TOO_CLOSE) {
      result.status = IntegrationStatus::kStepSizeUnderflow;
      result.message = name() + ": the step size fell to its minimum " + format_number(min_step) +
                       " (min_step " + format_number(relative_min_step) +
                       " relative to max(1, |t0|, |t_end|)) at t = " + format_number(t_reached) +
                       " (" + solver + ")";
      return;
    }
    result.status = IntegrationStatus::kSolverFailure;
    result.message = name() + " failed at t = " + format_number(t_reached) + ": " + solver;
  }

  void collect_statistics(void* mem, int k) {
    CvodesStatistics& s = statistics_;
    check(CVodeGetNumSteps(mem, &s.steps), "CVodeGetNumSteps");
    check(CVodeGetNumErrTestFails(mem, &s.error_test_failures), "CVodeGetNumErrTestFails");
    check(CVodeGetNumNonlinSolvConvFails(mem, &s.convergence_failures),
          "CVodeGetNumNonlinSolvConvFails");
    check(CVodeGetNumRhsEvals(mem, &s.field_evaluations), "CVodeGetNumRhsEvals");
    check(CVodeGetNumJacEvals(mem, &s.jacobian_evaluations), "CVodeGetNumJacEvals");
    check(CVodeGetNumNonlinSolvIters(mem, &s.nonlinear_iterations), "CVodeGetNumNonlinSolvIters");
    check(CVodeGetLastOrder(mem, &s.last_order), "CVodeGetLastOrder");
    check(CVodeGetLastStep(mem, &s.last_step), "CVodeGetLastStep");
    if (k > 0) {
      long tangent_failures = 0;
      long tangent_convergence_failures = 0;
      check(CVodeGetSensNumErrTestFails(mem, &tangent_failures), "CVodeGetSensNumErrTestFails");
      check(CVodeGetSensNumNonlinSolvConvFails(mem, &tangent_convergence_failures),
            "CVodeGetSensNumNonlinSolvConvFails");
      check(CVodeGetSensNumRhsEvals(mem, &s.tangent_evaluations), "CVodeGetSensNumRhsEvals");
      s.error_test_failures += tangent_failures;
      s.convergence_failures += tangent_convergence_failures;
    }
  }

  // |t_end - t0| of a few ulps: one explicit Euler step (its error, |dt|^2 |F'| |F|, is far
  // below the rounding of t itself). Crossings are judged at its end.
  void euler_step(const SegmentRequest& request, SegmentResult& result) {
    Problem& p = problem_;
    const double dt = request.t_end - request.t0;
    const double* x0 = request.x0.data();
    Eigen::VectorXd xdot(p.d);
    int r = p.field(request.t0, x0, xdot.data());
    if (r == 0 && p.k > 0) r = p.tangents(request.t0, x0, request.v0, p.fv);
    result.steps = 1;
    result.field_evaluations = 1;
    if (r != 0) {
      result.status = IntegrationStatus::kNonFinite;
      result.message = name() + ": " + p.nonfinite_what;
      return;
    }
    result.t = request.t_end;
    result.x = request.x0 + dt * xdot;
    if (p.k > 0) result.v = request.v0 + dt * p.fv;
    if (p.n == 0) return;
    std::vector<double> g0(static_cast<std::size_t>(p.n)), g1(static_cast<std::size_t>(p.n));
    if (p.surfaces(request.t0, x0, g0.data()) != 0 ||
        p.surfaces(request.t_end, result.x.data(), g1.data()) != 0) {
      result.status = IntegrationStatus::kNonFinite;
      result.message = name() + ": " + p.nonfinite_what;
      return;
    }
    for (int j = 0; j < p.n; ++j) {
      if (g0[static_cast<std::size_t>(j)] > 0.0 && g1[static_cast<std::size_t>(j)] <= 0.0) {
        result.crossed.push_back(j);
      }
    }
    if (!result.crossed.empty()) result.status = IntegrationStatus::kCrossing;
  }

  CvodesMethod method_;
  ContextHandle context_;
  int d_ = -1;
  int k_ = -1;
  VectorHandle y_;
  MatrixHandle matrix_;
  SolverHandle solver_;
  VectorArray ys_;
  Problem problem_;
  CvodesStatistics statistics_;
};

CvodesIntegrator::CvodesIntegrator(CvodesMethod method) : impl_(std::make_unique<Impl>(method)) {}
CvodesIntegrator::~CvodesIntegrator() = default;
CvodesIntegrator::CvodesIntegrator(CvodesIntegrator&&) noexcept = default;
CvodesIntegrator& CvodesIntegrator::operator=(CvodesIntegrator&&) noexcept = default;

CvodesMethod CvodesIntegrator::method() const { return impl_->method(); }

const CvodesStatistics& CvodesIntegrator::statistics() const { return impl_->statistics(); }

SegmentResult CvodesIntegrator::integrate(const SegmentModel& model, const SegmentRequest& request,
                                          const IntegratorOptions& options) {
  return impl_->integrate(model, request, options);
}

}  // namespace bflow

// One smooth segment of a nonsmooth flow: the contract between the hybrid flow driver and the
// integration backends (the explicit Runge-Kutta pairs Dormand-Prince 5(4) in dopri5.h and
// 8(5,3) in dop853.h, SUNDIALS CVODES in cvodes.h).
//
// On a segment the sides b of all surfaces are fixed, so the field F_b is smooth. A backend
// integrates x' = F_b(x) and, when tangents are given, V' = DF_b(x) V (the variational
// equation, [B] (2.4)), from t0 towards t_end, and stops at the first time a surface crosses.
//
// Zero-crossing semantics. Surface j is watched through g_j(x) = s_j h_j(x), where s_j = +1 if
// b puts j on its + side and -1 otherwise, so g_j >= 0 while the state is on the side b says.
// A crossing is g_j going from > 0 to <= 0 inside a step. A surface whose g_j is <= 0 at the
// start of the segment (one just crossed, sitting on the surface to within the tolerance) is
// not watched until g_j > 0: a crossing just handled is never detected again.
#ifndef BFLOW_INTEGRATORS_SEGMENT_H_
#define BFLOW_INTEGRATORS_SEGMENT_H_

#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <ceres/jet.h>
#include <Eigen/Core>

#include "bflow/ad/tangent_jet.h"
#include "bflow/core/signs.h"

namespace bflow {

/** A model seen through virtual calls, so that integrators compile once (see model_adapter.h
    for the adapter of a templated bflow model). */
class SegmentModel {
 public:
  virtual ~SegmentModel() = default;
  virtual int states() const = 0;
  virtual int surfaces() const = 0;
  virtual void field(const double* x, Signs b, double* xdot) const = 0;
  virtual void field(const Jet1* x, Signs b, Jet1* xdot) const = 0;
  virtual void field(const Jet2* x, Signs b, Jet2* xdot) const = 0;
  virtual void field(const Jet4* x, Signs b, Jet4* xdot) const = 0;
  virtual void field(const Jet6* x, Signs b, Jet6* xdot) const = 0;
  virtual void field(const JetChunk* x, Signs b, JetChunk* xdot) const = 0;
  virtual void field(const Jet12* x, Signs b, Jet12* xdot) const = 0;
  virtual void field(const Jet16* x, Signs b, Jet16* xdot) const = 0;
  /** f = F_b(x) and FV = DF_b(x) V for a d x k block V, by Jets in chunks (no differences). */
  virtual void field_tangents(const Eigen::Ref<const Eigen::VectorXd>& x, Signs b,
                              const Eigen::Ref<const Eigen::MatrixXd>& v,
                              Eigen::Ref<Eigen::VectorXd> f,
                              Eigen::Ref<Eigen::MatrixXd> fv) const = 0;
  virtual void surface_values(const double* x, double* h) const = 0;
  /** Dh(x), n x d, by Jets. */
  virtual Eigen::MatrixXd surface_normals(const Eigen::Ref<const Eigen::VectorXd>& x) const = 0;
  /** h(x) and the rates Dh(x) v (n each) for a direction v of d numbers, e.g. the field: how fast
      the surfaces are approached. By default through surface_normals(); the model adapter
      evaluates the surfaces once on Jet<double, 1>. */
  virtual void surface_rates(const double* x, const double* v, double* h, double* rate) const {
    const int d = states();
    const int n = surfaces();
    if (n == 0) return;
    surface_values(x, h);
    const Eigen::Map<const Eigen::VectorXd> point(x, d);
    Eigen::Map<Eigen::VectorXd>(rate, n) =
        surface_normals(point) * Eigen::Map<const Eigen::VectorXd>(v, d);
  }
};

enum class IntegrationStatus {
  kReachedEnd,         // t == t_end
  kCrossing,           // stopped at the first crossing; `crossed` says which surfaces
  kStepSizeUnderflow,  // the step size fell below min_step
  kTooManySteps,       // max_steps taken
  kNonFinite,          // the state, the field or a tangent became NaN or infinite
  kSolverFailure,      // a backend failure (CVODES return code), see message
  kTooManyEvents,      // the hybrid driver's event limit (a Zeno trajectory?), never a backend's
  kOverflow,           // a number the hybrid driver reports (a grouping window, a crossing time,
                       // a gap, a band) is beyond the double range; never a backend's
};

/** Name of a status, e.g. "step-size underflow". */
const char* to_string(IntegrationStatus status);

struct IntegratorOptions {
  /** Relative tolerance, >= kMinRtol: below about 5 ulps no step can meet it in double
      precision, so a smaller value is refused rather than left to shrink steps forever. */
  double rtol = 1e-8;
  static constexpr double kMinRtol = 1e-15;
  /** Absolute tolerance, >= kMinAtol. Unset (the default): 1e-2 x rtol, so that tightening rtol
      alone keeps tightening the error on states of order one, instead of stopping where a fixed
      atol takes over. Set it for states far from order one (atol ~ 1e-2 rtol |x|). */
  std::optional<double> atol;
  /** Where a component passes zero its error is held to atol alone, and the rounding of the
      field (eps times the forces summed into it) enters a step's error estimate as about
      0.05 h eps |F|: on a model in units of order one, an atol below 1e-20 forces steps below
      1e-3 there whatever the solution, and far below it nearly every step is rejected (the
      biped's orbit at atol 1e-30: a million steps of 1e-11 per simulation). A smaller atol is
      refused; rescale a model whose states are that small. */
  static constexpr double kMinAtol = 1e-20;
  /** The absolute tolerance in force: atol, or 1e-2 x rtol when unset. */
  double absolute_tolerance() const { return atol ? *atol : kAtolPerRtol * rtol; }
  static constexpr double kAtolPerRtol = 1e-2;
  /** First step; 0 chooses one from the field. */
  double initial_step = 0.0;
  double max_step = std::numeric_limits<double>::infinity();
  /** Smallest step relative to max(1, |t|) before giving up with kStepSizeUnderflow. */
  double min_step = 1e-14;
  /** The step budget of one segment, >= 1: a segment that has taken max_steps steps ends with
      kTooManySteps, its message naming max_steps and the time reached. dopri5 also stops at
      max_steps rejected steps; CVODES counts its internal steps. */
  long max_steps = 1000000;
  /** The tangents in the error norm (the default): each tangent direction's local error is held
      to rtol relative to that direction's size (plus atol), so that rtol bounds the relative
      error of the derivative as it bounds the state's. Without it the state alone sets the
      steps, and where the state's own error estimate is small or zero while the tangents move
      (a start at an equilibrium, a state that stays on an invariant set, a symmetric
      trajectory) the steps grow unchecked and the derivative is wrong by far more than rtol
      (x' = A x from x0 = 0 to t = 2.5 at rtol 1e-10, tests/integrators/error_control_test.cc:
      dopri5 takes 11 steps and its Jacobian is off by 28 relative to exp(At); with the tangents,
      207 steps and 1.5e-10). Set false for that state-only control: tangents then cost only
      their arithmetic, every chunk of tangents takes the state's steps, and the derivative's
      accuracy is not controlled. Honoured by every backend: dopri5 and dop853 as above (dop853
      damps each direction's order-5 estimate by that direction's own order-3 one), CVODES by
      CVodeSetSensErrCon (the sensitivities in its error test, tolerances rtol and atol per
      column). The step size itself is never differentiated. */
  bool tangents_in_error_norm = true;
};

struct SegmentRequest {
  Signs sides;
  double t0 = 0.0;
  double t_end = 0.0;
  Eigen::VectorXd x0;
  /** d x k tangents at t0 (k may be 0). */
  Eigen::MatrixXd v0;
};

/** A surface that an accepted step came close to without crossing it: g_j (see the zero-crossing
    semantics above) had a local minimum g_min > 0 inside the step, at time t, closer to zero than
    `band`, the distance within which the integrator's error could hide a crossing. */
struct NearMiss {
  int surface = 0;
  double t = 0.0;
  double g_min = 0.0;
  double band = 0.0;
};

struct SegmentResult {
  IntegrationStatus status = IntegrationStatus::kReachedEnd;
  std::string message;
  /** Where the segment stopped: t_end, the crossing time, or where it failed. */
  double t = 0.0;
  Eigen::VectorXd x;
  Eigen::MatrixXd v;
  /** With kCrossing: the surfaces found crossing at t (lowest index first). */
  std::vector<int> crossed;
  /** With kCrossing: for every surface, the located time of its first crossing inside the last
      step (the step that holds t), or +infinity when it does not cross in that step. Lets the
      driver group crossings by located times rather than by extrapolation. May be empty (a
      backend that locates only the first crossing). */
  std::vector<double> crossing_times;
  /** Surfaces passed at a distance within the integrator's error band (near grazing). */
  std::vector<NearMiss> near_misses;
  long steps = 0;
  long rejected_steps = 0;
  long field_evaluations = 0;
};

/** A backend: integrates one segment. */
class SegmentIntegrator {
 public:
  virtual ~SegmentIntegrator() = default;
  virtual SegmentResult integrate(const SegmentModel& model, const SegmentRequest& request,
                                  const IntegratorOptions& options) = 0;
};

}  // namespace bflow

#endif  // BFLOW_INTEGRATORS_SEGMENT_H_

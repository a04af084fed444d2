// CvodesIntegrator: the SUNDIALS CVODES backend of SegmentIntegrator (see segment.h for the
// contract, docs/cvodes.md for the details).
//
//   auto model = bflow::adapt(MyModel{});
//   bflow::CvodesIntegrator bdf(bflow::CvodesMethod::kBdf);    // stiff problems
//   bflow::SegmentRequest request;
//   request.sides = bflow::Signs::parse("-");
//   request.t0 = 0.0;
//   request.t_end = 2.0;
//   request.x0 = x0;                                          // d numbers
//   request.v0 = Eigen::MatrixXd::Identity(d, d);             // k tangents (k may be 0)
//   bflow::SegmentResult r = bdf.integrate(model, request, bflow::IntegratorOptions{});
//   // r.status == kCrossing: r.t is the crossing time, r.crossed the surfaces, r.x and r.v
//   // the state and tangents there; kReachedEnd: r.t == t_end.
//
// What CVODES does here.
//  * States: x' = F_b(x) by SegmentModel::field (doubles), scalar tolerances rtol and atol.
//  * Nonlinear solver: Newton iteration with the dense direct linear solver for both methods,
//    with the exact Jacobian DF_b(x) from Jets (SegmentModel::field_tangents with V = I). BDF
//    (orders 1-5) is for stiff problems. Adams-Moulton (orders 1-12) is for non-stiff ones;
//    it also uses Newton, not fixed-point iteration, because fixed-point iteration only
//    converges for h |DF_b| < 1 and then fails or crawls as soon as the problem is even mildly
//    stiff, whereas Newton costs one d x d LU per Jacobian update, small for the d of bflow.
//  * Tangents: forward sensitivities, one per column of v0, with a user sensitivity right-hand
//    side DF_b(x) S computed for all k columns by Jets in chunks of kTangentChunk (never by
//    CVODES difference quotients), and the staggered corrector (CV_STAGGERED). The tangents are
//    in the error test as IntegratorOptions::tangents_in_error_norm says (CVodeSetSensErrCon;
//    on by default, tolerances rtol and atol per column); off, the state alone sets the steps.
//  * Crossings: CVODES root finding on g_j(x) = s_j h_j(x) (s_j = +1 on the + side of b),
//    direction "decreasing" only, so a crossing is g_j going from >= 0 to < 0 or to 0.
//    A surface with g_j(x0) < 0 is not watched until it becomes positive (no decreasing
//    sign change can happen before that); one with g_j(x0) == 0 exactly is judged by its
//    value a small time later (CVODES), so leaving the surface either way is not a crossing.
//    A surface that stays exactly at g_j = 0 over that first instant is not watched for the
//    rest of the segment.
//  * Grazing: NOT detected inside a step. CVODES's root finder, like any sign-change test,
//    looks at g_j at the ends of its internal steps (and on the interpolant only after a sign
//    change there): a trajectory that dips through a surface and comes back within one
//    internal step (a crossing pair near a tangency) is missed without notice, and
//    SegmentResult::near_misses stays empty. A dip is seen when a step ends inside it, which
//    max_step can force (max_step below the dip's duration, ~ 2 sqrt(2 delta / |g''|) for a
//    depth delta). Use the dopri5 backend where near-grazing passes matter: it searches every
//    step for interior minima and reports crossing pairs, touches and near misses (dopri5.h).
//  * Stops exactly at t_end (stop time); integration backwards (t_end < t0) is allowed.
//  * max_steps counts all steps of the segment; min_step is applied as the CVODES minimum
//    step min_step * max(1, |t0|, |t_end|) (CVODES has one minimum per run, so it is taken
//    at the largest |t| of the segment).
//  * A segment shorter than 128 ulps of t or than 1e-100 (CVODES refuses the shortest,
//    extrapolates over the others, and its first-step estimate underflows below ~1e-150) is
//    taken as one explicit Euler step, with crossings judged at its end.
//
// Outcomes. The status follows segment.h; kTooManySteps, kStepSizeUnderflow, kNonFinite and
// kSolverFailure carry a message naming the time, and for solver failures the CVODES return
// flag (e.g. "CV_CONV_FAILURE") and its own message. A non-finite state, field value, tangent
// or surface value is reported as kNonFinite (after CVODES has tried smaller steps).
// Exceptions thrown by the model (bflow::InvalidArgument or any other) reach the caller
// unchanged: they are caught inside the CVODES callbacks and rethrown once CVODES returns.
//
// An integrator may be reused for any number of segments and models; it is not thread-safe
// (use one per thread).
#ifndef BFLOW_INTEGRATORS_CVODES_H_
#define BFLOW_INTEGRATORS_CVODES_H_

#include <memory>

#include "bflow/integrators/segment.h"

namespace bflow {

/** The linear multistep family CVODES uses. */
enum class CvodesMethod {
  kBdf,    ///< backward differentiation formulas, orders 1-5: stiff problems
  kAdams,  ///< Adams-Moulton, orders 1-12: non-stiff problems
};

/** "bdf" or "adams". */
const char* to_string(CvodesMethod method);

/** Counters of the last integrate() call that SegmentResult does not hold. */
struct CvodesStatistics {
  long steps = 0;
  long error_test_failures = 0;   ///< states and tangents
  long convergence_failures = 0;  ///< Newton failures (states and tangents)
  long field_evaluations = 0;     ///< F_b(x) with doubles
  long tangent_evaluations = 0;   ///< DF_b(x) S for all k columns (Jet passes)
  long jacobian_evaluations = 0;  ///< DF_b(x) for the Newton matrix (Jet passes)
  long nonlinear_iterations = 0;  ///< Newton iterations for the states
  int last_order = 0;             ///< method order of the last step
  double last_step = 0.0;         ///< size of the last successful step
};

/** SegmentIntegrator on SUNDIALS CVODES (BDF or Adams) with forward sensitivities by Jets and
    root finding for the crossings. */
class CvodesIntegrator final : public SegmentIntegrator {
 public:
  explicit CvodesIntegrator(CvodesMethod method = CvodesMethod::kBdf);
  ~CvodesIntegrator() override;
  CvodesIntegrator(CvodesIntegrator&&) noexcept;
  CvodesIntegrator& operator=(CvodesIntegrator&&) noexcept;
  CvodesIntegrator(const CvodesIntegrator&) = delete;
  CvodesIntegrator& operator=(const CvodesIntegrator&) = delete;

  CvodesMethod method() const;

  /** Integrates one segment (see segment.h and the header comment above).
      @throws InvalidArgument if x0 does not have d entries, v0 has columns but not d rows,
      x0, v0, t0 or t_end is not finite, sides does not have n surfaces, rtol is below
      IntegratorOptions::kMinRtol or atol below IntegratorOptions::kMinAtol, initial_step or
      min_step is negative, max_step is not positive, or max_steps is not positive; and any
      exception the model throws, unchanged. */
  SegmentResult integrate(const SegmentModel& model, const SegmentRequest& request,
                          const IntegratorOptions& options) override;

  /** Counters of the last integrate() call (zero before the first). */
  const CvodesStatistics& statistics() const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace bflow

#endif  // BFLOW_INTEGRATORS_CVODES_H_

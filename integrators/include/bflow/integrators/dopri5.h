// Dormand-Prince 5(4) with dense output of order 4: seven stages a step, the last one the first of
// the next step (FSAL), an error estimate of order 4, step control with exponent 1/5.
//
// The explicit Runge-Kutta family. dopri5 (here) and dop853 (dop853.h) are two tableaus in one
// stepper (integrators/src/explicit_rk_stepper.h), which owns everything below: tangents, step
// control, events and grazing. It is written once for any scalar: with T = double it integrates
// the state; with T = ceres::Jet<double, N> the same arithmetic carries N tangent directions in
// the Jet parts, which is the variational equation V' = DF_b(x) V ([B] (2.4)).
//
// Step control holds the state and, by default (IntegratorOptions::tangents_in_error_norm), each
// tangent direction to the tolerances: the error is the larger of the state's RMS norm and, over
// directions c, |e_c| / (atol + rtol |v_c|) in Euclidean norms, so a later chunk of tangents may
// take other steps than the first, to the same end time. The step size is a plain double and is
// never differentiated. With tangents_in_error_norm = false the state (the Jet values) alone sets
// the steps and every chunk of tangents takes exactly the same steps; the derivative's error is
// then not controlled (where the state's estimate vanishes, at an equilibrium or on an invariant
// set, it is not even bounded).
//
// Events follow segment.h: after each accepted step the watched g_j = s_j h_j are evaluated;
// a sign change from > 0 to <= 0 is located on the dense output (Illinois method on the
// values, to a few ulps of t) and the step is cut there. The state and tangents at the
// crossing come from the dense output, which is accurate to the integration tolerance.
//
// Grazing (docs/flow.md, "Grazing"). A watched g_j that is > 0 at both ends of a step may still
// dip to <= 0 inside it (a crossing pair near a tangency, typical of long steps). After each
// accepted step, for every watched surface: the rates dg_j/dt at the ends (the surfaces on
// Jet<double, 1> along the field, one evaluation per step, SegmentModel::surface_rates) decide
// whether a dip is possible (g_j turns from falling to rising, or min g_j <= h max |dg_j/dt|); if
// so, g_j at mid-step fixes a quartic model (exact for an affine h_j), and only if that model comes
// below half the lower end value is the minimum of g_j searched on the dense output (Brent, values
// only). Then:
//  * g_min < -r (r: 16 eps x the largest of |g_j| and h |dg_j/dt| at the ends, the rounding of
//    g_j on the dense output): a crossing, at the first root before the minimum;
//  * |g_min| <= r: a touch, reported as a crossing at the tangency (zero of Dh_j . F to a few
//    ulps), which the hybrid driver rejects as grazing (eta . F ~ 0);
//  * r < g_min < band = 8 sum_i |dh_j/dx_i| (atol + rtol |x_i|) at the minimum: a NearMiss in
//    SegmentResult::near_misses, no crossing.
// A surface <= 0 at both ends (one just crossed) whose g_j rises above r inside the step and
// falls back is a crossing too, at the root after its maximum. Not detected: two extrema of g_j
// in one step, and dips that the quartic model of a strongly curved surface misses by more
// than half the lower end value.
#ifndef BFLOW_INTEGRATORS_DOPRI5_H_
#define BFLOW_INTEGRATORS_DOPRI5_H_

#include <memory>

#include "bflow/integrators/segment.h"

namespace bflow {

/** Dormand-Prince 5(4) backend. k tangent directions are carried in chunks of at most
    kFlowChunk = 16, each by the narrowest compiled Jet that holds it (widths 1, 2, 4, 6, 8, 12,
    16; bflow/ad/tangent_jet.h). */
class Dopri5Integrator final : public SegmentIntegrator {
 public:
  /** Integrates one segment (segment.h). Ends within max_steps accepted and max_steps rejected
      steps; a field that is not finite at x0 ends it at once (kNonFinite, naming the row).
      @throws InvalidArgument if x0 or the tangents do not have d rows or are not finite, sides
      does not have n surfaces, t_end is not finite or below t0, rtol is below
      IntegratorOptions::kMinRtol or atol below IntegratorOptions::kMinAtol (or either is not
      finite), initial_step or min_step is negative or not finite, max_step is not positive, or
      max_steps is below 1. */
  SegmentResult integrate(const SegmentModel& model, const SegmentRequest& request,
                          const IntegratorOptions& options) override;

  Dopri5Integrator();
  ~Dopri5Integrator() override;
  Dopri5Integrator(Dopri5Integrator&&) noexcept;
  Dopri5Integrator& operator=(Dopri5Integrator&&) noexcept;

 private:
  // The steppers kept between segments (their stage vectors, one per tangent width met): a run
  // of many short segments allocates them once. One object per thread.
  struct Steppers;
  std::unique_ptr<Steppers> steppers_;
};

namespace internal {
/** The templated core, explicitly instantiated for double and every TangentJet width.
    x0 holds the state and, for Jets, the tangent directions in the derivative parts. */
template <typename T>
SegmentResult dopri5_segment(const SegmentModel& model, Signs sides, double t0, double t_end,
                             const std::vector<T>& x0, const IntegratorOptions& options,
                             std::vector<T>* x_out, bool watch);
}  // namespace internal

}  // namespace bflow

#endif  // BFLOW_INTEGRATORS_DOPRI5_H_

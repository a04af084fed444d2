// Dormand & Prince's 8(5,3) pair as in Hairer's DOP853 (Hairer, Norsett & Wanner, Solving ODEs I,
// II.10): twelve stages a step and F at the new point (the first stage of the next step), order
// 8; the error estimate of order 5 damped by one of order 3,
//   err = |e5|^2 / sqrt(|e5|^2 + 0.01 |e3|^2)   (RMS norms over the scaled components),
// step control with exponent 1/8; a dense output of order 7 from three more stages, spent only on
// a step in which a crossing is located.
//
// The tangents' error (IntegratorOptions::tangents_in_error_norm, on by default) is damped per
// tangent direction by that direction's own e5 and e3, as if the direction were a system of its
// own: the state's damping factor is 0 wherever the state's estimate is (an equilibrium), and
// would switch the tangents' control off there.
//
// One of the explicit Runge-Kutta family with Dormand-Prince 5(4) (dopri5.h): the same stepper
// (integrators/src/explicit_rk_stepper.h), so events, grazing checks, chunks of tangents, step
// control, budgets and errors are as dopri5.h describes. Fewer steps than dopri5 at tight
// tolerances on smooth segments (docs/peers.md, the flow comparison); at loose ones, or with many
// short segments, dopri5 is cheaper.
#ifndef BFLOW_INTEGRATORS_DOP853_H_
#define BFLOW_INTEGRATORS_DOP853_H_

#include <memory>

#include "bflow/integrators/segment.h"

namespace bflow {

/** DOP853 backend. k tangent directions are carried in chunks of at most kFlowChunk = 16, each
    by the narrowest compiled Jet that holds it (widths 1, 2, 4, 6, 8, 12, 16; bflow/ad/
    tangent_jet.h). */
class Dop853Integrator final : public SegmentIntegrator {
 public:
  /** As Dopri5Integrator::integrate (dopri5.h), with the same guarantees and @throws;
      messages start with "dop853:". */
  SegmentResult integrate(const SegmentModel& model, const SegmentRequest& request,
                          const IntegratorOptions& options) override;

  Dop853Integrator();
  ~Dop853Integrator() override;
  Dop853Integrator(Dop853Integrator&&) noexcept;
  Dop853Integrator& operator=(Dop853Integrator&&) noexcept;

 private:
  // The steppers kept between segments (their stage vectors, one per tangent width met): a run
  // of many short segments allocates them once. One object per thread.
  struct Steppers;
  std::unique_ptr<Steppers> steppers_;
};

}  // namespace bflow

#endif  // BFLOW_INTEGRATORS_DOP853_H_

// The Jet widths bflow evaluates models in: tangents of a flow (integrators), first derivatives
// of FESD's equations (fesd) and of an OCP's (ocp) all come in chunks of these.
#ifndef BFLOW_AD_TANGENT_JET_H_
#define BFLOW_AD_TANGENT_JET_H_

#include <ceres/jet.h>

namespace bflow {

/** Jet widths the models are compiled for: 1, 2, 4, 6 and 8 tangent directions. A block
    of k directions runs in chunks of at most kTangentChunk, each in the narrowest compiled width
    that holds it (tangent_width()), so that no derivative lane is computed for nothing beyond
    the rounding up to an even width. */
inline constexpr int kTangentChunk = 8;
template <int N>
using TangentJet = ceres::Jet<double, N>;
using Jet1 = TangentJet<1>;
using Jet2 = TangentJet<2>;
using Jet4 = TangentJet<4>;
using Jet6 = TangentJet<6>;
using JetChunk = TangentJet<kTangentChunk>;
/** The flow integrators' wider chunks (bflow/integrators/segment.h): a flow's k tangents run in
    one pass of the state when k <= kFlowChunk, so the state, its field's values and the step
    control are computed once for all of them (the full Jacobian of a model of up to 16
    states). */
inline constexpr int kFlowChunk = 16;
using Jet12 = TangentJet<12>;
using Jet16 = TangentJet<kFlowChunk>;

/** The narrowest compiled Jet width for k directions (1 <= k <= kTangentChunk). */
constexpr int tangent_width(long k) {
  return k <= 1 ? 1 : k <= 2 ? 2 : k <= 4 ? 4 : k <= 6 ? 6 : 8;
}
/** The same for the flow integrators' widths, 1 <= k <= kFlowChunk: also 12 and 16. */
constexpr int flow_tangent_width(long k) { return k <= 8 ? tangent_width(k) : k <= 12 ? 12 : 16; }

}  // namespace bflow

#endif  // BFLOW_AD_TANGENT_JET_H_

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

/** The narrowest compiled Jet width for k directions (1 <= k <= kTangentChunk). */
constexpr int tangent_width(long k) {
  return k <= 1 ? 1 : k <= 2 ? 2 : k <= 4 ? 4 : k <= 6 ? 6 : 8;
}

}  // namespace bflow

#endif  // BFLOW_AD_TANGENT_JET_H_

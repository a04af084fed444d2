// The model contract: what a user writes once and every bflow engine consumes.
//
//   struct Bouncer {
//     static constexpr int kStates = 2;     // d, or bflow::kDynamic with int states() const
//     static constexpr int kSurfaces = 1;   // n, or bflow::kDynamic with int surfaces() const
//     template <typename T> void field(const T* x, bflow::Signs b, T* xdot) const {
//       xdot[0] = x[1];
//       xdot[1] = b.plus(0) ? T(-9.8) : T(-9.8) - T(100.0) * x[0];
//     }
//     template <typename T> void surfaces(const T* x, T* h) const { h[0] = -x[0]; }
//   };
//
// field(x, b, xdot) is the smooth extension F_b: defined for every x, whichever side x is on,
// and it must never branch on which side x is (the engine decides b). Templates are on the
// scalar so that bflow can evaluate them with ceres::Jet to obtain DF_b and Dh.
#ifndef BFLOW_CORE_MODEL_H_
#define BFLOW_CORE_MODEL_H_

#include "bflow/core/signs.h"

namespace bflow {

/** Marks a size chosen at run time (then the model provides states() / surfaces()). */
inline constexpr int kDynamic = -1;

/** Number of states d of a model. */
template <typename Model>
int model_states(const Model& model) {
  static_assert(Model::kStates == kDynamic || Model::kStates > 0,
                "Model::kStates must be positive or bflow::kDynamic");
  if constexpr (Model::kStates == kDynamic) {
    return model.states();
  } else {
    return Model::kStates;
  }
}

/** Number of switching surfaces n of a model. */
template <typename Model>
int model_surfaces(const Model& model) {
  static_assert(Model::kSurfaces == kDynamic ||
                    (Model::kSurfaces >= 0 && Model::kSurfaces <= Signs::kMaxSurfaces),
                "Model::kSurfaces must be in [0, 64] or bflow::kDynamic");
  if constexpr (Model::kSurfaces == kDynamic) {
    return model.surfaces();
  } else {
    return Model::kSurfaces;
  }
}

}  // namespace bflow

#endif  // BFLOW_CORE_MODEL_H_

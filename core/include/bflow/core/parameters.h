// Derivatives with respect to parameters: a parametric model seen as a plain model whose
// parameters are extra states with zero derivative. The flow derivative of the wrapped model
// then holds d phi / d p in its last columns (its rows for the parameters are the identity).
//
//   struct Decay {                                     // x' = -k x, surface x = c
//     static constexpr int kStates = 1, kSurfaces = 1, kParameters = 2;   // p = (k, c)
//     template <class T> void field(const T* x, const T* p, bflow::Signs, T* f) const {
//       f[0] = -p[0] * x[0]; }
//     template <class T> void surfaces(const T* x, const T* p, T* h) const { h[0] = x[0] - p[1]; }
//   };
//   bflow::WithParameters<Decay> model;               // states (x, k, c)
//   // x0 = (1, 0.5, 0.3): d x(t) / d k is derivative.apply(e_1)[0].
#ifndef BFLOW_CORE_PARAMETERS_H_
#define BFLOW_CORE_PARAMETERS_H_

#include <utility>

#include "bflow/core/model.h"
#include "bflow/core/signs.h"

namespace bflow {

/** A parametric model: kStates, kSurfaces and kParameters (all fixed), and
    field(x, p, b, xdot) / surfaces(x, p, h) templated on the scalar. */
template <typename Parametric>
class WithParameters {
 public:
  static_assert(Parametric::kStates > 0 && Parametric::kParameters > 0,
                "WithParameters needs fixed kStates and kParameters > 0");
  static constexpr int kModelStates = Parametric::kStates;
  static constexpr int kParameters = Parametric::kParameters;
  static constexpr int kStates = kModelStates + kParameters;
  static constexpr int kSurfaces = Parametric::kSurfaces;

  WithParameters() = default;
  explicit WithParameters(Parametric model) : model_(std::move(model)) {}
  const Parametric& model() const { return model_; }

  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    model_.field(x, x + kModelStates, b, xdot);
    for (int i = kModelStates; i < kStates; ++i) xdot[i] = T(0.0);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    if constexpr (kSurfaces > 0) model_.surfaces(x, x + kModelStates, h);
  }

 private:
  Parametric model_;
};

}  // namespace bflow

#endif  // BFLOW_CORE_PARAMETERS_H_

// The model contract of the FESD engine (fesd.h) and of optimal control through it (ocp/):
// a step inclusion x' in f(x, a), a_j in gamma(c_j(x)), written once as a template
//
//   struct M {
//     static constexpr int kStates = 2, kSwitches = 1;
//     template <typename T> void switching(const T* x, T* c) const;          // c(x)
//     template <typename T> void field(const T* x, const T* a, T* xdot) const; // f(x, a)
//   };
//
// and seen by the engine through StepModel's virtual calls (double, Jet chunks for first
// derivatives, HessianScalar for second derivatives), so that FESD compiles once. A
// piecewise-smooth system (modes f_i and a sign matrix, core/filippov.h) is the special case
// PiecewiseSmoothAsStep; EventDrivenView shows a step inclusion to the event-driven engine.
#ifndef BFLOW_FESD_STEP_MODEL_H_
#define BFLOW_FESD_STEP_MODEL_H_

#include <string>
#include <type_traits>
#include <utility>

#include <Eigen/Core>

#include "bflow/ad/tangent_jet.h"
#include "bflow/core/errors.h"
#include "bflow/core/filippov.h"
#include "bflow/core/signs.h"
#include "bflow/fesd/hessian_jet.h"

namespace bflow {

/** The scalar of exact Hessians of the FESD NLP and an OCP's (hessian_jet.h): value, gradient
    and lower-triangle Hessian in up to HessianJet::kLanes directions. Models written as
    templates with T(c) constants compile with it. */
using HessianScalar = HessianJet;

/** A step inclusion seen through virtual calls (double, Jet chunks and, for exact Hessians,
    HessianScalar), so FESD compiles once. */
class StepModel {
 public:
  virtual ~StepModel() = default;
  virtual int states() const = 0;
  virtual int switches() const = 0;
  virtual void switching(const double* x, double* c) const = 0;
  virtual void switching(const JetChunk* x, JetChunk* c) const = 0;
  virtual void field(const double* x, const double* a, double* xdot) const = 0;
  virtual void field(const JetChunk* x, const JetChunk* a, JetChunk* xdot) const = 0;
  virtual void switching(const HessianScalar* x, HessianScalar* c) const = 0;
  virtual void field(const HessianScalar* x, const HessianScalar* a, HessianScalar* xdot) const = 0;
  /** The sign matrix of a piecewise-smooth model (its modes and unions, used by the lifted
      step formulation), or nullptr for a general step inclusion (then the dense S). */
  virtual const SignMatrix* sign_matrix() const { return nullptr; }
  /** A piecewise-smooth model's number of modes n_f, or 0. With n_f > 0 (and a sign matrix),
      mode_fields gives every f_i(x) in one call (F[i * d + k] = f_i(x)_k), so that Stewart's
      formulation evaluates the model once per point instead of once per base set. */
  virtual int modes() const { return 0; }
  virtual void mode_fields(const double*, double*) const {}
  virtual void mode_fields(const JetChunk*, JetChunk*) const {}
  virtual void mode_fields(const HessianScalar*, HessianScalar*) const {}
};

namespace detail {
template <typename Model, typename = void>
struct HasSignMatrix : std::false_type {};
template <typename Model>
struct HasSignMatrix<Model, std::void_t<decltype(std::declval<const Model&>().sign_matrix())>>
    : std::true_type {};
template <typename Model, typename = void>
struct HasModeFields : std::false_type {};
template <typename Model>
struct HasModeFields<Model,
                     std::void_t<decltype(Model::kModes),
                                 decltype(std::declval<const Model&>().mode_fields(
                                     std::declval<const double*>(), std::declval<double*>()))>>
    : std::true_type {};
}  // namespace detail

template <typename Model>
class StepModelAdapter final : public StepModel {
 public:
  explicit StepModelAdapter(Model model) : model_(std::move(model)) {}
  int states() const override { return Model::kStates; }
  int switches() const override { return Model::kSwitches; }
  void switching(const double* x, double* c) const override { model_.switching(x, c); }
  void switching(const JetChunk* x, JetChunk* c) const override { model_.switching(x, c); }
  void field(const double* x, const double* a, double* xdot) const override {
    model_.field(x, a, xdot);
  }
  void field(const JetChunk* x, const JetChunk* a, JetChunk* xdot) const override {
    model_.field(x, a, xdot);
  }
  void switching(const HessianScalar* x, HessianScalar* c) const override {
    model_.switching(x, c);
  }
  void field(const HessianScalar* x, const HessianScalar* a, HessianScalar* xdot) const override {
    model_.field(x, a, xdot);
  }
  const SignMatrix* sign_matrix() const override {
    if constexpr (detail::HasSignMatrix<Model>::value) {
      return &model_.sign_matrix();
    } else {
      return nullptr;
    }
  }
  int modes() const override {
    if constexpr (detail::HasModeFields<Model>::value) {
      return Model::kModes;
    } else {
      return 0;
    }
  }
  void mode_fields(const double* x, double* f) const override { modes_of(x, f); }
  void mode_fields(const JetChunk* x, JetChunk* f) const override { modes_of(x, f); }
  void mode_fields(const HessianScalar* x, HessianScalar* f) const override { modes_of(x, f); }
  const Model& model() const { return model_; }

 private:
  template <typename T>
  void modes_of(const T* x, T* f) const {
    if constexpr (detail::HasModeFields<Model>::value) model_.mode_fields(x, f);
  }
  Model model_;
};

template <typename Model>
StepModelAdapter<Model> adapt_step(Model model) {
  return StepModelAdapter<Model>(std::move(model));
}

/** A piecewise-smooth system (modes f_i and a sign matrix, core/filippov.h) as a step inclusion:
    f(x, a) = sum_i theta_i(a) f_i(x) ([F] (20)-(22); unions of base regions as in Section 6.2).
    The model provides kStates, kSwitches, kModes, `switching<T>(x, c)` and
    `modes<T>(x, F)` writing the d x n_f values column by column (F[i * d + k] = f_i(x)_k). */
template <typename Pss>
class PiecewiseSmoothAsStep {
 public:
  static constexpr int kStates = Pss::kStates;
  static constexpr int kSwitches = Pss::kSwitches;
  static constexpr int kModes = Pss::kModes;

  /** @throws InvalidArgument if S has other than kSwitches columns or kModes modes. */
  PiecewiseSmoothAsStep(Pss pss, SignMatrix s) : pss_(std::move(pss)), s_(std::move(s)) {
    if (s_.switches() != kSwitches || s_.modes() != kModes) {
      throw InvalidArgument("PiecewiseSmoothAsStep: S has " + std::to_string(s_.switches()) +
                            " columns and " + std::to_string(s_.modes()) + " modes, the model " +
                            std::to_string(kSwitches) + " switching functions and " +
                            std::to_string(kModes) + " modes");
    }
  }
  template <typename T>
  void switching(const T* x, T* c) const {
    pss_.switching(x, c);
  }
  template <typename T>
  void field(const T* x, const T* a, T* xdot) const {
    T theta[kModes];
    T f[kModes * kStates];
    s_.multipliers(a, theta);
    pss_.modes(x, f);
    for (int k = 0; k < kStates; ++k) {
      xdot[k] = T(0.0);
      for (int i = 0; i < kModes; ++i) xdot[k] += theta[i] * f[i * kStates + k];
    }
  }
  /** Every mode at x, F[i * d + k] = f_i(x)_k. */
  template <typename T>
  void mode_fields(const T* x, T* f) const {
    pss_.modes(x, f);
  }
  const SignMatrix& sign_matrix() const { return s_; }

 private:
  Pss pss_;
  SignMatrix s_;
};

/** A step inclusion seen by the event-driven engine (hybrid_flow.h): surface j is c_j, side + of
    surface j is a_j = 1. Where trajectories cross transversally both engines apply and agree. */
template <typename Model>
struct EventDrivenView {
  static constexpr int kStates = Model::kStates;
  static constexpr int kSurfaces = Model::kSwitches;
  Model model;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    T a[kSurfaces];
    for (int j = 0; j < kSurfaces; ++j) a[j] = T(b.plus(j) ? 1.0 : 0.0);
    model.field(x, a, xdot);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    model.switching(x, h);
  }
};

}  // namespace bflow

#endif  // BFLOW_FESD_STEP_MODEL_H_

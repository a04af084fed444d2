// ModelAdapter: a templated bflow model (bflow/core/model.h) seen as a SegmentModel.
#ifndef BFLOW_INTEGRATORS_MODEL_ADAPTER_H_
#define BFLOW_INTEGRATORS_MODEL_ADAPTER_H_

#include <utility>
#include <vector>

#include "bflow/ad/jet_bridge.h"
#include "bflow/core/model.h"
#include "bflow/integrators/segment.h"

namespace bflow {

/** Holds a copy of the model. */
template <typename Model>
class ModelAdapter final : public SegmentModel {
 public:
  explicit ModelAdapter(Model model) : model_(std::move(model)) {}
  const Model& model() const { return model_; }

  int states() const override { return model_states(model_); }
  int surfaces() const override { return model_surfaces(model_); }
  void field(const double* x, Signs b, double* xdot) const override { model_.field(x, b, xdot); }
  void field(const Jet1* x, Signs b, Jet1* xdot) const override { model_.field(x, b, xdot); }
  void field(const Jet2* x, Signs b, Jet2* xdot) const override { model_.field(x, b, xdot); }
  void field(const Jet4* x, Signs b, Jet4* xdot) const override { model_.field(x, b, xdot); }
  void field(const Jet6* x, Signs b, Jet6* xdot) const override { model_.field(x, b, xdot); }
  void field(const JetChunk* x, Signs b, JetChunk* xdot) const override {
    model_.field(x, b, xdot);
  }
  void field(const Jet12* x, Signs b, Jet12* xdot) const override { model_.field(x, b, xdot); }
  void field(const Jet16* x, Signs b, Jet16* xdot) const override { model_.field(x, b, xdot); }
  void field_tangents(const Eigen::Ref<const Eigen::VectorXd>& x, Signs b,
                      const Eigen::Ref<const Eigen::MatrixXd>& v, Eigen::Ref<Eigen::VectorXd> f,
                      Eigen::Ref<Eigen::MatrixXd> fv) const override {
    ad::field_jacobian_times<kTangentChunk>(model_, x, b, v, f, fv);
  }
  void surface_values(const double* x, double* h) const override {
    if (surfaces() > 0) model_.surfaces(x, h);
  }
  Eigen::MatrixXd surface_normals(const Eigen::Ref<const Eigen::VectorXd>& x) const override {
    return ad::normals<kTangentChunk>(model_, x);
  }
  void surface_rates(const double* x, const double* v, double* h, double* rate) const override {
    const int d = states();
    const int n = surfaces();
    if (n == 0) return;
    // Per-thread scratch: no allocation and no zero-filling per call (adapters are shared
    // between threads, so it cannot be a member).
    thread_local std::vector<Jet1> x_scratch, h_scratch;
    if (x_scratch.size() < static_cast<std::size_t>(d))
      x_scratch.resize(static_cast<std::size_t>(d));
    if (h_scratch.size() < static_cast<std::size_t>(n))
      h_scratch.resize(static_cast<std::size_t>(n));
    Jet1* xj = x_scratch.data();
    Jet1* hj = h_scratch.data();
    for (int i = 0; i < d; ++i) {
      xj[i] = Jet1(x[i]);
      xj[i].v[0] = v[i];
    }
    model_.surfaces(xj, hj);
    for (int j = 0; j < n; ++j) {
      h[j] = hj[j].a;
      rate[j] = hj[j].v[0];
    }
  }

 private:
  Model model_;
};

template <typename Model>
ModelAdapter<std::decay_t<Model>> adapt(Model&& model) {
  return ModelAdapter<std::decay_t<Model>>(std::forward<Model>(model));
}

}  // namespace bflow

#endif  // BFLOW_INTEGRATORS_MODEL_ADAPTER_H_

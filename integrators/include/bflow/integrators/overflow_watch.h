// Telling overflow apart from bad input. A finite start can still overflow: a huge velocity
// makes |F| exceed the double range, a huge direction makes its image infinite. The library then
// often reports what follows as bad input (a margin eta . F / (|eta| |F|) that is 0 because |F|
// is infinite reads as grazing; tangents that became infinite end flow_derivative() with an
// InvalidArgument). Run on an OverflowWatch of the model and ask it, when the library rejects
// the run, whether an evaluation overflowed first.
//
//   const bflow::OverflowWatch watched(model);
//   try {
//     derivative = bflow::flow_derivative(watched, x0, t, options);
//   } catch (const bflow::InvalidArgument& e) {
//     if (!watched.overflow().empty()) { /* the computation overflowed: watched.overflow() */ }
//     else throw;  // bad input
//   }
#ifndef BFLOW_INTEGRATORS_OVERFLOW_WATCH_H_
#define BFLOW_INTEGRATORS_OVERFLOW_WATCH_H_

#include <atomic>
#include <cmath>
#include <mutex>
#include <string>
#include <utility>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/signs.h"
#include "bflow/integrators/segment.h"

namespace bflow {
namespace internal {

inline bool finite(double value) { return std::isfinite(value); }
template <int N>
bool finite(const ceres::Jet<double, N>& value) {
  return std::isfinite(value.a) && value.v.allFinite();
}
inline double value_part(double value) { return value; }
template <int N>
double value_part(const ceres::Jet<double, N>& value) {
  return value.a;
}

}  // namespace internal

/** Forwards to a model and keeps the first overflow seen in its evaluations: a state, tangent,
    field value or surface that is not finite, or a field whose norm |F| is beyond the double
    range (the library divides by |F| in its transversality margins). The integrator may meet
    one in a trial step it then rejects, so consult the watch only when the library has rejected
    the run: a rejection that follows an overflow is a failed computation, not bad input.
    Thread-safe like the model it watches. */
class OverflowWatch final : public SegmentModel {
 public:
  explicit OverflowWatch(const SegmentModel& model) : model_(model) {}

  /** The first overflow, e.g. "|F_--| is beyond the double range at x = [...]"; "" if none. */
  std::string overflow() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return overflow_;
  }

  int states() const override { return model_.states(); }
  int surfaces() const override { return model_.surfaces(); }
  void field(const double* x, Signs b, double* xdot) const override { watch(x, b, xdot); }
  void field(const Jet1* x, Signs b, Jet1* xdot) const override { watch(x, b, xdot); }
  void field(const Jet2* x, Signs b, Jet2* xdot) const override { watch(x, b, xdot); }
  void field(const Jet4* x, Signs b, Jet4* xdot) const override { watch(x, b, xdot); }
  void field(const Jet6* x, Signs b, Jet6* xdot) const override { watch(x, b, xdot); }
  void field(const JetChunk* x, Signs b, JetChunk* xdot) const override { watch(x, b, xdot); }
  void field(const Jet12* x, Signs b, Jet12* xdot) const override { watch(x, b, xdot); }
  void field(const Jet16* x, Signs b, Jet16* xdot) const override { watch(x, b, xdot); }
  void field_tangents(const Eigen::Ref<const Eigen::VectorXd>& x, Signs b,
                      const Eigen::Ref<const Eigen::MatrixXd>& v, Eigen::Ref<Eigen::VectorXd> f,
                      Eigen::Ref<Eigen::MatrixXd> fv) const override {
    model_.field_tangents(x, b, v, f, fv);
    if (seen_.load(std::memory_order_relaxed)) return;
    if (!x.allFinite() || !v.allFinite()) {
      note("the integration reached a state or tangent that is not finite");
    } else if (!f.allFinite() || !fv.allFinite()) {
      note("F_" + b.str() +
           " or its derivative on the tangents is not finite at x = " + format_vector(x));
    } else if (!std::isfinite(f.squaredNorm())) {
      note(norm_overflow(b, x));
    }
  }
  void surface_values(const double* x, double* h) const override {
    model_.surface_values(x, h);
    watch_surfaces(x, h, nullptr);
  }
  Eigen::MatrixXd surface_normals(const Eigen::Ref<const Eigen::VectorXd>& x) const override {
    Eigen::MatrixXd normals = model_.surface_normals(x);
    if (!seen_.load(std::memory_order_relaxed) && x.allFinite() && !normals.allFinite()) {
      note("a surface normal is not finite at x = " + format_vector(x));
    }
    return normals;
  }
  void surface_rates(const double* x, const double* v, double* h, double* rate) const override {
    model_.surface_rates(x, v, h, rate);
    watch_surfaces(x, h, rate);
  }

 private:
  template <typename T>
  void watch(const T* x, Signs b, T* xdot) const {
    model_.field(x, b, xdot);
    if (seen_.load(std::memory_order_relaxed)) return;
    const int d = model_.states();
    bool state_finite = true;
    bool field_finite = true;
    double squared_norm = 0.0;
    for (int i = 0; i < d; ++i) {
      state_finite = state_finite && internal::finite(x[i]);
      field_finite = field_finite && internal::finite(xdot[i]);
      squared_norm += internal::value_part(xdot[i]) * internal::value_part(xdot[i]);
    }
    if (state_finite && field_finite && std::isfinite(squared_norm)) return;
    Eigen::VectorXd point(d);
    for (int i = 0; i < d; ++i) point[i] = internal::value_part(x[i]);
    if (!state_finite) {
      note("the integration reached a state or tangent that is not finite");
    } else if (!field_finite) {
      note("F_" + b.str() +
           " or its derivative on the tangents is not finite at x = " + format_vector(point));
    } else {
      note(norm_overflow(b, point));
    }
  }

  void watch_surfaces(const double* x, const double* h, const double* rate) const {
    if (seen_.load(std::memory_order_relaxed)) return;
    const int d = model_.states();
    const int n = model_.surfaces();
    const Eigen::Map<const Eigen::VectorXd> point(x, d);
    if (!point.allFinite()) return;  // reported by the field
    bool ok = Eigen::Map<const Eigen::VectorXd>(h, n).allFinite();
    if (rate != nullptr) ok = ok && Eigen::Map<const Eigen::VectorXd>(rate, n).allFinite();
    if (!ok) note("a surface value or rate is not finite at x = " + format_vector(point));
  }

  static std::string norm_overflow(Signs b, const Eigen::Ref<const Eigen::VectorXd>& x) {
    return "|F_" + b.str() + "| is beyond the double range at x = " + format_vector(x);
  }

  void note(std::string what) const {
    std::lock_guard<std::mutex> lock(mutex_);
    if (overflow_.empty()) overflow_ = std::move(what);
    seen_.store(true, std::memory_order_relaxed);
  }

  const SegmentModel& model_;
  mutable std::atomic<bool> seen_{false};
  mutable std::mutex mutex_;
  mutable std::string overflow_;
};

}  // namespace bflow

#endif  // BFLOW_INTEGRATORS_OVERFLOW_WATCH_H_

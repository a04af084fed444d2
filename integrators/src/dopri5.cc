// Dormand-Prince 5(4): the tableau; the stepper is explicit_rk_stepper.h.
#include "bflow/integrators/dopri5.h"

#include <vector>

#include "explicit_rk_stepper.h"

namespace bflow {

namespace {

using explicit_rk::TangentNorm;
using explicit_rk::value_of;

// Dormand & Prince (1980) tableau and Hairer's dense output of order 4.
constexpr double c2 = 1.0 / 5, c3 = 3.0 / 10, c4 = 4.0 / 5, c5 = 8.0 / 9;
constexpr double a21 = 1.0 / 5;
constexpr double a31 = 3.0 / 40, a32 = 9.0 / 40;
constexpr double a41 = 44.0 / 45, a42 = -56.0 / 15, a43 = 32.0 / 9;
constexpr double a51 = 19372.0 / 6561, a52 = -25360.0 / 2187, a53 = 64448.0 / 6561,
                 a54 = -212.0 / 729;
constexpr double a61 = 9017.0 / 3168, a62 = -355.0 / 33, a63 = 46732.0 / 5247, a64 = 49.0 / 176,
                 a65 = -5103.0 / 18656;
constexpr double a71 = 35.0 / 384, a73 = 500.0 / 1113, a74 = 125.0 / 192, a75 = -2187.0 / 6784,
                 a76 = 11.0 / 84;
constexpr double e1 = 71.0 / 57600, e3 = -71.0 / 16695, e4 = 71.0 / 1920, e5 = -17253.0 / 339200,
                 e6 = 22.0 / 525, e7 = -1.0 / 40;
constexpr double d1 = -12715105075.0 / 11282082432, d3 = 87487479700.0 / 32700410799,
                 d4 = -10690763975.0 / 1880347072, d5 = 701980252875.0 / 199316789632,
                 d6 = -1453857185.0 / 822651844, d7 = 69997945.0 / 29380423;

// The Dormand-Prince 5(4) pair (Hairer, Norsett & Wanner, Solving ODEs I, II.5), first same as
// last (stage 7 is F at the new point), with Hairer's dense output of order 4.
template <typename T>
class Dp54Stages {
 public:
  static constexpr const char* kName = "dopri5";
  /** Step-size control: h *= 0.9 error^(-kExponent), 1 / (order of the error estimate + 1). */
  static constexpr double kExponent = 0.2;
  explicit Dp54Stages(int d) : d_(d), k1_(d), k2_(d), k3_(d), k4_(d), k5_(d), k6_(d), k7_(d) {}
  /** F at the step's start (filled by the caller before the first step). */
  std::vector<T>& first() { return k1_; }
  /** F at the trial step's end. */
  const std::vector<T>& last() const { return k7_; }

  // One trial step from x into next; field(in, out, t) evaluates F_b.
  template <typename Field>
  void attempt(const std::vector<T>& x, double h, double t, std::vector<T>& stage,
               std::vector<T>& next, Field&& field) {
    for (int i = 0; i < d_; ++i) stage[i] = x[i] + h * (a21 * k1_[i]);
    field(stage, k2_, t + c2 * h);
    for (int i = 0; i < d_; ++i) stage[i] = x[i] + h * (a31 * k1_[i] + a32 * k2_[i]);
    field(stage, k3_, t + c3 * h);
    for (int i = 0; i < d_; ++i) {
      stage[i] = x[i] + h * (a41 * k1_[i] + a42 * k2_[i] + a43 * k3_[i]);
    }
    field(stage, k4_, t + c4 * h);
    for (int i = 0; i < d_; ++i) {
      stage[i] = x[i] + h * (a51 * k1_[i] + a52 * k2_[i] + a53 * k3_[i] + a54 * k4_[i]);
    }
    field(stage, k5_, t + c5 * h);
    for (int i = 0; i < d_; ++i) {
      stage[i] =
          x[i] + h * (a61 * k1_[i] + a62 * k2_[i] + a63 * k3_[i] + a64 * k4_[i] + a65 * k5_[i]);
    }
    field(stage, k6_, t + h);
    for (int i = 0; i < d_; ++i) {
      next[i] =
          x[i] + h * (a71 * k1_[i] + a73 * k3_[i] + a74 * k4_[i] + a75 * k5_[i] + a76 * k6_[i]);
    }
    field(next, k7_, t + h);
  }
  /** The accepted step's end becomes the next step's start. */
  void accept() { k1_.swap(k7_); }
  template <typename Scale>
  void prepare_error(double, const Scale&) {}
  /** The local error estimate of component i's value. */
  double error_value(int i, double h) const {
    return h * (e1 * value_of(k1_[i]) + e3 * value_of(k3_[i]) + e4 * value_of(k4_[i]) +
                e5 * value_of(k5_[i]) + e6 * value_of(k6_[i]) + e7 * value_of(k7_[i]));
  }
  /** Component i's share of the tangents' error norm: its tangent parts' estimate. */
  void add_tangent_error(int i, double h, const T& x0, const T& x1, TangentNorm<T>& norm) const {
    norm.add(
        h * (e1 * k1_[i] + e3 * k3_[i] + e4 * k4_[i] + e5 * k5_[i] + e6 * k6_[i] + e7 * k7_[i]), x0,
        x1);
  }
  template <typename Field>
  void prepare_dense(const std::vector<T>&, double, double, std::vector<T>&, Field&&) {}
  /** Component i at theta on the dense output of the step x -> next. */
  T dense(int i, const T& x, const T& next, double h, double theta) const {
    const double theta1 = 1.0 - theta;
    const T r2 = next - x;
    const T r3 = h * k1_[i] - r2;
    const T r4 = r2 - h * k7_[i] - r3;
    const T r5 =
        h * (d1 * k1_[i] + d3 * k3_[i] + d4 * k4_[i] + d5 * k5_[i] + d6 * k6_[i] + d7 * k7_[i]);
    return x + theta * (r2 + theta1 * (r3 + theta * (r4 + theta1 * r5)));
  }
  /** The same, values only. */
  double dense_value(int i, double x, double next, double h, double theta) const {
    const double theta1 = 1.0 - theta;
    const double r2 = next - x;
    const double r3 = h * value_of(k1_[i]) - r2;
    const double r4 = r2 - h * value_of(k7_[i]) - r3;
    const double r5 = h * (d1 * value_of(k1_[i]) + d3 * value_of(k3_[i]) + d4 * value_of(k4_[i]) +
                           d5 * value_of(k5_[i]) + d6 * value_of(k6_[i]) + d7 * value_of(k7_[i]));
    return x + theta * (r2 + theta1 * (r3 + theta * (r4 + theta1 * r5)));
  }

 private:
  int d_;
  std::vector<T> k1_, k2_, k3_, k4_, k5_, k6_, k7_;
};

}  // namespace

namespace internal {
template <typename T>
SegmentResult dopri5_segment(const SegmentModel& model, Signs sides, double t0, double t_end,
                             const std::vector<T>& x0, const IntegratorOptions& options,
                             std::vector<T>* x_out, bool watch) {
  return explicit_rk::rk_segment<T, Dp54Stages>(model, sides, t0, t_end, x0, options, x_out, watch);
}
}  // namespace internal

struct Dopri5Integrator::Steppers : explicit_rk::StepperCache<Dp54Stages> {};

Dopri5Integrator::Dopri5Integrator() : steppers_(std::make_unique<Steppers>()) {}
Dopri5Integrator::~Dopri5Integrator() = default;
Dopri5Integrator::Dopri5Integrator(Dopri5Integrator&&) noexcept = default;
Dopri5Integrator& Dopri5Integrator::operator=(Dopri5Integrator&&) noexcept = default;

SegmentResult Dopri5Integrator::integrate(const SegmentModel& model, const SegmentRequest& request,
                                          const IntegratorOptions& options) {
  if (!steppers_) steppers_ = std::make_unique<Steppers>();  // a moved-from object
  return explicit_rk::integrate_chunks<Dp54Stages>(model, request, options, *steppers_);
}

#define BFLOW_DOPRI5_INSTANTIATE(T)                                                                \
  template SegmentResult internal::dopri5_segment<T>(                                              \
      const SegmentModel&, Signs, double, double, const std::vector<T>&, const IntegratorOptions&, \
      std::vector<T>*, bool);
BFLOW_DOPRI5_INSTANTIATE(double)
BFLOW_DOPRI5_INSTANTIATE(Jet1)
BFLOW_DOPRI5_INSTANTIATE(Jet2)
BFLOW_DOPRI5_INSTANTIATE(Jet4)
BFLOW_DOPRI5_INSTANTIATE(Jet6)
BFLOW_DOPRI5_INSTANTIATE(JetChunk)
BFLOW_DOPRI5_INSTANTIATE(Jet12)
BFLOW_DOPRI5_INSTANTIATE(Jet16)
#undef BFLOW_DOPRI5_INSTANTIATE

}  // namespace bflow

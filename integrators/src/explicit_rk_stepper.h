// The explicit Runge-Kutta stepper shared by dopri5 (dopri5.cc) and dop853 (dop853.cc): a
// method is a class template Method<T> with its tableau (the stages, the error estimate, the
// dense output); this stepper owns everything else: step control with the state and the
// tangents (segment.h, IntegratorOptions::tangents_in_error_norm), the step budgets, events,
// grazing checks and near misses (dopri5.h), chunks of tangents, and the checks of a request.
//
// A Method<T> provides: kName, kExponent (1 / (order of the error estimate + 1)); first() (F at
// the step's start, filled by the stepper) and last() (F at the trial step's end); attempt(x, h,
// t, stage, next, field); accept(); prepare_error(h, scale) then error_value(i, h) (the local
// error estimate of component i's value, for the state's RMS norm) and add_tangent_error(i, h,
// x0, x1, norm) (its tangent parts' share of the tangents' norm; not called without tangents,
// so a tangent estimate is computed only where it is used); prepare_dense(x, h, t, stage, field)
// then dense(i, x, next, h, theta) and dense_value(...) (values only).
// Private to integrators/src.
#ifndef BFLOW_INTEGRATORS_SRC_EXPLICIT_RK_STEPPER_H_
#define BFLOW_INTEGRATORS_SRC_EXPLICIT_RK_STEPPER_H_

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <string>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

#include <ceres/jet.h>
#include <Eigen/Core>

#include "bflow/ad/tangent_jet.h"
#include "bflow/core/errors.h"
#include "bflow/integrators/segment.h"

namespace bflow::explicit_rk {

inline double value_of(double x) { return x; }
template <int N>
double value_of(const ceres::Jet<double, N>& x) {
  return x.a;
}
inline bool all_finite(double x) { return std::isfinite(x); }
template <int N>
bool all_finite(const ceres::Jet<double, N>& x) {
  return std::isfinite(x.a) && x.v.allFinite();
}
// Per-direction accumulators of the tangent error norm: for each tangent direction c, the
// squared Euclidean norms of its local error and of the tangent at the step's two ends. Empty for
// double.
template <typename T>
struct TangentNorm {
  void clear() {}
  void add(const T&, const T&, const T&) {}
  void add_damped(const T&, const T&, const T&, const T&) {}
  double error(double, double) const { return 0.0; }
};
template <int N>
struct TangentNorm<ceres::Jet<double, N>> {
  using Jet = ceres::Jet<double, N>;
  Eigen::Array<double, N, 1> error_sq, low_sq, size0_sq, size1_sq;
  bool damped = false;
  void clear() {
    error_sq.setZero();
    low_sq.setZero();
    size0_sq.setZero();
    size1_sq.setZero();
    damped = false;
  }
  /** A component's local error estimate err (its tangent parts) at a step x0 -> x1. */
  void add(const Jet& err, const Jet& x0, const Jet& x1) {
    error_sq += err.v.array().square();
    size0_sq += x0.v.array().square();
    size1_sq += x1.v.array().square();
  }
  /** The same for a pair whose estimate is `high` damped by a lower-order one, `low` (DOP853). */
  void add_damped(const Jet& high, const Jet& low, const Jet& x0, const Jet& x1) {
    add(high, x0, x1);
    low_sq += low.v.array().square();
    damped = true;
  }
  // max over directions c of |e_c| / (atol + rtol max(|v_c(t)|, |v_c(t + h)|)), Euclidean norms:
  // each direction is held to rtol relative to its own size, the way a derivative's accuracy is
  // judged (|D dx - D_ref dx| / |D_ref dx|), not to the state's per-component scale.
  // Damped (DOP853), e_c is each direction's own |e5_c| gamma_c, gamma_c = |e5_c| / sqrt(|e5_c|^2 +
  // 0.01 |e3_c|^2): DOP853's rule applied to that direction as if it were a system of its own.
  // The state's gamma would not do: it is 0 wherever the state's estimate is (an equilibrium),
  // whatever the tangents do.
  double error(double rtol, double atol) const {
    const auto scale = atol + rtol * size0_sq.max(size1_sq).sqrt();
    if (!damped) return (error_sq.sqrt() / scale).maxCoeff();
    // |e5|^2 <= denominator^2, so the floor (reached only when both are 0) gives 0, not 0 / 0.
    const Eigen::Array<double, N, 1> denominator =
        (error_sq + 0.01 * low_sq).sqrt().max(std::numeric_limits<double>::min());
    return (error_sq / denominator / scale).maxCoeff();
  }
};

template <typename T, template <typename> class Method>
class Stepper {
 public:
  Stepper(const SegmentModel& model, Signs sides, const IntegratorOptions& options)
      : model_(&model),
        sides_(sides),
        options_(&options),
        d_(model.states()),
        n_(model.surfaces()),
        method_(d_),
        stage_(d_),
        scratch_(d_),
        next_(d_),
        values_(d_),
        h_values_(n_),
        g_(n_),
        g_next_(n_),
        theta_(n_),
        g_trial_(n_),
        rate_(n_),
        rate_next_(n_),
        probe_(n_),
        g_middle_(n_),
        velocity_(d_),
        field_(d_),
        ratios_(d_),
        armed_(n_) {}

  /** Whether this stepper's storage fits `model` (the same d and n). */
  bool fits(const SegmentModel& model) const {
    return model.states() == d_ && model.surfaces() == n_;
  }
  /** The next segment's model, sides and options, in the storage of the last (fits()). */
  void bind(const SegmentModel& model, Signs sides, const IntegratorOptions& options) {
    model_ = &model;
    sides_ = sides;
    options_ = &options;
  }

  SegmentResult run(double t0, double t_end, std::vector<T>& x, bool watch) {
    SegmentResult result;
    result_ = &result;
    double t = t0;
    result.t = t;
    if (watch) {
      surface_g(x, g_);
      for (int j = 0; j < n_; ++j) armed_[j] = g_[j] > 0.0;
    }
    if (!field(x, method_.first(), t, result)) return result;
    for (int i = 0; i < d_; ++i) {
      // Every later step starts from a field checked finite (error_norm()); the first one too.
      if (!all_finite(method_.first()[i])) {
        return fail(result, IntegrationStatus::kNonFinite, t, x,
                    label() + ": F_b(x) row " + std::to_string(i) + " is non-finite (" +
                        format_number(value_of(method_.first()[i])) +
                        ") at t = " + format_number(t) + ", x = " + format_vector(values(x)) +
                        " (b = \"" + sides_.str() + "\")");
      }
    }
    if (watch && n_ > 0) surface_g_and_rates(x, method_.first(), g_, rate_);
    // The estimate can be tiny when x0 is near zero; steps then grow by up to 5x each. One that
    // is not a positive number (a field of 1e300 makes its ratios 0/0) starts at the floor.
    const double first_floor = 10 * options_->min_step * std::max(1.0, std::abs(t0));
    double h = options_->initial_step;
    if (!(h > 0.0)) {
      const double estimate = initial_step(x, t0, t_end);
      h = estimate > first_floor ? estimate : first_floor;
    }
    bool rejected_last = false;
    // Bounded: accepted steps by max_steps, rejected ones by max_steps too, and the rejections
    // in a row by the step size, which each one divides by at least 1 / 0.9 down to its floor
    // (the tests against the floor are written to hold for a NaN step as well).
    while (true) {
      h = std::min(h, options_->max_step);
      // Within 1% of the end, stretch the step to land on it (no sliver of a last step).
      const bool last = t + 1.01 * h >= t_end;
      if (last) h = t_end - t;
      if (result.steps >= options_->max_steps) {
        return fail(result, IntegrationStatus::kTooManySteps, t, x,
                    label() + ": max_steps = " + std::to_string(options_->max_steps) +
                        " steps taken, stopped at t = " + format_number(t) +
                        " before t_end = " + format_number(t_end));
      }
      if (result.rejected_steps >= options_->max_steps) {
        return fail(result, IntegrationStatus::kTooManySteps, t, x,
                    label() + ": max_steps = " + std::to_string(options_->max_steps) +
                        " rejected steps (and " + std::to_string(result.steps) +
                        " accepted), stopped at t = " + format_number(t) +
                        " before t_end = " + format_number(t_end));
      }
      if (!attempt(x, h, t, result)) return result;
      const double error = error_norm(x);
      const double floor = options_->min_step * std::max(1.0, std::abs(t));
      if (std::isnan(error)) {
        // A non-finite trial state: retry smaller, as a rejection.
        ++result.rejected_steps;
        h *= 0.2;
        rejected_last = true;
        if (!(h > floor)) {
          return fail(
              result, IntegrationStatus::kNonFinite, t, x,
              label() + ": the state becomes non-finite just after t = " + format_number(t));
        }
        continue;
      }
      if (error > 1.0) {  // +inf included: an error beyond the double range relative to atol
        ++result.rejected_steps;
        h *= std::max(0.2, 0.9 * std::pow(error, -Stages::kExponent));
        rejected_last = true;
        if (!(h > floor)) {
          return fail(result, IntegrationStatus::kStepSizeUnderflow, t, x,
                      label() + ": step size " + format_number(h) + " underflows at t = " +
                          format_number(t) + " (min_step " + format_number(options_->min_step) +
                          " relative to max(1, |t|)): the error estimate " + format_number(error) +
                          " does not fall as the step shrinks");
        }
        continue;
      }
      ++result.steps;
      if (!last && t + h == t) {
        return fail(result, IntegrationStatus::kStepSizeUnderflow, t, x,
                    label() + ": step size " + format_number(h) + " no longer advances t = " +
                        format_number(t) + " (the tolerances ask for more than double precision)");
      }
      if (watch && n_ > 0) {
        double theta = 0.0;
        if (locate_crossing(x, h, theta, result.crossed)) {
          dense(x, h, theta, next_);
          x = next_;
          result.t = t + theta * h;
          result.crossing_times.assign(static_cast<std::size_t>(n_), INFINITY);
          for (int j = 0; j < n_; ++j) {
            const double theta_j = theta_[static_cast<std::size_t>(j)];
            if (theta_j <= 1.0)
              result.crossing_times[static_cast<std::size_t>(j)] = t + theta_j * h;
          }
          result.status = IntegrationStatus::kCrossing;
          return result;
        }
      }
      t = last ? t_end : t + h;
      x.swap(next_);
      method_.accept();  // first same as last
      if (last) {
        result.t = t;
        result.status = IntegrationStatus::kReachedEnd;
        return result;
      }
      const double grow =
          error == 0.0 ? 5.0
                       : std::min(5.0, std::max(0.2, 0.9 * std::pow(error, -Stages::kExponent)));
      h *= rejected_last ? std::min(1.0, grow) : grow;
      rejected_last = false;
    }
  }

 private:
  bool field(const std::vector<T>& x, std::vector<T>& dx, double t, SegmentResult& result) {
    model_->field(x.data(), sides_, dx.data());
    ++result.field_evaluations;
    (void)t;
    return true;
  }

  Eigen::VectorXd values(const std::vector<T>& x) const {
    Eigen::VectorXd out(d_);
    for (int i = 0; i < d_; ++i) out[i] = value_of(x[i]);
    return out;
  }

  SegmentResult& fail(SegmentResult& result, IntegrationStatus status, double t,
                      const std::vector<T>&, std::string message) {
    result.status = status;
    result.t = t;
    result.message = std::move(message);
    return result;
  }

  double scale(double a, double b) const {
    return options_->absolute_tolerance() + options_->rtol * std::max(std::abs(a), std::abs(b));
  }

  double initial_step(const std::vector<T>& x, double t0, double t_end) {
    // Hairer, Norsett & Wanner, Solving ODEs I, II.4: from the size of x, x' and x''.
    double size0 = 0, size1 = 0;
    for (int i = 0; i < d_; ++i) {
      const double s = scale(value_of(x[i]), 0.0);
      size0 += std::pow(value_of(x[i]) / s, 2);
      size1 += std::pow(value_of(method_.first()[i]) / s, 2);
    }
    size0 = std::sqrt(size0 / d_);
    size1 = std::sqrt(size1 / d_);
    double h0 = (size0 < 1e-5 || size1 < 1e-5) ? 1e-6 : 0.01 * size0 / size1;
    h0 = std::min(h0, t_end - t0);
    // A field or state beyond the double range once scaled (ratios inf / inf, 0 / 0): no
    // estimate; the caller starts from its floor.
    if (!(h0 > 0.0) || !std::isfinite(h0)) return 0.0;
    for (int i = 0; i < d_; ++i) stage_[i] = x[i] + h0 * method_.first()[i];
    model_->field(stage_.data(), sides_, scratch_.data());
    double size2 = 0;
    for (int i = 0; i < d_; ++i) {
      size2 += std::pow(value_of(scratch_[i] - method_.first()[i]) / scale(value_of(x[i]), 0.0), 2);
    }
    size2 = std::sqrt(size2 / d_) / h0;
    const double h1 = std::max(size1, size2) <= 1e-15
                          ? std::max(1e-6, h0 * 1e-3)
                          : std::pow(0.01 / std::max(size1, size2), Stages::kExponent);
    return std::min(100 * h0, h1);
  }

  // One trial step from x: fills the stages and next_ (method_.last() = F(next_)).
  bool attempt(const std::vector<T>& x, double h, double t, SegmentResult& result) {
    method_.attempt(x, h, t, stage_, next_,
                    [&](const std::vector<T>& in, std::vector<T>& out, double at) {
                      field(in, out, at, result);
                    });
    last_h_ = h;
    last_t_ = t;
    return true;
  }

  // The RMS over components of |e_i| / (atol + rtol max(|x_i|, |x_i(t + h)|)): NaN when the
  // trial state or its field is not finite, +inf only when the norm itself is beyond the double
  // range (a tiny atol), never a spurious one from squaring a large ratio.
  double error_norm(const std::vector<T>& x) {
    double sum = 0;
    const bool tangents = options_->tangents_in_error_norm;
    if (tangents) tangent_norm_.clear();
    for (int i = 0; i < d_; ++i) {
      if (!all_finite(next_[i]) || !all_finite(method_.last()[i])) return NAN;
    }
    method_.prepare_error(last_h_,
                          [&](int i) { return scale(value_of(x[i]), value_of(next_[i])); });
    for (int i = 0; i < d_; ++i) {
      ratios_[i] = method_.error_value(i, last_h_) / scale(value_of(x[i]), value_of(next_[i]));
      sum += ratios_[i] * ratios_[i];
      if constexpr (!std::is_same_v<T, double>) {
        if (tangents) method_.add_tangent_error(i, last_h_, x[i], next_[i], tangent_norm_);
      }
    }
    double state = std::sqrt(sum / d_);
    if (!std::isfinite(state)) {
      // A ratio above 1e154: the same norm with the largest ratio factored out.
      double largest = 0.0;
      for (int i = 0; i < d_; ++i) largest = std::max(largest, std::abs(ratios_[i]));
      sum = 0.0;
      if (std::isfinite(largest)) {
        for (int i = 0; i < d_; ++i) sum += std::pow(ratios_[i] / largest, 2);
      }
      state = std::isfinite(largest) ? largest * std::sqrt(sum / d_) : largest;
    }
    if (!tangents) return state;
    return std::max(state, tangent_norm_.error(options_->rtol, options_->absolute_tolerance()));
  }

  // x(t + theta h) on the dense output of the last accepted step.
  void dense(const std::vector<T>& x, double h, double theta, std::vector<T>& out) {
    prepare_dense(x, h);
    for (int i = 0; i < d_; ++i) out[i] = method_.dense(i, x[i], next_[i], h, theta);
  }

  // x(t + theta h) on the dense output, values only, into values_.
  void dense_values(const std::vector<T>& x, double h, double theta) {
    prepare_dense(x, h);
    for (int i = 0; i < d_; ++i) {
      values_[i] = method_.dense_value(i, value_of(x[i]), value_of(next_[i]), h, theta);
    }
  }

  // The method's extra stages for its dense output, if it has any (once per step).
  void prepare_dense(const std::vector<T>& x, double h) {
    method_.prepare_dense(x, h, last_t_, stage_,
                          [&](const std::vector<T>& in, std::vector<T>& out, double) {
                            model_->field(in.data(), sides_, out.data());
                            ++result_->field_evaluations;
                          });
  }

  // g at theta on the dense output, values only.
  void dense_g(const std::vector<T>& x, double h, double theta, std::vector<double>& g) {
    dense_values(x, h, theta);
    signed_surfaces(g);
  }

  void signed_surfaces(std::vector<double>& g) {
    model_->surface_values(values_.data(), h_values_.data());
    for (int j = 0; j < n_; ++j) g[j] = sides_.plus(j) ? h_values_[j] : -h_values_[j];
  }

  void surface_g(const std::vector<T>& x, std::vector<double>& g) {
    for (int i = 0; i < d_; ++i) values_[i] = value_of(x[i]);
    signed_surfaces(g);
  }

  // g_j and dg_j/dt = s_j Dh_j(x) . f at x, moving along the field f: one evaluation of the
  // surfaces on Jets (SegmentModel::surface_rates), no difference quotient.
  void surface_g_and_rates(const std::vector<T>& x, const std::vector<T>& f, std::vector<double>& g,
                           std::vector<double>& rate) {
    for (int i = 0; i < d_; ++i) {
      values_[i] = value_of(x[i]);
      velocity_[i] = value_of(f[i]);
    }
    model_->surface_rates(values_.data(), velocity_.data(), h_values_.data(), probe_.data());
    for (int j = 0; j < n_; ++j) {
      const double s = sides_.plus(j) ? 1.0 : -1.0;
      g[j] = s * h_values_[j];
      rate[j] = s * probe_[j];
    }
  }

  // The rounding error of g_j on the dense output of a step with end values g0, g1 and end
  // rates s0, s1 (per unit theta): a few ulps of the largest term of the interpolant.
  static double rounding(double g0, double g1, double s0, double s1) {
    return 16 * std::numeric_limits<double>::epsilon() *
           std::max({std::abs(g0), std::abs(g1), std::abs(s0), std::abs(s1)});
  }

  // The minimum over theta in [0, 1] of the quartic q with q(0) = g0, q(1) = g1, q'(0) = s0,
  // q'(1) = s1 and q(1/2) = g_half: the cubic Hermite interpolant plus c theta^2 (1 - theta)^2.
  // On 16 cells; refined by golden sections only when a cell is below both ends (a dip), so that
  // the common case (g_j monotone towards an end) costs 17 evaluations of q and nothing else.
  static double quartic_minimum(double g0, double g1, double s0, double s1, double g_half) {
    const double hermite_half = 0.5 * (g0 + g1) + 0.125 * (s0 - s1);
    const double c = 16.0 * (g_half - hermite_half);
    const auto q = [&](double t) {
      const double t2 = t * t, t3 = t2 * t, u = t * (1.0 - t);
      return (2 * t3 - 3 * t2 + 1) * g0 + (t3 - 2 * t2 + t) * s0 + (3 * t2 - 2 * t3) * g1 +
             (t3 - t2) * s1 + c * u * u;
    };
    constexpr int kCells = 16;
    int best = 0;
    double q_best = g0;
    for (int i = 1; i <= kCells; ++i) {
      const double value = q(static_cast<double>(i) / kCells);
      if (value < q_best) best = i, q_best = value;
    }
    if (!(q_best < std::min(g0, g1))) return q_best;
    double a = std::max(0, best - 1) / static_cast<double>(kCells);
    double b = std::min(kCells, best + 1) / static_cast<double>(kCells);
    for (int iteration = 0; iteration < 16; ++iteration) {
      const double u = a + 0.3819660112501051 * (b - a), v = b - 0.3819660112501051 * (b - a);
      const double q_u = q(u), q_v = q(v);
      q_best = std::min({q_best, q_u, q_v});
      (q_u < q_v ? b : a) = q_u < q_v ? v : u;
    }
    return q_best;
  }

  // Brent's minimisation (values only) of sigma g_j on the dense output over theta in (0, 1): a
  // local minimum (sigma = +1) or maximum (sigma = -1). theta to about sqrt(eps), which puts the
  // value within a few ulps of the extreme value (the error is quadratic in theta). Returns
  // theta; g_at is g_j there.
  double extremum(const std::vector<T>& x, double h, int j, double sigma, double& g_at) {
    constexpr double kGolden = 0.3819660112501051;  // (3 - sqrt(5)) / 2
    constexpr double kRelative = 1.5e-8;
    constexpr double kAbsolute = 1e-12;
    const auto f = [&](double theta) {
      dense_g(x, h, theta, g_trial_);
      return sigma * g_trial_[static_cast<std::size_t>(j)];
    };
    double a = 0.0, b = 1.0;
    // best: lowest value so far; second: the one before; third: the one before that.
    double best = kGolden, second = best, third = best;
    double f_best = f(best), f_second = f_best, f_third = f_best;
    double step = 0.0, previous = 0.0;
    for (int iteration = 0; iteration < 100; ++iteration) {
      const double middle = 0.5 * (a + b);
      const double tol1 = kRelative * std::abs(best) + kAbsolute;
      const double tol2 = 2.0 * tol1;
      if (std::abs(best - middle) <= tol2 - 0.5 * (b - a)) break;
      bool golden = true;
      if (std::abs(previous) > tol1) {
        // Parabola through the three best points.
        const double r = (best - second) * (f_best - f_third);
        double q = (best - third) * (f_best - f_second);
        double p = (best - third) * q - (best - second) * r;
        q = 2.0 * (q - r);
        if (q > 0.0) p = -p;
        q = std::abs(q);
        const double before = previous;
        previous = step;
        if (std::abs(p) < std::abs(0.5 * q * before) && p > q * (a - best) && p < q * (b - best)) {
          step = p / q;
          const double u = best + step;
          if (u - a < tol2 || b - u < tol2) step = middle >= best ? tol1 : -tol1;
          golden = false;
        }
      }
      if (golden) {
        previous = best >= middle ? a - best : b - best;
        step = kGolden * previous;
      }
      const double u = std::abs(step) >= tol1 ? best + step : best + (step > 0.0 ? tol1 : -tol1);
      const double f_u = f(u);
      if (f_u <= f_best) {
        (u >= best ? a : b) = best;
        third = second;
        f_third = f_second;
        second = best;
        f_second = f_best;
        best = u;
        f_best = f_u;
      } else {
        (u < best ? a : b) = u;
        if (f_u <= f_second || second == best) {
          third = second;
          f_third = f_second;
          second = u;
          f_second = f_u;
        } else if (f_u <= f_third || third == best || third == second) {
          third = u;
          f_third = f_u;
        }
      }
    }
    g_at = sigma * f_best;
    return best;
  }

  // Illinois iteration on [lo, hi] with g_j(lo) > 0 >= g_j(hi), to a few ulps of theta: the root
  // when g_j changes sign once there. Returns a theta where g_j <= 0.
  double root(const std::vector<T>& x, double h, int j, double lo, double hi, double g_lo,
              double g_hi) {
    int side = 0;
    std::vector<double>& g = g_trial_;
    for (int iteration = 0; iteration < 100 && hi - lo > 4e-16; ++iteration) {
      double mid = (lo * g_hi - hi * g_lo) / (g_hi - g_lo);
      if (!(mid > lo && mid < hi)) mid = 0.5 * (lo + hi);
      dense_g(x, h, mid, g);
      if (g[j] > 0.0) {
        lo = mid;
        g_lo = g[j];
        if (side == -1) g_hi *= 0.5;
        side = -1;
      } else {
        hi = mid;
        g_hi = g[j];
        if (side == 1) g_lo *= 0.5;
        side = 1;
      }
    }
    return hi;
  }

  // dg_j/dt = s_j Dh_j(x) . F_b(x) at theta on the dense output, with the model's own field and
  // normals (Jets): the quantity the driver's transversality test is made of.
  double exact_rate(const std::vector<T>& x, double h, int j, double theta) {
    dense_values(x, h, theta);
    model_->field(values_.data(), sides_, field_.data());
    ++result_->field_evaluations;
    const Eigen::Map<const Eigen::VectorXd> state(values_.data(), d_);
    const Eigen::MatrixXd normals = model_->surface_normals(state);
    const double rate = normals.row(j).dot(Eigen::Map<const Eigen::VectorXd>(field_.data(), d_));
    return sides_.plus(j) ? rate : -rate;
  }

  // Where g_j touches zero near theta: the zero of dg_j/dt (from - to +), by bisection to a few
  // ulps of theta. A crossing reported there reaches the driver with eta . F ~ 0, which it
  // rejects as grazing; Brent's theta (sqrt(eps)) would leave eta . F ~ 1e-8 instead.
  double tangency(const std::vector<T>& x, double h, int j, double theta) {
    double lo = std::max(0.0, theta - 1e-6), hi = std::min(1.0, theta + 1e-6);
    if (!(exact_rate(x, h, j, lo) < 0.0 && exact_rate(x, h, j, hi) >= 0.0)) {
      lo = 0.0;
      hi = 1.0;
      if (!(exact_rate(x, h, j, lo) < 0.0 && exact_rate(x, h, j, hi) >= 0.0)) return theta;
    }
    for (int iteration = 0; iteration < 100 && hi - lo > 4e-16; ++iteration) {
      const double mid = 0.5 * (lo + hi);
      if (!(mid > lo && mid < hi)) break;
      (exact_rate(x, h, j, mid) < 0.0 ? lo : hi) = mid;
    }
    return hi;
  }

  // The band of a near miss at theta: kBandFactor sum_i |dh_j/dx_i| (atol + rtol |x_i|), the
  // change of g_j under a state error of one tolerance unit in every component.
  double miss_band(const std::vector<T>& x, double h, int j, double theta) {
    dense_values(x, h, theta);
    const Eigen::Map<const Eigen::VectorXd> state(values_.data(), d_);
    const Eigen::MatrixXd normals = model_->surface_normals(state);
    const double atol = options_->absolute_tolerance();
    double band = 0.0;
    for (int i = 0; i < d_; ++i) {
      band += std::abs(normals(j, i)) * (atol + options_->rtol * std::abs(values_[i]));
    }
    return kBandFactor * band;
  }

  // After an accepted step x -> next_: the first crossing in (0, 1], if any. Besides the sign
  // changes of g_j between the ends, a watched g_j that is > 0 at both ends may dip to <= 0 and
  // come back inside the step (a crossing pair near a tangency), and an unwatched one (<= 0 at
  // both ends, e.g. just crossed) may rise above 0 and come back. Both are looked for only where
  // the end values and rates allow them (cheap tests below); then the extreme of g_j on the
  // dense output is found and, if it is on the other side, the crossing is located before it
  // (after it for the rise). A minimum that stays > 0 within the error band is a NearMiss.
  bool locate_crossing(const std::vector<T>& x, double h, double& theta_first,
                       std::vector<int>& crossed) {
    surface_g_and_rates(next_, method_.last(), g_next_, rate_next_);
    std::vector<double>& theta = theta_;
    std::fill(theta.begin(), theta.end(), 2.0);
    misses_.clear();
    bool any = false;
    bool have_middle = false;  // g at theta = 1/2, computed once for all surfaces when needed
    for (int j = 0; j < n_; ++j) {
      const auto js = static_cast<std::size_t>(j);
      const double g0 = g_[js], g1 = g_next_[js];
      const double s0 = h * rate_[js], s1 = h * rate_next_[js];  // dg_j/dtheta at the ends
      if (!armed_[js]) {
        armed_[js] = g1 > 0.0;
        // Out to the watched side and back within the step: a maximum of g_j above zero.
        if (g1 <= 0.0 && s0 > 0.0 && s1 < 0.0) {
          double g_max = 0.0;
          const double top = extremum(x, h, j, -1.0, g_max);
          if (g_max > rounding(g0, g1, s0, s1)) {
            theta[js] = root(x, h, j, top, 1.0, g_max, g1);
            any = true;
          }
        }
        continue;
      }
      if (g1 <= 0.0) {
        theta[js] = root(x, h, j, 0.0, 1.0, g0, g1);
        any = true;
        continue;
      }
      // g_j > 0 at both ends. It can dip inside only if it turns (falling at the start, rising
      // at the end) or if it is small against what it changes in one step at the end rates.
      const bool turns = s0 < 0.0 && s1 > 0.0;
      const bool close = std::min(g0, g1) <= std::max(std::abs(s0), std::abs(s1));
      if (!turns && !close) continue;
      // Then a quartic model of g_j on the step (exact for an affine h_j): the searches below
      // run only if it comes below half the lower end value somewhere inside.
      if (!have_middle) {
        dense_g(x, h, 0.5, g_middle_);
        have_middle = true;
      }
      if (!(quartic_minimum(g0, g1, s0, s1, g_middle_[js]) < 0.5 * std::min(g0, g1))) continue;
      double g_min = 0.0;
      const double bottom = extremum(x, h, j, 1.0, g_min);
      const double noise = rounding(g0, g1, s0, s1);
      if (g_min < -noise) {
        theta[js] = root(x, h, j, 0.0, bottom, g0, g_min);
        any = true;
        continue;
      }
      if (g_min <= noise) {
        // Zero to rounding at an interior minimum: a touch, reported at the tangency itself.
        if (std::min(g0, g1) > 2.0 * noise) {
          theta[js] = tangency(x, h, j, bottom);
          any = true;
        }
        continue;
      }
      // The closest approach: inside the step when the rates turn (it may then sit at an end,
      // to the accuracy of the rates), or wherever g_j is below both ends.
      double closest = bottom, g_closest = g_min;
      if (turns && g0 < g_closest) closest = 0.0, g_closest = g0;
      if (turns && g1 < g_closest) closest = 1.0, g_closest = g1;
      if (!turns && !(g_min < std::min(g0, g1) - noise)) continue;
      const double band = miss_band(x, h, j, closest);
      if (g_closest < band) {
        misses_.push_back({NearMiss{j, last_t_ + closest * h, g_closest, band}, closest});
      }
    }
    const double first =
        any ? *std::min_element(theta.begin(), theta.end()) : std::numeric_limits<double>::max();
    for (const auto& [miss, at] : misses_) {
      if (at <= first) result_->near_misses.push_back(miss);
    }
    if (!any) {
      g_.swap(g_next_);
      rate_.swap(rate_next_);
      return false;
    }
    theta_first = first;
    // Crossings within a few ulps of the first are the same crossing.
    const double same = 8e-16 * std::max(1.0, 1.0 / h);
    for (int j = 0; j < n_; ++j) {
      if (theta[static_cast<std::size_t>(j)] <= theta_first + same) crossed.push_back(j);
    }
    return true;
  }

  // A near miss is a minimum g_min > 0 below kBandFactor tolerance units (miss_band()).
  static constexpr double kBandFactor = 8.0;

  const SegmentModel* model_;
  Signs sides_;
  const IntegratorOptions* options_;
  const int d_;
  const int n_;
  using Stages = Method<T>;
  static std::string label() { return Stages::kName; }

  Stages method_;
  std::vector<T> stage_, scratch_, next_;
  std::vector<double> values_, h_values_, g_, g_next_;
  TangentNorm<T> tangent_norm_;
  std::vector<double> theta_, g_trial_;  // scratch of locate_crossing(), no allocation per step
  // dg_j/dt at x and at next_, and scratch of surface_g_and_rates().
  std::vector<double> rate_, rate_next_, probe_, g_middle_, velocity_;
  std::vector<double> field_;   // F_b at a dense-output point (exact_rate())
  std::vector<double> ratios_;  // |e_i| / scale_i of the last trial step (error_norm())
  // Near misses of the step being checked, with their theta; kept if not after the crossing.
  std::vector<std::pair<NearMiss, double>> misses_;
  SegmentResult* result_ = nullptr;  // the result run() is filling
  std::vector<char> armed_;
  double last_h_ = 0.0;
  double last_t_ = 0.0;  // start of the last attempted step
};

template <typename T, template <typename> class Method>
SegmentResult rk_segment(const SegmentModel& model, Signs sides, double t0, double t_end,
                         const std::vector<T>& x0, const IntegratorOptions& options,
                         std::vector<T>* x_out, bool watch) {
  std::vector<T> x = x0;
  Stepper<T, Method> stepper(model, sides, options);
  SegmentResult result = stepper.run(t0, t_end, x, watch);
  *x_out = std::move(x);
  return result;
}

// The steppers an integrator object keeps between the segments it integrates, one per Jet width
// met: a run of many short segments (a bouncing ball, a gait) builds its stage vectors once, not
// once a segment. A stepper is rebuilt when the model's d or n changes. Not shared between
// threads (an integrator object is used by one thread at a time: integrate() is not const).
template <template <typename> class Method>
class StepperCache {
 public:
  template <typename T>
  Stepper<T, Method>& get(const SegmentModel& model, Signs sides,
                          const IntegratorOptions& options) {
    auto& slot = std::get<std::unique_ptr<Stepper<T, Method>>>(slots_);
    if (slot && slot->fits(model)) {
      slot->bind(model, sides, options);
    } else {
      slot = std::make_unique<Stepper<T, Method>>(model, sides, options);
    }
    return *slot;
  }

 private:
  template <typename... Ts>
  using Slots = std::tuple<std::unique_ptr<Stepper<Ts, Method>>...>;
  Slots<double, Jet1, Jet2, Jet4, Jet6, JetChunk, Jet12, Jet16> slots_;
};

inline void check_request(const std::string& name, const SegmentModel& model,
                          const SegmentRequest& request, const IntegratorOptions& options) {
  const int d = model.states();
  if (request.x0.size() != d || (request.v0.size() > 0 && request.v0.rows() != d)) {
    throw InvalidArgument(name + ": x0 has " + std::to_string(request.x0.size()) +
                          " numbers and the tangents " + std::to_string(request.v0.rows()) +
                          " rows; the model has d = " + std::to_string(d) + " states");
  }
  if (!request.x0.allFinite() || !request.v0.allFinite()) {
    throw InvalidArgument(name +
                          ": x0 or the tangents are not finite: x0 = " + format_vector(request.x0));
  }
  if (request.sides.size() != model.surfaces()) {
    throw InvalidArgument(name + ": sides \"" + request.sides.str() + "\" name " +
                          std::to_string(request.sides.size()) + " surfaces, the model has " +
                          std::to_string(model.surfaces()));
  }
  if (!(request.t_end >= request.t0) || !std::isfinite(request.t_end)) {
    throw InvalidArgument(name + ": need finite t_end >= t0, got t0 = " +
                          format_number(request.t0) + ", t_end = " + format_number(request.t_end));
  }
  if (!(options.rtol >= IntegratorOptions::kMinRtol) || !std::isfinite(options.rtol) ||
      !(options.absolute_tolerance() >= IntegratorOptions::kMinAtol) ||
      !std::isfinite(options.absolute_tolerance())) {
    throw InvalidArgument(name +
                          ": need a finite rtol >= " + format_number(IntegratorOptions::kMinRtol) +
                          " and a finite atol >= " + format_number(IntegratorOptions::kMinAtol) +
                          ", got rtol = " + format_number(options.rtol) +
                          ", atol = " + format_number(options.absolute_tolerance()));
  }
  if (!(options.initial_step >= 0.0) || !(options.min_step >= 0.0) || !(options.max_step > 0.0) ||
      !std::isfinite(options.initial_step) || !std::isfinite(options.min_step)) {
    throw InvalidArgument(name + ": need initial_step >= 0, min_step >= 0 and max_step > 0, got " +
                          format_number(options.initial_step) + ", " +
                          format_number(options.min_step) + ", " + format_number(options.max_step));
  }
  if (options.max_steps < 1) {
    throw InvalidArgument(name + ": max_steps must be positive, got " +
                          std::to_string(options.max_steps));
  }
}

template <typename T, template <typename> class Method>
SegmentResult run_chunk(const SegmentModel& model, const SegmentRequest& request,
                        const IntegratorOptions& options, double t_end, Eigen::Index first,
                        int width, bool watch, Eigen::MatrixXd* v, StepperCache<Method>& cache) {
  const int d = model.states();
  std::vector<T> x(static_cast<std::size_t>(d));
  for (int i = 0; i < d; ++i) {
    if constexpr (std::is_same_v<T, double>) {
      x[i] = request.x0[i];
    } else {
      x[i] = T(request.x0[i]);
      for (int c = 0; c < width; ++c) x[i].v[c] = request.v0(i, first + c);
    }
  }
  SegmentResult result =
      cache.template get<T>(model, request.sides, options).run(request.t0, t_end, x, watch);
  result.x.resize(d);
  for (int i = 0; i < d; ++i) {
    if constexpr (std::is_same_v<T, double>) {
      result.x[i] = x[i];
    } else {
      result.x[i] = x[i].a;
      for (int c = 0; c < width; ++c) (*v)(i, first + c) = x[i].v[c];
    }
  }
  return result;
}

// A whole segment for a method: the state alone, or k tangents in chunks.
template <template <typename> class Method>
SegmentResult integrate_chunks(const SegmentModel& model, const SegmentRequest& request,
                               const IntegratorOptions& options, StepperCache<Method>& cache) {
  check_request(Method<double>::kName, model, request, options);
  const Eigen::Index k = request.v0.cols();
  Eigen::MatrixXd v(model.states(), k);
  if (k == 0) {
    SegmentResult result =
        run_chunk<double, Method>(model, request, options, request.t_end, 0, 0, true, &v, cache);
    result.v = v;
    return result;
  }
  // The first chunk finds where the segment ends; the others integrate to exactly there.
  SegmentResult result;
  for (Eigen::Index first = 0; first < k; first += kFlowChunk) {
    const int width = static_cast<int>(std::min<Eigen::Index>(kFlowChunk, k - first));
    const bool watch = first == 0;
    const double t_end = watch ? request.t_end : result.t;
    SegmentResult chunk;
    switch (flow_tangent_width(width)) {
      case 1:
        chunk =
            run_chunk<Jet1, Method>(model, request, options, t_end, first, width, watch, &v, cache);
        break;
      case 2:
        chunk =
            run_chunk<Jet2, Method>(model, request, options, t_end, first, width, watch, &v, cache);
        break;
      case 4:
        chunk =
            run_chunk<Jet4, Method>(model, request, options, t_end, first, width, watch, &v, cache);
        break;
      case 6:
        chunk =
            run_chunk<Jet6, Method>(model, request, options, t_end, first, width, watch, &v, cache);
        break;
      case 8:
        chunk = run_chunk<JetChunk, Method>(model, request, options, t_end, first, width, watch, &v,
                                            cache);
        break;
      case 12:
        chunk = run_chunk<Jet12, Method>(model, request, options, t_end, first, width, watch, &v,
                                         cache);
        break;
      default:
        chunk = run_chunk<Jet16, Method>(model, request, options, t_end, first, width, watch, &v,
                                         cache);
        break;
    }
    if (watch) {
      result = std::move(chunk);
      const bool stopped = result.status == IntegrationStatus::kReachedEnd ||
                           result.status == IntegrationStatus::kCrossing;
      if (!stopped) break;  // a failure: the other chunks would fail the same way
      continue;
    }
    result.field_evaluations += chunk.field_evaluations;
    if (chunk.status != IntegrationStatus::kReachedEnd) {
      result.status = chunk.status;
      result.message = chunk.message;
      break;
    }
  }
  result.v = v;
  return result;
}

}  // namespace bflow::explicit_rk

#endif  // BFLOW_INTEGRATORS_SRC_EXPLICIT_RK_STEPPER_H_

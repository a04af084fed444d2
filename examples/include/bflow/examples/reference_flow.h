// ReferenceFlow: an independent, event-driven simulation of a bflow model in long double, and
// the one-sided differences of its flow. It shares no code with bflow's engine (it uses only
// the model contract of bflow/core/model.h and bflow::Signs) and serves as the reference
// against which the engine's flow and B-derivative are checked.
//
//   bflow::examples::ReferenceFlow<ThreeSurfaces> ref(ThreeSurfaces{});
//   auto x0 = ref.backward(rho, 1.0L, bflow::Signs(3));      // phi_{-1}(rho), sides ---
//   auto run = ref.flow(x0, 1.5L);                            // x(1.5) and the crossings
//   auto d = ref.richardson(x0, dx, 1.5L, 1e-6L);             // one-sided D phi(x0; dx)
//
// Method. A fixed step h = t / ceil(t / max_step) of Butcher's seven-stage, sixth-order
// explicit Runge-Kutta method (J. C. Butcher, 1964; tableau below, its order checked by step
// halving in the test). After each step the surfaces are evaluated; a surface whose sign disagrees
// with its side has been crossed. For each such surface the crossing is located by bisection on the
// length tau of a Runge-Kutta step from the step's start (to kTimeResolution = 1e-20 in tau),
// the earliest one is taken (the lower index on a tie), the state is advanced to the end of
// its bracket (just past the surface), its side flips, and the rest of the step is integrated
// again with the new field, looking for further crossings. Side + of surface j means
// h_j > 0. The step grid does not move: crossings only split the step they fall in.
//
// Guarantees and limits. Crossings are assumed transversal and at most one crossing of the
// same surface per step (sliding, grazing and chattering are not detected). Every crossing
// is recorded in the order it happened. All arithmetic is long double (64-bit mantissa,
// eps = 1.1e-19 on x86-64); the state is summed with Kahan compensation, so that rounding
// does not accumulate over the steps (uncompensated it reaches ~1e-17, which a difference
// quotient divides by alpha).
//
// Accuracy (measured in reference_flow_test.cc on ThreeSurfaces, t = 1.5, |x| ~ 2, unit dx):
//  - the flow: the method is sixth order (halving the step divides the error on a smooth
//    segment by 62.7 to 63.3); at the default step 2^-9 the flow is accurate to ~1e-17, and
//    a trajectory placed by backward() reaches the triple crossing at t = 1 to ~1e-19;
//  - richardson(x, dx, t, alpha) = 2 D(alpha/2) - D(alpha), D(a) = (phi(x + a dx) - phi(x)) / a:
//    inside one crossing order the flow is smooth in a (a selection function), so R has a
//    truncation error O(alpha^2) (up to 7e-13 at alpha = 1e-6) plus rounding ~2e-19 / alpha;
//    at alpha = 1e-6 and the default step, halving the step changes R by 2.3e-13 relative,
//    halving alpha by 1.2e-12, while the plain D(alpha) is off by 1.6e-7 (its O(alpha) term);
//    on PiecewiseConstantField (exactly piecewise affine) R matches the closed form
//    (1 - delta)/(1 + delta) dx to 2e-14 and Algorithm 2.1's B to 3e-13;
//  - richardson2(x, dx, t, alpha) = (8 D(alpha/4) - 6 D(alpha/2) + D(alpha)) / 3 removes the
//    O(alpha^2) term too: at alpha = 5e-5 halving the step changes it by 1.4e-14, halving
//    alpha by 9.6e-14 (on the biped of bflow/core/biped.h: 4e-14 and 8e-14), so it is the
//    sharper reference (bench/accuracy.cc uses it);
//  - the base point must be on the nonsmooth trajectory in long double: from a start rounded
//    to double the "simultaneous" crossings are ~1e-16 apart and D carries ~1e-16 / alpha
//    (1e-10 at alpha = 1e-6). Use backward() from the crossing point.
#ifndef BFLOW_EXAMPLES_REFERENCE_FLOW_H_
#define BFLOW_EXAMPLES_REFERENCE_FLOW_H_

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/model.h"
#include "bflow/core/signs.h"

namespace bflow::examples {

/** A crossing of one surface by the reference simulation. */
struct ReferenceCrossing {
  long double t = 0.0L;
  int surface = -1;
};

template <typename Model>
class ReferenceFlow {
 public:
  using Vector = Eigen::Matrix<long double, Eigen::Dynamic, 1>;

  /** Bisection stops when the bracket on the step length is this short. */
  static constexpr long double kTimeResolution = 1e-20L;
  /** Default largest step; sixth order makes the flow accurate to ~1e-17 at |F| ~ 1. */
  static constexpr long double kDefaultMaxStep = 1.0L / 512;

  struct Result {
    Vector x;
    Signs sides;
    /** Every crossing, in the order it happened. */
    std::vector<ReferenceCrossing> crossings;
    long steps = 0;
  };

  /** A one-sided difference and the crossings of its perturbed runs. */
  struct Difference {
    Vector value;
    /** Crossings of phi(x + alpha dx) (the larger perturbation). */
    std::vector<ReferenceCrossing> crossings;
    /** Crossings of phi(x + alpha / 2 dx), for Richardson; empty for one_sided(). */
    std::vector<ReferenceCrossing> crossings_half;
  };

  explicit ReferenceFlow(Model model, long double max_step = kDefaultMaxStep)
      : model_(std::move(model)), max_step_(max_step) {
    if (!(max_step > 0.0L)) throw std::invalid_argument("ReferenceFlow: max_step must be > 0");
  }

  const Model& model() const { return model_; }
  long double max_step() const { return max_step_; }
  int states() const { return model_states(model_); }
  int surfaces() const { return model_surfaces(model_); }

  /** The sides of x: + where h_j(x) > 0. @throws std::invalid_argument if some h_j(x) = 0. */
  Signs sides_of(const Vector& x) const {
    const int n = surfaces();
    Vector h(n);
    if (n > 0) model_.surfaces(x.data(), h.data());
    Signs b(n);
    for (int j = 0; j < n; ++j) {
      if (h[j] == 0.0L) {
        throw std::invalid_argument("ReferenceFlow: x0 is on surface " + std::to_string(j));
      }
      if (h[j] > 0.0L) b = b.with_plus(j);
    }
    return b;
  }

  /** phi_t(x0) for t >= 0 with event detection; sides at x0 from h(x0) unless given. */
  Result flow(const Vector& x0, long double t, std::optional<Signs> sides = std::nullopt) const {
    if (!(t >= 0.0L)) throw std::invalid_argument("ReferenceFlow::flow: t must be >= 0");
    Work work(states(), surfaces());
    Result result;
    result.x = x0;
    result.sides = sides ? *sides : sides_of(x0);
    const long n_steps = std::max(1L, static_cast<long>(std::ceil(t / max_step_)));
    const long double h = t / static_cast<long double>(n_steps);
    for (long k = 0; k < n_steps; ++k) {
      const long double t0 = t * static_cast<long double>(k) / static_cast<long double>(n_steps);
      step_with_events(t0, h, &result, &work);
    }
    result.steps = n_steps;
    return result;
  }

  /** phi_{-t}(x) for t >= 0 with the sides fixed (the field F_sides integrated backwards, no
      event detection): places starts on a trajectory that reaches x at time t. */
  Vector backward(const Vector& x, long double t, Signs sides) const {
    if (!(t >= 0.0L)) throw std::invalid_argument("ReferenceFlow::backward: t must be >= 0");
    Work work(states(), surfaces());
    Vector y = x;
    const long n_steps = std::max(1L, static_cast<long>(std::ceil(t / max_step_)));
    const long double h = t / static_cast<long double>(n_steps);
    for (long k = 0; k < n_steps; ++k) {
      increment(y, -h, sides, &work.incr, &work);
      add_compensated(work.incr, &y, &work.compensation);
    }
    return y;
  }

  /** D(alpha) = (phi_t(x + alpha dx) - phi_t(x)) / alpha. */
  Difference one_sided(const Vector& x, const Vector& dx, long double t, long double alpha,
                       std::optional<Signs> sides = std::nullopt) const {
    const Result base = flow(x, t, sides);
    Result moved = flow(x + alpha * dx, t, sides);
    return Difference{(moved.x - base.x) / alpha, std::move(moved.crossings), {}};
  }

  /** R(alpha) = 2 D(alpha/2) - D(alpha): the one-sided directional derivative D phi_t(x; dx)
      with the O(alpha) term of the differences removed. */
  Difference richardson(const Vector& x, const Vector& dx, long double t, long double alpha,
                        std::optional<Signs> sides = std::nullopt) const {
    const Result base = flow(x, t, sides);
    Result full = flow(x + alpha * dx, t, sides);
    Result half = flow(x + (alpha / 2) * dx, t, sides);
    const Vector d_full = (full.x - base.x) / alpha;
    const Vector d_half = (half.x - base.x) / (alpha / 2);
    return Difference{2.0L * d_half - d_full, std::move(full.crossings), std::move(half.crossings)};
  }

  /** R2(alpha) = (4 R(alpha/2) - R(alpha)) / 3 = (8 D(alpha/4) - 6 D(alpha/2) + D(alpha)) / 3:
      the O(alpha^2) term removed as well. Truncation O(alpha^3), rounding ~15x that of one D,
      so it wants a larger alpha than R (see the accuracy notes above). */
  Difference richardson2(const Vector& x, const Vector& dx, long double t, long double alpha,
                         std::optional<Signs> sides = std::nullopt) const {
    const Result base = flow(x, t, sides);
    Result full = flow(x + alpha * dx, t, sides);
    Result half = flow(x + (alpha / 2) * dx, t, sides);
    const Result quarter = flow(x + (alpha / 4) * dx, t, sides);
    const Vector d_full = (full.x - base.x) / alpha;
    const Vector d_half = (half.x - base.x) / (alpha / 2);
    const Vector d_quarter = (quarter.x - base.x) / (alpha / 4);
    return Difference{(8.0L * d_quarter - 6.0L * d_half + d_full) / 3.0L, std::move(full.crossings),
                      std::move(half.crossings)};
  }

 private:
  // Butcher's sixth-order method: c, A (strictly lower triangular, row-major), b.
  static constexpr int kStages = 7;

  struct Work {
    Work(int d, int n)
        : k(kStages, Vector(d)),
          stage(d),
          incr(d),
          trial(d),
          compensation(Vector::Zero(d)),
          h_end(n),
          h_try(n),
          x_try(d) {}
    std::vector<Vector> k;
    Vector stage;
    Vector incr;
    Vector trial;
    // The low-order part of the state lost to rounding (Kahan summation of the increments).
    Vector compensation;
    Vector h_end;
    Vector h_try;
    Vector x_try;
  };

  static long double a(int i, int j) {
    static const long double kA[kStages][kStages] = {
        {0, 0, 0, 0, 0, 0, 0},
        {1.0L / 3, 0, 0, 0, 0, 0, 0},
        {0, 2.0L / 3, 0, 0, 0, 0, 0},
        {1.0L / 12, 1.0L / 3, -1.0L / 12, 0, 0, 0, 0},
        {-1.0L / 16, 9.0L / 8, -3.0L / 16, -3.0L / 8, 0, 0, 0},
        {0, 9.0L / 8, -3.0L / 8, -3.0L / 4, 1.0L / 2, 0, 0},
        {9.0L / 44, -9.0L / 11, 63.0L / 44, 18.0L / 11, 0, -16.0L / 11, 0}};
    return kA[i][j];
  }
  static long double b(int i) {
    static const long double kB[kStages] = {11.0L / 120, 0,          27.0L / 40, 27.0L / 40,
                                            -4.0L / 15,  -4.0L / 15, 11.0L / 120};
    return kB[i];
  }

  // The increment of one explicit Runge-Kutta step of length h (negative: backwards) with the
  // field F_sides: x(t + h) - x(t).
  void increment(const Vector& x, long double h, Signs sides, Vector* incr, Work* work) const {
    for (int i = 0; i < kStages; ++i) {
      work->stage = x;
      for (int j = 0; j < i; ++j) {
        const long double aij = a(i, j);
        if (aij != 0.0L) work->stage += (h * aij) * work->k[j];
      }
      model_.field(work->stage.data(), sides, work->k[i].data());
    }
    incr->setZero();
    for (int i = 0; i < kStages; ++i) {
      const long double bi = b(i);
      if (bi != 0.0L) *incr += (h * bi) * work->k[i];
    }
  }

  // x += incr with Kahan compensation: without it the rounding of x (1e-19 |x| per step)
  // accumulates over the steps to ~1e-17, which one-sided differences divide by alpha.
  static void add_compensated(const Vector& incr, Vector* x, Vector* compensation) {
    for (Eigen::Index i = 0; i < x->size(); ++i) {
      const long double y = incr[i] - (*compensation)[i];
      const long double sum = (*x)[i] + y;
      (*compensation)[i] = (sum - (*x)[i]) - y;
      (*x)[i] = sum;
    }
  }

  static bool crossed(Signs sides, int j, long double hj) {
    return sides.plus(j) ? !(hj > 0.0L) : hj > 0.0L;
  }

  // Integrates [t0, t0 + h] from result->x, flipping sides at each crossing found.
  void step_with_events(long double t0, long double h, Result* result, Work* work) const {
    const int n = surfaces();
    long double start = t0;
    long double remaining = h;
    // Each pass either ends the step or crosses one surface; a transversal crossing of each
    // surface at most once per step bounds the passes.
    for (int pass = 0; pass <= n + 1; ++pass) {
      increment(result->x, remaining, result->sides, &work->incr, work);
      work->x_try = result->x + work->incr;
      if (n > 0) model_.surfaces(work->x_try.data(), work->h_end.data());
      int first = -1;
      long double first_tau = remaining;
      for (int j = 0; j < n; ++j) {
        if (!crossed(result->sides, j, work->h_end[j])) continue;
        // Bisection on the step length: lo not crossed (or 0), hi crossed.
        long double lo = 0.0L;
        long double hi = remaining;
        while (hi - lo > kTimeResolution) {
          const long double mid = lo + (hi - lo) / 2;
          if (!(mid > lo && mid < hi)) break;
          increment(result->x, mid, result->sides, &work->trial, work);
          work->x_try = result->x + work->trial;
          model_.surfaces(work->x_try.data(), work->h_try.data());
          if (crossed(result->sides, j, work->h_try[j])) {
            hi = mid;
          } else {
            lo = mid;
          }
        }
        if (first < 0 || hi < first_tau) {
          first = j;
          first_tau = hi;
        }
      }
      if (first < 0) {
        add_compensated(work->incr, &result->x, &work->compensation);
        return;
      }
      increment(result->x, first_tau, result->sides, &work->incr, work);
      add_compensated(work->incr, &result->x, &work->compensation);
      start += first_tau;
      remaining -= first_tau;
      result->crossings.push_back(ReferenceCrossing{start, first});
      result->sides = result->sides.flipped(std::uint64_t{1} << first);
      if (!(remaining > 0.0L)) return;
    }
    throw std::runtime_error("ReferenceFlow: more crossings in one step than surfaces at t = " +
                             std::to_string(static_cast<double>(t0)));
  }

  Model model_;
  long double max_step_;
};

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_REFERENCE_FLOW_H_

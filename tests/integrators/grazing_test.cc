// Grazing: trajectories that pass a surface at signed distance +delta (no crossing), dip through
// it by delta and come back (two crossings, often inside one step), or touch it (delta = 0), on
// two models whose flows have closed forms:
//
//   Parabola  x' = 1, y' = 2x above h = y (y = x^2 + C); below, x' = 2, y' = 6x
//             (y = 1.5 x^2 + C'). From (-1, 1 + C), C = y0 - x0^2 = +-delta, to t = 2. dopri5 is
//             exact on this polynomial trajectory, so its steps grow 5x each: the dip is a few
//             1e-5 wide inside a step of order one, exactly the case an end-point sign test misses.
//   Circle    rotation x' = -y, y' = x below h = y - c; above, twice as fast (x' = -2y,
//             y' = 2x, same circles). From (1, 0), c = 1 -+ delta, to t = 3. The closest
//             approach is at (0, 1); the dip crosses at the angles asin(c) and pi - asin(c).
//
// The fields differ across the surface, so the saltation matrix is non-trivial, and at the
// crossings of a dip eta . F / (|eta| |F|) ~ sqrt(delta): the derivative grows like
// 1/sqrt(delta). Derivatives are checked against one-sided differences of the closed forms in
// long double, Richardson-extrapolated twice, with a step a = 1e-2 delta small against delta.
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/integrators/dopri5.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;
using Vec2L = Eigen::Matrix<long double, 2, 1>;

constexpr long double kPi = 3.141592653589793238462643383279502884L;

struct Parabola {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    if (b.plus(0)) {
      xdot[0] = T(1.0);
      xdot[1] = 2.0 * x[0];
    } else {
      xdot[0] = T(2.0);
      xdot[1] = 6.0 * x[0];
    }
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[1];
  }
};

struct Circle {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  double c = 1.0;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    const double w = b.plus(0) ? 2.0 : 1.0;
    xdot[0] = -w * x[1];
    xdot[1] = w * x[0];
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[1] - c;
  }
};

// Closed-form flows in long double, for starts before the first crossing (x0 < -r for the
// parabola, angle < asin(c / r0) for the circle).
Vec2L parabola_flow(long double x0, long double y0, long double t) {
  const long double c = y0 - x0 * x0;
  long double x = x0 + t;
  if (c < 0.0L) {
    const long double r = std::sqrt(-c);
    const long double t1 = -r - x0;  // enters y < 0 at x = -r
    const long double t2 = t1 + r;   // leaves at x = r, at speed 2
    if (t > t1 && t <= t2) {
      x = -r + 2.0L * (t - t1);
      return Vec2L(x, 1.5L * (x * x - r * r));
    }
    if (t > t2) {
      x = r + (t - t2);
      return Vec2L(x, x * x - r * r);
    }
  }
  return Vec2L(x, y0 + x * x - x0 * x0);
}

Vec2L circle_flow(long double c, long double x0, long double y0, long double t) {
  const long double r0 = std::sqrt(x0 * x0 + y0 * y0);
  const long double phi0 = std::atan2(y0, x0);
  long double phi = phi0 + t;
  if (r0 > c) {
    // Half the arc above y = c: alpha = acos(c / r0), written to keep r0 - c exact.
    const long double alpha = std::atan2(std::sqrt((r0 - c) * (r0 + c)), c);
    const long double t1 = kPi / 2 - alpha - phi0;
    const long double t2 = t1 + alpha;  // 2 alpha at speed 2
    if (t > t1 && t <= t2) phi = kPi / 2 - alpha + 2.0L * (t - t1);
    if (t > t2) phi = kPi / 2 + alpha + (t - t2);
  }
  return Vec2L(r0 * std::cos(phi), r0 * std::sin(phi));
}

// A model, its start, final time and closed form.
struct Case {
  std::string name;
  double delta = 0.0;  // signed: > 0 passes by, < 0 dips through
  bool parabola = true;
  Eigen::Vector2d x0() const {
    return parabola ? Eigen::Vector2d(-1.0, 1.0 + delta) : Eigen::Vector2d(1.0, 0.0);
  }
  double c() const { return 1.0 + delta; }
  double final_time() const { return parabola ? 2.0 : 3.0; }
  Vec2L flow(const Vec2L& x) const {
    return parabola ? parabola_flow(x[0], x[1], final_time())
                    : circle_flow(static_cast<long double>(c()), x[0], x[1], final_time());
  }
  // Closed-form crossing times of a dip, and the time of closest approach.
  std::vector<long double> crossings() const {
    if (delta >= 0.0) return {};
    if (parabola) {
      const long double r = std::sqrt(static_cast<long double>(-delta));
      return {1.0L - r, 1.0L};
    }
    const long double cc = c();
    const long double alpha = std::atan2(std::sqrt((1.0L - cc) * (1.0L + cc)), cc);
    return {kPi / 2 - alpha, kPi / 2};
  }
  double closest_time() const { return parabola ? 1.0 : static_cast<double>(kPi / 2); }
  // |y| at the closest approach, for the band rule.
  double closest_y() const { return parabola ? std::abs(delta) : 1.0; }
};

// d phi / dx0 by one-sided differences D(a) = (phi(x0 + a e) - phi(x0)) / a, extrapolated twice
// (Richardson): R(a) = (8 D(a/4) - 6 D(a/2) + D(a)) / 3, error O(a^3). a = kappa |delta| balances
// that error (~0.1 kappa^3 relative, measured) against long double rounding amplified by the
// 1/sqrt(delta) conditioning (~1e-19 / (kappa |delta|) relative); `error` gets |R(a) - R(a/2)|,
// relative, which estimates R(a)'s error.
Eigen::Matrix<long double, 2, 2> reference_jacobian(const Case& c, double* error) {
  const long double delta = std::abs(static_cast<long double>(c.delta));
  const long double kappa = std::min(1e-2L, std::pow(1e-18L / delta, 0.25L));
  const Vec2L x0 = c.x0().cast<long double>();
  const Vec2L phi = c.flow(x0);
  const auto extrapolated = [&](long double a) {
    Eigen::Matrix<long double, 2, 2> jacobian;
    for (int col = 0; col < 2; ++col) {
      const auto difference = [&](long double step) {
        Vec2L moved = x0;
        moved[col] += step;
        return Vec2L((c.flow(moved) - phi) / step);
      };
      jacobian.col(col) =
          (8.0L * difference(a / 4) - 6.0L * difference(a / 2) + difference(a)) / 3.0L;
    }
    return jacobian;
  };
  const Eigen::Matrix<long double, 2, 2> coarse = extrapolated(kappa * delta);
  const Eigen::Matrix<long double, 2, 2> fine = extrapolated(kappa * delta / 2);
  *error =
      static_cast<double>((coarse - fine).cwiseAbs().maxCoeff() / coarse.cwiseAbs().maxCoeff());
  return coarse;
}

struct SegmentRun {
  std::vector<double> crossings;
  std::vector<NearMiss> misses;
  IntegrationStatus status = IntegrationStatus::kReachedEnd;
};

// The segments one after another through the backend the driver runs with `flow` (its own
// choice for Backend::kAutomatic), flipping the side at each crossing.
SegmentRun run_segments(const SegmentModel& model, const Case& c, Signs sides,
                        const FlowOptions& flow) {
  const IntegratorOptions& options = flow.integrator;
  const std::unique_ptr<SegmentIntegrator> backend =
      make_integrator(choose_backend(flow.backend, options.rtol, model.states(), model.surfaces()));
  SegmentRequest request;
  request.sides = sides;
  request.t0 = 0.0;
  request.t_end = c.final_time();
  request.x0 = c.x0();
  // The tangents flow_derivative() carries (the identity at the start of every segment): they
  // are in the error norm, so with them the backend takes the driver's steps exactly.
  request.v0 = Eigen::MatrixXd::Identity(model.states(), model.states());
  SegmentRun run;
  for (int segment = 0; segment < 10; ++segment) {
    const SegmentResult result = backend->integrate(model, request, options);
    run.misses.insert(run.misses.end(), result.near_misses.begin(), result.near_misses.end());
    run.status = result.status;
    if (result.status != IntegrationStatus::kCrossing) break;
    run.crossings.push_back(result.t);
    request.sides = request.sides.flipped(1);
    request.t0 = result.t;
    request.x0 = result.x;
  }
  return run;
}

struct Setting {
  const char* name;
  double rtol;
  Backend backend;
};
// The defaults (backend auto: dop853 at these tolerances) and dopri5 named.
constexpr Setting kSettings[] = {{"default", 1e-8, Backend::kAutomatic},
                                 {"tight", 1e-12, Backend::kAutomatic},
                                 {"dopri5", 1e-8, Backend::kDopri5},
                                 {"dopri5-tight", 1e-12, Backend::kDopri5}};

// The state error at the closest approach: rounding for the parabola (both are exact on it;
// measured 1-3 eps for dopri5, up to 21 eps for dop853's twelve stages), one tolerance unit atol +
// rtol |x| for the circle (measured 0.1-0.2 units).
double state_error(const Case& c, double rtol, double atol, Backend ran) {
  const double rounding = ran == Backend::kDop853 ? 32.0 : 8.0;
  return c.parabola ? rounding * std::numeric_limits<double>::epsilon()
                    : atol + rtol * c.closest_y();
}

// eta . F / (|eta| |F|) at the first crossing of a dip, closed form.
double exact_margin(const Case& c) {
  if (c.parabola) return 2 * std::sqrt(-c.delta) / std::sqrt(1 - 4 * c.delta);
  return std::sqrt(1 - c.c() * c.c());
}

// Passing at +delta: no crossing, a NearMiss (and a near-grazing notice) exactly when delta is
// inside the band. Dipping by delta: two crossings at the closed-form times whenever delta is
// outside the band; inside it the integrator's trajectory may miss the dip (the circle's radius
// error is 0.2 tolerance units), and then the NearMiss reports it: a dip is never lost silently.
// The derivative, on the branch the run took, against the closed form's differences.
TEST(GrazingTest, PassesDipsAndDerivativesAgainstClosedForms) {
  std::printf("%-8s %-7s %9s %6s %6s %9s %9s %9s %9s %9s %9s %10s\n", "model", "setting", "delta",
              "events", "misses", "margin", "t error", "t tol", "D error", "D tol", "ref err",
              "g_min/band");
  for (const Setting& setting : kSettings) {
    FlowOptions options;
    options.integrator.rtol = setting.rtol;
    options.backend = setting.backend;
    const double atol = options.integrator.absolute_tolerance();
    for (const bool parabola : {true, false}) {
      for (int e = 2; e <= 10; ++e) {
        for (const double sign : {1.0, -1.0}) {
          Case c;
          c.parabola = parabola;
          c.name = parabola ? "parabola" : "circle";
          c.delta = sign * std::pow(10.0, -e);
          const std::string label =
              c.name + " " + setting.name + " delta " + std::to_string(sign * e);
          const auto parabola_model = adapt(Parabola{});
          const auto circle_model = adapt(Circle{c.c()});
          const SegmentModel& model =
              parabola ? static_cast<const SegmentModel&>(parabola_model) : circle_model;
          const double band = 8.0 * (atol + setting.rtol * c.closest_y());  // the documented rule
          const double error = state_error(c, setting.rtol, atol,
                                           choose_backend(setting.backend, setting.rtol, 2, 1));

          // Segment level: the crossings and near misses as the backend reports them.
          const SegmentRun run = run_segments(model, c, Signs(1, parabola ? 1 : 0), options);
          ASSERT_EQ(run.status, IntegrationStatus::kReachedEnd) << label;
          const std::vector<long double> exact = c.crossings();
          const bool dip_seen = run.crossings.size() == 2;
          if (c.delta > 0.0) {
            EXPECT_TRUE(run.crossings.empty()) << label;
            EXPECT_EQ(run.misses.size(), c.delta < band ? 1u : 0u) << label;
          } else if (-c.delta > band) {
            EXPECT_TRUE(dip_seen) << label << ": " << run.crossings.size() << " crossings";
            EXPECT_TRUE(run.misses.empty()) << label;
          } else {
            EXPECT_TRUE((dip_seen && run.misses.empty()) ||
                        (run.crossings.empty() && run.misses.size() == 1u))
                << label << ": " << run.crossings.size() << " crossings, " << run.misses.size()
                << " near misses";
          }
          double ratio = 0.0;
          for (const NearMiss& miss : run.misses) {
            // Measured: |g_min - delta| <= 0.2 error; |t - t_closest| <= 2e-5 (a flat minimum).
            ratio = miss.g_min / miss.band;
            EXPECT_EQ(miss.surface, 0) << label;
            EXPECT_NEAR(miss.band, band, 1e-6 * band) << label;  // at the integrated state
            EXPECT_NEAR(miss.g_min, std::abs(c.delta), error) << label;
            EXPECT_NEAR(miss.t, c.closest_time(), 1e-4) << label;
          }

          // Driver: the same events, the near misses as notices, and the B-derivative.
          FlowResult result;
          const FlowDerivative derivative =
              flow_derivative(model, c.x0(), c.final_time(), options, &result);
          ASSERT_EQ(result.events.size(), run.crossings.size()) << label;
          int notices = 0;
          for (const FlowNotice& notice : result.notices) {
            if (notice.kind == FlowNotice::Kind::kNearGrazing) ++notices;
          }
          EXPECT_EQ(notices, static_cast<int>(run.misses.size())) << label;

          // Crossing times: a state error e moves a crossing by e / (margin |F|), |F| ~ 1.
          double margin = 0.0, t_error = 0.0, t_tol = 0.0;
          if (dip_seen) {
            margin = exact_margin(c);
            t_tol = error / margin + 4 * std::numeric_limits<double>::epsilon();
            for (std::size_t k = 0; k < 2; ++k) {
              EXPECT_EQ(result.events[k].t, run.crossings[k]) << label;
              t_error = std::max(
                  t_error, static_cast<double>(
                               std::abs(static_cast<long double>(run.crossings[k]) - exact[k])));
            }
            EXPECT_LE(t_error, t_tol) << label;
          }

          // Derivative: on a dip it is ~1/sqrt(delta) and its relative error ~ error / delta
          // (the trajectory's effective delta is off by the state error; measured 0.1 for the
          // circle, 1-3 eps for the parabola): tolerance 0.5 error / delta, plus the reference's
          // own error estimate four times. Passing by, the flow is smooth: 2 error.
          double d_error = NAN, d_tol = NAN, ref_error = NAN;
          if (c.delta > 0.0 || dip_seen) {
            const auto reference = reference_jacobian(c, &ref_error);
            d_error = static_cast<double>(
                (derivative.jacobian().cast<long double>() - reference).cwiseAbs().maxCoeff() /
                reference.cwiseAbs().maxCoeff());
            d_tol = 4 * ref_error + (dip_seen ? 0.5 * error / -c.delta : 2 * error);
            EXPECT_LE(d_error, d_tol) << label;
          }
          std::printf("%-8s %-7s %9.0e %6zu %6zu %9.2e %9.2e %9.2e %9.2e %9.2e %9.2e %10.2e\n",
                      c.name.c_str(), setting.name, c.delta, result.events.size(),
                      run.misses.size(), margin, t_error, t_tol, d_error, d_tol, ref_error, ratio);
        }
      }
    }
  }
}

// delta = 0. The parabola is integrated exactly, so its trajectory touches y = 0 to rounding: the
// touch is reported at the tangency and the driver raises the documented grazing error. The
// circle's integrated trajectory misses the surface by its error (0.2 tolerance units, inside
// the band): no event, and a near-grazing notice says the crossing is undecided at this tolerance;
// or (dop853 at 1e-12) dips below it by less than its error: a pair of crossings at the tangency.
TEST(GrazingTest, ExactTangency) {
  for (const Setting& setting : kSettings) {
    FlowOptions options;
    options.integrator.rtol = setting.rtol;
    options.backend = setting.backend;
    Case c;
    c.delta = 0.0;
    c.parabola = true;
    const auto parabola_model = adapt(Parabola{});
    EXPECT_THAT(
        testing::message_of([&] { simulate(parabola_model, c.x0(), c.final_time(), options); }),
        HasSubstr("the B-derivative does not exist at a tangency"))
        << setting.name;

    c.parabola = false;
    const auto circle_model = adapt(Circle{1.0});
    const FlowResult result = simulate(circle_model, c.x0(), c.final_time(), options);
    EXPECT_TRUE(result.ok()) << setting.name;
    if (!result.events.empty()) {
      // The integrated trajectory dipped below y = 0 by less than its error (dop853 at 1e-12):
      // a crossing pair around the tangency, as for any dip inside the band
      // (PassesDipsAndDerivativesAgainstClosedForms).
      ASSERT_EQ(result.events.size(), 2u) << setting.name;
      EXPECT_NEAR(result.events[0].t, c.closest_time(), 1e-4) << setting.name;
      EXPECT_NEAR(result.events[1].t, c.closest_time(), 1e-4) << setting.name;
      continue;
    }
    ASSERT_EQ(result.notices.size(), 1u) << setting.name;
    const FlowNotice& notice = result.notices[0];
    EXPECT_EQ(notice.kind, FlowNotice::Kind::kNearGrazing);
    // Measured g_min = 0.19 tolerance units at both settings.
    const double unit = options.integrator.absolute_tolerance() + setting.rtol;
    EXPECT_GT(notice.gap, 0.0) << setting.name;
    EXPECT_LT(notice.gap, unit) << setting.name;
    EXPECT_NEAR(notice.times[0], c.closest_time(), 1e-4) << setting.name;
  }
}

}  // namespace
}  // namespace bflow

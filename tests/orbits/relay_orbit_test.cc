// The relay oscillator  x' = y,  y' = (k - y^2) y - s,  s = sign(x)  (surface h = x): near the
// origin, a point of the switching surface where both fields point across it, every small loop
// returns close to where it started, so |P(x) - x| is tiny there although x is no fixed point.
//
// Reference, independent of the library's flow code: on each side y' = g(y) depends on y alone
// (x > 0: g(y) = k y - y^3 - 1 < 0 for |y| < 1), so a half loop in x > 0 runs from y = v down
// to y = -v, with dt = dy / g(y) and dx = y dy / g(y). The field is odd under (x, y, s) ->
// (-x, -y, -s), so the orbit is symmetric and v solves
//     F(v) = int_{-v}^{v} y / (1 + y^3 - k y) dy = 0,
// the period is T = 2 int_{-v}^{v} dy / (1 + y^3 - k y), and the orbit crosses the section
// y = 0 (from y > 0 to y < 0) at x* = int_0^v y / (1 + y^3 - k y) dy. The integrands are smooth
// and analytic on [-v, v] (1 + y^3 - k y >= 0.8 there for k <= 0.2): composite 8-point
// Gauss-Legendre on 64 panels is exact to rounding (an error below 1e-15, checked against 128
// panels), and v is found by bisection to 1e-15. For k <= 0, F(v) < 0 for every v > 0
// (F = -2 v^5 / 5 + O(v^7) at k = 0, and the k term only lowers it): there is no orbit.
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "bflow/integrators/model_adapter.h"
#include "bflow/orbits/orbit_family.h"
#include "bflow/orbits/periodic_orbit.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;

struct Relay {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  double k = 0.2;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    xdot[0] = x[1];
    xdot[1] = (T(k) - x[1] * x[1]) * x[1] - T(b.sign(0));
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
  }
};

const CoordinateSection kDownwardY{1, 0.0, -1.0};  // "-x1"

// int_a^b f by composite 8-point Gauss-Legendre on `panels` panels.
template <typename F>
double gauss(F f, double a, double b, int panels = 64) {
  static const double kNodes[4] = {0.1834346424956498, 0.5255324099163290, 0.7966664774136267,
                                   0.9602898564975363};
  static const double kWeights[4] = {0.3626837833783620, 0.3137066458778873, 0.2223810344533745,
                                     0.1012285362903763};
  const double h = (b - a) / panels;
  double sum = 0.0;
  for (int p = 0; p < panels; ++p) {
    const double mid = a + (p + 0.5) * h;
    for (int i = 0; i < 4; ++i) {
      sum += kWeights[i] * (f(mid - 0.5 * h * kNodes[i]) + f(mid + 0.5 * h * kNodes[i]));
    }
  }
  return 0.5 * h * sum;
}

struct RelayReference {
  double v = 0.0, period = 0.0, x_star = 0.0;
};

RelayReference relay_reference(double k, int panels = 64) {
  auto den = [k](double y) { return 1.0 + y * y * y - k * y; };
  auto balance = [&](double v) {
    return gauss([&](double y) { return y / den(y); }, -v, v, panels);
  };
  double lo = 0.2, hi = 0.9;  // F(0.2) > 0 > F(0.9) for k = 0.02 .. 0.2
  for (int i = 0; i < 200 && hi - lo > 1e-15; ++i) {
    const double mid = 0.5 * (lo + hi);
    (balance(mid) > 0.0 ? lo : hi) = mid;
  }
  RelayReference r;
  r.v = 0.5 * (lo + hi);
  r.period = 2.0 * gauss([&](double y) { return 1.0 / den(y); }, -r.v, r.v, panels);
  r.x_star = gauss([&](double y) { return y / den(y); }, 0.0, r.v, panels);
  return r;
}

// The reference itself: 64 and 128 panels agree to rounding, and at k = 0.2 the period is the
// 2.310931 an independent integration gives.
TEST(RelayOrbit, ReferenceQuadratureIsConverged) {
  const RelayReference a = relay_reference(0.2, 64);
  const RelayReference b = relay_reference(0.2, 128);
  EXPECT_NEAR(a.period, b.period, 1e-13);
  EXPECT_NEAR(a.x_star, b.x_star, 1e-13);
  EXPECT_NEAR(a.period, 2.310931, 5e-7);
}

// From x = 0.0834 the iterates slide towards the origin, where every loop nearly closes
// (P(x) / x = 1.0013 at x = 3e-6): |P(x) - x| = 3.7e-9 there meets the tolerance 1e-8 (1 + |x|)
// while x is no fixed point. The run must not report it as an orbit; converged, it must be the
// true one.
TEST(RelayOrbit, NoOrbitIsReportedWhereTheLoopsShrinkToTheOrigin) {
  const RelayReference ref = relay_reference(0.2);
  const PeriodicOrbit orbit =
      find_periodic_orbit(adapt(Relay{}), kDownwardY, Eigen::Vector2d(0.0834, 0.0));
  if (orbit.converged) {
    EXPECT_NEAR(orbit.period, ref.period, 1e-7);
    EXPECT_NEAR(orbit.x[0], ref.x_star, 1e-7);
  } else {
    EXPECT_THAT(orbit.message, HasSubstr("vanishing orbit"));
  }
  // The false orbit had period 0.00966; a point whose return time is below a tenth of the true
  // period is never an orbit of this model.
  EXPECT_FALSE(orbit.converged && orbit.period < 0.1 * ref.period)
      << "period " << orbit.period << " at x " << orbit.x.transpose();
}

// From guesses on both sides of the true orbit, Newton converges to it. Bound: converged means
// |P(x) - x| and Newton's correction |dx| are within 1e-8 (1 + |x|) = 1.17e-8, so x is within
// about that (plus rounding of the linearisation) of x*; the period moves with x by
// |dT/dx| (|T(0.15) - T(x*)| / 0.017 = 6 from the first step's period 2.206, so at most about
// 7e-8 for 1.17e-8), and the integration at rtol 1e-10 adds about 1e-10 T. 2e-7 bounds both;
// the reference itself is exact to 1e-13 (ReferenceQuadratureIsConverged).
TEST(RelayOrbit, ConvergesToTheTrueOrbitFromNearIt) {
  const RelayReference ref = relay_reference(0.2);
  for (double guess : {0.15, 0.19}) {
    const PeriodicOrbit orbit =
        find_periodic_orbit(adapt(Relay{}), kDownwardY, Eigen::Vector2d(guess, 0.0));
    ASSERT_TRUE(orbit.converged) << guess << ": " << orbit.message;
    EXPECT_NEAR(orbit.period, ref.period, 2e-7) << guess;
    EXPECT_NEAR(orbit.x[0], ref.x_star, 3e-8) << guess;
    EXPECT_LE(orbit.correction, 1e-8 * (1.0 + orbit.x.lpNorm<Eigen::Infinity>()));
    std::printf("guess %g: period - reference %.2e, x - x* %.2e, correction %.2e\n", guess,
                orbit.period - ref.period, orbit.x[0] - ref.x_star, orbit.correction);
  }
}

// Along k from 0.2 down the orbit shrinks (v^2 ~ 5 k / 3) and is gone at k = 0: every member
// with k > 0 is the reference's orbit, and no member at k <= 0 is reported, each with a reason
// (not an orbit shrunk to the origin).
TEST(RelayOrbit, ContinuationStopsWhereTheOrbitVanishes) {
  const std::vector<double> ks = {0.2, 0.15, 0.1, 0.07, 0.05, 0.0, -0.05};
  const std::vector<OrbitFamilyMember> family =
      continue_orbits(ks, Eigen::Vector2d(0.17, 0.0), [](double k, const Eigen::VectorXd& guess) {
        Relay relay;
        relay.k = k;
        return find_periodic_orbit(adapt(relay), kDownwardY, guess);
      });
  ASSERT_EQ(family.size(), ks.size());
  for (std::size_t i = 0; i < ks.size(); ++i) {
    const PeriodicOrbit& orbit = family[i].orbit;
    std::printf("k %5.2f: converged %d period %.9g x %.3e: %s\n", ks[i], orbit.converged,
                orbit.period, orbit.x[0], orbit.message.substr(0, 60).c_str());
    if (ks[i] > 0.0) {
      const RelayReference ref = relay_reference(ks[i]);
      ASSERT_TRUE(orbit.converged) << "k " << ks[i] << ": " << orbit.message;
      EXPECT_NEAR(orbit.period, ref.period, 2e-7) << ks[i];
      EXPECT_NEAR(orbit.x[0], ref.x_star, 3e-8) << ks[i];
    } else {
      EXPECT_FALSE(orbit.converged)
          << "k " << ks[i] << ": period " << orbit.period << " at x " << orbit.x.transpose();
      EXPECT_FALSE(orbit.message.empty());
    }
  }
}

}  // namespace
}  // namespace bflow

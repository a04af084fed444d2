// The growth-rate bracket is about L's growth, which scales with L: rho(c L) = c rho(L) for
// c > 0. For c over 1e-150 .. 1e150 the bracket of c L is c times the bracket of L, and holds
// the growth rate of c L found by iterating the map itself (FlowDerivative::apply only).
#include <cmath>
#include <cstdio>
#include <random>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "bflow/core/flow_derivative.h"
#include "bflow/core/jump_map.h"
#include "bflow/orbits/periodic_orbit.h"

namespace bflow {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;

// The plane map of growth_bracket_test.cc (every piece contracts, a 3-cycle of pieces expands),
// with its last transition scaled by c: L_c = c L.
FlowDerivative plane_map(double c) {
  MatrixXd phi0(2, 2), eta(2, 2), limits(2, 4), phi1(2, 2);
  phi0 << -0.6, 0, -0.7, -1.3;
  eta << -1.3, 1.6, 1, -0.3;
  limits << 1.14, 2.5, 0.69, 2.89, 1.8, 2.35, 1.31, 2.98;
  phi1 << 1.1, -0.6, -0.6, 0.5;
  FlowDerivative map(2);
  map.append_transition(phi0);
  map.append_jump(JumpMap(eta, limits), 1.0);
  map.append_transition(c * 3.661 * phi1);
  return map;
}

// A linear map (no event) with the eigenvalues 1 +- sqrt(0.07), scaled by c.
FlowDerivative linear_map(double c) {
  MatrixXd a(2, 2);
  a << 0.9, 0.3, 0.2, 1.1;
  FlowDerivative map(2);
  map.append_transition(c * a);
  return map;
}

// max over directions of exp(mean log |L z_k| / |z_k|) over steps 200..2000 (normalised
// iterates: no overflow for any c), with the difference of the two halves' rates as its error.
struct Iterated {
  double rate = 0.0, error = 0.0;
};
Iterated iterate(const FlowDerivative& map) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> normal;
  Iterated out;
  for (int k = 0; k < 24; ++k) {
    VectorXd z(2);
    z << normal(rng), normal(rng);
    z.normalize();
    double sum = 0.0, first = 0.0;
    for (int step = 1; step <= 2000; ++step) {
      const VectorXd w = map.apply(z);
      const double norm = w.norm();
      if (step > 200) sum += std::log(norm);
      if (step == 1100) first = sum;
      z = w / norm;
    }
    const double rate = std::exp(sum / 1800.0);
    if (rate > out.rate) {
      out.rate = rate;
      out.error = std::abs(first / 900.0 - (sum - first) / 900.0) + 1e-12;
    }
  }
  return out;
}

void expect_scaled(FlowDerivative (*make)(double), const char* name) {
  const MatrixXd basis = MatrixXd::Identity(2, 2);
  const GrowthBracket unit = growth_rate_bracket(make(1.0), basis);
  ASSERT_GT(unit.lower, 0.0) << name;
  for (double c : {1e-150, 1e-100, 1e-30, 1e-8, 0.37, 3.0, 1e8, 1e30, 1e100, 1e150}) {
    const FlowDerivative map = make(c);
    const GrowthBracket b = growth_rate_bracket(map, basis);
    const Iterated reference = iterate(map);
    std::printf("%s, c = %.0e: bracket / c = [%.12f, %.12f], iterated rate / c %.12f\n", name, c,
                b.lower / c, b.upper / c, reference.rate / c);
    // c times the unit bracket: the pieces of c L differ from c times those of L by rounding
    // (a few u), which moves the ends by about as much relative to their margins (1e-11 here).
    EXPECT_NEAR(b.lower / c, unit.lower, 1e-9 * unit.lower) << name << ", c = " << c;
    EXPECT_NEAR(b.upper / c, unit.upper, 1e-9 * unit.upper) << name << ", c = " << c;
    EXPECT_EQ(b.lower_period, unit.lower_period) << name << ", c = " << c;
    EXPECT_LE(b.lower, reference.rate * (1.0 + reference.error)) << name << ", c = " << c;
    EXPECT_LE(reference.rate, b.upper * (1.0 + reference.error)) << name << ", c = " << c;
  }
}

TEST(GrowthBracketScaling, PiecewiseLinearBracketScalesWithTheMap) {
  expect_scaled(plane_map, "plane");
}

TEST(GrowthBracketScaling, LinearBracketScalesWithTheMap) { expect_scaled(linear_map, "linear"); }

}  // namespace
}  // namespace bflow

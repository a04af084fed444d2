// The pronking body (core/pronk.h): a stable periodic hop on which both feet land and lift off
// together, so every event crosses two surfaces at once and the return map is piecewise linear.
//
// References, independent of the library's flow, jump and orbit code:
//  - the apex and period from the vertical motion alone, written by hand as one scalar equation
//    and integrated by a classic RK4 (tests/support/vertical_hop.h; on the orbit x = theta = 0 and
//    both feet act alike: flight y'' = -g; stance y'' = -g + 2 kappa (l - y) - 2 beta y' + 2 F
//    tanh(y'/v)); the height multiplier is the derivative of that hand map's next apex;
//  - the fixed point by one period of bflow::simulate at tight tolerances;
//  - the tether block of the return map in closed form: x'' = -(k_x x + c_x x') / m is all that
//    acts on x, so DP maps (x, xdot) by exp(A T);
//  - the return map against one-sided differences of the return map itself, on both sides of
//    the boundary between the crossing orders;
//  - the growth rate as the square root of the hand height multiplier (Liouville's formula for
//    the pitch block, which has the bounce's damping when J = m d^2);
//  - the verdict against the decay of true iterates of P from perturbed points.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "bflow/core/pronk.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "bflow/orbits/periodic_orbit.h"
#include "support/error_message.h"
#include "support/vertical_hop.h"

namespace bflow {
namespace {

const CoordinateSection kApex{4, 0.0, -1.0};  // vertical speed from + to -

Eigen::VectorXd guess() { return pronk_initial_state(); }

Eigen::VectorXd unit(int i) { return Eigen::VectorXd::Unit(6, i); }

// The library's defaults, which hold the tangents to the integrator's tolerance too
// (default_orbit_flow_options: tangents_in_error_norm). On this orbit x and theta stay 0, so the
// state's own error estimate is blind to the tangents that move them and would let the flight's
// steps grow until those tangents are off by 2e-5; held to rtol they agree with the closed form
// to 4e-11. The state alone is checked separately (StateAloneInTheErrorNormLoosensTheBracket).
OrbitOptions accurate() {
  OrbitOptions options;
  EXPECT_TRUE(options.flow.integrator.tangents_in_error_norm);
  return options;
}

using ::testing::HasSubstr;
using testing::Hop;

// The vertical hop of support/vertical_hop.h with this body's numbers.
testing::VerticalHop hop_of(const PronkParams& p) {
  testing::VerticalHop hop;
  hop.m = p.m;
  hop.g = p.g;
  hop.kappa = p.kappa;
  hop.beta = p.beta;
  hop.thrust = p.thrust;
  hop.thrust_speed = p.thrust_speed;
  hop.touchdown = p.leg_length;
  return hop;
}

Hop vertical_hop(const PronkParams& p, double y) { return testing::vertical_hop(hop_of(p), y); }
Hop vertical_orbit(const PronkParams& p, double y0) {
  return testing::vertical_orbit(hop_of(p), y0);
}

class PronkOrbit : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    orbit_ = new PeriodicOrbit(find_periodic_orbit(model(), kApex, guess(), accurate()));
  }
  static void TearDownTestSuite() {
    delete orbit_;
    orbit_ = nullptr;
  }
  static const ModelAdapter<PronkScene>& model() {
    static const ModelAdapter<PronkScene> adapted = adapt(make_pronk(PronkParams{}));
    return adapted;
  }
  static const PeriodicOrbit& orbit() { return *orbit_; }

 private:
  static PeriodicOrbit* orbit_;
};

PeriodicOrbit* PronkOrbit::orbit_ = nullptr;

TEST_F(PronkOrbit, ConvergesFromTheDefaultGuessToTheVerticalHopByHand) {
  const PeriodicOrbit& o = orbit();
  ASSERT_TRUE(o.converged) << o.message;
  // Achieved: 2 iterations from rest at height 1.
  EXPECT_LE(o.newton_iterations, 4);
  EXPECT_TRUE(o.decisions.empty());
  EXPECT_LE(o.residual, 1e-8 * (1.0 + o.x.lpNorm<Eigen::Infinity>()));
  // On the orbit the body bounces straight up and down: x = theta = xdot = thetadot = 0.
  for (int i : {0, 2, 3, 5}) EXPECT_NEAR(o.x[i], 0.0, 1e-9) << "state " << i;
  EXPECT_EQ(o.x[4], 0.0);  // on the section
  const Hop hand = vertical_orbit(PronkParams{}, 0.9);
  // Achieved: apex and period within 2e-9 of the hand hop (0.977396, 0.764871); bound 2e-8.
  EXPECT_NEAR(o.x[1], hand.apex, 2e-8);
  EXPECT_NEAR(o.period, hand.time, 2e-8);
  std::printf("apex %.9f (hand %.9f), period %.9f (hand %.9f), %d Newton iterations\n", o.x[1],
              hand.apex, o.period, hand.time, o.newton_iterations);
}

TEST_F(PronkOrbit, IsAFixedPointOfAnIndependentSimulation) {
  const PeriodicOrbit& o = orbit();
  ASSERT_TRUE(o.converged) << o.message;
  FlowOptions flow;
  flow.integrator.rtol = 1e-12;
  flow.integrator.atol = 1e-14;
  const FlowResult end = simulate(model(), o.x, o.period, flow);
  const FlowResult before = simulate(model(), o.x, 0.99 * o.period, flow);
  ASSERT_TRUE(end.ok()) << end.message;
  ASSERT_TRUE(before.ok()) << before.message;
  // Achieved: |phi_T(x*) - x*| about 1e-9; bound 1e-6. Reached rising (ydot > 0 before T).
  EXPECT_LE((end.x - o.x).lpNorm<Eigen::Infinity>(), 1e-6);
  EXPECT_GT(before.x[4], 0.0);
  // The same two events, both feet at each: touchdown and liftoff.
  ASSERT_EQ(end.events.size(), 2u);
  for (std::size_t k = 0; k < 2; ++k) {
    EXPECT_EQ(end.events[k].surfaces, (std::vector<int>{0, 1}));
    EXPECT_NEAR(end.events[k].t, o.events[k].t, 1e-7);
  }
}

TEST_F(PronkOrbit, EveryEventCrossesBothFeetAndThePiecesDiffer) {
  const PeriodicOrbit& o = orbit();
  ASSERT_TRUE(o.converged) << o.message;
  ASSERT_EQ(o.events.size(), 2u);
  for (const EventRecord& e : o.events) {
    EXPECT_EQ(e.surfaces, (std::vector<int>{0, 1}));
    EXPECT_GE(e.group_size(), 2);
  }
  EXPECT_EQ(o.events[0].sides_before.count_plus(), 0);  // touchdown: both land
  EXPECT_EQ(o.events[0].sides_after.count_plus(), 2);
  EXPECT_EQ(o.events[1].sides_after.count_plus(), 0);  // liftoff: both leave
  EXPECT_FALSE(o.return_map.is_linear());
  const std::vector<FlowPiece> pieces = o.return_map.pieces();
  ASSERT_EQ(pieces.size(), 4u);  // which foot lands first x which foot lifts off first
  EXPECT_GT(pieces.size(), 1u);
  // Every two pieces differ on the section, by far more than the integration tolerance.
  const Eigen::MatrixXd& basis = o.tangent_basis;
  for (std::size_t a = 0; a < pieces.size(); ++a) {
    for (std::size_t b = a + 1; b < pieces.size(); ++b) {
      const Eigen::MatrixXd pa = basis.transpose() * pieces[a].matrix * basis;
      const Eigen::MatrixXd pb = basis.transpose() * pieces[b].matrix * basis;
      EXPECT_GT((pa - pb).norm(), 1e-2 * pa.norm()) << "pieces " << a << " and " << b;
    }
  }
  // Not linear: the images of a pitch perturbation and of its opposite are not opposite.
  const Eigen::VectorXd plus = o.return_map.apply(unit(2));
  const Eigen::VectorXd minus = o.return_map.apply(-unit(2));
  EXPECT_GT((plus + minus).norm(), 1e-2 * plus.norm());
}

TEST_F(PronkOrbit, TetherBlockIsTheDampedOscillatorInClosedForm) {
  const PeriodicOrbit& o = orbit();
  ASSERT_TRUE(o.converged) << o.message;
  const PronkParams p;
  // x'' = -(k x + c x') / m: exp(A T) with alpha = c / (2 m), omega^2 = k / m - alpha^2.
  const double alpha = p.tether_damping / (2.0 * p.m);
  const double omega = std::sqrt(p.tether / p.m - alpha * alpha);
  const double t = o.period;
  const double decay = std::exp(-alpha * t);
  const double c = std::cos(omega * t), s = std::sin(omega * t);
  Eigen::Matrix2d phi;
  phi << decay * (c + alpha / omega * s), decay * s / omega, -decay * (p.tether / p.m) / omega * s,
      decay * (c - alpha / omega * s);
  for (int k = 0; k < 2; ++k) {
    const Eigen::VectorXd image = o.return_map.apply(unit(k == 0 ? 0 : 3));
    Eigen::VectorXd expected = Eigen::VectorXd::Zero(6);
    expected[0] = phi(0, k);
    expected[3] = phi(1, k);
    // Achieved: 4e-11 (with the default options, whose steps ignore the tangents, 2e-5);
    // bound 1e-9.
    EXPECT_LE((image - expected).lpNorm<Eigen::Infinity>(), 1e-9) << "column " << k;
  }
  // Nothing else reaches x or xdot: the block is decoupled.
  for (int i : {1, 2, 5}) {
    const Eigen::VectorXd image = o.return_map.apply(unit(i));
    EXPECT_LE(std::abs(image[0]) + std::abs(image[3]), 1e-12) << "direction " << i;
  }
  // The block's multipliers have modulus exp(-c T / (2 m)) = 0.682, below the bracket's top.
  EXPECT_NEAR(decay, 0.6822, 1e-4);
  EXPECT_LT(decay, o.growth_rate_upper);
}

TEST_F(PronkOrbit, ReturnMapMatchesOneSidedDifferencesOnBothSidesOfTheCones) {
  const PeriodicOrbit& o = orbit();
  ASSERT_TRUE(o.converged) << o.message;
  const ReturnMap base = return_map(model(), kApex, o.x, accurate());
  // A symmetric perturbation (height) keeps both feet together: it lies on the boundary of the
  // cones. Pitch tips it to one side: theta > 0 lifts the front foot, so the hind foot lands
  // first. Each pair below lies on both sides of that boundary.
  const Eigen::VectorXd height = unit(1);
  Eigen::VectorXd mixed(6);
  mixed << 0.3, 0.5, -0.7, 0.2, 0.0, -0.4;
  // Pitch and pitch rate, height tipped slightly by each, and everything at once.
  const std::vector<Eigen::VectorXd> directions = {unit(2),
                                                   -unit(2),
                                                   unit(5),
                                                   -unit(5),
                                                   height + 0.05 * unit(2),
                                                   height - 0.05 * unit(2),
                                                   height + 0.02 * unit(5),
                                                   height - 0.02 * unit(5),
                                                   mixed,
                                                   -mixed};
  const double eps = 1e-6;
  double worst = 0.0;
  int sides_seen = 0;
  for (std::size_t k = 0; k < directions.size(); ++k) {
    const Eigen::VectorXd& v = directions[k];
    const ReturnMap moved = return_map(model(), kApex, o.x + eps * v, accurate());
    const Eigen::VectorXd difference = (moved.image - base.image) / eps;
    const Eigen::VectorXd derivative = o.return_map.apply(v);
    const double error = (difference - derivative).norm() / (1.0 + derivative.norm());
    worst = std::max(worst, error);
    // Achieved: worst 4.2e-6 (the difference's O(eps) term); bound 1e-4.
    EXPECT_LT(error, 1e-4) << "direction " << k;
    // The foot the derivative says lands first is the one the perturbed trajectory reached
    // first: a pure pitch perturbation separates the feet by 1.6e-7 in time, far beyond the
    // grouping window, so the simulation lands them as two events.
    const std::vector<CrossingOrder> orders = o.return_map.crossing_orders(v);
    ASSERT_EQ(orders.size(), 2u);
    const int first = orders[0].order[0];
    sides_seen |= first == 0 ? 1 : 2;
    const EventRecord& landing = moved.events.front();
    if (k < 4) {
      EXPECT_EQ(landing.group_size(), 1) << "direction " << k;
    }
    if (landing.group_size() == 1) {
      EXPECT_EQ(landing.surfaces[0], first) << "direction " << k;
    }
  }
  EXPECT_EQ(sides_seen, 3) << "both landing orders were exercised";
  std::printf("one-sided differences: worst relative error %.2e\n", worst);
}

TEST_F(PronkOrbit, VerdictStableAndTrueIteratesShrinkAtTheBracketedRate) {
  const PeriodicOrbit& o = orbit();
  ASSERT_TRUE(o.converged) << o.message;
  EXPECT_EQ(o.stability, OrbitStability::kStable);
  EXPECT_STREQ(to_string(o.stability), "stable");
  EXPECT_GT(o.growth_rate_lower, 0.0);
  EXPECT_LE(o.growth_rate_lower, o.growth_rate_upper);
  // Stable by a clear margin. Achieved: [0.5545, 0.7456].
  EXPECT_LT(o.growth_rate_upper, 0.8);

  // The height multiplier from the hand hop: d(next apex) / d(apex) by central differences. A
  // pure height perturbation stays symmetric, so it is the lower end's direction.
  const PronkParams p;
  const double apex = o.x[1], h = 1e-5;
  const double height_multiplier =
      (vertical_hop(p, apex + h).apex - vertical_hop(p, apex - h).apex) / (2.0 * h);
  // Achieved: within 1e-8; bound 1e-5.
  EXPECT_NEAR(o.growth_rate_lower, height_multiplier, 1e-5);
  // The growth rate itself: with J = m d^2 pitch and bounce see the same damping and thrust
  // (d(thetaddot)/d(thetadot) = d(yddot)/d(ydot) on the orbit, and every saltation has
  // determinant 1), so by Liouville's formula the pitch block's determinant is the height
  // multiplier; its multipliers are a complex pair, of modulus sqrt(height multiplier) =
  // 0.744655, the largest (the tether's are 0.682). The bracket must hold it, and its top is
  // tight. Achieved: upper - rate = 1.7e-5; bound 1e-4.
  const double growth_rate = std::sqrt(height_multiplier);
  EXPECT_LE(o.growth_rate_lower, growth_rate);
  EXPECT_GE(o.growth_rate_upper, growth_rate - 1e-6);
  EXPECT_LT(o.growth_rate_upper - growth_rate, 1e-4);

  // True iterates of P (nonlinear) from x* + 1e-3 z: |x_k - x*| must shrink at a rate within
  // the bracket, measured as the geometric mean of the decay from period `from` to `to`, while
  // the distance is still far above where the iterates settle (2e-9 from x*, the integration
  // and Newton tolerances).
  auto decay_rate = [&](Eigen::VectorXd z, int from, int to) {
    z.normalize();
    Eigen::VectorXd x = o.x + 1e-3 * z;
    std::vector<double> distance;
    for (int k = 0; k <= to; ++k) {
      distance.push_back((x - o.x).norm());
      x = return_map(model(), kApex, x, accurate()).image;
    }
    EXPECT_GT(distance[static_cast<std::size_t>(to)], 1e-7);
    return std::pow(
        distance[static_cast<std::size_t>(to)] / distance[static_cast<std::size_t>(from)],
        1.0 / (to - from));
  };
  Eigen::VectorXd mixed(6);
  mixed << 0.3, 0.5, -0.7, 0.2, 0.0, -0.4;
  const double mixed_rate = decay_rate(mixed, 10, 30);
  const double height_rate = decay_rate(unit(1), 1, 11);
  // Achieved: 0.7457 (the pitch pair, 0.057 +- 0.742i, dominates) and 0.5544 (a symmetric
  // perturbation stays symmetric); the bound allows the oscillation of a complex pair over 20
  // periods.
  EXPECT_GE(mixed_rate, o.growth_rate_lower - 0.02);
  EXPECT_LE(mixed_rate, o.growth_rate_upper + 0.02);
  EXPECT_NEAR(mixed_rate, growth_rate, 0.02);
  EXPECT_NEAR(height_rate, o.growth_rate_lower, 1e-3);
  std::printf(
      "bracket [%.6f, %.6f]; by hand: height multiplier %.6f, growth rate %.6f; true iterates "
      "%.6f (mixed), %.6f (height)\n",
      o.growth_rate_lower, o.growth_rate_upper, height_multiplier, growth_rate, mixed_rate,
      height_rate);
}

TEST_F(PronkOrbit, StateAloneInTheErrorNormLoosensTheBracket) {
  // The steps set by the state alone (IntegratorOptions::tangents_in_error_norm = false).
  OrbitOptions state_alone;
  state_alone.flow.integrator.tangents_in_error_norm = false;
  const PeriodicOrbit plain = find_periodic_orbit(model(), kApex, guess(), state_alone);
  const PeriodicOrbit& o = orbit();
  ASSERT_TRUE(plain.converged) << plain.message;
  ASSERT_TRUE(o.converged) << o.message;
  EXPECT_LE((plain.x - o.x).lpNorm<Eigen::Infinity>(), 1e-8);
  EXPECT_NEAR(plain.period, o.period, 1e-8);
  EXPECT_EQ(plain.stability, OrbitStability::kStable);
  // The return map's steps ignore the tangents there: its pieces are off by about 1e-5 (achieved:
  // 1.2e-5 at worst, relative to the pieces' size), which the bracket may or may not show.
  double worst = 0.0;
  const std::vector<FlowPiece> loose = plain.return_map.pieces();
  const std::vector<FlowPiece> tight = o.return_map.pieces();
  ASSERT_EQ(loose.size(), tight.size());
  for (std::size_t i = 0; i < loose.size(); ++i) {
    worst = std::max(worst, (loose[i].matrix - tight[i].matrix).norm() / tight[i].matrix.norm());
  }
  std::printf("state alone in the error norm: pieces off by %.1e\n", worst);
  EXPECT_GT(worst, 1e-6);
  EXPECT_LT(worst, 1e-3);
  EXPECT_NEAR(plain.growth_rate_lower, o.growth_rate_lower, 1e-6);
  EXPECT_LT(plain.growth_rate_upper, 0.8);
}

// The section y = 0.9 crossed downwards, from the guess at rest at height 1: projected onto the
// section the guess is at rest on it, where the flow is tangent to the section and falls away
// from it (s = 0.9 - y grows as g t^2 / 2). Its return is the next downward crossing, after a
// bounce, and Newton finds the same hop as through the apex, falling through 0.9 at
// ydot = -sqrt(2 g (apex - 0.9)).
TEST(PronkOrbitSections, ASectionCrossedDownwardsIsFoundFromTheGuessAtRest) {
  const PronkParams p;
  const PeriodicOrbit o = find_periodic_orbit(adapt(make_pronk(p)), CoordinateSection{1, 0.9, -1.0},
                                              guess(), accurate());
  ASSERT_TRUE(o.converged) << o.message;
  const Hop hand = vertical_orbit(p, 0.9);
  // Achieved: ydot 5e-10 and period 2e-9 from the hand hop's; bounds as for the apex.
  EXPECT_NEAR(o.x[1], 0.9, 1e-14);
  EXPECT_NEAR(o.x[4], -std::sqrt(2.0 * p.g * (hand.apex - 0.9)), 1e-7);
  EXPECT_NEAR(o.period, hand.time, 2e-8);
  for (int i : {0, 2, 3, 5}) EXPECT_NEAR(o.x[i], 0.0, 1e-9) << "state " << i;
  EXPECT_EQ(o.stability, OrbitStability::kStable);
  ASSERT_FALSE(o.decisions.empty());
  EXPECT_NE(o.decisions.front().find("does not cross the section"), std::string::npos)
      << o.decisions.front();
  std::printf("section y = 0.9 downwards: ydot %.10f (hand %.10f), period %.10f (hand %.10f)\n",
              o.x[4], -std::sqrt(2.0 * p.g * (hand.apex - 0.9)), o.period, hand.time);
}

// The same section as a hyperplane, s = -e_1 . x + 0.9: the same function of x, so the same
// Newton steps and the same orbit, bit for bit up to the order of the sums.
TEST(PronkOrbitSections, AHyperplaneSectionFindsTheSameHopAsTheCoordinateLevel) {
  const PronkParams p;
  const auto model = adapt(make_pronk(p));
  const PeriodicOrbit level =
      find_periodic_orbit(model, CoordinateSection{1, 0.9, -1.0}, guess(), accurate());
  Eigen::VectorXd normal = Eigen::VectorXd::Zero(6);
  normal[1] = -1.0;
  const PeriodicOrbit plane =
      find_periodic_orbit(model, HyperplaneSection{normal, -0.9}, guess(), accurate());
  ASSERT_TRUE(level.converged && plane.converged) << plane.message;
  EXPECT_LT((plane.x - level.x).lpNorm<Eigen::Infinity>(), 1e-12);
  EXPECT_NEAR(plane.period, level.period, 1e-12);
  EXPECT_NEAR(plane.growth_rate_upper, level.growth_rate_upper, 1e-12);
  EXPECT_EQ(plane.stability, level.stability);
}

TEST(PronkOrbitSections, BadHyperplanesAreRefusedWithTheirValues) {
  const auto model = adapt(make_pronk(PronkParams{}));
  const auto message = [&](Eigen::VectorXd normal, double offset) {
    return testing::message_of([&] {
      find_periodic_orbit(model, HyperplaneSection{std::move(normal), offset}, guess());
    });
  };
  EXPECT_THAT(message(Eigen::VectorXd::Ones(5), 0.0),
              HasSubstr("the normal has 5 entries, the model 6 states"));
  EXPECT_THAT(message(Eigen::VectorXd::Zero(6), 0.0), HasSubstr("the normal is zero"));
  Eigen::VectorXd bad = Eigen::VectorXd::Ones(6);
  bad[3] = std::numeric_limits<double>::infinity();
  EXPECT_THAT(message(bad, 0.0), HasSubstr("normal[3] is inf"));
  EXPECT_THAT(message(Eigen::VectorXd::Ones(6), std::nan("")), HasSubstr("the offset is nan"));
}

// At a loose Newton tolerance the hop is still a hop. Its trajectory stays within 3.1 of x (the
// vertical speed swings by that much), less than 1000 times the tolerance (1000 x 2e-3 x
// (1 + |x|) = 4): where a rest point the iterates slide to would look the same, Newton goes on to
// 1e-8, where the hop keeps its motion and is found as at the default tolerance.
TEST(PronkOrbitSections, ALooseToleranceFindsTheHopNotAnEquilibrium) {
  const PronkParams p;
  const Hop hand = vertical_orbit(p, 0.9);
  for (double tolerance : {2e-3, 1e-2, 0.5}) {
    OrbitOptions options = accurate();
    options.tolerance = tolerance;
    options.stability = false;
    const PeriodicOrbit o = find_periodic_orbit(adapt(make_pronk(p)), kApex, guess(), options);
    ASSERT_TRUE(o.converged) << "tolerance " << tolerance << ": " << o.message;
    // Achieved: as at the default tolerance (2e-9 from the hand hop).
    EXPECT_NEAR(o.x[1], hand.apex, 2e-8) << tolerance;
    EXPECT_NEAR(o.period, hand.time, 2e-8) << tolerance;
    EXPECT_LE(o.residual, 1e-8 * (1.0 + o.x.lpNorm<Eigen::Infinity>()));
    ASSERT_EQ(o.decisions.size(), 1u) << tolerance;
    EXPECT_NE(o.decisions[0].find("to tell an orbit from a rest point"), std::string::npos)
        << o.decisions[0];
  }
}

TEST(PronkOrbitDesign, FootGradientMatchesCentralDifferences) {
  // The hand gradient Da of core/pronk.h, and the penetration against the foot's position.
  const double qs[][3] = {{0.0, 0.5, 0.0}, {0.3, 0.4, 0.2}, {-1.0, 0.7, -1.1}, {2.0, -0.1, 2.5}};
  for (const int side : {1, -1}) {
    const PronkFoot foot{0.5, 0.5, side};
    for (const auto& q0 : qs) {
      double grad[3];
      const double a = foot(q0, grad);
      double point[2];
      foot.foot(q0, point);
      EXPECT_NEAR(a, -point[1], 1e-15);
      for (int i = 0; i < 3; ++i) {
        double plus[3] = {q0[0], q0[1], q0[2]}, minus[3] = {q0[0], q0[1], q0[2]};
        const double h = 1e-6;
        plus[i] += h;
        minus[i] -= h;
        const double difference = (foot(plus, static_cast<double*>(nullptr)) -
                                   foot(minus, static_cast<double*>(nullptr))) /
                                  (2.0 * h);
        // Achieved: about 1e-10 (the difference's O(h^2) and rounding); bound 1e-8.
        EXPECT_NEAR(grad[i], difference, 1e-8) << "side " << side << " component " << i;
      }
    }
  }
}

TEST(PronkOrbitDesign, WithoutTheTetherTheDriftIsNeutral) {
  PronkParams free_body;
  free_body.tether = 0.0;
  free_body.tether_damping = 0.0;
  const auto model = adapt(make_pronk(free_body));
  const PeriodicOrbit o = find_periodic_orbit(model, kApex, guess());
  ASSERT_TRUE(o.converged) << o.message;
  // Translation invariance: a shift of x comes back unchanged, so the growth rate is 1 and no
  // verdict says stable.
  EXPECT_LE((o.return_map.apply(unit(0)) - unit(0)).lpNorm<Eigen::Infinity>(), 1e-9);
  // The cycle's computed rate is 1; the lower end is below it by the eigenvalue's margin, which
  // for this double eigenvalue (a Jordan block) is a root of the rounding.
  EXPECT_NEAR(o.growth_rate_lower + o.bracket.lower_margin, 1.0, 1e-6);
  EXPECT_LE(o.growth_rate_lower, 1.0);
  EXPECT_NE(o.stability, OrbitStability::kStable);
}

TEST(PronkOrbitDesign, StableOnlyNearJEqualsMHipSquared) {
  // The same orbit (J does not enter the vertical hop) with the body's inertia 20% off m d^2:
  // pitch turns too far or not far enough in stance, and the hop is unstable.
  for (const double inertia : {0.2, 0.3}) {
    PronkParams p;
    p.J = inertia;
    const auto model = adapt(make_pronk(p));
    const PeriodicOrbit o = find_periodic_orbit(model, kApex, guess());
    ASSERT_TRUE(o.converged) << o.message;
    EXPECT_EQ(o.stability, OrbitStability::kUnstable) << "J = " << inertia;
    EXPECT_GT(o.growth_rate_lower, 1.0) << "J = " << inertia;
  }
}

}  // namespace
}  // namespace bflow

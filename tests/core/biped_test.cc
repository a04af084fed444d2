#include "bflow/core/biped.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <iostream>
#include <string>
#include <type_traits>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/ad/jet_bridge.h"
#include "bflow/ad/model_jump.h"
#include "bflow/ad/tangent_checker.h"
#include "bflow/core/errors.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/model.h"
#include "bflow/core/signs.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;
using Vector6 = Eigen::Matrix<double, 6, 1>;

static_assert(BipedScene::kStates == 6 && BipedScene::kSurfaces == 2);
static_assert(BipedModeDampingScene::kStates == 6 && BipedModeDampingScene::kSurfaces == 2);

BipedParams params(BipedVariant variant) {
  BipedParams p;
  p.variant = variant;
  return p;
}

template <typename Model>
Vector6 field_of(const Model& model, const Vector6& x, Signs b) {
  Vector6 xdot;
  model.field(x.data(), b, xdot.data());
  return xdot;
}

std::vector<Signs> all_words() {
  return {Signs::parse("--"), Signs::parse("+-"), Signs::parse("-+"), Signs::parse("++")};
}

std::vector<Vector6> sample_states() {
  std::vector<Vector6> states;
  states.push_back(biped_touchdown(BipedParams{}).state);
  Vector6 x;
  x << 0.13, 0.05, 0.4, -0.7, -2.1, 0.9;
  states.push_back(x);
  x << -0.4, 0.6, -1.2, 0.3, 0.8, -1.5;
  states.push_back(x);
  return states;
}

const Eigen::IOFormat kMatrixFormat(8, 0, ", ", "\n", "  [", "]");

TEST(BipedTest, FeetAndPenetrationFollowTheGeometry) {
  const BipedParams p;
  const double l = 0.5, sin_psi = std::sin(p.psi), cos_psi = std::cos(p.psi);
  const BipedScene scene = make_biped(params(BipedVariant::kDissipative));
  const Vector6 x0 = biped_initial_state();
  // At (0, 1, 0) the feet are at (+-l sin psi, 1 - l cos psi), above the ground y = -x^2.
  double foot[2];
  scene.effect<2>().constraint.foot(x0.data(), foot);
  EXPECT_NEAR(foot[0], l * sin_psi, 1e-16);
  EXPECT_NEAR(foot[1], 1.0 - l * cos_psi, 1e-16);
  scene.effect<3>().constraint.foot(x0.data(), foot);
  EXPECT_NEAR(foot[0], -l * sin_psi, 1e-16);
  EXPECT_NEAR(foot[1], 1.0 - l * cos_psi, 1e-16);
  double h[2];
  scene.surfaces(x0.data(), h);
  const double a = -l * l * sin_psi * sin_psi - (1.0 - l * cos_psi);  // -0.125 - 0.6464
  EXPECT_NEAR(h[0], a, 1e-15);
  EXPECT_NEAR(h[1], a, 1e-15);
  EXPECT_LT(h[0], 0.0);
  // Rotating by theta: foot 0 = (x + l sin(theta + psi), y - l cos(theta + psi)).
  Vector6 x;
  x << 0.2, 0.3, 0.5, 0, 0, 0;
  scene.effect<2>().constraint.foot(x.data(), foot);
  EXPECT_NEAR(foot[0], 0.2 + l * std::sin(0.5 + p.psi), 1e-15);
  EXPECT_NEAR(foot[1], 0.3 - l * std::cos(0.5 + p.psi), 1e-15);
}

TEST(BipedTest, HandGradientOfEachFootMatchesAd) {
  const BipedScene scene = make_biped(params(BipedVariant::kConservative));
  const ad::TangentChecker checker(ad::TangentCheckerOptions{1e-6, 1e-14});
  for (const BipedFoot& foot : {scene.effect<2>().constraint, scene.effect<3>().constraint}) {
    for (const Vector6& x : sample_states()) {
      const Eigen::Vector3d q = x.head<3>();
      Eigen::RowVector3d grad;
      foot(q.data(), grad.data());
      const auto a = [&foot](const auto* in, auto* out) {
        using T = std::remove_cv_t<std::remove_pointer_t<decltype(in)>>;
        out[0] = foot(in, static_cast<T*>(nullptr));
      };
      const ad::TangentReport r = checker.check_against_ad(a, 1, q, grad);
      EXPECT_TRUE(r.ok) << "side " << foot.side << ": " << r.str();
    }
  }
}

TEST(BipedTest, TouchdownHelperPutsBothFeetOnTheGround) {
  const BipedParams p;
  const BipedTouchdown td = biped_touchdown(p);
  // y_td = l cos psi - l^2 sin^2 psi = 0.35355 - 0.125; t = sqrt(2 (1 - y_td) / g).
  const double y_td = 0.5 * std::cos(p.psi) - 0.125;
  EXPECT_NEAR(td.state[1], y_td, 1e-16);
  EXPECT_NEAR(td.time, std::sqrt(2.0 * (1.0 - y_td) / 9.8), 1e-15);
  EXPECT_NEAR(td.time, 0.3967847, 1e-7);
  // Free fall: y = 1 - g t^2 / 2, ydot = -g t.
  EXPECT_NEAR(1.0 - 0.5 * 9.8 * td.time * td.time, td.state[1], 1e-15);
  EXPECT_NEAR(td.state[4], -9.8 * td.time, 1e-14);
  EXPECT_EQ(td.state[0], 0.0);
  EXPECT_EQ(td.state[2], 0.0);
  EXPECT_EQ(td.state[3], 0.0);
  EXPECT_EQ(td.state[5], 0.0);
  const BipedScene scene = make_biped(params(BipedVariant::kDissipative));
  double h[2];
  scene.surfaces(td.state.data(), h);
  EXPECT_LT(std::abs(h[0]), 1e-15);
  EXPECT_LT(std::abs(h[1]), 1e-15);
  std::cout << "touchdown t = " << td.time << ", rho = " << td.state.transpose() << ", h(rho) = ("
            << h[0] << ", " << h[1] << ")\n";

  EXPECT_EQ(
      testing::message_of([&] { biped_touchdown(p, 0.2); }),
      "biped_touchdown: start_height 0.2 must be above the touchdown height " +
          format_number(0.5 * std::cos(p.psi) - 0.5 * 0.5 * std::sin(p.psi) * std::sin(p.psi)));
  BipedParams up = p;
  up.g = -1.0;
  EXPECT_EQ(testing::message_of([&] { biped_touchdown(up); }),
            "biped_touchdown: the body falls only for g > 0, got g = -1");
}

// Conservative variant: M qddot = -grad V(q), V = m g y + sum over active j of kappa a_j^2 / 2,
// for every word.
TEST(BipedTest, ConservativeForceIsNegativeGradientOfPotential) {
  BipedParams p = params(BipedVariant::kConservative);
  p.kappa = 7.0;
  p.m = 1.3;
  p.J = 0.6;
  const BipedScene scene = make_biped(p);
  const Eigen::Vector3d mass(p.m, p.m, p.J);
  const ad::TangentChecker checker(ad::TangentCheckerOptions{std::cbrt(2.2e-16), 1e-7});
  for (const Vector6& x : sample_states()) {
    for (const Signs& b : all_words()) {
      const auto energy = [&scene, b](const auto* in, auto* out) { out[0] = scene.energy(in, b); };
      // d energy / dx = (grad V(q), M qdot) = (-M qddot, M qdot).
      const Vector6 xdot = field_of(scene, x, b);
      Eigen::RowVectorXd expected(6);
      expected << -(mass.array() * xdot.tail<3>().array()).transpose(),
          (mass.array() * x.tail<3>().array()).transpose();
      const ad::TangentReport by_ad = checker.check_against_ad(energy, 1, x, expected);
      EXPECT_LT(by_ad.max_rel_error, 1e-13) << b.str() << ": " << by_ad.str();
      const ad::TangentReport by_fd = checker.check_jacobian(energy, 1, x, expected);
      EXPECT_TRUE(by_fd.ok) << b.str() << ": " << by_fd.str();
    }
  }
}

// Classic RK4 with the word held fixed (F_b is smooth for a fixed b).
template <typename Model>
Vector6 rk4(const Model& model, Vector6 x, Signs b, double duration, int steps) {
  const double h = duration / steps;
  for (int k = 0; k < steps; ++k) {
    const Vector6 k1 = field_of(model, x, b);
    const Vector6 k2 = field_of(model, Vector6(x + 0.5 * h * k1), b);
    const Vector6 k3 = field_of(model, Vector6(x + 0.5 * h * k2), b);
    const Vector6 k4 = field_of(model, Vector6(x + h * k3), b);
    x += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
  }
  return x;
}

TEST(BipedTest, EnergyIsConservedWithBothFeetDownOnlyWithoutDamping) {
  const Signs both = Signs::parse("++");
  Vector6 x0 = biped_touchdown(BipedParams{}).state;
  x0[3] = 0.3;  // break the symmetry so that theta moves too
  x0[5] = -0.8;
  const BipedScene conservative = make_biped(params(BipedVariant::kConservative));
  const double e0 = conservative.energy(x0.data(), both);
  const Vector6 x1 = rk4(conservative, x0, both, 0.5, 500);
  const double drift = std::abs(conservative.energy(x1.data(), both) - e0);
  std::cout << "conservative: E(0) = " << e0 << ", |E(0.5) - E(0)| = " << drift
            << " (RK4, h = 1e-3)\n";
  // RK4's energy error is O(h^4) ~ 1e-12 times the field's derivatives here.
  EXPECT_LT(drift, 1e-9);
  EXPECT_GT(std::abs(x1[2]), 1e-3);  // theta moved: the test exercises the rotation

  for (const BipedVariant variant : {BipedVariant::kDissipative, BipedVariant::kModeDamping}) {
    visit_biped(params(variant), [&](const auto& scene) {
      const double start = scene.energy(x0.data(), both);
      const double end = scene.energy(rk4(scene, x0, both, 0.5, 500).data(), both);
      std::cout << biped_variant_name(variant) << ": E(0) = " << start << ", E(0.5) = " << end
                << "\n";
      EXPECT_LT(end, start - 1e-2) << biped_variant_name(variant);
      return 0;
    });
  }
}

TEST(BipedTest, ModeDampingIsHalfDampingWithOneFootAndFullWithBoth) {
  const BipedModeDampingScene mode = make_biped_mode_damping(BipedParams{});
  BipedParams half = params(BipedVariant::kDissipative);
  half.beta = 0.5;
  const BipedScene half_damped = make_biped(half);
  const BipedScene full_damped = make_biped(params(BipedVariant::kDissipative));
  const BipedScene undamped = make_biped(params(BipedVariant::kConservative));
  for (const Vector6& x : sample_states()) {
    for (const char* one : {"+-", "-+"}) {
      const Signs b = Signs::parse(one);
      EXPECT_LT((field_of(mode, x, b) - field_of(half_damped, x, b)).norm(), 1e-14) << one;
    }
    const Signs both = Signs::parse("++");
    EXPECT_LT((field_of(mode, x, both) - field_of(full_damped, x, both)).norm(), 1e-14);
    const Signs none = Signs::parse("--");
    EXPECT_EQ(field_of(mode, x, none), field_of(undamped, x, none));
  }
}

TEST(BipedTest, AdJacobiansOfEveryVariantAndWordAgreeWithCentralDifferences) {
  const ad::TangentChecker checker(ad::TangentCheckerOptions{std::cbrt(2.2e-16), 1e-7});
  for (const BipedVariant variant :
       {BipedVariant::kConservative, BipedVariant::kDissipative, BipedVariant::kModeDamping}) {
    visit_biped(params(variant), [&](const auto& scene) {
      for (const Vector6& x : sample_states()) {
        for (const Signs& b : all_words()) {
          const ad::TangentReport r = checker.check_field_jacobian(scene, x, b);
          EXPECT_TRUE(r.ok) << biped_variant_name(variant) << " " << r.str();
        }
        const ad::TangentReport r = checker.check_normals(scene, x);
        EXPECT_TRUE(r.ok) << biped_variant_name(variant) << " " << r.str();
      }
      return 0;
    });
  }
}

// The saltation matrix of [B] (2.5) for surface j crossed from word `before` to `after`.
template <typename Model>
Eigen::MatrixXd saltation_by_hand(const Model& model, const Vector6& rho, int j, Signs before,
                                  Signs after) {
  const Eigen::MatrixXd eta = ad::normals(model, rho);
  const Eigen::VectorXd f_before = ad::field_value(model, rho, before);
  const Eigen::VectorXd f_after = ad::field_value(model, rho, after);
  return Eigen::MatrixXd::Identity(6, 6) +
         (f_after - f_before) * eta.row(j) / eta.row(j).dot(f_before);
}

struct Pieces {
  Eigen::MatrixXd m01;  // foot 0 touches first
  Eigen::MatrixXd m10;  // foot 1 touches first
};

template <typename Model>
Pieces pieces_at_touchdown(const Model& model, const char* name) {
  const Vector6 rho = biped_touchdown(BipedParams{}).state;
  const JumpMap jump = ad::jump_map_at(model, rho, {0, 1});
  Pieces p{jump.saltation({0, 1}), jump.saltation({1, 0})};
  // Independent check: products of the single-surface saltation matrices (2.5).
  const Signs none = Signs::parse("--"), zero = Signs::parse("+-"), one = Signs::parse("-+"),
              both = Signs::parse("++");
  const Eigen::MatrixXd m01 =
      saltation_by_hand(model, rho, 1, zero, both) * saltation_by_hand(model, rho, 0, none, zero);
  const Eigen::MatrixXd m10 =
      saltation_by_hand(model, rho, 0, one, both) * saltation_by_hand(model, rho, 1, none, one);
  EXPECT_LT((p.m01 - m01).norm(), 1e-13 * m01.norm()) << name;
  EXPECT_LT((p.m10 - m10).norm(), 1e-13 * m10.norm()) << name;
  std::cout << name << " at touchdown:\nM_01 (foot 0 first) =\n"
            << p.m01.format(kMatrixFormat) << "\nM_10 (foot 1 first) =\n"
            << p.m10.format(kMatrixFormat) << "\n|M_01 - M_10| = " << (p.m01 - p.m10).norm()
            << ", |M_01 - I| = " << (p.m01 - Eigen::MatrixXd::Identity(6, 6)).norm() << "\n";
  return p;
}

TEST(BipedTest, ConservativeJumpIsIdentity) {
  const Pieces p =
      pieces_at_touchdown(make_biped(params(BipedVariant::kConservative)), "conservative");
  // F_b(rho) is the same for every word (kappa a_j(rho) = 0): both saltations are I.
  EXPECT_LT((p.m01 - Eigen::MatrixXd::Identity(6, 6)).norm(), 1e-12);
  EXPECT_LT((p.m10 - Eigen::MatrixXd::Identity(6, 6)).norm(), 1e-12);
  EXPECT_LE((p.m01 - p.m10).norm(), 1e-12 * p.m01.norm());
}

TEST(BipedTest, DissipativeJumpHasEqualPieces) {
  const Pieces p =
      pieces_at_touchdown(make_biped(params(BipedVariant::kDissipative)), "dissipative");
  // The factors (3.7) commute: one linear piece, a C^1 flow, but not the identity.
  EXPECT_LE((p.m01 - p.m10).norm(), 1e-12 * p.m01.norm());
  EXPECT_GT((p.m01 - Eigen::MatrixXd::Identity(6, 6)).norm(), 1e-1);
}

TEST(BipedTest, ModeDampingJumpHasTwoDistinctPieces) {
  const Pieces p = pieces_at_touchdown(make_biped_mode_damping(BipedParams{}), "mode-damping");
  EXPECT_GT((p.m01 - p.m10).norm(), 1e-3);
  // The B-derivative is continuous: the pieces agree on the boundary between their cones,
  // the directions dx that still reach both surfaces at the same time,
  // eta_0 dx / (eta_0 F_--) = eta_1 dx / (eta_1 F_--).
  const BipedModeDampingScene scene = make_biped_mode_damping(BipedParams{});
  const Vector6 rho = biped_touchdown(BipedParams{}).state;
  const Eigen::MatrixXd eta = ad::normals(scene, rho);
  const Eigen::VectorXd f = ad::field_value(scene, rho, Signs::parse("--"));
  const Eigen::RowVectorXd difference =
      eta.row(0) / eta.row(0).dot(f) - eta.row(1) / eta.row(1).dot(f);
  for (int i = 0; i < 6; ++i) {
    // A basis of {dx : (eta_0 - eta_1) dx = 0}: e_i minus its component along the difference.
    Eigen::VectorXd dx = Eigen::VectorXd::Unit(6, i);
    dx -= difference.transpose() * difference.dot(dx) / difference.squaredNorm();
    EXPECT_LT((p.m01 * dx - p.m10 * dx).norm(), 1e-12) << "i = " << i;
  }
}

// One RK4 step of length h with the word b held fixed.
template <typename Model>
Vector6 rk4_step(const Model& model, const Vector6& x, Signs b, double h) {
  const Vector6 k1 = field_of(model, x, b);
  const Vector6 k2 = field_of(model, Vector6(x + 0.5 * h * k1), b);
  const Vector6 k3 = field_of(model, Vector6(x + 0.5 * h * k2), b);
  const Vector6 k4 = field_of(model, Vector6(x + h * k3), b);
  return x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
}

// True when some surface is on the other side than b says.
template <typename Model>
bool crossed(const Model& model, const Vector6& x, Signs b) {
  double h[2];
  model.surfaces(x.data(), h);
  return (h[0] > 0.0) != b.plus(0) || (h[1] > 0.0) != b.plus(1);
}

// The flow phi_duration(x) from word b: RK4 steps of at most h; a step in which a surface is
// crossed is cut (by bisection on its length) just after the first crossing, where the word
// takes the new sides.
template <typename Model>
Vector6 hybrid_flow(const Model& model, Vector6 x, Signs b, double duration, double h) {
  double t = 0.0;
  while (t < duration) {
    double step = std::min(h, duration - t);
    if (crossed(model, rk4_step(model, x, b, step), b)) {
      double lo = 0.0;
      for (int k = 0; k < 80; ++k) {
        const double mid = 0.5 * (lo + step);
        (crossed(model, rk4_step(model, x, b, mid), b) ? step : lo) = mid;
      }
    }
    x = rk4_step(model, x, b, step);
    t += step;
    double values[2];
    model.surfaces(x.data(), values);
    for (int j = 0; j < 2; ++j) b = values[j] > 0.0 ? b.with_plus(j) : b.with_minus(j);
  }
  return x;
}

// The jump map against one-sided differences of the simulated flow over [-tau, tau] around
// touchdown: (phi(rho- + alpha dx) - phi(rho-)) / alpha with alpha << tau picks the piece of
// the crossing order dx causes, and must match (I + tau A_++) B((I + tau A_--) dx) up to
// O(tau^2 |A|^2 + alpha) (A_b = DF_b(rho)). The two pieces of the mode-damping biped differ
// by O(1), so this checks the order and the orientation of the normals end to end.
TEST(BipedTest, ModeDampingJumpAgreesWithOneSidedDifferencesOfTheFlow) {
  const BipedParams p;
  const BipedModeDampingScene scene = make_biped_mode_damping(p);
  const BipedTouchdown td = biped_touchdown(p);
  const double tau = 1e-4, alpha = 1e-9, h = 1e-5;
  const double t0 = td.time - tau;
  Vector6 start;  // free fall, no contact before touchdown
  start << 0.0, 1.0 - 0.5 * p.g * t0 * t0, 0.0, 0.0, -p.g * t0, 0.0;
  const JumpMap jump = ad::jump_map_at(scene, td.state, {0, 1});
  const Eigen::MatrixXd before = Eigen::MatrixXd::Identity(6, 6) +
                                 tau * ad::field_jacobian(scene, td.state, Signs::parse("--"));
  const Eigen::MatrixXd after = Eigen::MatrixXd::Identity(6, 6) +
                                tau * ad::field_jacobian(scene, td.state, Signs::parse("++"));
  const Signs none = Signs::parse("--");
  const Vector6 base = hybrid_flow(scene, start, none, 2.0 * tau, h);
  std::vector<Vector6> directions(4);
  directions[0] << 1.0, 0.0, 0.0, 0.0, 0.0, 0.0;
  directions[1] << -1.0, 0.0, 0.0, 0.0, 0.0, 0.0;
  directions[2] << 0.0, 0.0, 1.0, 0.0, 0.0, 0.0;
  directions[3] << 0.3, -0.5, -0.8, 0.2, 0.7, -0.4;
  for (const Vector6& dx : directions) {
    const Vector6 perturbed = hybrid_flow(scene, Vector6(start + alpha * dx), none, 2.0 * tau, h);
    const Vector6 one_sided = (perturbed - base) / alpha;
    const Eigen::VectorXd predicted = after * jump.apply(before * dx);
    const CrossingOrder order = jump.order(before * dx);
    const Eigen::VectorXd other_piece =
        after * jump.saltation({order.order[1], order.order[0]}) * (before * dx);
    std::cout << "dx = " << dx.transpose() << " (foot " << order.order[0] << " first)\n"
              << "  jump map   " << predicted.transpose() << "\n"
              << "  one-sided  " << one_sided.transpose() << "\n"
              << "  other piece " << other_piece.transpose() << "\n"
              << "  |one-sided - jump map| / |jump map| = "
              << (one_sided - predicted).norm() / predicted.norm() << "\n";
    EXPECT_LT((one_sided - predicted).norm(), 1e-5 * predicted.norm()) << dx.transpose();
    EXPECT_GT((one_sided - other_piece).norm(), 0.1 * predicted.norm()) << dx.transpose();
  }
}

TEST(BipedTest, VisitBipedBuildsTheSceneOfTheVariant) {
  const auto is_mode = [](const auto& scene) {
    return std::is_same_v<std::decay_t<decltype(scene)>, BipedModeDampingScene>;
  };
  EXPECT_FALSE(visit_biped(params(BipedVariant::kConservative), is_mode));
  EXPECT_FALSE(visit_biped(params(BipedVariant::kDissipative), is_mode));
  EXPECT_TRUE(visit_biped(params(BipedVariant::kModeDamping), is_mode));
  EXPECT_EQ(make_biped(params(BipedVariant::kConservative)).effect<2>().damping, 0.0);
  EXPECT_EQ(make_biped(params(BipedVariant::kDissipative)).effect<3>().damping, 1.0);
  const BipedModeDampingScene mode = make_biped_mode_damping(BipedParams{});
  EXPECT_EQ(mode.effect<2>().damping, 0.0);
  EXPECT_EQ(mode.effect<4>().damping_by_count[1], 0.5);
  EXPECT_EQ(mode.effect<4>().damping_by_count[2], 1.0);
  EXPECT_EQ(testing::message_of([] { make_biped(BipedParams{}); }),
            "make_biped: the mode-damping variant is a BipedModeDampingScene; use "
            "make_biped_mode_damping() or visit_biped()");
  EXPECT_EQ(
      testing::message_of([] { make_biped_mode_damping(params(BipedVariant::kDissipative)); }),
      "make_biped_mode_damping: variant is dissipative, use make_biped()");
}

TEST(BipedTest, SetParamParsesKeyValueText) {
  BipedParams p;
  set_param(p, "kappa", "1e6");
  set_param(p, "beta", "0");
  set_param(p, "m", "2.5");
  set_param(p, "J", "0.25");
  set_param(p, "g", "-1.5");
  set_param(p, "leg_length", "0.75");
  set_param(p, "psi", "0.5");
  set_param(p, "variant", "conservative");
  EXPECT_EQ(p.kappa, 1e6);
  EXPECT_EQ(p.beta, 0.0);
  EXPECT_EQ(p.m, 2.5);
  EXPECT_EQ(p.J, 0.25);
  EXPECT_EQ(p.g, -1.5);
  EXPECT_EQ(p.leg_length, 0.75);
  EXPECT_EQ(p.psi, 0.5);
  EXPECT_EQ(p.variant, BipedVariant::kConservative);
  set_param(p, "variant", "mode_damping");
  EXPECT_EQ(p.variant, BipedVariant::kModeDamping);
  set_param(p, "variant", "dissipative");
  EXPECT_EQ(p.variant, BipedVariant::kDissipative);
  EXPECT_NO_THROW(validate_biped_params(p));
}

TEST(BipedTest, SetParamRejectsUnknownKeysAndBadValues) {
  using testing::message_of;
  BipedParams p;
  const BipedParams before = p;
  EXPECT_EQ(message_of([&] { set_param(p, "stiffness", "3"); }),
            "set_param: unknown biped parameter \"stiffness\" (known: m, J, g, leg_length, psi, "
            "kappa, beta, thrust, thrust_speed, variant)");
  EXPECT_EQ(message_of([&] { set_param(p, "kappa", "1e6x"); }),
            "set_param: biped parameter \"kappa\" = \"1e6x\" is not a number");
  EXPECT_EQ(message_of([&] { set_param(p, "kappa", ""); }),
            "set_param: biped parameter \"kappa\" = \"\" is not a number");
  EXPECT_EQ(message_of([&] { set_param(p, "m", "1e999"); }),
            "set_param: biped parameter \"m\" = \"1e999\" is not a number");
  EXPECT_EQ(message_of([&] { set_param(p, "kappa", "-1"); }),
            "set_param: biped parameter \"kappa\" must be > 0, got -1");
  EXPECT_EQ(message_of([&] { set_param(p, "beta", "-0.5"); }),
            "set_param: biped parameter \"beta\" must be >= 0, got -0.5");
  EXPECT_EQ(message_of([&] { set_param(p, "psi", "2"); }),
            "set_param: biped parameter \"psi\" must be in (0, pi/2), got 2");
  EXPECT_EQ(message_of([&] { set_param(p, "g", "nan"); }),
            "set_param: biped parameter \"g\" must be finite, got nan");
  EXPECT_EQ(message_of([&] { set_param(p, "variant", "springy"); }),
            "set_param: biped variant \"springy\" is not one of conservative, dissipative, "
            "mode-damping");
  EXPECT_EQ(p.kappa, before.kappa);
  EXPECT_EQ(p.beta, before.beta);
  EXPECT_EQ(p.psi, before.psi);
  EXPECT_EQ(p.variant, before.variant);

  BipedParams bad;
  bad.J = 0.0;
  EXPECT_EQ(message_of([&] { validate_biped_params(bad); }),
            "validate_biped_params: biped parameter \"J\" must be > 0, got 0");
  EXPECT_THAT(message_of([&] { make_biped(bad); }), HasSubstr("make_biped: biped parameter"));
}

}  // namespace
}  // namespace bflow

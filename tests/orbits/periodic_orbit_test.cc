// CornerOrbit (examples/corner_orbit.h) against references written here from its closed forms,
// none of them using the library's flow or jump code:
//  - the fixed point's w from the piecewise-exponential solution of w' = -a w + g_b, with the
//    regions' words read off the signs of h_j along the unit circle;
//  - with separate events, the monodromy composed of closed-form transition matrices and
//    saltation matrices;
//  - through the corner, the return map's pieces from each surface's crossing-time shift (g_b of
//    the perturbed trajectory integrated over the reordered crossings), and one-sided
//    differences of the return map itself.
#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "bflow/examples/corner_orbit.h"
#include "bflow/integrators/model_adapter.h"
#include "bflow/orbits/orbit_family.h"
#include "bflow/orbits/periodic_orbit.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using examples::CornerOrbit;
using examples::CornerOrbitSection;
using ::testing::HasSubstr;

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2.0 * kPi;
constexpr double kSectionAngle = 1.25 * kPi;  // where p - q = 0 is crossed upwards

// The point at radius r and height w on the section, with d states (z = 0).
Eigen::VectorXd on_section(double r, double w, int d = 3) {
  Eigen::VectorXd x = Eigen::VectorXd::Zero(d);
  x[0] = x[1] = -r / std::sqrt(2.0);
  x[2] = w;
  return x;
}

// The section's tangent space at the orbit: e_r (radial), e_w and the e_z.
Eigen::MatrixXd radial_basis(int d = 3) {
  Eigen::MatrixXd basis = Eigen::MatrixXd::Zero(d, d - 1);
  basis.col(0) = on_section(1.0, 0.0, d);
  for (int i = 2; i < d; ++i) basis(i, i - 1) = 1.0;
  return basis;
}

// The angle travelled from the section to theta, in [0, 2 pi).
double from_section(double theta) {
  const double phi = std::fmod(theta - kSectionAngle, kTwoPi);
  return phi < 0.0 ? phi + kTwoPi : phi;
}

// The sides at angle theta on the unit circle, where h_j = sin theta - kappa_j (1 - cos theta).
Signs sides_at(const CornerOrbit& m, double theta) {
  Signs b(m.surfaces());
  for (int j = 0; j < m.surfaces(); ++j) {
    const double kappa = m.kappas[static_cast<std::size_t>(j)];
    if (std::sin(theta) - kappa * (1.0 - std::cos(theta)) > 0.0) b = b.with_plus(j);
  }
  return b;
}

// The w jump of the trajectory perturbed by dr and dz (at the event) at the event at angle
// theta: each crossed surface's crossing moves by dt_j (implicit function theorem on
// h_j = r sin theta - kappa_j (1 - r cos theta) + z_{j-1} = 0, the z term for j >= 2); the
// perturbed trajectory's g_b minus the nominal one, integrated over the moved crossings.
double w_jump(const CornerOrbit& m, double theta, Signs before, Signs after, double dr,
              const Eigen::VectorXd& dz = Eigen::VectorXd()) {
  const double c = std::cos(theta), s = std::sin(theta);
  std::vector<std::pair<double, int>> shifts;
  for (int j = 0; j < m.surfaces(); ++j) {
    if (before.plus(j) == after.plus(j)) continue;
    const double kappa = m.kappas[static_cast<std::size_t>(j)];
    const double z = (j >= 2 && dz.size() > j - 2) ? dz[j - 2] : 0.0;
    shifts.emplace_back(-(dr * (s + kappa * c) + z) / (m.omega * (c - kappa * s)), j);
  }
  std::sort(shifts.begin(), shifts.end());
  const double lo = std::min(0.0, shifts.front().first);
  const double hi = std::max(0.0, shifts.back().first);
  double perturbed = 0.0, at = lo;
  Signs word = before;
  for (const auto& [dt, j] : shifts) {
    perturbed += m.g(word) * (dt - at);
    at = dt;
    word = word.flipped(std::uint64_t{1} << j);
  }
  perturbed += m.g(word) * (hi - at);
  return perturbed - (m.g(before) * (0.0 - lo) + m.g(after) * hi);
}

struct HandOrbit {
  double period = 0.0, mu_r = 0.0, mu_w = 0.0, w_star = 0.0;
  std::vector<double> events;  // angles from the section, increasing (the corner once)
  std::vector<Signs> regions;  // regions[i] before events[i]; the last after the last event
  Eigen::Vector2d image_plus, image_minus;  // DP(e_r) and DP(-e_r) in (e_r, e_w)
  double mu_z = 0.0;
  // The w component of DP(+-e_z_i): z_i decays as e^{-a_z t} and moves surface i + 2's crossings.
  std::vector<double> w_of_z_plus, w_of_z_minus;
};

HandOrbit hand_orbit(const CornerOrbit& m) {
  HandOrbit o;
  o.period = kTwoPi / m.omega;
  o.mu_r = std::exp(-2.0 * m.k * o.period);
  o.mu_w = std::exp(-m.a * o.period);
  o.events.push_back(from_section(0.0));
  for (double kappa : m.kappas) {
    o.events.push_back(from_section(kappa == 0.0 ? kPi : 2.0 * std::atan(1.0 / kappa)));
  }
  std::sort(o.events.begin(), o.events.end());
  const std::size_t events = o.events.size();
  auto end_of = [&](std::size_t i) { return i < events ? o.events[i] : kTwoPi; };
  for (std::size_t i = 0; i <= events; ++i) {
    const double start = i == 0 ? 0.0 : o.events[i - 1];
    o.regions.push_back(sides_at(m, kSectionAngle + 0.5 * (start + end_of(i))));
  }
  // w(T) = e^{-aT} w(0) + sum over regions of g_i / a (e^{-a (T - t_{i+1})} - e^{-a (T - t_i)}).
  double forced = 0.0;
  for (std::size_t i = 0; i <= events; ++i) {
    const double start = (i == 0 ? 0.0 : o.events[i - 1]) / m.omega;
    const double end = end_of(i) / m.omega;
    forced += m.g(o.regions[i]) / m.a *
              (std::exp(-m.a * (o.period - end)) - std::exp(-m.a * (o.period - start)));
  }
  o.w_star = forced / (1.0 - o.mu_w);
  // dr decays as e^{-2kt} and leaves the return time alone; each event's w jump decays as e^{-at}.
  for (double sign : {1.0, -1.0}) {
    double w = 0.0;
    for (std::size_t i = 0; i < events; ++i) {
      const double t = o.events[i] / m.omega;
      w +=
          std::exp(-m.a * (o.period - t)) * w_jump(m, kSectionAngle + o.events[i], o.regions[i],
                                                   o.regions[i + 1], sign * std::exp(-2 * m.k * t));
    }
    (sign > 0 ? o.image_plus : o.image_minus) = Eigen::Vector2d(sign * o.mu_r, w);
  }
  o.mu_z = std::exp(-m.a_z * o.period);
  for (int i = 0; i < m.extra_states(); ++i) {
    for (double sign : {1.0, -1.0}) {
      double w = 0.0;
      for (std::size_t k = 0; k < events; ++k) {
        const double t = o.events[k] / m.omega;
        Eigen::VectorXd dz = Eigen::VectorXd::Zero(m.extra_states());
        dz[i] = sign * std::exp(-m.a_z * t);
        w += std::exp(-m.a * (o.period - t)) *
             w_jump(m, kSectionAngle + o.events[k], o.regions[k], o.regions[k + 1], 0.0, dz);
      }
      (sign > 0 ? o.w_of_z_plus : o.w_of_z_minus).push_back(w);
    }
  }
  return o;
}

// [e_r e_theta e_w] at angle theta.
Eigen::Matrix3d frame(double theta) {
  Eigen::Matrix3d e;
  e << std::cos(theta), -std::sin(theta), 0.0, std::sin(theta), std::cos(theta), 0.0, 0.0, 0.0, 1.0;
  return e;
}

// The monodromy from the section around once when every event crosses one surface: on r = 1,
// dr decays as e^{-2kt}, dtheta stays, dw decays as e^{-at}; a crossing of surface j is the
// saltation matrix I + (F+ - F-) eta^T / (eta . F-) with eta = Dh_j = (kappa_j, 1, 0).
Eigen::Matrix3d hand_monodromy(const CornerOrbit& m, const HandOrbit& o) {
  Eigen::Matrix3d monodromy = Eigen::Matrix3d::Identity();
  double at = 0.0;
  auto advance = [&](double to) {
    const double t = (to - at) / m.omega;
    const Eigen::Vector3d decay(std::exp(-2.0 * m.k * t), 1.0, std::exp(-m.a * t));
    monodromy = frame(kSectionAngle + to) * decay.asDiagonal() *
                frame(kSectionAngle + at).transpose() * monodromy;
    at = to;
  };
  for (std::size_t i = 0; i < o.events.size(); ++i) {
    advance(o.events[i]);
    const double theta = kSectionAngle + o.events[i];
    const std::uint64_t crossed = o.regions[i].bits() ^ o.regions[i + 1].bits();
    int j = 0;
    while (!((crossed >> j) & 1u)) ++j;
    EXPECT_EQ(crossed, std::uint64_t{1} << j) << "event " << i << " crosses one surface";
    const Eigen::Vector3d eta(m.kappas[static_cast<std::size_t>(j)], 1.0, 0.0);
    const Eigen::Vector3d f_before(-m.omega * std::sin(theta), m.omega * std::cos(theta), 0.0);
    const Eigen::Vector3d jump(0.0, 0.0, m.g(o.regions[i + 1]) - m.g(o.regions[i]));
    monodromy =
        (Eigen::Matrix3d::Identity() + jump * eta.transpose() / eta.dot(f_before)) * monodromy;
  }
  advance(kTwoPi);
  return monodromy;
}

// Real eigenvalues, increasing (the imaginary parts checked to vanish).
std::vector<double> real_eigenvalues(const Eigen::MatrixXd& a) {
  const Eigen::VectorXcd values = Eigen::EigenSolver<Eigen::MatrixXd>(a).eigenvalues();
  std::vector<double> real;
  for (Eigen::Index i = 0; i < values.size(); ++i) {
    EXPECT_NEAR(values[i].imag(), 0.0, 1e-12);
    real.push_back(values[i].real());
  }
  std::sort(real.begin(), real.end());
  return real;
}

// One surface, crossed at theta = 0 and again at 2 atan(1 / kappa): with_surfaces(1) (kappa = 0,
// where dr moves neither crossing) and kappa = 2 (where it moves both, so the saltation matrices
// couple r and w).
class CornerOrbitSeparateEvents : public ::testing::TestWithParam<double> {};

TEST_P(CornerOrbitSeparateEvents, OrbitAndMultipliersMatchTheHandMonodromy) {
  CornerOrbit m = CornerOrbit::with_surfaces(1);
  m.kappas[0] = GetParam();
  const auto model = adapt(m);
  const HandOrbit hand = hand_orbit(m);
  const PeriodicOrbit orbit = find_periodic_orbit(model, CornerOrbitSection{}, on_section(1.1, 0));
  ASSERT_TRUE(orbit.converged) << orbit.message;
  const double r = std::hypot(orbit.x[0], orbit.x[1]);
  std::printf("smooth %g: |r - 1| %.1e, |p - q| %.1e, |T - T*| %.1e, |w - w*| %.1e, newton %d\n",
              GetParam(), std::abs(r - 1.0), std::abs(orbit.x[0] - orbit.x[1]),
              std::abs(orbit.period - hand.period), std::abs(orbit.x[2] - hand.w_star),
              orbit.newton_iterations);
  // Achieved: |r - 1| 2e-11, p - q = 0, |T - T*| 4e-12, |w - w*| 3e-11 (kappa = 2: dr moves w).
  EXPECT_NEAR(r, 1.0, 1e-9);
  EXPECT_NEAR(orbit.x[0] - orbit.x[1], 0.0, 1e-14);
  EXPECT_LT(orbit.x[0], 0.0);
  EXPECT_NEAR(orbit.period, hand.period, 1e-10);
  EXPECT_NEAR(orbit.x[2], hand.w_star, 1e-9);
  ASSERT_EQ(orbit.events.size(), 2u);

  // DP(x*) = Pi M, Pi = I - F Ds^T / (Ds . F) at x*, against the library's Jacobian entry by
  // entry, and their nontrivial eigenvalues against mu_r and mu_w.
  ASSERT_TRUE(orbit.return_map.is_linear());
  const Eigen::Matrix3d monodromy = hand_monodromy(m, hand);
  const Eigen::Vector3d ds(1.0, -1.0, 0.0);
  const Eigen::Vector3d f(m.omega / std::sqrt(2.0), -m.omega / std::sqrt(2.0),
                          -m.a * hand.w_star + m.g(hand.regions[0]));
  const Eigen::Matrix3d projected =
      (Eigen::Matrix3d::Identity() - f * ds.transpose() / ds.dot(f)) * monodromy;
  // Two hand representations agree: saltation products and crossing-time shifts.
  const Eigen::MatrixXd e = radial_basis();
  Eigen::Matrix2d shifts;
  shifts << hand.image_plus, Eigen::Vector2d(0.0, hand.mu_w);
  EXPECT_LT((e.transpose() * projected * e - shifts).lpNorm<Eigen::Infinity>(), 1e-14);
  const double jacobian_error = (orbit.return_map.jacobian() - projected).lpNorm<Eigen::Infinity>();
  const Eigen::MatrixXd& basis = orbit.tangent_basis;
  const std::vector<double> reduced =
      real_eigenvalues(basis.transpose() * orbit.return_map.jacobian() * basis);
  std::vector<double> hand_multipliers = real_eigenvalues(monodromy);
  ASSERT_EQ(hand_multipliers.size(), 3u);
  // The multiplier along F is 1; the other two are the nontrivial ones.
  const auto trivial =
      std::min_element(hand_multipliers.begin(), hand_multipliers.end(),
                       [](double x, double y) { return std::abs(x - 1.0) < std::abs(y - 1.0); });
  EXPECT_NEAR(*trivial, 1.0, 1e-14);
  hand_multipliers.erase(trivial);
  const std::vector<double> closed = {std::min(hand.mu_r, hand.mu_w),
                                      std::max(hand.mu_r, hand.mu_w)};
  ASSERT_EQ(reduced.size(), 2u);
  std::vector<double> listed;
  for (const std::complex<double>& z : orbit.bracket.multipliers) {
    EXPECT_EQ(z.imag(), 0.0);
    listed.push_back(z.real());
  }
  std::sort(listed.begin(), listed.end());
  ASSERT_EQ(listed.size(), 2u);
  double multiplier_error = 0.0;
  for (int i = 0; i < 2; ++i) {
    // The hand monodromy's multipliers are the closed forms to round-off (achieved 3e-17).
    EXPECT_NEAR(hand_multipliers[i], closed[i], 1e-14);
    multiplier_error = std::max({multiplier_error, std::abs(reduced[i] - hand_multipliers[i]),
                                 std::abs(listed[i] - closed[i])});
  }
  const double rate = closed[1];
  const double bracket_error =
      std::max(std::abs(orbit.growth_rate_lower - rate), std::abs(orbit.growth_rate_upper - rate));
  std::printf("smooth %g: |J - Pi M| %.1e, multipliers %.1e, bracket %.1e\n", GetParam(),
              jacobian_error, multiplier_error, bracket_error);
  // Achieved: |J - Pi M| 5e-11, multipliers 5e-11, bracket 1e-12 (one piece: the spectral
  // radius, moved apart by the eigenvalues' rounding margin).
  EXPECT_LT(jacobian_error, 1e-9);
  EXPECT_LT(multiplier_error, 1e-9);
  EXPECT_LT(bracket_error, 1e-10);
  EXPECT_EQ(orbit.bracket.pieces, 1);
  EXPECT_EQ(orbit.stability, OrbitStability::kStable);
}

INSTANTIATE_TEST_SUITE_P(Kappa, CornerOrbitSeparateEvents, ::testing::Values(0.0, 2.0));

// The corner: n = 2 and 3 surfaces crossed at once at theta = 0.
class CornerOrbitThroughCorner : public ::testing::TestWithParam<int> {
 protected:
  CornerOrbitThroughCorner() : m_(CornerOrbit::with_surfaces(GetParam())), hand_(hand_orbit(m_)) {}
  PeriodicOrbit find(bool stability) const {
    OrbitOptions options;
    options.stability = stability;
    return find_periodic_orbit(adapt(m_), CornerOrbitSection{}, on_section(1.1, 0.0, d()), options);
  }
  int d() const { return m_.states(); }
  // The hand image of basis direction i (in radial_basis(d())) with the given sign.
  Eigen::VectorXd hand_image(int i, double sign) const {
    Eigen::VectorXd image = Eigen::VectorXd::Zero(d() - 1);
    if (i == 0) {
      image.head<2>() = sign > 0 ? hand_.image_plus : hand_.image_minus;
    } else if (i == 1) {
      image[1] = sign * hand_.mu_w;
    } else {
      image[i] = sign * hand_.mu_z;
      image[1] = sign > 0 ? hand_.w_of_z_plus[static_cast<std::size_t>(i - 2)]
                          : hand_.w_of_z_minus[static_cast<std::size_t>(i - 2)];
    }
    return image;
  }
  CornerOrbit m_;
  HandOrbit hand_;
};

TEST_P(CornerOrbitThroughCorner, FixedPointAndPiecesMatchTheHandCrossingShifts) {
  // The return map at the exact orbit, where every surface is crossed at one instant.
  EXPECT_NO_THROW(return_map(adapt(m_), CornerOrbitSection{}, on_section(1.0, hand_.w_star, d())));
  const PeriodicOrbit orbit = find(false);
  ASSERT_TRUE(orbit.converged) << orbit.message;
  EXPECT_TRUE(orbit.decisions.empty()) << orbit.decisions.front();
  const double x_error = (orbit.x - on_section(1.0, hand_.w_star, d())).lpNorm<Eigen::Infinity>();
  std::printf("corner %d: |x - x*| %.1e, |T - T*| %.1e, newton %d, residual %.1e\n", GetParam(),
              x_error, std::abs(orbit.period - hand_.period), orbit.newton_iterations,
              orbit.residual);
  // Achieved (n = 2): |x - x*| 2e-11, |T - T*| 3e-12, residual 6e-12.
  EXPECT_LT(x_error, 1e-9);
  EXPECT_NEAR(orbit.period, hand_.period, 1e-10);
  // One event crosses every surface (the corner), the others one each.
  EXPECT_EQ(orbit.events.size(), hand_.events.size());
  int largest = 0;
  for (const EventRecord& event : orbit.events) largest = std::max(largest, event.group_size());
  EXPECT_EQ(largest, GetParam());

  // The pieces differ: for n = 2 along e_r (c+ = -0.075, c- = 0.150); for n = 3 (kappa = 0, 2,
  // -1) the radial ones coincide (kappa = 0 lies between the others, so the product term's w
  // jump is odd in dr), and the order that z_1 sets at the corner makes the difference.
  const double c_plus = hand_.image_plus[1], c_minus = -hand_.image_minus[1];
  if (GetParam() == 2) {
    EXPECT_GT(std::abs(c_plus - c_minus), 0.2);
  }
  EXPECT_FALSE(orbit.return_map.is_linear());
  const Eigen::MatrixXd e = radial_basis(d());
  double worst = 0.0;
  for (int i = 0; i < d() - 1; ++i) {
    for (double sign : {1.0, -1.0}) {
      const Eigen::VectorXd image = e.transpose() * orbit.return_map.apply(sign * e.col(i));
      const double error = (image - hand_image(i, sign)).lpNorm<Eigen::Infinity>();
      worst = std::max(worst, error);
      // Achieved: 5e-11 (n = 2 and 3).
      EXPECT_LT(error, 1e-9) << "direction " << i << " sign " << sign;
    }
  }
  std::printf("corner %d: images of +-basis against the hand pieces, worst %.1e\n", GetParam(),
              worst);
}

TEST_P(CornerOrbitThroughCorner, ReturnMapMatchesOneSidedDifferences) {
  const PeriodicOrbit orbit = find(false);
  ASSERT_TRUE(orbit.converged) << orbit.message;
  const CornerOrbitSection section;
  const auto model = adapt(m_);
  const ReturnMap base = return_map(model, section, orbit.x);
  const Eigen::MatrixXd e = radial_basis(d());
  const double alpha = 1e-6;
  double worst = 0.0;
  Eigen::MatrixXd directions = Eigen::MatrixXd::Zero(d() - 1, 2 * (d() - 1) + 2);
  for (int i = 0; i < d() - 1; ++i) {
    directions(i, 2 * i) = 1.0;
    directions(i, 2 * i + 1) = -1.0;
  }
  directions.col(2 * (d() - 1)).setConstant(0.6);
  directions(1, 2 * (d() - 1)) = -0.8;
  directions.col(2 * (d() - 1) + 1) = -directions.col(2 * (d() - 1));
  for (Eigen::Index k = 0; k < directions.cols(); ++k) {
    const Eigen::VectorXd v = e * directions.col(k);
    const ReturnMap moved = return_map(model, section, orbit.x + alpha * v);
    const Eigen::VectorXd difference = (moved.image - base.image) / alpha;
    const double error = (difference - orbit.return_map.apply(v)).lpNorm<Eigen::Infinity>();
    worst = std::max(worst, error);
    // Achieved: worst 7e-6 (the difference's O(alpha) term and the integration error over
    // alpha).
    EXPECT_LT(error, 1e-4) << "direction " << k;
  }
  std::printf("corner %d: one-sided differences, worst error %.1e\n", GetParam(), worst);
}

TEST_P(CornerOrbitThroughCorner, GrowthBracketHoldsTheClosedFormRate) {
  const PeriodicOrbit orbit = find(true);
  ASSERT_TRUE(orbit.converged) << orbit.message;
  const double rate = std::max(hand_.mu_r, hand_.mu_w);
  std::printf("corner %d: bracket [%.3e, %.3e] around %.6f, width %.1e, pieces %d\n", GetParam(),
              orbit.growth_rate_lower - rate, orbit.growth_rate_upper - rate, rate,
              orbit.growth_rate_upper - orbit.growth_rate_lower, orbit.bracket.pieces);
  // Achieved (n = 2 and 3): lower = rate - 5e-13 (an eigenvector of a piece, in its own cone);
  // upper = rate + 3.7e-10 (n = 2) and + 4.4e-7 (n = 3): the pieces share a triangular form, so
  // in the frame of one piece's eigenvectors in the right order, scaled by t, every piece's norm
  // tends to its diagonal's largest as t -> 0, while the rounding margin grows as t^-(m-1); the
  // least sum is taken.
  EXPECT_NEAR(orbit.growth_rate_lower, rate, 1e-10);
  EXPECT_GE(orbit.growth_rate_upper, rate);
  EXPECT_LT(orbit.growth_rate_upper - rate, 1e-6);
  EXPECT_EQ(orbit.stability, OrbitStability::kStable);
  EXPECT_STREQ(to_string(orbit.stability), "stable");
}

INSTANTIATE_TEST_SUITE_P(Surfaces, CornerOrbitThroughCorner, ::testing::Values(2, 3));

TEST(CornerOrbitUnstable, NewtonFindsTheRepellingOrbit) {
  CornerOrbit m = CornerOrbit::with_surfaces(2);
  m.k = -0.5;
  const auto model = adapt(m);
  const HandOrbit hand = hand_orbit(m);
  ASSERT_GT(hand.mu_r, 1.0);
  // Iterating P moves away: u = r^2 solves u' = 2k u (1 - u), so 1/u - 1 grows by e^{-2kT}.
  const Eigen::VectorXd guess = on_section(1.05, 0.0);
  const ReturnMap once = return_map(model, CornerOrbitSection{}, guess);
  const double u = 1.0 / (1.0 + (1.0 / (1.05 * 1.05) - 1.0) * hand.mu_r);
  const double r_once = std::hypot(once.image[0], once.image[1]);
  std::printf("unstable: P(r = 1.05) has r = %.12f, closed form %.12f\n", r_once, std::sqrt(u));
  // Achieved: 1.6e-10.
  EXPECT_NEAR(r_once, std::sqrt(u), 1e-8);
  EXPECT_GT(r_once - 1.0, 3.0 * 0.05);

  const PeriodicOrbit orbit = find_periodic_orbit(model, CornerOrbitSection{}, guess);
  ASSERT_TRUE(orbit.converged) << orbit.message;
  const double x_error = (orbit.x - on_section(1.0, hand.w_star)).lpNorm<Eigen::Infinity>();
  std::printf("unstable: |x - x*| %.1e, newton %d, lower - mu_r %.1e, upper - mu_r %.1e\n", x_error,
              orbit.newton_iterations, orbit.growth_rate_lower - hand.mu_r,
              orbit.growth_rate_upper - hand.mu_r);
  // Achieved: |x - x*| 6e-11 in 4 Newton iterations; lower = mu_r + 6e-10 (the eigenvector of
  // each piece lies in its own cone), upper = mu_r + 6.4e-10 (a common triangular frame).
  EXPECT_LT(x_error, 1e-9);
  EXPECT_LE(orbit.newton_iterations, 6);
  EXPECT_FALSE(orbit.return_map.is_linear());
  EXPECT_EQ(orbit.stability, OrbitStability::kUnstable);
  EXPECT_STREQ(to_string(orbit.stability), "unstable");
  EXPECT_GT(orbit.growth_rate_lower, 1.0);
  EXPECT_NEAR(orbit.growth_rate_lower, hand.mu_r, 1e-8);
  EXPECT_GE(orbit.growth_rate_upper, orbit.growth_rate_lower);
  EXPECT_NEAR(orbit.growth_rate_upper, hand.mu_r, 1e-8);
}

// Three lines through (1, 0) in the (p, q) plane: their normals at the corner are dependent, so
// the jump there is refused; Newton's steps that land on the corner are shortened, and the
// result says so.
struct DependentCorner {
  static constexpr int kStates = 3;
  static constexpr int kSurfaces = 3;
  CornerOrbit two = CornerOrbit::with_surfaces(2);
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    two.field(x, Signs(2, b.bits() & 3u), xdot);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    two.surfaces(x, h);
    h[2] = x[1] + T(1.0) * (T(1.0) - x[0]);
  }
};

TEST(PeriodicOrbitDecisions, ShortenedStepsAreReported) {
  const auto model = adapt(DependentCorner{});
  EXPECT_THAT(testing::message_of([&] {
                return_map(model, CornerOrbitSection{},
                           on_section(1.0, hand_orbit(CornerOrbit::with_surfaces(2)).w_star));
              }),
              HasSubstr("rank"));
  const PeriodicOrbit orbit =
      find_periodic_orbit(model, CornerOrbitSection{}, on_section(1.1, 0.0));
  ASSERT_FALSE(orbit.decisions.empty());
  EXPECT_THAT(orbit.decisions.front(), HasSubstr("because the return map failed"));
  EXPECT_THAT(orbit.decisions.front(), HasSubstr("rank"));
}

TEST(PeriodicOrbitDecisions, TooManyPiecesLeaveTheVerdictUndecidedAndSaySo) {
  // Nine surfaces through the corner: 9! = 362880 pieces, more than FlowDerivative::pieces()
  // enumerates. The orbit is found (Algorithm 2.1 needs no pieces); its stability is not judged.
  CornerOrbit m;
  m.kappas = {0.0, 2.0, -1.0, 4.0, -3.0, 0.5, 6.0, -5.0, 8.0};
  m.c = {0.3, -0.2, 0.25, -0.15, 0.2, -0.1, 0.15, -0.05, 0.1};
  const auto model = adapt(m);
  const PeriodicOrbit orbit =
      find_periodic_orbit(model, CornerOrbitSection{}, on_section(1.05, 0.0, m.states()));
  ASSERT_TRUE(orbit.converged) << orbit.message;
  int largest = 0;
  for (const EventRecord& event : orbit.events) largest = std::max(largest, event.group_size());
  EXPECT_EQ(largest, 9);
  EXPECT_EQ(orbit.stability, OrbitStability::kUndecided);
  EXPECT_EQ(orbit.growth_rate_lower, 0.0);
  EXPECT_EQ(orbit.growth_rate_upper, std::numeric_limits<double>::infinity());
  ASSERT_EQ(orbit.decisions.size(), 1u);
  EXPECT_THAT(orbit.decisions.front(), HasSubstr("the growth-rate bracket was not computed"));
}

TEST(PeriodicOrbitInput, BadSectionTextIsQuoted) {
  for (const char* text : {"y4", "x9", "x1=abc"}) {
    const std::string message = testing::message_of([&] { parse_coordinate_section(text, 6); });
    EXPECT_THAT(message, HasSubstr(std::string("\"") + text + "\"")) << text;
  }
  const CoordinateSection good = parse_coordinate_section("-x1=0.3", 6);
  EXPECT_EQ(good.index, 1);
  EXPECT_EQ(good.value, 0.3);
  EXPECT_EQ(good.sign, -1.0);
}

TEST(PeriodicOrbitInput, BadGuessThrows) {
  const auto model = adapt(CornerOrbit{});
  const std::string size = testing::message_of(
      [&] { find_periodic_orbit(model, CornerOrbitSection{}, Eigen::VectorXd::Zero(2)); });
  EXPECT_THAT(size, HasSubstr("2"));
  Eigen::VectorXd nan = on_section(1.0, 0.0);
  nan[2] = std::numeric_limits<double>::quiet_NaN();
  const std::string not_finite =
      testing::message_of([&] { find_periodic_orbit(model, CornerOrbitSection{}, nan); });
  EXPECT_THAT(not_finite, HasSubstr("nan"));
}

// w stays below max g_b / a = 1.5: the section w = 100 is never reached.
struct FarAbove {
  template <typename T>
  T operator()(const T* x) const {
    return x[2] - T(100.0);
  }
};

TEST(PeriodicOrbitInput, NoReturnNamesTheTimeSearched) {
  OrbitOptions options;
  options.max_return_time = 3.25;
  const std::string message = testing::message_of(
      [&] { return_map(adapt(CornerOrbit{}), FarAbove{}, on_section(1.0, 0.0), options); });
  EXPECT_THAT(message, HasSubstr("3.25"));
}

// A curved section through the same orbit point: s = p - q + c ((p + q)^2 - 2) is zero on the
// unit circle exactly where p - q is (theta = 5 pi / 4, crossed upwards, and pi / 4, crossed
// downwards), so the fixed point is the flat section's closed form; off the circle it bends
// (at p = q = -r / sqrt 2, s = 2 c (r^2 - 1)). Its normal at the fixed point, (1, -1, 0) -
// 2 sqrt 2 c (1, 1, 0), is not the flat one: the projection Pi and the tangent space differ.
struct CurvedSection {
  double c = 0.6;
  template <typename T>
  T operator()(const T* x) const {
    const T sum = x[0] + x[1];
    return x[0] - x[1] + T(c) * (sum * sum - T(2.0));
  }
};

TEST(CornerOrbitCurvedSection, FixedPointReturnMapAndProjectionOnABentSection) {
  const CornerOrbit m = CornerOrbit::with_surfaces(2);
  const auto model = adapt(m);
  const HandOrbit hand = hand_orbit(m);
  const CurvedSection section;
  // A guess well off the section: projecting it takes several Newton steps along Ds (one step
  // leaves |s| ~ 1e-2 here).
  Eigen::VectorXd guess = on_section(1.3, 0.2);
  guess[0] += 0.2;
  OrbitOptions projection_only;
  projection_only.max_newton_iterations = 0;
  const PeriodicOrbit projected = find_periodic_orbit(model, section, guess, projection_only);
  EXPECT_GT(std::abs(section(guess.data())), 0.1);
  EXPECT_LE(std::abs(section(projected.x.data())), 1e-13);
  const PeriodicOrbit orbit = find_periodic_orbit(model, section, guess);
  ASSERT_TRUE(orbit.converged) << orbit.message;
  EXPECT_LE(std::abs(section(orbit.x.data())), 1e-13);
  const double x_error = (orbit.x - on_section(1.0, hand.w_star)).lpNorm<Eigen::Infinity>();
  std::printf("curved: |x - x*| %.1e, period error %.1e, newton %d\n", x_error,
              std::abs(orbit.period - hand.period), orbit.newton_iterations);
  // Achieved: 2e-11, as on the flat section.
  EXPECT_LT(x_error, 1e-9);
  EXPECT_NEAR(orbit.period, hand.period, 1e-9);
  // Every image lies in the tangent space at P(x) = x: Ds(x*) . DP(v) = 0.
  const Eigen::VectorXd normal = SectionAdapter<CurvedSection>(section).gradient(orbit.x);
  const Eigen::Vector3d flat(1.0, -1.0, 0.0);
  EXPECT_GT((normal.normalized() - flat.normalized()).norm(), 0.5);
  // DP at the fixed point and at a point off it (where P(x) != x, so Ds at P(x) and at x differ)
  // against one-sided differences of the return map on the bent section.
  const Eigen::VectorXd off = on_section(1.15, 0.4) + 0.05 * Eigen::Vector3d(1.0, 1.0, 0.0);
  const Eigen::VectorXd off_point = off;  // need not lie on the section
  double worst = 0.0;
  for (const Eigen::VectorXd& base_point : {Eigen::VectorXd(orbit.x), off_point}) {
    const ReturnMap base = return_map(model, section, base_point);
    const Eigen::MatrixXd tangent =
        orthogonal_complement(SectionAdapter<CurvedSection>(section).gradient(base_point));
    for (Eigen::Index i = 0; i < tangent.cols(); ++i) {
      for (double sign : {1.0, -1.0}) {
        const Eigen::VectorXd v = sign * tangent.col(i);
        const double alpha = 1e-6;
        const ReturnMap moved = return_map(model, section, base_point + alpha * v);
        const Eigen::VectorXd difference = (moved.image - base.image) / alpha;
        const Eigen::VectorXd image = base.derivative.apply(v);
        const double error = (difference - image).lpNorm<Eigen::Infinity>();
        worst = std::max(worst, error);
        // Achieved: 1e-5 (the difference's O(alpha) term).
        EXPECT_LT(error, 1e-4) << "direction " << i << " sign " << sign;
        const Eigen::VectorXd at_image =
            SectionAdapter<CurvedSection>(section).gradient(base.image);
        EXPECT_LT(std::abs(at_image.dot(image)), 1e-9 * (1.0 + image.norm()));
      }
    }
  }
  std::printf("curved: one-sided differences, worst error %.1e\n", worst);
}

// A period of 3.5 time units is found across four windows of the default search (1), and across
// twelve of 0.3.
TEST(CornerOrbitSlow, ReturnAfterSeveralSearchWindows) {
  CornerOrbit m = CornerOrbit::with_surfaces(2);
  m.omega = kTwoPi / 3.5;
  const HandOrbit hand = hand_orbit(m);
  for (double window : {1.0, 0.3}) {
    OrbitOptions options;
    options.return_search_window = window;
    const PeriodicOrbit orbit =
        find_periodic_orbit(adapt(m), CornerOrbitSection{}, on_section(1.1, 0.0), options);
    ASSERT_TRUE(orbit.converged) << orbit.message;
    EXPECT_NEAR(orbit.period, 3.5, 1e-9) << "window " << window;
    EXPECT_LT((orbit.x - on_section(1.0, hand.w_star)).lpNorm<Eigen::Infinity>(), 1e-9);
  }
}

// The Newton equation on a map of one event through two surfaces, restricted to e_0: with
// eta = I and the limits below, a direction c e_0 crosses surface 0 first when c > 0 (image
// Gamma(+-)_0 c = 3 c) and surface 1 first when c < 0 (image Gamma(++)_0 c = 0.5 c). So
// L(c) - c = r has two solutions (r / 2 and -2 r) for r > 0 and none for r < 0.
FlowDerivative two_slopes(double plus = 3.0, double minus = 0.5) {
  Eigen::MatrixXd limits(2, 4);  // columns --, +-, -+, ++
  limits << 1.0, plus, 1.0, minus, 1.0, 1.0, 1.0, 1.0;
  FlowDerivative map(2);
  map.append_jump(JumpMap(Eigen::MatrixXd::Identity(2, 2), limits), 0.0);
  return map;
}

TEST(NewtonEquation, TwoSolutionsOrNoneAreReported) {
  const FlowDerivative map = two_slopes();
  const Eigen::MatrixXd e0 = Eigen::Vector2d(1.0, 0.0);
  ASSERT_NEAR(map.apply(Eigen::Vector2d(1.0, 0.0))[0], 3.0, 1e-15);
  ASSERT_NEAR(map.apply(Eigen::Vector2d(-1.0, 0.0))[0], -0.5, 1e-15);
  const NewtonEquationSolution two = solve_newton_equation(map, e0, Eigen::VectorXd::Ones(1));
  ASSERT_EQ(two.solutions.size(), 2u);
  EXPECT_TRUE(two.exhaustive);
  EXPECT_EQ(two.pieces_checked, 2);
  EXPECT_NEAR(two.solutions[0][0], 0.5, 1e-14);  // the shorter first
  EXPECT_NEAR(two.solutions[1][0], -2.0, 1e-14);
  EXPECT_NEAR(two.c[0], 0.5, 1e-14);
  const NewtonEquationSolution none = solve_newton_equation(map, e0, -Eigen::VectorXd::Ones(1));
  EXPECT_TRUE(none.solutions.empty());
  EXPECT_TRUE(none.exhaustive);
  EXPECT_GT(none.residual, 0.1);
  // Slopes 0.5 and 0.25: L - I is one-to-one, and for r = 1 (on the piece c > 0) the only
  // solution is c = -1 / 0.75 on the other piece, which iterating on the piece active at r
  // reaches only in a second round.
  const NewtonEquationSolution other =
      solve_newton_equation(two_slopes(0.5, 0.25), e0, Eigen::VectorXd::Ones(1));
  ASSERT_EQ(other.solutions.size(), 1u);
  EXPECT_NEAR(other.c[0], -1.0 / 0.75, 1e-14);
  EXPECT_TRUE(other.piece_changed);
  EXPECT_LT(other.residual, 1e-14);
  EXPECT_THROW(
      solve_newton_equation(map, Eigen::MatrixXd::Identity(3, 1), Eigen::VectorXd::Ones(1)),
      InvalidArgument);
}

// A limit cycle with no event: r' = k r (1 - r^2 / R^2), theta' = omega. The circle r = R is
// the orbit, period 2 pi / omega, and a radial perturbation decays as e^{-2 k t} (the one
// nontrivial multiplier). The section q = 0 crossed upwards meets it at (R, 0).
struct SmallCycle {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 0;
  double radius = 1e-6, k = 0.5, omega = kTwoPi;
  template <typename T>
  void field(const T* x, Signs, T* xdot) const {
    const T u = T(k) * (T(1.0) - (x[0] * x[0] + x[1] * x[1]) / T(radius * radius));
    xdot[0] = u * x[0] - T(omega) * x[1];
    xdot[1] = u * x[1] + T(omega) * x[0];
  }
  template <typename T>
  void surfaces(const T*, T*) const {}
};

// A periodic orbit whose whole motion, 2e-6, is small against the state's size but far above
// 1000 times Newton's tolerance: it is an orbit, not an equilibrium. It has no event, so only
// the samples between events can see it move; a threshold of 1e6 times the tolerance, 1e-5,
// would call it one.
TEST(SmallCycleOrbit, AnOrbitWithoutEventsThatMovesLittleIsNoEquilibrium) {
  const SmallCycle cycle;
  OrbitOptions options;
  options.tolerance = 1e-11;
  options.flow.integrator.atol = 1e-20;  // states of order 1e-6
  const PeriodicOrbit orbit =
      find_periodic_orbit(adapt(cycle), CoordinateSection{1, 0.0, 1.0},
                          Eigen::Vector2d(1.3 * cycle.radius, 0.0), options);
  ASSERT_TRUE(orbit.converged) << orbit.message;
  EXPECT_TRUE(orbit.events.empty());
  // |P(x) - x| <= 1e-11 (1 + |x|) and the multiplier e^{-1} put x within 1.6e-11 of (R, 0).
  // Achieved: |x - (R, 0)| 7e-14, period 1 + 9e-13, multiplier e^{-1} - 4.9e-8: x is 7e-8 of R
  // off the circle, which moves the multiplier by about as much.
  EXPECT_LT((orbit.x - Eigen::Vector2d(cycle.radius, 0.0)).lpNorm<Eigen::Infinity>(), 1.6e-11);
  EXPECT_NEAR(orbit.period, 1.0, 1e-9);
  ASSERT_EQ(orbit.bracket.multipliers.size(), 1u);
  EXPECT_NEAR(orbit.bracket.multipliers[0].real(), std::exp(-2.0 * cycle.k), 2e-7);
  EXPECT_EQ(orbit.stability, OrbitStability::kStable);
  std::printf("small cycle: |x - x*| %.1e, period - 1 %.1e, multiplier - e^-1 %.1e\n",
              (orbit.x - Eigen::Vector2d(cycle.radius, 0.0)).lpNorm<Eigen::Infinity>(),
              orbit.period - 1.0, orbit.bracket.multipliers[0].real() - std::exp(-1.0));
}

// On the identity map, L(c) - c = rhs has no solution for rhs != 0: the least-norm step c = 0
// leaves the residual |rhs|. For rhs = (1e300, 1e300) that residual's square overflows; it is
// still no solution, and every number reported is finite. On 0.5 I the same rhs is solved
// exactly (c = -2 rhs). max_pieces outside [1, kMaxPieces] is refused.
TEST(NewtonEquation, AHugeResidualProvesNoSolution) {
  FlowDerivative identity(2);
  identity.append_transition(Eigen::Matrix2d::Identity());
  const Eigen::MatrixXd basis = Eigen::Matrix2d::Identity();
  const Eigen::Vector2d rhs(1e300, 1e300);
  const NewtonEquationSolution none = solve_newton_equation(identity, basis, rhs);
  EXPECT_TRUE(none.solutions.empty());
  EXPECT_EQ(none.c, Eigen::Vector2d::Zero());
  EXPECT_NEAR(none.residual, std::sqrt(2.0) * 1e300, 1e285);
  FlowDerivative half(2);
  half.append_transition(0.5 * Eigen::Matrix2d::Identity());
  const NewtonEquationSolution solved = solve_newton_equation(half, basis, rhs);
  ASSERT_EQ(solved.solutions.size(), 1u);
  EXPECT_EQ(solved.c, -2.0 * rhs);
  EXPECT_EQ(solved.residual, 0.0);
  const FlowDerivative& map = half;
  for (long max_pieces : {-1L, 0L, static_cast<long>(FlowDerivative::kMaxPieces) + 1}) {
    EXPECT_THAT(testing::message_of([&] {
                  solve_newton_equation(map, basis, Eigen::Vector2d(1.0, 3.0), max_pieces);
                }),
                HasSubstr("max_pieces must be in [1, 100000]"))
        << max_pieces;
  }
  EXPECT_THAT(testing::message_of(
                  [&] { solve_newton_equation(map, basis, Eigen::Vector2d(1.5e308, 1.5e308)); }),
              HasSubstr("overflows"));
}

// Flow options that every simulation would refuse are refused before the first one, naming the
// value, instead of ending Newton's run with converged = false.
TEST(PeriodicOrbitInput, FlowOptionsOutOfRangeAreRefusedUpFront) {
  const auto model = adapt(CornerOrbit::with_surfaces(2));
  struct Case {
    std::function<void(FlowOptions&)> set;
    std::string quoted;
  };
  const std::vector<Case> cases = {
      {[](FlowOptions& f) { f.integrator.rtol = 0.0; }, "rtol must be finite and >= 1e-15, got 0"},
      {[](FlowOptions& f) { f.integrator.rtol = std::nan(""); }, "got nan"},
      {[](FlowOptions& f) { f.integrator.atol = -1.0; }, "atol must be finite"},
      {[](FlowOptions& f) { f.integrator.max_steps = 0; }, "max_steps must be >= 1, got 0"},
      {[](FlowOptions& f) { f.integrator.initial_step = std::nan(""); }, "got nan, 1e-14, inf"},
      {[](FlowOptions& f) { f.integrator.max_step = 0.0; }, "max_step > 0"},
      {[](FlowOptions& f) { f.initial_sides = Signs::parse("+"); },
       "names 1 surfaces, the model has 2"},
      {[](FlowOptions& f) { f.max_events = 0; }, "max_events must be >= 1, got 0"},
      {[](FlowOptions& f) { f.grouping_safety = 0.0; }, "grouping_safety > 0"},
      {[](FlowOptions& f) { f.grazing_threshold = std::nan(""); }, "grazing_threshold"},
      {[](FlowOptions& f) { f.backend = static_cast<Backend>(7); }, "backend 7"},
  };
  for (const Case& c : cases) {
    OrbitOptions options;
    c.set(options.flow);
    for (int call = 0; call < 2; ++call) {
      const std::string message = testing::message_of([&] {
        if (call == 0) {
          find_periodic_orbit(model, CornerOrbitSection{}, on_section(1.1, 0.0), options);
        } else {
          return_map(model, CornerOrbitSection{}, on_section(1.1, 0.0), options);
        }
      });
      EXPECT_THAT(message, HasSubstr(c.quoted)) << message;
      EXPECT_THAT(message, HasSubstr("OrbitOptions::flow")) << message;
      EXPECT_LE(message.size(), 500u);
    }
  }
}

// From guesses below the orbit, the piece active at Newton's right-hand side -(P(x) - x) is not
// the piece active at the step: the step sits where the active piece changes during the solve.
// Each equation has exactly one solution and Newton converges to the closed-form orbit.
TEST(NewtonEquation, StepsWhoseActivePieceChangesDuringTheSolve) {
  for (int n : {2, 3}) {
    const CornerOrbit m = CornerOrbit::with_surfaces(n);
    const HandOrbit hand = hand_orbit(m);
    int changed = 0, steps = 0, piecewise = 0;
    for (double r : {0.7, 0.9, 1.1, 1.3}) {
      for (double w : {-1.0, 0.0, 1.0, 2.0}) {
        OrbitOptions options;
        options.stability = false;
        // Crossings of the corner's surfaces within 0.05 of each other are one event: the
        // iterates' return maps are piecewise linear before they reach the orbit.
        options.flow.grouping = Grouping::kFixedWindow;
        options.flow.simultaneity_window = 0.05;
        const PeriodicOrbit orbit = find_periodic_orbit(adapt(m), CornerOrbitSection{},
                                                        on_section(r, w, m.states()), options);
        ASSERT_TRUE(orbit.converged) << orbit.message;
        // Within what Newton's tolerance allows: |P(x) - x| <= 1e-8 (1 + |x|) and contraction
        // e^{-1} per period put x within 4e-8 of the orbit (achieved: 1e-8 at worst).
        EXPECT_LT((orbit.x - on_section(1.0, hand.w_star, m.states())).lpNorm<Eigen::Infinity>(),
                  4e-8);
        for (const OrbitNewtonStep& step : orbit.steps) {
          if (step.iteration == 0) continue;
          ++steps;
          EXPECT_EQ(step.solutions, 1) << "r " << r << " w " << w << " step " << step.iteration;
          // Off the orbit the corner's crossings are separate events (one piece); near it they
          // are grouped.
          if (step.pieces_checked >= 2) ++piecewise;
          if (step.piece_changed) ++changed;
        }
      }
    }
    std::printf("corner %d: %d Newton steps, %d on several pieces, %d changed piece\n", n, steps,
                piecewise, changed);
    EXPECT_GT(piecewise, 0);
    EXPECT_GT(changed, 0);
  }
}

TEST(PeriodicOrbitInput, SectionsAndBasesOfTheWrongSizeAreRefused) {
  const auto model = adapt(CornerOrbit{});
  for (int index : {3, -1, 1000000}) {
    const std::string message = testing::message_of([&] {
      find_periodic_orbit(model, CoordinateSection{index, 0.0, 1.0}, on_section(1.0, 0.0));
    });
    EXPECT_THAT(message, HasSubstr("index " + std::to_string(index))) << message;
  }
  struct ShortGradient final : PoincareSection {
    double value(const Eigen::Ref<const Eigen::VectorXd>& x) const override { return x[0] - x[1]; }
    Eigen::VectorXd gradient(const Eigen::Ref<const Eigen::VectorXd>&) const override {
      return Eigen::Vector2d(1.0, -1.0);
    }
  };
  EXPECT_THAT(
      testing::message_of([&] { return_map(model, ShortGradient{}, on_section(1.0, 0.0)); }),
      HasSubstr("2 entries"));
  const PeriodicOrbit orbit =
      find_periodic_orbit(model, CornerOrbitSection{}, on_section(1.1, 0.0));
  ASSERT_TRUE(orbit.converged);
  EXPECT_THAT(testing::message_of(
                  [&] { growth_rate_bracket(orbit.return_map, Eigen::MatrixXd::Identity(2, 2)); }),
              HasSubstr("2 x 2"));
  EXPECT_THAT(testing::message_of(
                  [&] { growth_rate_bracket(orbit.return_map, 2.0 * orbit.tangent_basis); }),
              HasSubstr("orthonormal"));
  // Near the ends of the double range the complement is still orthonormal and finite.
  for (double scale : {1e308, 1e-310}) {
    const Eigen::MatrixXd q = orthogonal_complement(Eigen::Vector3d(scale, scale, 0.5 * scale));
    ASSERT_TRUE(q.allFinite()) << scale;
    EXPECT_LT((q.transpose() * q - Eigen::Matrix2d::Identity()).norm(), 1e-14);
    EXPECT_LT(std::abs(q.col(0).dot(Eigen::Vector3d(1.0, 1.0, 0.5))), 1e-14);
  }
  EXPECT_THAT(testing::message_of([&] { parse_coordinate_section("-x1=1e-400", 6); }),
              HasSubstr("underflows"));
  const std::string long_text = "x1=" + std::string(100000, '7') + "z";
  EXPECT_LT(testing::message_of([&] { parse_coordinate_section(long_text, 6); }).size(), 400u);
}

// A family of corner orbits through three surfaces at once, along omega. Every member found
// crosses the three at one instant (six pieces, 3!) and matches its closed form; the member at
// omega = 1e-6 has no return within max_return_time (its period is 6e6) and is not found, and
// the family goes on past it from the last member found.
TEST(CornerOrbitFamily, SixPiecesAlongAFamilyThatLosesAMemberInTheMiddle) {
  const std::vector<double> omegas = {kTwoPi, 0.8 * kTwoPi, 0.6 * kTwoPi,
                                      1e-6,   0.5 * kTwoPi, 0.45 * kTwoPi};
  const CornerOrbitSection section;
  std::vector<int> progress;
  OrbitFamilyOptions options;
  options.progress = [&](int k, const OrbitFamilyMember&) { progress.push_back(k); };
  const std::vector<OrbitFamilyMember> family = continue_orbits(
      omegas, on_section(1.1, 0.0, 4),
      [&](double omega, const Eigen::VectorXd& guess) {
        CornerOrbit m = CornerOrbit::with_surfaces(3);
        m.omega = omega;
        return find_periodic_orbit(adapt(m), section, guess);
      },
      options);
  ASSERT_EQ(family.size(), omegas.size());
  EXPECT_EQ(progress, (std::vector<int>{0, 1, 2, 3, 4, 5}));
  for (std::size_t k = 0; k < family.size(); ++k) {
    const OrbitFamilyMember& member = family[k];
    if (k == 3) {
      EXPECT_FALSE(member.orbit.converged);
      EXPECT_THAT(member.orbit.message, HasSubstr("max_return_time"));
      continue;
    }
    ASSERT_TRUE(member.orbit.converged) << "omega " << omegas[k] << ": " << member.orbit.message;
    CornerOrbit m = CornerOrbit::with_surfaces(3);
    m.omega = omegas[k];
    const HandOrbit hand = hand_orbit(m);
    EXPECT_NEAR(member.orbit.period, kTwoPi / omegas[k], 1e-9);
    EXPECT_LT((member.orbit.x - on_section(1.0, hand.w_star, 4)).lpNorm<Eigen::Infinity>(), 1e-9);
    int largest = 0;
    for (const EventRecord& e : member.orbit.events) largest = std::max(largest, e.group_size());
    EXPECT_EQ(largest, 3);
    EXPECT_EQ(member.orbit.return_map.pieces().size(), 6u);
    EXPECT_EQ(member.orbit.stability, OrbitStability::kStable);
    // Above the rate by the scaled frame's off-diagonal part and rounding margin (as in
    // GrowthBracketHoldsTheClosedFormRate): achieved at most 4.4e-7.
    const double rate = std::max(hand.mu_r, hand.mu_w);
    EXPECT_GE(member.orbit.growth_rate_upper, rate - 1e-9);
    EXPECT_LT(member.orbit.growth_rate_upper - rate, 1e-6);
  }
  // The predictors: the caller's guess, the first member, then the secant of the last two found
  // (over the member not found: omega = 0.5 2 pi from 0.8 and 0.6).
  EXPECT_EQ(family[0].predictor, "guess");
  EXPECT_EQ(family[1].predictor, "previous");
  EXPECT_EQ(family[2].predictor, "secant");
  EXPECT_EQ(family[4].predictor, "secant");
  EXPECT_TRUE(family[4].guess.isApprox(1.5 * family[2].orbit.x - 0.5 * family[1].orbit.x, 1e-14));
  EXPECT_THROW(continue_orbits({1.0, std::nan("")}, on_section(1.0, 0.0, 4),
                               [](double, const Eigen::VectorXd&) { return PeriodicOrbit{}; }),
               InvalidArgument);
}

// A solver whose points lie on the unit circle, x*(v) = (cos v, sin v), and that converges only
// from a guess within 1.5 of x*(v): at v = pi the secant of the members at 0 and pi / 2 predicts
// (-1, 2), 2 away, while the member at pi / 2, (0, 1), is sqrt 2 away. The member is found only
// by solving again from the last member found.
TEST(OrbitFamilyRetry, AFailedSecantStartIsSolvedAgainFromTheLastMemberFound) {
  std::vector<Eigen::VectorXd> starts;
  const OrbitSolver solve = [&](double v, const Eigen::VectorXd& guess) {
    starts.push_back(guess);
    PeriodicOrbit orbit;
    orbit.x = Eigen::Vector2d(std::cos(v), std::sin(v));
    orbit.converged = (guess - orbit.x).norm() < 1.5;
    if (!orbit.converged) orbit.message = "too far";
    return orbit;
  };
  const std::vector<OrbitFamilyMember> family =
      continue_orbits({0.0, 0.5 * kPi, kPi}, Eigen::Vector2d(1.0, 0.0), solve);
  ASSERT_EQ(family.size(), 3u);
  ASSERT_TRUE(family[1].orbit.converged);
  ASSERT_EQ(starts.size(), 4u);
  EXPECT_LT((starts[2] - Eigen::Vector2d(-1.0, 2.0)).norm(), 1e-15);  // the secant's
  EXPECT_EQ(starts[3], family[1].orbit.x);
  EXPECT_TRUE(family[2].orbit.converged) << family[2].orbit.message;
  EXPECT_EQ(family[2].runs, 2);
  EXPECT_EQ(family[2].predictor, "previous");
  EXPECT_EQ(family[2].guess, family[1].orbit.x);
  ASSERT_EQ(family[2].decisions.size(), 1u);
  EXPECT_THAT(family[2].decisions[0], HasSubstr("secant prediction did not converge (too far)"));
}

// A solver that calls points converged that cannot start another member: one of another size
// (the secant would read past its end) and one with a NaN. Neither counts as found, both say
// why, and every later run starts from a finite point of the guess's size.
TEST(OrbitFamilyInput, ConvergedPointsOfAnotherSizeOrNotFiniteAreNotMembers) {
  std::vector<Eigen::VectorXd> starts;
  const OrbitSolver solve = [&](double v, const Eigen::VectorXd& guess) {
    starts.push_back(guess);
    PeriodicOrbit orbit;
    orbit.converged = true;
    orbit.x = Eigen::Vector2d(v, 2.0 * v);
    if (v == 1.0) orbit.x = Eigen::Vector3d(1.0, 2.0, 3.0);
    if (v == 3.0) orbit.x[1] = std::numeric_limits<double>::quiet_NaN();
    return orbit;
  };
  const std::vector<OrbitFamilyMember> family =
      continue_orbits({0.0, 1.0, 2.0, 3.0, 4.0, 5.0}, Eigen::Vector2d(0.5, 0.5), solve);
  ASSERT_EQ(family.size(), 6u);
  EXPECT_FALSE(family[1].orbit.converged);
  EXPECT_THAT(family[1].orbit.message, HasSubstr("3 entries for a guess of 2"));
  EXPECT_FALSE(family[3].orbit.converged);
  EXPECT_THAT(family[3].orbit.message, HasSubstr("entry 1 is nan"));
  ASSERT_EQ(family[3].decisions.size(), 1u);
  for (std::size_t k : {0u, 2u, 4u, 5u}) {
    EXPECT_TRUE(family[k].orbit.converged) << k << ": " << family[k].orbit.message;
  }
  for (const Eigen::VectorXd& start : starts) {
    ASSERT_EQ(start.size(), 2);
    EXPECT_TRUE(start.allFinite()) << start.transpose();
  }
  // Member 2 from member 0 (the only one found before it); 4 from the secant of 0 and 2; 5 from
  // the secant of 2 and 4: the exact points on the line x = (v, 2 v).
  EXPECT_EQ(family[2].predictor, "previous");
  EXPECT_EQ(family[2].guess, Eigen::Vector2d(0.0, 0.0));
  EXPECT_EQ(family[4].predictor, "secant");
  EXPECT_LT((family[4].guess - Eigen::Vector2d(4.0, 8.0)).norm(), 1e-14);
  EXPECT_EQ(family[5].predictor, "secant");
  EXPECT_LT((family[5].guess - Eigen::Vector2d(5.0, 10.0)).norm(), 1e-14);
}

}  // namespace
}  // namespace bflow

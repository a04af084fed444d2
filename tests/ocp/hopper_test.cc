// The hopping robot (bflow/examples/hopper.h) and the problem options it brought: the clock
// within a tolerance of the stage times, tracking scaled by a control (the speed of time), and
// state bounds on every collocation stage. Each against a closed form or a hand computation.
#include "bflow/examples/hopper.h"

#include <cmath>
#include <cstdio>
#include <limits>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "bflow/examples/contact_examples.h"
#include "bflow/ocp/ocp.h"
#include "bflow/ocp/time_freezing.h"

namespace bflow {
namespace {

using examples::Hopper;
using examples::HopperTask;

TEST(Hopper, ContactJacobiansAreTheGradientsOfTheFootsPosition) {
  for (const Eigen::Vector4d& q :
       {Eigen::Vector4d(0.1, 0.5, 0.0, 0.5), Eigen::Vector4d(1.3, 0.8, 0.7, 0.2),
        Eigen::Vector4d(-0.4, 0.3, -2.5, 0.45)}) {
    const ContactJacobianCheck c = check_contact_jacobians(Hopper{}, q);
    EXPECT_LT(c.normal_error, 1e-15) << q.transpose();
    EXPECT_LT(c.tangent_error, 1e-15) << q.transpose();
  }
  // The start stands: the foot at (0.1, 0) under the body.
  EXPECT_EQ(Hopper{}.gap(HopperTask::reference_state(0.0).data()), 0.0);
}

// The modes by hand at theta = 0.3, l = 0.4, u = (2, 30, 7), s = 1.5: free flight
// (v, M^-1 f_v, 1) s, and the auxiliary dynamics (0, M^-1 (J_n -+ mu J_t) a_n, 0) s.
TEST(Hopper, ModesAreFreeFlightAndTheImpactDirections) {
  using Tf = examples::HopperTimeFreezing<TimeFreezingRegions::kBaseSets>;
  const Tf tf(Hopper{}, {0.45, 100.0});
  Eigen::VectorXd x(9);
  x << 0.2, 0.6, 0.3, 0.4, 0.5, -1.0, 0.25, -0.3, 1.1;
  const double u[4] = {2.0, 30.0, 7.0, 1.5};
  Eigen::MatrixXd f(9, 8);  // f(:, i) = mode i
  tf.modes(x.data(), u, f.data());
  const double th = 0.3, l = 0.4, s = 1.5, m = 1.1, inertia = 0.275, ml = 0.1, g = 9.81;
  Eigen::VectorXd flight(9);
  flight << 0.5, -1.0, 0.25, -0.3, -30.0 * std::sin(th) / m, (-m * g + 30.0 * std::cos(th)) / m,
      2.0 / inertia, 30.0 / ml, 1.0;
  flight *= s;
  for (int i = 0; i < 6; ++i) EXPECT_LT((f.col(i) - flight).cwiseAbs().maxCoeff(), 1e-13) << i;
  const Eigen::Vector4d jn(0.0, 1.0, l * std::sin(th), -std::cos(th));
  const Eigen::Vector4d jt(1.0, 0.0, l * std::cos(th), std::sin(th));
  const Eigen::Vector4d inverse_mass(1.0 / m, 1.0 / m, 1.0 / inertia, 1.0 / ml);
  for (int k = 0; k < 2; ++k) {
    const double sign = k == 0 ? -1.0 : 1.0;  // R7: J_t' v > 0, friction against it
    Eigen::VectorXd aux = Eigen::VectorXd::Zero(9);
    aux.segment<4>(4) = s * 100.0 * inverse_mass.cwiseProduct(jn + sign * 0.45 * jt);
    EXPECT_LT((f.col(6 + k) - aux).cwiseAbs().maxCoeff(), 1e-12) << k;
  }
}

// The reference of the package: per jump the parabola through start, apex and end. At the
// normalised time r of a jump, x = x_start + 0.98 r, y = 0.5 + 2 r (1 - r), l = 0.5 - 1.6 r (1 - r)
// (the parabolas in closed form), velocities 0; row i of N = 50 is jump i / 10 at r = (i % 10)
// / 10.
TEST(Hopper, ReferenceIsTheParabolaOfEachJump) {
  const HopperTask task(50);
  for (int i = 0; i <= 50; ++i) {
    const int jump = std::min(i / 10, 4);
    const double r = i == 50 ? 1.0 : (i % 10) / 10.0;
    const Eigen::VectorXd x = task.reference_row(i);
    ASSERT_EQ(x.size(), 8);
    EXPECT_NEAR(x[0], 0.1 + 0.98 * (jump + r), 1e-14) << i;
    EXPECT_NEAR(x[1], 0.5 + 2.0 * r * (1.0 - r), 1e-14) << i;
    EXPECT_NEAR(x[3], 0.5 - 1.6 * r * (1.0 - r), 1e-14) << i;
    EXPECT_EQ(x[2], 0.0);
    EXPECT_EQ(x.tail(4).cwiseAbs().maxCoeff(), 0.0);
  }
  // Stage k (t in (k h, (k + 1) h]) tracks row k + 1; the guess's clock is k T / (N - 1).
  const double h = 0.1;
  EXPECT_EQ(task.stage_of(0.0), 0);
  EXPECT_EQ(task.stage_of(h), 0);
  EXPECT_EQ(task.stage_of(1.5 * h), 1);
  EXPECT_EQ(task.stage_of(5.0), 49);
  EXPECT_EQ(task.stage_reference(2.55).head(8), task.reference_row(26));
  EXPECT_NEAR(task.guess(2.55)[8], 5.0 * 25 / 49, 1e-15);
  EXPECT_LT((HopperTask::target().head(4) - Eigen::Vector4d(5.0, 0.5, 0.0, 0.5)).norm(), 1e-14);
  try {
    HopperTask bad(12);
    FAIL();
  } catch (const InvalidArgument& e) {
    EXPECT_STREQ(e.what(),
                 "the hopper's N = 12 must be a positive multiple of 5 (the reference samples "
                 "every jump at N / 5 points)");
  }
}

TEST(Hopper, HopsCountFlightsThatStartFromTheGround) {
  Eigen::MatrixXd x = Eigen::MatrixXd::Zero(9, 7);
  const double heights[7] = {0.5, 0.7, 0.5, 0.5, 0.8, 0.5, 0.9};  // l = 0.5, theta = 0
  for (int j = 0; j < 7; ++j) {
    x(1, j) = heights[j];
    x(3, j) = 0.5;
  }
  EXPECT_EQ(HopperTask::hops(x), 3);
  EXPECT_THROW(HopperTask::hops(x.topRows(8)), InvalidArgument);
}

// p' = v, v' = u (one stage, one element, Radau IIA n_s = 2) from (0, 1), minimising
// int (u + 2)^2 dt over T = 1 with p <= 0.2. With u = -2 the position rises to 0.25 at t = 1/2
// and is 0 at t = 1; Radau IIA is exact for the quadratic p(t) = t + u t^2 / 2, so the interior
// stage (c = 1/3) holds p(1/3) = 1/3 + u / 18. Bounds at element boundaries only: u* = -2, cost 0.
// With the bounds on the stage points as well: p(1/3) <= 0.2 gives u* = -2.4, cost 0.16.
struct Cart {
  static constexpr int kStates = 2, kControls = 1, kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[1] + T(10.0);  // never crossed
  }
  template <typename T>
  void field(const T* x, const T* u, const T*, T* xdot) const {
    xdot[0] = x[1];
    xdot[1] = u[0];
  }
};

TEST(OcpProblemOptions, StateBoundsOnTheStagePointsCutTheInteriorOfAnElement) {
  const double inf = std::numeric_limits<double>::infinity();
  OcpProblem p;
  p.x0 = Eigen::Vector2d(0.0, 1.0);
  p.horizon = 1.0;
  p.x_lower = Eigen::Vector2d(-inf, -inf);
  p.x_upper = Eigen::Vector2d(0.2, inf);
  p.track_R = Eigen::VectorXd::Constant(1, 1.0);
  p.u_ref = Eigen::VectorXd::Constant(1, -2.0);
  p.guess_u = Eigen::MatrixXd::Constant(1, 1, -3.0);
  OcpOptions o;
  o.stages = 1;
  o.elements = 1;
  o.homotopy.polish = false;
  const OcpResult ends = ocp_solve(adapt_ocp(Cart{}), p, o);
  ASSERT_TRUE(ends.ok()) << ends.message;
  EXPECT_NEAR(ends.u(0, 0), -2.0, 1e-8);
  EXPECT_NEAR(ends.objective, 0.0, 1e-12);
  p.x_bounds_at_stage_points = true;
  const OcpResult points = ocp_solve(adapt_ocp(Cart{}), p, o);
  ASSERT_TRUE(points.ok()) << points.message;
  std::printf("u* = %.10f, cost %.10f (closed form -2.4, 0.16)\n", points.u(0, 0),
              points.objective);
  EXPECT_NEAR(points.u(0, 0), -2.4, 1e-8);
  EXPECT_NEAR(points.objective, 0.16, 1e-8);
}

// x' = u_0 with a second control s that only scales the tracking: with s pinned to 2 by its
// bounds the cost is twice the unscaled one at the same optimum (the integrand doubles).
struct ScaledIntegrator {
  static constexpr int kStates = 1, kControls = 2, kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0] + T(10.0);
  }
  template <typename T>
  void field(const T*, const T* u, const T*, T* xdot) const {
    xdot[0] = u[0];
  }
};

TEST(OcpProblemOptions, TrackingScaledByAControlIsIntegratedOverItsTime) {
  OcpProblem p;
  p.x0 = Eigen::VectorXd::Zero(1);
  p.horizon = 1.0;
  p.u_lower = Eigen::Vector2d(-5.0, 2.0);
  p.u_upper = Eigen::Vector2d(5.0, 2.0);
  p.track_Q = Eigen::VectorXd::Constant(1, 1.0);
  p.x_ref = [](double t) { return Eigen::VectorXd::Constant(1, std::sin(3.0 * t)); };
  p.track_R = Eigen::Vector2d(0.1, 0.0);
  p.u_ref = Eigen::Vector2d(0.0, 2.0);
  OcpOptions o;
  o.stages = 4;
  o.homotopy.polish = false;
  const OcpResult plain = ocp_solve(adapt_ocp(ScaledIntegrator{}), p, o);
  ASSERT_TRUE(plain.ok()) << plain.message;
  p.track_time_scale = 1;
  const OcpResult scaled = ocp_solve(adapt_ocp(ScaledIntegrator{}), p, o);
  ASSERT_TRUE(scaled.ok()) << scaled.message;
  EXPECT_GT(plain.objective, 1e-3);
  EXPECT_NEAR(scaled.objective, 2.0 * plain.objective, 1e-9 * plain.objective);
  EXPECT_LT((scaled.u.row(0) - plain.u.row(0)).cwiseAbs().maxCoeff(), 1e-7);
  p.track_time_scale = 2;
  try {
    ocp_solve(adapt_ocp(ScaledIntegrator{}), p, o);
    FAIL();
  } catch (const InvalidArgument& e) {
    EXPECT_STREQ(e.what(), "ocp: track_time_scale = 2 is no control index (0..1) and not -1");
  }
}

// The ball of the clock test (time_freezing_test.cc) with the clock free within 1e-3 of the
// stage times: every stage end's clock inside the band, the band's edges reached where a
// speed of time below 1 pays (s is penalised towards 0.9 here, below its bound 1: the clock
// lags by the full tolerance), and the validation of the tolerance.
TEST(OcpProblemOptions, ClockToleranceLetsTheClockLagWithinItsBand) {
  using Controlled = TimeFreezing<examples::FallingBall, TimeFreezingRegions::kUnions, true>;
  const Controlled tf(examples::FallingBall{}, {0.5, 100.0});
  const ControlledPiecewiseSmoothAsStep<Controlled> model(tf, Controlled::sign_matrix());
  OcpProblem p;
  p.x0.resize(5);
  p.x0 << 0.0, 1.0, 3.0, 0.0, 0.0;
  p.horizon = 0.3;  // before the impact at 0.4515
  p.clock_state = 4;
  p.clock_tolerance = 1e-3;
  p.u_lower = Eigen::VectorXd::Constant(1, 0.5);
  p.u_upper = Eigen::VectorXd::Constant(1, 2.0);
  p.track_R = Eigen::VectorXd::Constant(1, 1.0);
  p.u_ref = Eigen::VectorXd::Constant(1, 0.5);
  p.guess_u = Eigen::MatrixXd::Constant(1, 1, 1.0);
  OcpOptions o;
  o.stages = 3;
  o.homotopy.polish = false;
  const OcpResult r = ocp_solve(adapt_ocp(model), p, o);
  ASSERT_TRUE(r.ok()) << r.message;
  for (int k = 1; k <= 3; ++k) {
    const double lag = r.x_stages(4, k) - 0.1 * k;
    EXPECT_GE(lag, -1e-3 - 1e-9) << k;
    EXPECT_LE(lag, 1e-3 + 1e-9) << k;
  }
  // Pulled towards s = 0.5, the clock sits at the band's lower edge at every stage end.
  EXPECT_NEAR(r.x_stages(4, 3), 0.3 - 1e-3, 1e-8);
  p.clock_tolerance = -1.0;
  try {
    ocp_solve(adapt_ocp(model), p, o);
    FAIL();
  } catch (const InvalidArgument& e) {
    EXPECT_STREQ(e.what(), "ocp: clock_tolerance = -1 must be finite and >= 0");
  }
  p.clock_tolerance = 1e-3;
  p.clock_state = -1;
  EXPECT_THROW(ocp_solve(adapt_ocp(model), p, o), InvalidArgument);
}

}  // namespace
}  // namespace bflow

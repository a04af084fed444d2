// The monoped's model (examples/monoped.h) against independent computations: its point
// Jacobians against Jets and one-sided differences of the positions, M(q) symmetric positive
// definite, gravity against Jets of the potential energy, energy conserved in free flight (a
// wrong Coriolis term would not conserve it), and the contact Jacobians.
#include "bflow/examples/monoped.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <random>

#include <ceres/jet.h>
#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "bflow/examples/monoped_ocp.h"
#include "bflow/ocp/time_freezing.h"

namespace bflow::examples {
namespace {

Eigen::Vector4d random_q(std::mt19937& rng) {
  std::uniform_real_distribution<double> angle(-3.0, 3.0), pos(-1.0, 1.0);
  return {pos(rng), 0.4 + 0.2 * pos(rng), angle(rng), angle(rng)};
}

// Every point's hand-written Jacobian against Jets of its position and against one-sided
// differences with step 1e-7 (error O(h |p''|) <= 1e-7 * 0.4 plus rounding 1e-16 / 1e-7).
TEST(Monoped, PointJacobiansMatchJetsAndDifferences) {
  const Monoped robot;
  std::mt19937 rng(7);
  using J = ceres::Jet<double, 4>;
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Vector4d q = random_q(rng);
    for (const auto& [a, b] :
         {std::pair{robot.s_thigh, 0.0}, std::pair{robot.l_thigh, 0.0},
          std::pair{robot.l_thigh, robot.s_shank}, std::pair{robot.l_thigh, robot.l_shank}}) {
      double p[2], jac[8];
      robot.point<double>(q.data(), nullptr, a, b, p, jac, nullptr);
      J qj[4], pj[2];
      for (int i = 0; i < 4; ++i) qj[i] = J(q[i], i);
      robot.point<J>(qj, nullptr, a, b, pj, nullptr, nullptr);
      for (int r = 0; r < 2; ++r) {
        for (int c = 0; c < 4; ++c) {
          EXPECT_NEAR(jac[r * 4 + c], pj[r].v[c], 1e-15);
          Eigen::Vector4d qh = q;
          qh[c] += 1e-7;
          double ph[2];
          robot.point<double>(qh.data(), nullptr, a, b, ph, nullptr, nullptr);
          EXPECT_NEAR(jac[r * 4 + c], (ph[r] - p[r]) / 1e-7, 1e-7);
        }
      }
    }
  }
}

TEST(Monoped, MassMatrixIsSymmetricPositiveDefinite) {
  const Monoped robot;
  std::mt19937 rng(11);
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector4d q = random_q(rng);
    Eigen::Matrix<double, 4, 4, Eigen::RowMajor> m;
    robot.mass(q.data(), m.data());
    EXPECT_EQ((m - m.transpose()).cwiseAbs().maxCoeff(), 0.0);
    const Eigen::Vector4d eig = Eigen::SelfAdjointEigenSolver<Eigen::Matrix4d>(m).eigenvalues();
    EXPECT_GT(eig.minCoeff(), 1e-4);
    // The translational block is the total mass.
    EXPECT_NEAR(m(0, 0), robot.m_body + robot.m_thigh + robot.m_shank, 1e-14);
    EXPECT_NEAR(m(1, 1), robot.m_body + robot.m_thigh + robot.m_shank, 1e-14);
  }
}

// At rest and without torques f_v = -grad V, V the potential energy (Jets of energy()).
TEST(Monoped, GravityIsMinusTheGradientOfThePotential) {
  const Monoped robot;
  std::mt19937 rng(3);
  using J = ceres::Jet<double, 4>;
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Vector4d q = random_q(rng);
    const double v[4] = {0, 0, 0, 0};
    double f[4];
    robot.forces<double>(q.data(), v, nullptr, f);
    J qj[4], vj[4];
    for (int i = 0; i < 4; ++i) {
      qj[i] = J(q[i], i);
      vj[i] = J(0.0);
    }
    const J e = robot.energy<J>(qj, vj);
    for (int i = 0; i < 4; ++i) EXPECT_NEAR(f[i], -e.v[i], 1e-12);
  }
}

// Free flight with no torques conserves energy: classical Runge-Kutta, h = 1e-4 over 0.5 s from
// a spinning leg (the energy error of RK4 is O(h^4)). Measured: largest drift 2.3e-13 of
// E = 128.1 J.
TEST(Monoped, FreeFlightConservesEnergy) {
  const Monoped robot;
  using State = Eigen::Matrix<double, 8, 1>;
  const auto rhs = [&](const State& x) {
    double m[16], f[4];
    robot.mass(x.data(), m);
    robot.forces<double>(x.data(), x.data() + 4, nullptr, f);
    detail::cholesky_factor<double, 4>(m);
    detail::cholesky_solve<double, 4>(m, f);
    State dx;
    dx << x.tail<4>(), f[0], f[1], f[2], f[3];
    return dx;
  };
  State x;
  x << 0.0, 2.0, 0.3, -0.5, 1.0, 0.5, 8.0, -12.0;
  const double e0 = robot.energy(x.data(), x.data() + 4);
  const double h = 1e-4;
  double worst = 0.0;
  for (int step = 0; step < 5000; ++step) {
    const State k1 = rhs(x), k2 = rhs(x + 0.5 * h * k1), k3 = rhs(x + 0.5 * h * k2),
                k4 = rhs(x + h * k3);
    x += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
    worst = std::max(worst, std::abs(robot.energy(x.data(), x.data() + 4) - e0));
  }
  std::printf("energy %.6f, largest drift %.2e\n", e0, worst);
  EXPECT_LT(worst, 1e-11);
}

// The foot's gap and Jacobians: J_n and J_t are the gradients of F_z and F_x (Jets), and the
// straight leg at q = (0, 0.4, 0, 0) stands on the ground, under the base.
TEST(Monoped, ContactJacobiansAreTheFootsGradients) {
  const Monoped robot;
  std::mt19937 rng(5);
  for (int trial = 0; trial < 20; ++trial) {
    const ContactJacobianCheck c = check_contact_jacobians(robot, random_q(rng));
    EXPECT_LT(c.normal_error, 1e-15);
    EXPECT_LT(c.tangent_error, 1e-15);
  }
  const double q0[4] = {0.0, 0.4, 0.0, 0.0};
  EXPECT_NEAR(robot.gap(q0), 0.0, 1e-15);
  double foot[2];
  robot.foot(q0, foot);
  EXPECT_NEAR(foot[0], 0.0, 1e-15);
  // Hip forward by a quarter turn: the leg points forward, level with the base.
  const double forward[4] = {0.0, 0.4, 1.5707963267948966, 0.0};
  robot.foot(forward, foot);
  EXPECT_NEAR(foot[0], 0.4, 1e-15);
  EXPECT_NEAR(robot.gap(forward), 0.4, 1e-15);
}

// The OCP of Section 7.2: the reference passes through the published knots (two hops), ends at
// the target at rest, and the NLP has the step formulation's three switching functions against
// the eight base sets of Stewart's: 9 states, 3 controls (u_hip, u_knee, s).
TEST(MonopedOcp, ProblemAndSizes) {
  const double knots[5][2] = {{0.0, 0.4}, {0.75, 0.6}, {1.5, 0.4}, {2.25, 0.6}, {3.0, 0.4}};
  for (int k = 0; k < 5; ++k) {
    const Eigen::VectorXd x = MonopedTask::reference(0.75 * k);
    EXPECT_NEAR(x[0], knots[k][0], 1e-15);
    EXPECT_NEAR(x[1], knots[k][1], 1e-15);
    EXPECT_EQ(x[8], 0.75 * k);
  }
  const OcpProblem p = MonopedTask{}.problem();
  EXPECT_EQ(p.x0.size(), 9);
  EXPECT_EQ(p.clock_state, 8);
  EXPECT_EQ(p.x_ref(3.0).head(8), (Eigen::VectorXd(8) << 3, 0.4, 0, 0, 0, 0, 0, 0).finished());
  OcpOptions o;
  o.stages = 30;
  const auto step = adapt_ocp(monoped_model<TimeFreezingRegions::kUnions>());
  o.formulation = DcsFormulation::kStewart;
  const auto stewart = adapt_ocp(monoped_model<TimeFreezingRegions::kBaseSets>());
  EXPECT_EQ(step.states(), 9);
  EXPECT_EQ(step.controls(), 3);
  EXPECT_EQ(step.switches(), 3);
  EXPECT_EQ(stewart.sign_matrix()->modes(), 8);
  const OcpProblemSize s_stewart = ocp_problem_size(stewart, o);
  o.formulation = DcsFormulation::kStep;
  const OcpProblemSize s_step = ocp_problem_size(step, o);
  EXPECT_EQ(s_step.elements, 90);
  EXPECT_LT(s_step.unknowns, s_stewart.unknowns);
  std::printf("N = 30: step %lld unknowns, Stewart %lld\n", static_cast<long long>(s_step.unknowns),
              static_cast<long long>(s_stewart.unknowns));
}

// Hops are flight phases that start from the ground. With both angles 0 the leg hangs straight,
// so the foot's gap is q_z - 0.4: a run of gaps 0.3 (in the air before any contact: no hop), 0
// (ground), 0.05 (hop 1), 0.02, 1e-5 (ground again, within 1e-4), 0.005 (below the 1 cm lift:
// no hop), 0, 0.1 (hop 2), 0.2 (the same flight) gives two hops.
TEST(MonopedOcp, HopsCountFlightPhasesFromTheGround) {
  const double gaps[] = {0.3, 0.0, 0.05, 0.02, 1e-5, 0.005, 0.0, 0.1, 0.2};
  const int n = static_cast<int>(std::size(gaps));
  Eigen::MatrixXd x = Eigen::MatrixXd::Zero(9, n);
  for (int j = 0; j < n; ++j) x(1, j) = gaps[j] + 0.4;
  for (int j = 0; j < n; ++j) {
    const Eigen::Vector4d q = x.col(j).head(4);
    ASSERT_NEAR(Monoped{}.gap(q.data()), gaps[j], 1e-15);
  }
  EXPECT_EQ(MonopedTask::hops(x), 2);
  EXPECT_EQ(MonopedTask::hops(x.leftCols(3)), 1);
  EXPECT_EQ(MonopedTask::hops(x.leftCols(1)), 0);
  // A lower lift counts the 5 mm rise as a hop too.
  EXPECT_EQ(MonopedTask::hops(x, 1e-4, 1e-3), 3);
  EXPECT_THROW(MonopedTask::hops(x.topRows(8)), InvalidArgument);
  EXPECT_THROW(MonopedTask::hops(x, 1e-2, 1e-3), InvalidArgument);
}

}  // namespace
}  // namespace bflow::examples

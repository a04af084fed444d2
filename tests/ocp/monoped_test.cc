// The monoped's model (examples/monoped.h) against independent computations: its point
// Jacobians against Jets and one-sided differences of the positions, M(q) symmetric positive
// definite, M and f_v against Lagrange's equations of the kinetic and potential energy written
// from the bodies' positions (Jets), gravity against Jets of the potential energy, energy
// conserved in free flight, and the contact Jacobians.
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

// The Lagrangian written from the bodies' positions alone, independently of Monoped::point,
// mass() and forces(): the main body translates with B = (q_x, q_z) (its centre s_bm above B),
// the thigh's centre at B + s_thigh d(phi_hip), the shank's at the knee B + l_thigh d(phi_hip)
// plus s_shank d(phi_hip + phi_knee), d(theta) = (sin theta, -cos theta).
// The constant c in a scalar type S (double or Jets, nested).
template <typename S>
struct Constant {
  static S of(double c) { return S(c); }
};
template <typename T, int N>
struct Constant<ceres::Jet<T, N>> {
  static ceres::Jet<T, N> of(double c) { return ceres::Jet<T, N>(Constant<T>::of(c)); }
};

template <typename S>
void centres(const Monoped& r, const S* q, S* p) {
  using std::cos;
  using std::sin;
  const S t1 = q[2], t2 = q[2] + q[3];
  p[0] = q[0];
  p[1] = q[1] + Constant<S>::of(r.s_bm);
  p[2] = q[0] + Constant<S>::of(r.s_thigh) * sin(t1);
  p[3] = q[1] - Constant<S>::of(r.s_thigh) * cos(t1);
  p[4] = q[0] + Constant<S>::of(r.l_thigh) * sin(t1) + Constant<S>::of(r.s_shank) * sin(t2);
  p[5] = q[1] - Constant<S>::of(r.l_thigh) * cos(t1) - Constant<S>::of(r.s_shank) * cos(t2);
}

// T(q, v): the centres' velocities are the Jets' derivatives of their positions along v (one
// lane, q + eps v), the links turn at phi_hip' and phi_hip' + phi_knee'.
template <typename S>
S kinetic(const Monoped& r, const S* q, const double* v) {
  using D = ceres::Jet<S, 1>;
  D qd[4];
  for (int i = 0; i < 4; ++i) {
    qd[i] = D(q[i]);
    qd[i].v[0] = Constant<S>::of(v[i]);
  }
  D p[6];
  centres(r, qd, p);
  const double m[3] = {r.m_body, r.m_thigh, r.m_shank};
  S t = Constant<S>::of(0.0);
  for (int b = 0; b < 3; ++b) {
    t += Constant<S>::of(0.5 * m[b]) *
         (p[2 * b].v[0] * p[2 * b].v[0] + p[2 * b + 1].v[0] * p[2 * b + 1].v[0]);
  }
  const double w1 = v[2], w2 = v[2] + v[3];
  return t + Constant<S>::of(0.5 * r.i_thigh * w1 * w1 + 0.5 * r.i_shank * w2 * w2);
}

// M(q) = d2T/dv2; T is a quadratic form in v, so its second derivatives are exactly
// M_ii = 2 T(e_i) and M_ij = T(e_i + e_j) - T(e_i) - T(e_j).
template <typename S>
void lagrangian_mass(const Monoped& r, const S* q, S* m) {
  const auto at = [&](int i, int j) {
    double v[4] = {0, 0, 0, 0};
    v[i] += 1.0;
    v[j] += 1.0;
    return kinetic(r, q, v);
  };
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) {
      m[i * 4 + j] = i == j ? Constant<S>::of(0.5) * at(i, i)
                            : at(i, j) - Constant<S>::of(0.25) * (at(i, i) + at(j, j));
    }
  }
}

// The mass matrix and f_v against Lagrange's equations of the Lagrangian above:
//   M(q) v' = tau - (dM/dq . v) v + dT/dq - dV/dq,   V = g sum_b m_b p_b,z,
// dM/dq . v (M along q + eps v) and dT/dq, dV/dq by Jets. Measured: largest relative
// differences 1.2e-16 (M) and 2.3e-16 (f_v); the bounds are 1e-14 and 2e-14. Negative controls,
// run by hand: the shank's inertia left out of the coupling M_34 = M_43 gives 5.1e-4 in M (M
// stays symmetric positive definite and free flight still conserves energy), and the shank's
// centripetal term with phi_hip' phi_knee' in place of (phi_hip' + phi_knee')^2 gives 1.1e-2 in
// f_v.
TEST(Monoped, MassMatrixAndForcesFollowFromTheLagrangian) {
  const Monoped robot;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> speed(-3.0, 3.0), torque(-20.0, 20.0);
  using J1 = ceres::Jet<double, 1>;
  using J4 = ceres::Jet<double, 4>;
  double worst_m = 0.0, worst_f = 0.0;
  for (int trial = 0; trial < 30; ++trial) {
    const Eigen::Vector4d q = random_q(rng);
    const Eigen::Vector4d v(speed(rng), speed(rng), speed(rng), speed(rng));
    const double u[2] = {torque(rng), torque(rng)};
    Eigen::Matrix<double, 4, 4, Eigen::RowMajor> m, m_ref;
    robot.mass(q.data(), m.data());
    lagrangian_mass(robot, q.data(), m_ref.data());
    worst_m = std::max(worst_m, (m - m_ref).cwiseAbs().maxCoeff() / m_ref.cwiseAbs().maxCoeff());
    // dM/dq . v
    J1 qv[4];
    for (int i = 0; i < 4; ++i) {
      qv[i] = J1(q[i]);
      qv[i].v[0] = v[i];
    }
    J1 mj[16];
    lagrangian_mass(robot, qv, mj);
    // dT/dq and dV/dq
    J4 qj[4];
    for (int i = 0; i < 4; ++i) qj[i] = J4(q[i], i);
    const J4 t = kinetic(robot, qj, v.data());
    J4 p[6];
    centres(robot, qj, p);
    const J4 potential =
        robot.g * (robot.m_body * p[1] + robot.m_thigh * p[3] + robot.m_shank * p[5]);
    Eigen::Vector4d f_ref;
    for (int i = 0; i < 4; ++i) {
      double mdot_v = 0.0;
      for (int j = 0; j < 4; ++j) mdot_v += mj[i * 4 + j].v[0] * v[j];
      f_ref[i] = -mdot_v + t.v[i] - potential.v[i] + (i >= 2 ? u[i - 2] : 0.0);
    }
    Eigen::Vector4d f;
    robot.forces<double>(q.data(), v.data(), u, f.data());
    worst_f = std::max(worst_f, (f - f_ref).cwiseAbs().maxCoeff() / f_ref.cwiseAbs().maxCoeff());
  }
  EXPECT_LT(worst_m, 1e-14);
  EXPECT_LT(worst_f, 2e-14);
  std::printf("largest relative differences: M %.1e, f_v %.1e\n", worst_m, worst_f);
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
  MonopedTask strict;
  strict.setup = MonopedSetup::kStrict;
  const OcpProblem p = strict.problem(30);
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
  // nosnoc's cross complementarity: Stewart's every product of two points (8 pairs, 3 x 2
  // products per element), the step formulation's aggregated products.
  const MonopedTask nosnoc;
  EXPECT_EQ(nosnoc.options(30, DcsFormulation::kStewart).cross_complementarity,
            CrossComplementarity::kPointPairs);
  EXPECT_EQ(nosnoc.options(30).cross_complementarity, CrossComplementarity::kElementSums);
  OcpOptions pairs = o;
  pairs.cross_complementarity = CrossComplementarity::kPointPairs;
  EXPECT_EQ(ocp_problem_size(stewart, pairs).constraints - s_stewart.constraints, 90 * 8 * 5);
  o.formulation = DcsFormulation::kStep;
  const OcpProblemSize s_step = ocp_problem_size(step, o);
  EXPECT_EQ(s_step.elements, 90);
  EXPECT_LT(s_step.unknowns, s_stewart.unknowns);
  std::printf("N = 30: step %lld unknowns, Stewart %lld\n", static_cast<long long>(s_step.unknowns),
              static_cast<long long>(s_stewart.unknowns));
}

// The not-a-knot spline reproduces every cubic exactly (the not-a-knot conditions hold for
// it, and the interpolant is unique), on uneven knots too; measured 4.4e-16 against the cubic,
// bound 1e-13. A natural spline (M_0 = M_n = 0) would miss this cubic's end curvatures.
TEST(MonopedOcp, NotAKnotSplineReproducesCubics) {
  const auto cubic = [](double t) { return 0.3 - 1.2 * t + 2.5 * t * t - 0.7 * t * t * t; };
  const Eigen::VectorXd knots = (Eigen::VectorXd(5) << -0.5, 0.1, 0.4, 1.3, 2.0).finished();
  Eigen::VectorXd values(5);
  for (int i = 0; i < 5; ++i) values[i] = cubic(knots[i]);
  double worst = 0.0;
  for (int k = 0; k <= 50; ++k) {
    const double t = -0.6 + 2.7 * k / 50.0;
    worst = std::max(worst, std::abs(not_a_knot_spline(knots, values, t) - cubic(t)));
  }
  std::printf("cubic: %.1e\n", worst);
  EXPECT_LT(worst, 1e-13);
  EXPECT_THROW(not_a_knot_spline(knots.head(3), values.head(3), 0.0), InvalidArgument);
  EXPECT_THROW(not_a_knot_spline(knots.reverse(), values, 0.0), InvalidArgument);
}

// The not-a-knot spline in another representation: the four power-basis coefficients of each
// of the n pieces, from interpolation at both ends of every piece, continuity of the first and
// second derivatives at the inner knots and of the third at the second and the second-to-last
// knot (4n equations), solved densely.
double spline_by_coefficients(const Eigen::VectorXd& t, const Eigen::VectorXd& y, double at) {
  const int n = static_cast<int>(t.size()) - 1;
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(4 * n, 4 * n);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(4 * n);
  // Piece i: sum_p c_{i,p} (s - t_i)^p; its p-th derivative's row at s.
  const auto row = [&](int i, double s, int derivative) {
    Eigen::RowVectorXd r = Eigen::RowVectorXd::Zero(4 * n);
    const double d = s - t[i];
    for (int p = derivative; p < 4; ++p) {
      double factor = 1.0;
      for (int k = 0; k < derivative; ++k) factor *= p - k;
      r[4 * i + p] = factor * std::pow(d, p - derivative);
    }
    return r;
  };
  int e = 0;
  for (int i = 0; i < n; ++i) {
    A.row(e) = row(i, t[i], 0);
    b[e++] = y[i];
    A.row(e) = row(i, t[i + 1], 0);
    b[e++] = y[i + 1];
  }
  for (int i = 1; i < n; ++i) {
    for (int derivative : {1, 2})
      A.row(e++) = row(i - 1, t[i], derivative) - row(i, t[i], derivative);
  }
  A.row(e++) = row(0, t[1], 3) - row(1, t[1], 3);
  A.row(e++) = row(n - 2, t[n - 1], 3) - row(n - 1, t[n - 1], 3);
  const Eigen::VectorXd c = A.fullPivLu().solve(b);
  int i = 0;
  while (i + 1 < n && at > t[i + 1]) ++i;
  return row(i, at, 0).dot(c);
}

// nosnoc's reference passes through its knots (q_x = 3 s, q_z alternating 0.4 / 0.6, v_x = (0,
// 1, 1, 1, 0) at s = t / T = 0, 1/4, ..., 1, the clock t) and between them is the spline of the
// coefficient representation above: measured 1.1e-16, bound 1e-14.
TEST(MonopedOcp, SplineReferencePassesThroughNosnocsKnots) {
  const Eigen::VectorXd knots = (Eigen::VectorXd(5) << 0.0, 0.25, 0.5, 0.75, 1.0).finished();
  const Eigen::VectorXd qz = (Eigen::VectorXd(5) << 0.4, 0.6, 0.4, 0.6, 0.4).finished();
  const Eigen::VectorXd vx = (Eigen::VectorXd(5) << 0.0, 1.0, 1.0, 1.0, 0.0).finished();
  for (int k = 0; k < 5; ++k) {
    const Eigen::VectorXd x = MonopedTask::spline_reference(0.75 * k);
    EXPECT_NEAR(x[0], 0.75 * k, 1e-14) << k;
    EXPECT_NEAR(x[1], qz[k], 1e-14) << k;
    EXPECT_NEAR(x[4], vx[k], 1e-14) << k;
    EXPECT_EQ(x[8], 0.75 * k);
    EXPECT_EQ(x[2], 0.0);
  }
  double worst = 0.0;
  for (int k = 0; k <= 40; ++k) {
    const double s = k / 40.0;
    const Eigen::VectorXd x = MonopedTask::spline_reference(3.0 * s);
    worst =
        std::max({worst, std::abs(x[1] - spline_by_coefficients(knots, qz, s)),
                  std::abs(x[4] - spline_by_coefficients(knots, vx, s)), std::abs(x[0] - 3.0 * s)});
  }
  std::printf("spline reference: %.1e\n", worst);
  EXPECT_LT(worst, 1e-14);
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

// Standing still at x0 for 0.3 s, the reference x0 with the clock running.
OcpProblem standing_problem(const MonopedTask& task, int stages) {
  OcpProblem p = task.problem(stages);
  p.horizon = 0.3;
  const Eigen::VectorXd x0 = p.x0;
  p.x_ref = [x0](double t) {
    Eigen::VectorXd x = x0;
    x[8] = t;
    return x;
  };
  return p;
}

// The monoped's OCP solved: standing. From the published start (the straight leg vertical on
// the ground, at rest) with the reference held at that state, nosnoc's setup over a short
// horizon T = 0.3 (N = 3 stages, the stage-wise clock constraint, the speed of time free in
// [0.99, 100]), the homotopy allowed down to sigma = 1e-6: at the setup's 1e-4 the residual is
// still 6.8e-5 (the products follow sigma, 0.7 sigma at every NLP), and stopping at 1e-5 takes
// sigma = 1e-5. Gravity acts through the foot, so the robot stands with zero torques: the
// optimum is u = 0, x = x0 throughout, cost 0 (the closed form), reached only if contact holds
// the robot up (without the auxiliary dynamics it falls g T^2 / 2 = 0.44 m). Measured (22 IPOPT
// iterations): cost 3.5e-11, largest |q - q0| on the grid 2.3e-7, |u| 1.8e-10, clock error 0,
// complementarity 8.8e-6; bounds 3e-9, 2e-5, 2e-8, 1e-12 and the tolerance 1e-5.
TEST(MonopedOcp, StandsStillWithoutTorques) {
  const int stages = 3;
  const MonopedTask task;  // nosnoc's setup
  OcpProblem p = standing_problem(task, stages);
  const Eigen::VectorXd x0 = p.x0;
  OcpOptions o = task.options(stages);
  o.homotopy.sigma_final = 1e-6;
  const OcpResult r =
      ocp_solve(adapt_ocp(monoped_free_model<TimeFreezingRegions::kUnions>()), p, o);
  ASSERT_EQ(r.status, OcpStatus::kSolved) << r.message;
  double q_error = 0.0;
  for (Eigen::Index j = 0; j < r.x_grid.cols(); ++j) {
    q_error = std::max(q_error, (r.x_grid.col(j).head(4) - x0.head(4)).cwiseAbs().maxCoeff());
  }
  const double u_max = r.u.topRows(2).cwiseAbs().maxCoeff();
  const double clock_error = std::abs(r.x_stages(8, stages) - 0.3);
  std::printf(
      "standing: cost %.1e, q %.1e, u %.1e, clock %.1e, complementarity %.1e, %d "
      "iterations, %s\n",
      r.objective, q_error, u_max, clock_error, r.max_complementarity, r.ipopt_iterations,
      r.ipopt_status.c_str());
  EXPECT_LT(r.objective, 3e-9);
  EXPECT_LT(q_error, 2e-5);
  EXPECT_LT(u_max, 2e-8);
  EXPECT_LT(clock_error, 1e-12);
  EXPECT_LE(r.max_complementarity, 1e-5);
  EXPECT_LE(r.kkt_error, 1e-5);
}

// The polish in Stewart's formulation from a relaxed point of the standing robot (eight regions,
// theta spread over those of the sliding contact). At sigma = 0.1 (and 1) every theta of some
// points lay below its lambda, and the polish fixed them all at 0: IPOPT ended with the row
// sum theta = 1 (algebraic row 8) violated by 1 at elements 7 and 8. One region now stays free at
// every point (and a crossing out of a sliding arc fixes no theta at the earlier element's end);
// those polishes still end infeasible, on the stages' sums of element lengths and the clock, but
// not on that row. From sigma = 0.01 the polish reaches the closed-form optimum, cost 0 (measured
// 1.5e-15; bound 1e-12).
TEST(MonopedOcp, StewartPolishKeepsARegionAtEveryPoint) {
  const int stages = 3;
  const MonopedTask task;
  for (const double sigma : {0.1, 0.01}) {
    const OcpProblem p = standing_problem(task, stages);
    OcpOptions o = task.options(stages, DcsFormulation::kStewart);
    o.homotopy.sigma_initial = o.homotopy.sigma_final = sigma;
    o.homotopy.stop_at_complementarity = false;
    o.homotopy.polish = true;
    const OcpResult r =
        with_monoped(task, DcsFormulation::kStewart, stages,
                     [&](const auto& model, const OcpProblem&) { return ocp_solve(model, p, o); });
    const OcpHomotopyStep& polish = r.homotopy.back();
    std::printf("sigma %g: relaxed %s cost %.3g; polish %s cost %.3g products %.2g; %s\n", sigma,
                r.homotopy.front().ipopt_status.c_str(), r.homotopy.front().objective,
                polish.ipopt_status.c_str(), polish.objective, polish.complementarity,
                polish.worst_rows.c_str());
    ASSERT_TRUE(polish.polish);
    EXPECT_EQ(polish.worst_rows.find("algebraic row 8"), std::string::npos) << polish.worst_rows;
    // nosnoc's setup penalises the lengths' deviation instead of equilibrating them exactly: the
    // polish keeps the penalty and imposes no equal lengths (it did, and ended on those rows).
    EXPECT_EQ(polish.worst_rows.find("equal lengths"), std::string::npos) << polish.worst_rows;
    if (sigma == 0.01) {
      EXPECT_EQ(polish.ipopt_status, "Solve_Succeeded");
      EXPECT_LT(polish.objective, 1e-12);
      EXPECT_EQ(polish.complementarity, 0.0);
    }
  }
}

}  // namespace
}  // namespace bflow::examples

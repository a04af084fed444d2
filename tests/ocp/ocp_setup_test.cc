// The options of ocp_solve that reproduce nosnoc's benchmark setup (ocp.h): least-squares
// tracking at the stage ends (OcpTracking::kStageEnds), the penalty on the element lengths'
// deviation from uniform (step_deviation_weight), IPOPT's acceptable level
// (acceptable_tolerance) and the status that reports how IPOPT stopped beside whether the KKT
// error meets nlp_tolerance.
#include <cmath>
#include <cstdio>
#include <limits>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "bflow/examples/ocp_examples.h"
#include "bflow/ocp/ocp.h"

namespace bflow {
namespace {

// x' = u with a switching function that stays positive (x > -10 throughout): the transcription
// is exact for a constant control, x_{k+1} = x_k + h u_k with h = T / N.
struct Integrator {
  static constexpr int kStates = 1, kControls = 1, kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0] + T(10.0);
  }
  template <typename T>
  void field(const T*, const T* u, const T*, T* xdot) const {
    xdot[0] = u[0];
  }
};

// The discrete problem of kStageEnds in closed form: with x_{k+1} = h (L u)_k (L the lower
// triangular matrix of ones), the cost
//   J(u) = h [q |h L u - r|^2 + rho |u - u_ref|^2] + q_T (h (L u)_{N-1} - r_T)^2
// is a linear least-squares problem; its normal equations give u* directly (a dense solve,
// nothing of the transcription).
struct StageEndOptimum {
  Eigen::VectorXd u, x;
  double cost = 0.0;
};
StageEndOptimum stage_end_optimum(int n, double horizon, double q, double rho, double u_ref,
                                  double q_terminal, const Eigen::VectorXd& r, double r_terminal) {
  const double h = horizon / n;
  Eigen::MatrixXd L = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i < n; ++i) L.row(i).head(i + 1).setOnes();
  const Eigen::MatrixXd A = h * L;
  const Eigen::RowVectorXd last = A.row(n - 1);
  const Eigen::MatrixXd H = h * q * A.transpose() * A + h * rho * Eigen::MatrixXd::Identity(n, n) +
                            q_terminal * last.transpose() * last;
  const Eigen::VectorXd g = h * q * A.transpose() * r +
                            h * rho * Eigen::VectorXd::Constant(n, u_ref) +
                            q_terminal * r_terminal * last.transpose();
  StageEndOptimum o;
  o.u = H.llt().solve(g);
  o.x = A * o.u;
  o.cost = h * (q * (o.x - r).squaredNorm() + rho * (o.u.array() - u_ref).matrix().squaredNorm()) +
           q_terminal * std::pow(o.x[n - 1] - r_terminal, 2);
  return o;
}

// Tracking x_ref(t) = sin(t) + t at the stage ends with u_ref = 0.5 and a terminal weight on
// x_ref(T), N = 6 stages over T = 2: the optimum of the NLP is the least-squares solution
// above. Measured: largest errors 3.9e-12 (u), 1.6e-12 (x), 0 (cost, about 1.5); bounds 2e-10,
// 1e-10, 1e-12. Integrated
// by quadrature instead (x_ref at the stage middles), the same data give another optimum, so
// the test tells the two rules apart.
TEST(OcpSetup, TrackingAtTheStageEndsIsTheDiscreteLeastSquaresOptimum) {
  const int n = 6;
  const double horizon = 2.0, q = 3.0, rho = 0.2, u_ref = 0.5, q_terminal = 7.0;
  const auto ref = [](double t) { return Eigen::VectorXd::Constant(1, std::sin(t) + t); };
  OcpProblem p;
  p.x0 = Eigen::VectorXd::Zero(1);
  p.horizon = horizon;
  p.track_Q = Eigen::VectorXd::Constant(1, q);
  p.track_R = Eigen::VectorXd::Constant(1, rho);
  p.u_ref = Eigen::VectorXd::Constant(1, u_ref);
  p.track_Q_terminal = Eigen::VectorXd::Constant(1, q_terminal);
  p.x_ref = ref;
  OcpOptions o;
  o.stages = n;
  o.elements = 2;
  o.tracking = OcpTracking::kStageEnds;
  const OcpResult r = ocp_solve(adapt_ocp(Integrator{}), p, o);
  ASSERT_EQ(r.status, OcpStatus::kSolved) << r.message;

  Eigen::VectorXd targets(n);
  for (int k = 0; k < n; ++k) targets[k] = ref((k + 1) * horizon / n)[0];
  const StageEndOptimum exact =
      stage_end_optimum(n, horizon, q, rho, u_ref, q_terminal, targets, ref(horizon)[0]);
  const double u_error = (r.u.row(0).transpose() - exact.u).cwiseAbs().maxCoeff();
  const double x_error = (r.x_stages.row(0).tail(n).transpose() - exact.x).cwiseAbs().maxCoeff();
  const double cost_error = std::abs(r.objective - exact.cost);
  std::printf("stage ends: u %.1e, x %.1e, cost %.1e\n", u_error, x_error, cost_error);
  EXPECT_LT(u_error, 2e-10);
  EXPECT_LT(x_error, 1e-10);
  EXPECT_LT(cost_error, 1e-12);

  o.tracking = OcpTracking::kQuadrature;
  const OcpResult quadrature = ocp_solve(adapt_ocp(Integrator{}), p, o);
  ASSERT_EQ(quadrature.status, OcpStatus::kSolved) << quadrature.message;
  EXPECT_GT((quadrature.u.row(0).transpose() - exact.u).cwiseAbs().maxCoeff(), 1e-3);
}

// The turbo car (ocp_examples.h) at N = 5 with nosnoc's stopping rules: IPOPT's tol and
// acceptable_tol both 1e-5, acceptable_iter 3 and, as nosnoc's benchmark, dual_inf_tol 1e-12, so
// that IPOPT can only stop at its acceptable level; the homotopy stops at complementarity 1e-5,
// no polish. The result is "solved" (the KKT error within 1e-5) and says that IPOPT stopped at
// the acceptable level. Measured: KKT error 1.0e-11 after 274 iterations, |T - 40/3| = 1.2e-6.
// With nlp_tolerance 1e-13 the same kind of stop (KKT error 2.8e-11) is "acceptable_only".
TEST(OcpSetup, AnAcceptableStopIsSolvedOnlyWhenItsKktErrorMeetsTheTolerance) {
  using examples::TurboCar;
  OcpOptions o;
  o.stages = 5;
  o.homotopy.nlp_tolerance = 1e-5;
  o.homotopy.complementarity_tolerance = 1e-5;
  o.homotopy.stop_at_complementarity = true;
  o.homotopy.acceptable_tolerance = 1e-5;
  o.homotopy.acceptable_iterations = 3;
  o.homotopy.polish = false;
  o.solver.ipopt_numeric_options = {{"dual_inf_tol", 1e-12}};
  const OcpResult r = ocp_solve(adapt_ocp(TurboCar{}), TurboCar::problem(), o);
  ASSERT_EQ(r.status, OcpStatus::kSolved) << r.message;
  EXPECT_EQ(r.ipopt_status, "Solved_To_Acceptable_Level");
  EXPECT_LE(r.kkt_error, 1e-5);
  EXPECT_LE(r.max_complementarity, 1e-5);
  std::printf("turbo car: %s, KKT error %.1e, |T - 40/3| = %.1e, %d iterations\n",
              r.ipopt_status.c_str(), r.kkt_error, std::abs(r.T - TurboCar::kOptimalTime),
              r.ipopt_iterations);
  EXPECT_LT(std::abs(r.T - TurboCar::kOptimalTime), 1e-4);
  for (const OcpHomotopyStep& s : r.homotopy) {
    EXPECT_TRUE(std::isfinite(s.kkt_error)) << s.index;
    EXPECT_GE(s.constraint_violation, 0.0) << s.index;
  }

  o.homotopy.nlp_tolerance = 1e-13;
  const OcpResult strict = ocp_solve(adapt_ocp(TurboCar{}), TurboCar::problem(), o);
  std::printf("tol 1e-13: %s, %s, KKT error %.1e\n", to_string(strict.status),
              strict.ipopt_status.c_str(), strict.kkt_error);
  EXPECT_EQ(strict.ipopt_status, "Solved_To_Acceptable_Level");
  EXPECT_GT(strict.kkt_error, 1e-13);
  EXPECT_EQ(strict.status, OcpStatus::kAcceptableOnly) << strict.message;
}

// The homotopy's options keep the defaults docs/ocp.md and docs/fesd.md state for each owner:
// OcpHomotopyOptions sets HomotopyOptions' six fields by position, so a field out of place
// there would give the OCP another schedule without any other test noticing the cause.
TEST(OcpSetup, EachHomotopyGroupHasItsOwnersDefaults) {
  const OcpHomotopyOptions ocp = OcpOptions{}.homotopy;
  EXPECT_EQ(ocp.sigma_initial, 100.0);
  EXPECT_EQ(ocp.sigma_final, 1e-10);
  EXPECT_EQ(ocp.sigma_factor, 0.1);
  EXPECT_FALSE(ocp.superlinear);
  EXPECT_EQ(ocp.nlp_tolerance, 1e-10);
  EXPECT_EQ(ocp.max_nlp_iterations, 3000);
  EXPECT_EQ(ocp.complementarity_tolerance, 1e-9);
  EXPECT_EQ(ocp.early_polish_sigma, 1e-4);
  EXPECT_EQ(ocp.monotone_mu_down_to, 1e-2);
  EXPECT_TRUE(ocp.polish);
  const HomotopyOptions fesd = FesdOptions{}.homotopy;
  EXPECT_EQ(fesd.sigma_initial, 1.0);
  EXPECT_EQ(fesd.sigma_final, 1e-12);
  EXPECT_EQ(fesd.sigma_factor, 0.1);
  EXPECT_TRUE(fesd.superlinear);
  EXPECT_EQ(fesd.nlp_tolerance, 1e-13);
  EXPECT_EQ(fesd.max_nlp_iterations, 500);
}

TEST(OcpSetup, BadOptionsAreRefusedWithTheValues) {
  using examples::TurboCar;
  OcpOptions o;
  o.step_deviation_weight = -1.0;
  try {
    ocp_solve(adapt_ocp(TurboCar{}), TurboCar::problem(), o);
    FAIL() << "no exception";
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("step_deviation_weight = -1"), std::string::npos)
        << e.what();
  }
  o.step_deviation_weight = 0.0;
  o.homotopy.acceptable_tolerance = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(ocp_solve(adapt_ocp(TurboCar{}), TurboCar::problem(), o), InvalidArgument);
  o.homotopy.acceptable_tolerance = 0.0;
  o.homotopy.intermediate_tolerance_factor = -0.5;
  try {
    ocp_solve(adapt_ocp(TurboCar{}), TurboCar::problem(), o);
    FAIL() << "no exception";
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("intermediate_tolerance_factor = -0.5"), std::string::npos)
        << e.what();
  }
  o.homotopy.intermediate_tolerance_factor = 1e-2;
  for (const double bad : {-1e-3, std::numeric_limits<double>::quiet_NaN()}) {
    o.homotopy.monotone_mu_down_to = bad;
    try {
      ocp_solve(adapt_ocp(TurboCar{}), TurboCar::problem(), o);
      FAIL() << "no exception for " << bad;
    } catch (const InvalidArgument& e) {
      EXPECT_NE(std::string(e.what()).find("monotone_mu_down_to = " +
                                           std::string(std::isnan(bad) ? "nan" : "-0.001")),
                std::string::npos)
          << e.what();
    }
  }
}

}  // namespace
}  // namespace bflow

// ocp_solve from several threads (IPOPT and MUMPS serialised by ipopt_mutex), its checks of
// non-finite, absurd and contradictory input before IPOPT runs, and the cancellation hook.
#include <cmath>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/examples/ocp_examples.h"
#include "bflow/ocp/ocp.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;

constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

using testing::message_of;

// Bit-equal results.
void expect_same(const OcpResult& a, const OcpResult& b) {
  EXPECT_EQ(a.status, b.status);
  EXPECT_EQ(a.objective, b.objective);
  EXPECT_EQ(a.T, b.T);
  EXPECT_EQ(a.grid, b.grid);
  EXPECT_EQ(a.switch_times, b.switch_times);
  ASSERT_EQ(a.u.cols(), b.u.cols());
  EXPECT_TRUE((a.u.array() == b.u.array()).all());
  ASSERT_EQ(a.x_grid.cols(), b.x_grid.cols());
  EXPECT_TRUE((a.x_grid.array() == b.x_grid.array()).all());
}

// Two ocp_solve of the turbo car at N = 5 at once: MUMPS's module state is shared by its
// instances, and two factorisations at once crashed the process ("PB allocation in
// DMUMPS_LOAD_INIT"). Serialised NLP by NLP, each thread gets the serial result, bit for bit.
TEST(OcpThreads, TwoThreadsGiveTheSerialResult) {
  const auto model = adapt_ocp(examples::TurboCar{});
  const OcpProblem problem = examples::TurboCar::problem();
  OcpOptions o;
  o.stages = 5;
  const OcpResult serial = ocp_solve(model, problem, o);
  ASSERT_TRUE(serial.ok()) << serial.message;
  EXPECT_NEAR(serial.T, examples::TurboCar::kOptimalTime, 1e-9);
  for (int round = 0; round < 2; ++round) {
    std::vector<OcpResult> results(2);
    std::vector<std::thread> threads;
    for (int k = 0; k < 2; ++k) {
      threads.emplace_back(
          [&, k] { results[static_cast<std::size_t>(k)] = ocp_solve(model, problem, o); });
    }
    for (std::thread& t : threads) t.join();
    for (const OcpResult& r : results) expect_same(r, serial);
  }
}

// The braking block (L = v^2 + u^2, u unbounded) with a guess: NaN and infinity are refused
// where they enter, naming the entry; a finite guess whose model values overflow (u = 1e308:
// u^2 = inf) is refused before IPOPT runs, naming what is not finite. Each of these reached
// IPOPT and MUMPS before and ended the process with SIGSEGV.
TEST(OcpInput, NonFiniteAndOverflowingGuessesAreRefused) {
  const auto model = adapt_ocp(examples::BrakingBlock{});
  OcpOptions o;
  o.stages = 5;
  const auto with = [&](auto change) {
    OcpProblem p = examples::BrakingBlock::problem();
    change(p);
    return message_of([&] { ocp_solve(model, p, o); });
  };
  EXPECT_EQ(with([](OcpProblem& p) { p.guess_u = Eigen::MatrixXd::Constant(1, 1, kNan); }),
            "ocp: guess_u(0, 0) = nan must be finite");
  EXPECT_EQ(with([](OcpProblem& p) {
              p.guess_u = Eigen::MatrixXd::Constant(1, 5, 1.0);
              p.guess_u(0, 3) = -kInf;
            }),
            "ocp: guess_u(0, 3) = -inf must be finite");
  EXPECT_EQ(with([](OcpProblem& p) { p.guess_x = Eigen::Vector2d(0.0, kInf); }),
            "ocp: guess_x[1] = inf must be finite");
  EXPECT_EQ(with([](OcpProblem& p) { p.x0 = Eigen::Vector2d(kInf, 2.0); }),
            "ocp: x0[0] = inf must be finite");
  const std::string overflow =
      with([](OcpProblem& p) { p.guess_u = Eigen::MatrixXd::Constant(1, 1, 1e308); });
  EXPECT_THAT(overflow, HasSubstr("ocp: at the initial guess (constant; guess_x, guess_u, x0) "
                                  "the objective is inf"));
  // A guess whose field overflows: the collocation rows of the first element name it.
  const std::string field = with([](OcpProblem& p) { p.guess_x = Eigen::Vector2d(0.0, 1e308); });
  EXPECT_THAT(field, HasSubstr("ocp: at the initial guess"));
  EXPECT_THAT(field, HasSubstr("inf"));
  // A large but harmless guess is accepted (and solved: the optimum does not depend on it).
  OcpProblem fine = examples::BrakingBlock::problem();
  fine.guess_u = Eigen::MatrixXd::Constant(1, 1, 1e3);
  EXPECT_NO_THROW(ocp_solve(model, fine, o));
}

TEST(OcpInput, BoundsHorizonsReferencesAndWeightsAreChecked) {
  const auto model = adapt_ocp(examples::BrakingBlock{});
  OcpOptions o;
  o.stages = 5;
  const auto with = [&](auto change) {
    OcpProblem p = examples::BrakingBlock::problem();
    change(p);
    return message_of([&] { ocp_solve(model, p, o); });
  };
  EXPECT_EQ(with([](OcpProblem& p) { p.u_lower = Eigen::VectorXd::Constant(1, kNan); }),
            "ocp: u_lower[0] = nan must be a number");
  EXPECT_EQ(with([](OcpProblem& p) { p.x_lower = Eigen::Vector2d(kInf, -kInf); }),
            "ocp: x_lower[0] = inf: a lower bound may be -inf (unbounded), not +inf");
  EXPECT_EQ(with([](OcpProblem& p) { p.u_upper = Eigen::VectorXd::Constant(1, -kInf); }),
            "ocp: u_upper[0] = -inf: an upper bound may be inf (unbounded), not -inf");
  EXPECT_THAT(with([](OcpProblem& p) { p.horizon = kInf; }),
              HasSubstr("the horizon must be positive and finite, got inf"));
  EXPECT_THAT(with([](OcpProblem& p) { p.T_max = 10.0; }),
              HasSubstr("T_min = 0, T_max = 10 bound a free horizon, but time_optimal is not set"));
  EXPECT_THAT(with([](OcpProblem& p) {
                p.time_optimal = true;
                p.T_min = kNan;
              }),
              HasSubstr("T_min = nan, T_max = inf is no interval"));
  EXPECT_EQ(with([](OcpProblem& p) {
              p.track_R = Eigen::VectorXd::Constant(1, -1.0);
              p.u_ref = Eigen::VectorXd::Zero(1);
            }),
            "ocp: track_R[0] = -1 must be finite and >= 0");
  EXPECT_EQ(with([](OcpProblem& p) {
              p.track_R = Eigen::VectorXd::Constant(1, 1.0);
              p.u_ref = Eigen::VectorXd::Constant(1, kInf);
            }),
            "ocp: u_ref[0] = inf must be finite");
  EXPECT_THAT(with([](OcpProblem& p) {
                p.track_Q = Eigen::Vector2d(1.0, 1.0);
                p.x_ref = [](double t) { return Eigen::Vector2d(t < 1.0 ? 0.0 : kInf, 0.0); };
              }),
              HasSubstr("ocp: x_ref(1.5)[0] = inf must be finite"));
  EXPECT_THAT(with([](OcpProblem& p) { p.x_bounds_at_stage_points = true; }),
              HasSubstr("x_bounds_at_stage_points is set, but there are no x bounds"));
  EXPECT_THAT(with([](OcpProblem& p) {
                p.guess_policy = [](int, const Eigen::VectorXd&) {
                  return Eigen::VectorXd(Eigen::VectorXd::Zero(1));
                };
              }),
              HasSubstr("guess_policy is given, but the guess is not the simulated guess"));
}

// Options that contradict each other (one asks for what the other switches off) are refused:
// with the command's --cross point-sums --standard the solve ran and said nothing.
TEST(OcpInput, ContradictoryOptionsAreRefused) {
  const auto model = adapt_ocp(examples::TurboCar{});
  const OcpProblem problem = examples::TurboCar::problem();
  OcpOptions o;
  o.stages = 5;
  o.standard = true;
  o.cross_complementarity = CrossComplementarity::kPointSums;
  EXPECT_THAT(message_of([&] { ocp_solve(model, problem, o); }),
              HasSubstr("ocp: cross complementarity point-sums belongs to FESD, but standard "
                        "time-stepping is asked for"));
  o.cross_complementarity = CrossComplementarity::kPointPairs;
  EXPECT_THAT(message_of([&] { ocp_solve(model, problem, o); }),
              HasSubstr("cross complementarity point-pairs belongs to FESD"));
  o.cross_complementarity = CrossComplementarity::kElementSums;
  o.step_deviation_weight = 1.0;
  EXPECT_THAT(message_of([&] { ocp_solve(model, problem, o); }),
              HasSubstr("weigh the element lengths, which standard time-stepping fixes"));
  o = {};
  o.stages = 5;
  o.exact_hessian = false;
  o.solver.exact_hessian_scale = 2.0;
  EXPECT_THAT(
      message_of([&] { ocp_solve(model, problem, o); }),
      HasSubstr("exact_hessian_scale = 2 scales the exact Hessian, but exact_hessian is off"));
  o = {};
  o.stages = 5;
  o.tracking = OcpTracking::kStageEnds;
  EXPECT_THAT(message_of([&] { ocp_solve(model, problem, o); }),
              HasSubstr("tracking at the stage ends is chosen, but no track_Q"));
  // Standard time-stepping alone still solves (the default element-sum rows are one per point).
  o = {};
  o.stages = 5;
  o.standard = true;
  EXPECT_NO_THROW(ocp_solve(model, problem, o));
}

// cancelled: polled after every IPOPT iteration. Set after the first NLP (sigma = 100) is
// reported, the next NLP stops at its first iteration: status cancelled, the result the first
// NLP's solution (its objective as the progress reported it).
TEST(OcpCancel, CancellingKeepsTheLastSolvedNlp) {
  const auto model = adapt_ocp(examples::TurboCar{});
  const OcpProblem problem = examples::TurboCar::problem();
  OcpOptions o;
  o.stages = 5;
  std::vector<OcpHomotopyStep> steps;
  o.progress = [&](const OcpHomotopyStep& s) { steps.push_back(s); };
  o.cancelled = [&] { return !steps.empty(); };
  const OcpResult r = ocp_solve(model, problem, o);
  EXPECT_EQ(r.status, OcpStatus::kCancelled);
  EXPECT_STREQ(to_string(r.status), "cancelled");
  EXPECT_FALSE(r.ok());
  ASSERT_EQ(steps.size(), 2u);
  EXPECT_EQ(steps[0].sigma, o.homotopy.sigma_initial);
  EXPECT_EQ(steps[1].ipopt_status, "User_Requested_Stop");
  EXPECT_THAT(r.message,
              HasSubstr("cancelled (OcpOptions::cancelled) during the NLP at sigma = 10; "
                        "the result is the solution at sigma = 100"));
  EXPECT_EQ(r.objective, steps[0].objective);
  EXPECT_TRUE(r.x_grid.allFinite());
  EXPECT_FALSE(r.polished);

  // Cancelled at once: no NLP solved, the result is the first NLP's last iterate.
  o.progress = nullptr;
  o.cancelled = [] { return true; };
  const OcpResult now = ocp_solve(model, problem, o);
  EXPECT_EQ(now.status, OcpStatus::kCancelled);
  EXPECT_THAT(now.message, HasSubstr("no NLP was solved"));
}

}  // namespace
}  // namespace bflow

// fesd_simulate from several threads (IPOPT and MUMPS serialised by ipopt_mutex), its horizon
// checks, the cancellation hook and the progress callback.
#include <cmath>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/examples/switching_cases.h"
#include "bflow/fesd/fesd.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;

// Bit-equal results: the same grid, states, active sets and end.
void expect_same(const FesdResult& a, const FesdResult& b) {
  EXPECT_EQ(a.status, b.status);
  EXPECT_EQ(a.grid, b.grid);
  EXPECT_EQ(a.step_sizes, b.step_sizes);
  EXPECT_EQ(a.active_sets, b.active_sets);
  ASSERT_EQ(a.states.cols(), b.states.cols());
  EXPECT_TRUE((a.states.array() == b.states.array()).all());
  EXPECT_TRUE((a.x_end.array() == b.x_end.array()).all());
}

// The IPOPT path (newton = false) of the sliding case on two threads at once: MUMPS's module
// state is shared by its instances, and two factorisations at once crashed the process
// ("PB allocation in DMUMPS_LOAD_INIT"). Serialised, each thread gets the serial result.
TEST(FesdThreads, TwoThreadsOnTheIpoptPathGiveTheSerialResult) {
  const examples::SwitchingCaseSolution exact = examples::exact_switching_case("sliding-enter");
  const auto model = adapt_step(examples::SlidingEnterCase{});
  FesdOptions o;
  o.newton = false;
  o.steps = 4;
  const FesdResult serial = fesd_simulate(model, exact.x0, exact.t_end, o);
  ASSERT_TRUE(serial.ok()) << serial.message;
  for (int round = 0; round < 2; ++round) {
    std::vector<FesdResult> results(2);
    std::vector<std::thread> threads;
    for (int k = 0; k < 2; ++k) {
      threads.emplace_back([&, k] {
        results[static_cast<std::size_t>(k)] = fesd_simulate(model, exact.x0, exact.t_end, o);
      });
    }
    for (std::thread& t : threads) t.join();
    for (const FesdResult& r : results) expect_same(r, serial);
  }
}

// A horizon whose steps cannot be integrated is refused, naming T and N_sim (T = 1e308 used to
// return x0 with a failed status and no exception).
TEST(FesdInput, AHorizonWhoseStepsCannotBeIntegratedIsRefused) {
  const auto model = adapt_step(examples::CrossingCase{});
  const Eigen::VectorXd x0 = Eigen::VectorXd::Constant(1, -1.0);
  FesdOptions o;
  o.steps = 10;
  std::string m = testing::message_of([&] { fesd_simulate(model, x0, 1e308, o); });
  EXPECT_THAT(m, HasSubstr("T = 1e+308 over N_sim = 10 steps"));
  EXPECT_THAT(m, HasSubstr("need T / N_sim <= 1e+18"));
  m = testing::message_of([&] { fesd_simulate(model, x0, 1e-310, o); });
  EXPECT_THAT(m, HasSubstr("T = 1e-310 over N_sim = 10 steps"));
  // At the bound the run is accepted (and ends as IPOPT ends it: a status, no exception).
  o.steps = 1;
  o.elements = 1;
  EXPECT_NO_THROW(fesd_simulate(model, x0, kFesdMaxStepLength, o));
  for (const double t : {std::numeric_limits<double>::quiet_NaN(),
                         std::numeric_limits<double>::infinity(), 0.0, -1.0}) {
    EXPECT_THAT(testing::message_of([&] { fesd_simulate(model, x0, t, o); }),
                HasSubstr("T must be finite and > 0"));
  }
}

TEST(FesdInput, NonFiniteOrContradictoryOptionsAreRefused) {
  const auto model = adapt_step(examples::CrossingCase{});
  const Eigen::VectorXd x0 = Eigen::VectorXd::Constant(1, -1.0);
  FesdOptions o;
  o.homotopy.sigma_initial = std::numeric_limits<double>::infinity();
  EXPECT_THAT(testing::message_of([&] { fesd_simulate(model, x0, 1.0, o); }),
              HasSubstr("sigma_initial = inf"));
  o = {};
  o.homotopy.nlp_tolerance = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THAT(testing::message_of([&] { fesd_simulate(model, x0, 1.0, o); }),
              HasSubstr("nlp_tolerance = nan"));
  o = {};
  o.solver.exact_hessian_scale = 2.0;  // scales a Hessian that is not computed
  EXPECT_THAT(
      testing::message_of([&] { fesd_simulate(model, x0, 1.0, o); }),
      HasSubstr("exact_hessian_scale = 2 scales the exact Hessian, but exact_hessian is off"));
  o = {};
  o.solver.print_level = 13;
  EXPECT_THAT(testing::message_of([&] { fesd_simulate(model, x0, 1.0, o); }),
              HasSubstr("print_level = 13"));
}

// progress: one report per step, in order, the lengths summing to T; cancelled after the third
// report: the run stops there with kCancelled, its grid and states those of the first three
// steps of the full run (bit-equal: the same computation up to there).
TEST(FesdCancel, ProgressReportsEveryStepAndCancellingKeepsTheStepsDone) {
  const examples::SwitchingCaseSolution exact = examples::exact_switching_case("sliding-enter");
  const auto model = adapt_step(examples::SlidingEnterCase{});
  FesdOptions o;
  o.steps = 4;  // steps of 0.25, exact in binary
  std::vector<FesdStepReport> reports;
  o.progress = [&](const FesdStepReport& r) { reports.push_back(r); };
  const FesdResult full = fesd_simulate(model, exact.x0, exact.t_end, o);
  ASSERT_TRUE(full.ok()) << full.message;
  ASSERT_EQ(reports.size(), 4u);  // no step of this run is halved (halved_steps == 0)
  ASSERT_EQ(full.halved_steps, 0);
  double t = 0.0;
  for (std::size_t k = 0; k < reports.size(); ++k) {
    EXPECT_EQ(reports[k].index, static_cast<int>(k));
    EXPECT_EQ(reports[k].planned, 4);
    EXPECT_DOUBLE_EQ(reports[k].t, t);
    t += reports[k].length;
  }
  EXPECT_EQ(t, exact.t_end);

  for (const bool newton : {true, false}) {
    SCOPED_TRACE(newton ? "newton" : "ipopt");
    o.newton = newton;
    int done = 0;
    o.progress = [&](const FesdStepReport&) { ++done; };
    const FesdResult whole = fesd_simulate(model, exact.x0, exact.t_end, o);
    done = 0;
    o.cancelled = [&] { return done >= 3; };
    const FesdResult cut = fesd_simulate(model, exact.x0, exact.t_end, o);
    o.cancelled = nullptr;
    EXPECT_EQ(cut.status, FesdStatus::kCancelled);
    EXPECT_FALSE(cut.ok());
    EXPECT_THAT(cut.message, HasSubstr("cancelled at t = 0.75 after 3 integration steps"));
    const int n = 3 * o.elements;
    ASSERT_EQ(cut.grid.size(), static_cast<std::size_t>(n + 1));
    ASSERT_EQ(cut.states.cols(), n + 1);
    for (int i = 0; i <= n; ++i) {
      EXPECT_EQ(cut.grid[static_cast<std::size_t>(i)], whole.grid[static_cast<std::size_t>(i)]);
      EXPECT_TRUE((cut.states.col(i).array() == whole.states.col(i).array()).all());
    }
    EXPECT_TRUE((cut.x_end.array() == cut.states.col(n).array()).all());
    EXPECT_EQ(cut.sensitivity.size(), 0);
  }
  // Cancelled inside IPOPT (at its first iteration callback): the run ends at t = 0, x0.
  o.newton = false;
  o.progress = nullptr;
  int polls = 0;
  o.cancelled = [&] { return ++polls > 1; };  // the check before the first step passes
  const FesdResult at_once = fesd_simulate(model, exact.x0, exact.t_end, o);
  EXPECT_EQ(at_once.status, FesdStatus::kCancelled);
  EXPECT_THAT(at_once.message, HasSubstr("cancelled at t = 0 after 0 integration steps"));
  EXPECT_TRUE((at_once.x_end.array() == exact.x0.array()).all());
}

}  // namespace
}  // namespace bflow

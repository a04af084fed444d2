#include "bflow/sweep/sweep.h"

#include <cmath>
#include <cstdint>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "bflow/core/errors.h"
#include "bflow/examples/piecewise_constant.h"
#include "bflow/integrators/model_adapter.h"
#include "bflow/sweep/parallel.h"

namespace bflow {
namespace {

TEST(SweepGrid, TheFirstAxisVariesSlowestAndTheEndsAreExact) {
  const SweepGrid grid(
      {SweepAxis::state_axis(1, -1.0, 1.0, 3), SweepAxis::parameter_axis("delta", 0.1, 0.7, 4)});
  ASSERT_EQ(grid.samples(), 12u);
  EXPECT_EQ(grid.values(0), (std::vector<double>{-1.0, 0.1}));
  EXPECT_EQ(grid.values(3), (std::vector<double>{-1.0, 0.7}));
  EXPECT_EQ(grid.values(4), (std::vector<double>{0.0, 0.1}));
  EXPECT_EQ(grid.values(11), (std::vector<double>{1.0, 0.7}));
  // The inner values: lo + k (hi - lo) / (count - 1).
  EXPECT_DOUBLE_EQ(grid.values(1)[1], 0.1 + 0.6 / 3.0);
  EXPECT_DOUBLE_EQ(grid.values(2)[1], 0.1 + 1.2 / 3.0);
  Eigen::VectorXd x = Eigen::VectorXd::Constant(2, 5.0);
  grid.apply_states(5, x);
  EXPECT_EQ(x[0], 5.0);  // not varied
  EXPECT_EQ(x[1], 0.0);
}

TEST(SweepGrid, NoAxesIsOneSample) {
  const SweepGrid grid({});
  EXPECT_EQ(grid.samples(), 1u);
  EXPECT_TRUE(grid.values(0).empty());
}

TEST(SweepGrid, BadAxesAreRefusedWithTheirValues) {
  const auto message = [](std::vector<SweepAxis> axes) {
    try {
      SweepGrid grid(std::move(axes));
    } catch (const InvalidArgument& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_NE(message({SweepAxis::state_axis(0, 0.0, 1.0, 0)}).find("x[0] has a count of 0"),
            std::string::npos);
  EXPECT_NE(message({SweepAxis::parameter_axis("m", 0.0, INFINITY, 3)}).find("m has a non-finite"),
            std::string::npos);
  EXPECT_NE(message({SweepAxis::state_axis(0, 0.0, 1.0, std::uint64_t{1} << 30),
                     SweepAxis::state_axis(1, 0.0, 1.0, std::uint64_t{1} << 30)})
                .find("more than 2^53"),
            std::string::npos);
  const SweepGrid grid({SweepAxis::state_axis(3, 0.0, 1.0, 2)});
  Eigen::VectorXd x = Eigen::VectorXd::Zero(2);
  EXPECT_THROW(grid.apply_states(0, x), InvalidArgument);
}

// The piecewise-constant field of [B] Section 3.1 (d = 2, linear Delta, delta = 0.5): straight
// lines between the coordinate planes, so its exact flow (PiecewiseConstantField::flow) is the
// reference for x_t and its one-sided differences for the images (the flow is piecewise affine).
class PwconstSweep : public ::testing::Test {
 protected:
  const examples::PiecewiseConstantField field_ = examples::PiecewiseConstantField::linear(2, 0.5);
  const ModelAdapter<examples::PiecewiseConstantField> model_ = adapt(field_);
  FlowSweepRequest request_{1.5, {Eigen::Vector2d(1.0, 0.0), Eigen::Vector2d(0.3, -0.7)}, {}};
  // x0 over [-1, -0.1] x [-0.9, 0.2]: every sample crosses x_0 = 0, some x_1 = 0 too, and the
  // samples with x0[1] = 0 start on a surface.
  const SweepGrid grid_{
      {SweepAxis::state_axis(0, -1.0, -0.1, 4), SweepAxis::state_axis(1, -0.9, 0.2, 12)}};

  std::vector<FlowSampleRecord> sweep(int threads, std::string* text = nullptr) {
    std::vector<FlowSampleRecord> out;
    std::ostringstream stream;
    SweepWriter writer(stream, SweepFormat::kJsonLines, grid_, 2, 2);
    SweepRunOptions o;
    o.threads = threads;
    run_ordered<FlowSampleRecord>(
        0, grid_.samples(),
        [&](std::uint64_t i) {
          Eigen::VectorXd x0 = Eigen::VectorXd::Zero(2);
          grid_.apply_states(i, x0);
          return evaluate_flow_sample(model_, x0, request_, i, grid_.values(i));
        },
        [&](std::uint64_t i, const std::string& what) {
          return FlowSampleRecord::error(i, grid_.values(i), what);
        },
        [&](FlowSampleRecord&& r) {
          writer.write(r);
          out.push_back(std::move(r));
        },
        o);
    if (text != nullptr) *text = stream.str();
    return out;
  }
};

TEST_F(PwconstSweep, EverySampleAgreesWithTheExactFlowAndItsOneSidedDifferences) {
  const std::vector<FlowSampleRecord> out = sweep(2);
  ASSERT_EQ(out.size(), 48u);
  int ok = 0, simultaneous = 0;
  for (const FlowSampleRecord& r : out) {
    const Eigen::Vector2d x0(r.varied[0], r.varied[1]);
    if (x0[1] == 0.0) continue;  // on a surface: the next test
    ASSERT_EQ(r.status, "ok") << r.index << ": " << r.message;
    ++ok;
    const Eigen::VectorXd exact = field_.flow(x0, request_.t);
    // Constant fields between the planes: rounding alone (at most 3.2e-16 measured).
    EXPECT_LT((r.x_t - exact).norm(), 2e-15) << r.index;
    for (std::size_t k = 0; k < request_.directions.size(); ++k) {
      const Eigen::VectorXd& dx = request_.directions[k];
      const double alpha = 1e-7;
      const Eigen::VectorXd fd = (field_.flow(x0 + alpha * dx, request_.t) - exact) / alpha;
      // Piecewise affine: the one-sided difference is exact up to rounding, 1e-16 / alpha (at
      // most 1.7e-9 measured), also where both planes are crossed at once (the B-derivative is
      // the one-sided derivative, whichever plane dx brings first).
      EXPECT_LT((r.images[k] - fd).norm(), 1e-8) << r.index << " dx " << k;
    }
    // x_1 moves at 1.5 while negative, so it reaches its plane before t = 0.6; x_0 always does.
    // Plane j is crossed where the constant speed 1.5 (Delta = -0.5 b on both sides' words
    // before it) takes x0[j] to 0: t_j = -x0[j] / 1.5. Event location by the integrator's
    // interpolant is exact up to rounding here: at most 1.1e-16 measured with dopri5, 3.1e-15
    // with dop853 (the defaults' choice at rtol 1e-8), whose weights sum to 1 through terms of
    // up to 5.8 in magnitude, so each step rounds a constant field's increment by ~13 eps.
    int crossed = 0;
    for (const EventRecord& e : r.events) {
      for (const int j : e.surfaces) {
        EXPECT_NEAR(e.t, -x0[j] / 1.5, 8e-15) << r.index << " surface " << j;
      }
      crossed += e.group_size();
    }
    EXPECT_EQ(crossed, x0[1] < 0.0 ? 2 : 1) << r.index;
    // Both planes at once where F_-- = (1.5, 1.5) takes x0 to the origin: x0[0] = x0[1].
    const bool together = std::abs(x0[0] - x0[1]) < 1e-12;
    simultaneous += together ? 1 : 0;
    EXPECT_EQ(r.pieces, together ? 2.0 : 1.0) << r.index;
  }
  EXPECT_EQ(ok, 44);
  EXPECT_EQ(simultaneous, 3);  // (-0.7, -0.7), (-0.4, -0.4), (-0.1, -0.1)
}

TEST_F(PwconstSweep, SamplesThatStartOnASurfaceFailAloneInTheMiddleOfTheSweep) {
  // x0[1] = -0.9 + 1.1 k / 11 is 0 exactly at k = 9: indices 9, 21, 33 and 45.
  const std::vector<FlowSampleRecord> out = sweep(3);
  ASSERT_EQ(out.size(), 48u);
  std::vector<std::uint64_t> failed;
  for (const FlowSampleRecord& r : out) {
    if (r.ok()) continue;
    failed.push_back(r.index);
    EXPECT_EQ(r.status, "rejected");
    EXPECT_NE(r.message.find("h_1 = 0"), std::string::npos) << r.message;
    EXPECT_EQ(r.pieces, 0.0);
    EXPECT_EQ(r.x_t.size(), 0);
  }
  EXPECT_EQ(failed, (std::vector<std::uint64_t>{9, 21, 33, 45}));
  EXPECT_TRUE(out[10].ok());  // the sweep went on after it
}

TEST_F(PwconstSweep, TheOutputIsTheSameByteForByteWithOneTwoOrFiveThreads) {
  std::string one, two, five;
  sweep(1, &one);
  sweep(2, &two);
  sweep(5, &five);
  EXPECT_FALSE(one.empty());
  EXPECT_EQ(one, two);
  EXPECT_EQ(one, five);
}

TEST_F(PwconstSweep, ASimultaneousCrossingHasTwoPiecesAndTheOrderOfTheDirection) {
  // From -F_--(0)/2 the flow reaches the origin at t = 1/2: both planes at once ([B] 3.1).
  const Eigen::VectorXd x0 = -0.5 * field_.limits().col(0);
  request_.directions = {Eigen::Vector2d(1.0, 0.0), Eigen::Vector2d(0.0, 1.0)};
  const FlowSampleRecord r = evaluate_flow_sample(model_, x0, request_, 0, {});
  ASSERT_EQ(r.status, "ok") << r.message;
  ASSERT_EQ(r.events.size(), 1u);
  EXPECT_EQ(r.events[0].surfaces, (std::vector<int>{0, 1}));
  EXPECT_EQ(r.pieces, 2.0);
  // Pushing x_0 forward makes plane 0 come first, and pushing x_1 forward plane 1.
  EXPECT_EQ(r.orders[0], (std::vector<std::vector<int>>{{0, 1}}));
  EXPECT_EQ(r.orders[1], (std::vector<std::vector<int>>{{1, 0}}));
}

TEST(FlowSample, AGroupOfThreeSurfacesHasThreeFactorialPiecesTimesTheOtherGroups) {
  // d = 5, delta = 0.25: every coordinate moves at 1.25 while negative. From
  // (-0.5, -0.5, -0.5, -0.75, -0.75) planes 0, 1, 2 are crossed together at t = 0.4 and planes
  // 3, 4 together at t = 0.6: 3! 2! = 12 pieces (the product of the groups' sizes would be 6).
  const examples::PiecewiseConstantField field = examples::PiecewiseConstantField::linear(5, 0.25);
  const auto model = adapt(field);
  Eigen::VectorXd x0(5);
  x0 << -0.5, -0.5, -0.5, -0.75, -0.75;
  Eigen::VectorXd dx(5);
  dx << 1.0, 0.5, 0.0, 0.0, -1.0;
  const FlowSweepRequest request{1.0, {dx}, {}};
  const FlowSampleRecord r = evaluate_flow_sample(model, x0, request, 0, {});
  ASSERT_EQ(r.status, "ok") << r.message;
  ASSERT_EQ(r.events.size(), 2u);
  EXPECT_EQ(r.events[0].surfaces, (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(r.events[1].surfaces, (std::vector<int>{3, 4}));
  EXPECT_NEAR(r.events[0].t, 0.4, 1e-15);
  EXPECT_NEAR(r.events[1].t, 0.6, 1e-15);
  EXPECT_EQ(r.pieces, 12.0);
  // A larger push reaches its plane sooner: 0 (by 1), 1 (by 0.5), 2; then 3 before 4 (held
  // back by -1).
  EXPECT_EQ(r.orders[0], (std::vector<std::vector<int>>{{0, 1, 2}, {3, 4}}));
  // Linear Delta: B = (1 - delta)/(1 + delta) I = 0.6 I whatever the order ([B] (3.2)).
  EXPECT_LT((r.images[0] - 0.6 * dx).norm(), 1e-15);
}

TEST(SweepAxis, ValuesStayFiniteWhenTheRangeExceedsTheDoubles) {
  const SweepAxis wide = SweepAxis::state_axis(0, -1e308, 1e308, 3);
  EXPECT_EQ(wide.value(0), -1e308);
  EXPECT_EQ(wide.value(1), 0.0);
  EXPECT_EQ(wide.value(2), 1e308);
  const SweepAxis five = SweepAxis::state_axis(0, 1.7e308, -1.7e308, 5);
  EXPECT_DOUBLE_EQ(five.value(1), 0.85e308);
  EXPECT_EQ(five.value(2), 0.0);
  EXPECT_DOUBLE_EQ(five.value(3), -0.85e308);
  // (hi - lo) k overflows though hi - lo does not: 1e308 * 2.
  const SweepAxis steps = SweepAxis::state_axis(0, 0.0, 1e308, 4);
  EXPECT_DOUBLE_EQ(steps.value(2), 1e308 * (2.0 / 3.0));
  EXPECT_TRUE(std::isfinite(steps.value(2)));
  // Ordinary ranges keep lo + k (hi - lo) / (count - 1), bit for bit.
  const SweepAxis usual = SweepAxis::state_axis(0, -0.01, 0.01, 5);
  EXPECT_EQ(usual.value(3), -0.01 + 0.02 * 3.0 / 4.0);
}

TEST_F(PwconstSweep, AnIntegrationThatStopsEarlyIsRecordedWithItsStatus) {
  request_.flow.integrator.max_steps = 3;
  const FlowSampleRecord r =
      evaluate_flow_sample(model_, Eigen::Vector2d(-1.0, -0.9), request_, 3, {-1.0, -0.9});
  EXPECT_EQ(r.status, "too many steps") << r.message;
  EXPECT_NE(r.message.find("max_steps"), std::string::npos) << r.message;
  EXPECT_GT(r.t_reached, 0.0);
  EXPECT_LT(r.t_reached, request_.t);
  EXPECT_EQ(r.pieces, 0.0);
  EXPECT_TRUE(r.images.empty());
}

TEST_F(PwconstSweep, AnOutputCutAnywhereResumesAtItsFirstIncompleteRecord) {
  for (const SweepFormat format : {SweepFormat::kJsonLines, SweepFormat::kCsv}) {
    // The whole output of the sweep, and where each of its lines ends.
    std::ostringstream whole;
    SweepWriter writer(whole, format, grid_, 2, 2);
    writer.header();
    for (const FlowSampleRecord& r : sweep(2)) writer.write(r);
    const std::string text = whole.str();
    std::vector<std::size_t> ends;
    for (std::size_t k = 0; k < text.size(); ++k) {
      if (text[k] == '\n') ends.push_back(k + 1);
    }
    // The identity line, and for CSV the column header.
    const std::size_t header_lines = format == SweepFormat::kCsv ? 2 : 1;
    ASSERT_EQ(ends.size(), 48 + header_lines);
    for (const std::size_t cut :
         {std::size_t{0}, std::size_t{7}, ends[0] - 1, ends[0], ends[0] + 3, ends[1] - 1, ends[1],
          ends[1] + 1, ends[10] - 1, ends[10], ends[30] + 7, text.size() - 1, text.size()}) {
      std::istringstream in(text.substr(0, cut));
      const SweepResumePoint point = find_resume_point(in, writer);
      std::size_t whole_lines = 0;
      while (whole_lines < ends.size() && ends[whole_lines] <= cut) ++whole_lines;
      const std::size_t kept = whole_lines < header_lines ? 0 : whole_lines - header_lines;
      EXPECT_EQ(point.records, kept) << "cut at " << cut;
      // A cut header is rewritten whole: nothing of it is kept.
      EXPECT_EQ(point.bytes, whole_lines < header_lines ? 0 : ends[whole_lines - 1])
          << "cut at " << cut;
    }
    // Reads are bounded: a line longer than the limit ends the reading with an error.
    std::istringstream endless(text.substr(0, ends[header_lines - 1]) + std::string(5000, 'x'));
    try {
      find_resume_point(endless, writer, 4096);
      ADD_FAILURE() << "a 5000-byte line was read";
    } catch (const InvalidArgument& e) {
      EXPECT_NE(std::string(e.what()).find("is longer than 4096 bytes"), std::string::npos)
          << e.what();
    }
  }
}

TEST_F(PwconstSweep, AnOutputOfAnotherSweepIsNotResumed) {
  std::ostringstream whole;
  SweepWriter writer(whole, SweepFormat::kJsonLines, grid_, 2, 2);
  writer.header();
  for (const FlowSampleRecord& r : sweep(2)) writer.write(r);
  // The same records read as those of a grid whose second axis has 13 values.
  const SweepGrid other(
      {SweepAxis::state_axis(0, -1.0, -0.1, 4), SweepAxis::state_axis(1, -0.9, 0.2, 13)});
  std::ostringstream unused;
  const SweepWriter other_writer(unused, SweepFormat::kJsonLines, other, 2, 2);
  std::istringstream in(whole.str());
  try {
    find_resume_point(in, other_writer);
    FAIL() << "resumed another sweep's output";
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("is from another sweep: its \"axes\" is "),
              std::string::npos)
        << e.what();
  }
  // The identity line alone does not make records of another grid this sweep's.
  const std::string text = whole.str();
  const std::string forged = other_writer.header_line() + text.substr(text.find('\n') + 1);
  std::istringstream forged_in(forged);
  try {
    find_resume_point(forged_in, other_writer);
    FAIL() << "resumed records of another grid";
  } catch (const InvalidArgument& e) {
    EXPECT_NE(std::string(e.what()).find("line 3 has index and varied values [1, -1, -0.8"),
              std::string::npos)
        << e.what();
  }
  // A CSV reader does not take JSON lines.
  const SweepWriter csv(unused, SweepFormat::kCsv, grid_, 2, 2);
  std::istringstream again(whole.str());
  EXPECT_THROW(find_resume_point(again, csv), InvalidArgument);
}

TEST_F(PwconstSweep, TheEventStructuresAreTheKnownConesOfTheField) {
  // From x0 = (a, b) in the open negative quadrant both coordinates grow at 1.25 until their
  // plane (Delta(b) = -0.25 b: crossing one plane leaves the other coordinate's speed alone), so
  // plane 0 comes first where a > b, plane 1 where a < b, both at once on the diagonal a = b;
  // there dx = (1, 0) brings plane 0 first. A 21 x 21 grid over [-1, -0.05]^2.
  request_.directions = {Eigen::Vector2d(1.0, 0.0)};
  const SweepGrid grid(
      {SweepAxis::state_axis(0, -1.0, -0.05, 21), SweepAxis::state_axis(1, -1.0, -0.05, 21)});
  int diagonal = 0;
  for (std::uint64_t i = 0; i < grid.samples(); ++i) {
    Eigen::VectorXd x0(2);
    grid.apply_states(i, x0);
    const FlowSampleRecord r = evaluate_flow_sample(model_, x0, request_, i, grid.values(i));
    const std::string expected = x0[0] > x0[1] ? "0 | 1" : x0[0] < x0[1] ? "1 | 0" : "0+1 (0>1)";
    diagonal += x0[0] == x0[1] ? 1 : 0;
    EXPECT_EQ(event_structure(r), expected) << "x0 = " << x0.transpose();
  }
  EXPECT_EQ(diagonal, 21);
  EXPECT_EQ(event_structure(FlowSampleRecord::error(0, {}, "boom")), "error");
  FlowSampleRecord quiet;
  EXPECT_EQ(event_structure(quiet), "no event");
}

TEST(SweepWriter, CsvHasTheAxesAsColumnsAndQuotesMessages) {
  const SweepGrid grid({SweepAxis::state_axis(0, 0.0, 1.0, 2)});
  std::ostringstream out;
  SweepWriter writer(out, SweepFormat::kCsv, grid, 2, 1);
  writer.header();
  FlowSampleRecord ok;
  ok.index = 0;
  ok.varied = {0.0};
  ok.t_reached = 1.0;
  ok.x_t = Eigen::Vector2d(0.1, 2.0);
  ok.images = {Eigen::Vector2d(1.0, -1.0)};
  EventRecord e;
  e.t = 0.5;
  e.surfaces = {0, 1};
  ok.events = {e};
  ok.orders = {{{1, 0}}};
  ok.pieces = 2.0;
  writer.write(ok);
  writer.write(FlowSampleRecord::error(1, {1.0}, "bad, \"really\"\nworse"));
  EXPECT_EQ(out.str(),
            "# bflow sweep {\"format\":\"csv\",\"states\":2,\"directions\":1,\"axes\":[{\"name\":"
            "\"x[0]\",\"lo\":0.0,\"hi\":1.0,\"count\":2}]}\n"
            "index,x[0],status,message,t_reached,x_t[0],x_t[1],image0[0],image0[1],events,orders,"
            "pieces\n"
            "0,0,ok,,1,0.1,2,1,-1,0.5:0+1,1>0,2\n"
            "1,1,error,\"bad, \"\"really\"\" worse\",0,,,,,,,0\n");
  EXPECT_EQ(parse_sweep_format("csv"), SweepFormat::kCsv);
  EXPECT_EQ(parse_sweep_format("jsonl"), SweepFormat::kJsonLines);
  EXPECT_THROW(parse_sweep_format("xml"), InvalidArgument);
}

}  // namespace
}  // namespace bflow

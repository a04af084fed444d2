// `bflow jump` in-process: numbers against closed forms and hand computations, exact printing,
// and one precise error line (exit code 2) for every kind of malformed input.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <streambuf>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bflow/core/jump_map.h"
#include "bflow/core/signs.h"
#include "bflow/core/triangulation.h"
#include "cli_commands.h"
#include "cli_util.h"
#include "support/run_command.h"

namespace bflow::cli {
namespace {

using bflow::testing::capture;
using bflow::testing::command_line;
using bflow::testing::Outcome;

using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::StartsWith;
using Json = nlohmann::json;

constexpr double kEps = 2.220446049250313e-16;

Outcome jump(const std::string& input, const JumpOptions& options = {}) {
  std::istringstream in(input);
  return capture(
      [&](std::ostream& out, std::ostream& err) { return run_jump(in, out, err, options); });
}

Json rows_json(const Eigen::MatrixXd& m) {
  Json rows = Json::array();
  for (Eigen::Index r = 0; r < m.rows(); ++r) {
    Json row = Json::array();
    for (Eigen::Index c = 0; c < m.cols(); ++c) row.push_back(m(r, c));
    rows.push_back(row);
  }
  return rows;
}

// The input document for normals eta (n x d), a limits table (d x 2^n) and tangents (columns).
Json document(const Eigen::MatrixXd& eta, const Eigen::MatrixXd& limits,
              const Eigen::MatrixXd& tangents) {
  const int n = static_cast<int>(eta.rows());
  Json words = Json::object();
  for (Eigen::Index w = 0; w < limits.cols(); ++w) {
    words[Signs(n, static_cast<std::uint64_t>(w)).str()] = rows_json(limits.col(w).transpose())[0];
  }
  return Json{{"normals", rows_json(eta)},
              {"field_limits", words},
              {"tangents", rows_json(tangents.transpose())}};
}

Eigen::VectorXd vector_of(const Json& v) {
  Eigen::VectorXd out(static_cast<Eigen::Index>(v.size()));
  for (std::size_t i = 0; i < v.size(); ++i) out[static_cast<Eigen::Index>(i)] = v[i].get<double>();
  return out;
}

Eigen::MatrixXd matrix_of(const Json& rows) {
  Eigen::MatrixXd out(static_cast<Eigen::Index>(rows.size()),
                      static_cast<Eigen::Index>(rows[0].size()));
  for (std::size_t r = 0; r < rows.size(); ++r) {
    out.row(static_cast<Eigen::Index>(r)) = vector_of(rows[r]).transpose();
  }
  return out;
}

// Parses a successful run.
Json result_of(const Json& input) {
  const Outcome o = jump(input.dump());
  EXPECT_EQ(o.code, 0) << o.err;
  EXPECT_EQ(o.err, "");
  return Json::parse(o.out);
}

// Gamma(b) = 1 - delta * b for the piecewise-constant field of [B] (3.1), eta = I.
Eigen::MatrixXd linear_limits(int d, double delta) {
  Eigen::MatrixXd limits(d, Eigen::Index{1} << d);
  for (Eigen::Index w = 0; w < limits.cols(); ++w) {
    for (int i = 0; i < d; ++i) limits(i, w) = ((w >> i) & 1) ? 1.0 - delta : 1.0 + delta;
  }
  return limits;
}

// The non-linear planar demo of [B] Section 3.1 (PiecewiseConstantField::planar_demo()).
Eigen::MatrixXd planar_limits() {
  Eigen::MatrixXd limits(2, 4);
  limits << 1.0, 0.5, 1.7, 0.7,  //
      1.0, 1.6, 0.6, 0.7;
  return limits;
}

TEST(JumpCommandTest, LinearCaseImageIsScaledTangent) {
  // [B] (3.2): Delta(b) = -delta b gives B = (1 - delta)/(1 + delta) I, here d = n = 3.
  const double delta = 0.3;
  const double factor = (1.0 - delta) / (1.0 + delta);
  Eigen::MatrixXd tangents(3, 5);
  tangents << 1.0, 3.0, -1.0, 2.0, 0.25,  //
      2.0, 1.0, 0.5, -3.0, -0.75,         //
      3.0, 2.0, 2.0, 1.0, 0.5;
  const Json out =
      result_of(document(Eigen::MatrixXd::Identity(3, 3), linear_limits(3, delta), tangents));
  EXPECT_EQ(out["n"], 3);
  EXPECT_EQ(out["d"], 3);
  ASSERT_EQ(out["results"].size(), 5u);
  for (Eigen::Index k = 0; k < tangents.cols(); ++k) {
    SCOPED_TRACE(k);
    const Json& r = out["results"][static_cast<std::size_t>(k)];
    const Eigen::VectorXd dx = tangents.col(k);
    // Algorithm 2.1 takes n = 3 steps with O(1) entries: a few eps relative to |dx|.
    EXPECT_LE((vector_of(r["image"]) - factor * dx).norm(), 16 * kEps * dx.norm());
    EXPECT_LE((matrix_of(r["jacobian"]) - factor * Eigen::MatrixXd::Identity(3, 3)).norm(),
              16 * kEps);
    std::vector<int> order = r["order"].get<std::vector<int>>();
    std::sort(order.begin(), order.end());
    EXPECT_THAT(order, ElementsAre(0, 1, 2));
    EXPECT_EQ(r["crossing_times"].size(), 3u);
    EXPECT_FALSE(r.contains("barycentric_image"));
  }
  EXPECT_FALSE(out.contains("pieces"));
  EXPECT_FALSE(out.contains("triangulation"));
}

TEST(JumpCommandTest, OneSurfaceGivesClassicSaltationMatrix) {
  // n = 1, [B] (2.5): M = I + (F+ - F-) eta^T / (eta . F-), computed here by hand.
  Eigen::MatrixXd eta(1, 3);
  eta << 2.0, -1.0, 0.5;
  Eigen::Vector3d f_minus(1.0, 0.5, 2.0);  // eta . F- = 2.5
  Eigen::Vector3d f_plus(0.3, -1.0, 4.0);  // eta . F+ = 3.6
  Eigen::MatrixXd limits(3, 2);
  limits << f_minus, f_plus;
  const Eigen::Vector3d dx(0.4, -1.2, 0.7);
  const Eigen::Matrix3d saltation =
      Eigen::Matrix3d::Identity() + (f_plus - f_minus) * eta.row(0) / 2.5;

  const Json out = result_of(document(eta, limits, dx));
  const Json& r = out["results"][0];
  EXPECT_LE((matrix_of(r["jacobian"]) - saltation).norm(), 8 * kEps * saltation.norm());
  EXPECT_LE((vector_of(r["image"]) - saltation * dx).norm(),
            8 * kEps * saltation.norm() * dx.norm());
  EXPECT_THAT(r["order"].get<std::vector<int>>(), ElementsAre(0));
  // Crossed when eta . (dx + t F-) = 0.
  EXPECT_NEAR(r["crossing_times"][0].get<double>(), -eta.row(0).dot(dx) / 2.5, 4 * kEps);
}

TEST(JumpCommandTest, OrderAndCrossingTimesOfHandBuiltTangents) {
  // Every Gamma(b) = (1, 1), eta = I: dx moves along (1, 1) and crosses surface j when
  // dx_j + t = 0. (-1, -2) reaches x_0 = 0 at t = 1, then x_1 = 0 at t = 2; B = I.
  Eigen::MatrixXd tangents(2, 2);
  tangents << -1.0, -2.0,  //
      -2.0, -1.0;
  const Json out =
      result_of(document(Eigen::MatrixXd::Identity(2, 2), Eigen::MatrixXd::Ones(2, 4), tangents));
  const Json& first = out["results"][0];
  EXPECT_THAT(first["order"].get<std::vector<int>>(), ElementsAre(0, 1));
  EXPECT_THAT(first["crossing_times"].get<std::vector<double>>(), ElementsAre(1.0, 2.0));
  EXPECT_THAT(first["image"].get<std::vector<double>>(), ElementsAre(-1.0, -2.0));
  EXPECT_EQ(matrix_of(first["jacobian"]), Eigen::MatrixXd::Identity(2, 2));
  const Json& second = out["results"][1];
  EXPECT_THAT(second["order"].get<std::vector<int>>(), ElementsAre(1, 0));
  EXPECT_THAT(second["crossing_times"].get<std::vector<double>>(), ElementsAre(1.0, 2.0));
  EXPECT_THAT(second["image"].get<std::vector<double>>(), ElementsAre(-2.0, -1.0));
}

TEST(JumpCommandTest, PiecesOfThePlanarDemoMatchHandComputation) {
  // M_(0,1) = S_1 S_0 with S_0 = I + (F+- - F--) e_0^T / 1 and
  // S_1 = I + (F++ - F+-) e_1^T / 1.6; M_(1,0) likewise with F-+ and 1.7.
  Eigen::Matrix2d m01, m10;
  m01 << 0.575, 0.125,  //
      0.2625, 0.4375;
  m10 << 7.0 / 17.0, 4.9 / 17.0,  //
      1.0 / 17.0, 10.9 / 17.0;
  Json input =
      document(Eigen::MatrixXd::Identity(2, 2), planar_limits(), Eigen::Matrix2d::Identity());
  input["pieces"] = true;
  const Json out = result_of(input);
  ASSERT_EQ(out["pieces"].size(), 2u);
  EXPECT_THAT(out["pieces"][0]["order"].get<std::vector<int>>(), ElementsAre(0, 1));
  EXPECT_THAT(out["pieces"][1]["order"].get<std::vector<int>>(), ElementsAre(1, 0));
  EXPECT_LE((matrix_of(out["pieces"][0]["matrix"]) - m01).norm(), 8 * kEps);
  EXPECT_LE((matrix_of(out["pieces"][1]["matrix"]) - m10).norm(), 8 * kEps);
  // (1, 0) crosses surface 0 first (tau_0 = -1 < tau_1 = 0), (0, 1) surface 1 first: the
  // active Jacobians are the pieces, printed identically.
  EXPECT_EQ(out["results"][0]["jacobian"], out["pieces"][0]["matrix"]);
  EXPECT_EQ(out["results"][1]["jacobian"], out["pieces"][1]["matrix"]);
  EXPECT_THAT(out["results"][0]["crossing_times"].get<std::vector<double>>(),
              ElementsAre(-1.0, -0.375));
}

TEST(JumpCommandTest, PiecesAreAllNFactorialOrdersInLexicographicOrder) {
  Json input =
      document(Eigen::MatrixXd::Identity(3, 3), linear_limits(3, 0.5), Eigen::MatrixXd(3, 0));
  input["pieces"] = true;
  const Json out = result_of(input);
  EXPECT_EQ(out["results"], Json::array());
  ASSERT_EQ(out["pieces"].size(), 6u);
  std::vector<int> expected = {0, 1, 2};
  for (const Json& piece : out["pieces"]) {
    EXPECT_EQ(piece["order"].get<std::vector<int>>(), expected);
    // Linear case: every piece is (1 - delta)/(1 + delta) I = I / 3.
    EXPECT_LE((matrix_of(piece["matrix"]) - Eigen::MatrixXd::Identity(3, 3) / 3.0).norm(),
              16 * kEps);
    std::next_permutation(expected.begin(), expected.end());
  }
}

TEST(JumpCommandTest, PrintedNumbersReadBackExactly) {
  // A tangent in ker eta is not moved at all (every tau is 0), so 0.1 and 1/3 come back as they
  // went in, and must be printed in their shortest exact form.
  Eigen::MatrixXd eta(1, 3);
  eta << 1.0, 0.0, 0.0;
  Eigen::MatrixXd limits(3, 2);
  limits << 1.0, 2.0,  //
      0.0, 1.0,        //
      0.0, 0.0;
  const Eigen::Vector3d dx(0.0, 0.1, 1.0 / 3.0);
  const Outcome o = jump(document(eta, limits, dx).dump());
  ASSERT_EQ(o.code, 0) << o.err;
  EXPECT_THAT(o.out, HasSubstr("\"image\": [0.0, 0.1, 0.3333333333333333]"));
  const Json out = Json::parse(o.out);
  EXPECT_EQ(out["results"][0]["image"][1].get<double>(), 0.1);
  EXPECT_EQ(out["results"][0]["image"][2].get<double>(), 1.0 / 3.0);

  // Every number printed for the planar demo is the library's double, bit for bit.
  Eigen::MatrixXd tangents(2, 3);
  tangents << 0.1, 1.0 / 3.0, -std::sqrt(2.0),  //
      0.7, -1e-7, 2.0 / 7.0;
  Json input = document(Eigen::MatrixXd::Identity(2, 2), planar_limits(), tangents);
  input["pieces"] = true;
  const Json planar = result_of(input);
  const JumpMap reference(Eigen::MatrixXd::Identity(2, 2), planar_limits());
  for (Eigen::Index k = 0; k < tangents.cols(); ++k) {
    const Json& r = planar["results"][static_cast<std::size_t>(k)];
    EXPECT_EQ(vector_of(r["image"]), reference.apply(tangents.col(k)));
    EXPECT_EQ(matrix_of(r["jacobian"]), reference.active_jacobian(tangents.col(k)));
    EXPECT_EQ(r["crossing_times"].get<std::vector<double>>(),
              reference.order(tangents.col(k)).times);
  }
  const auto pieces = reference.pieces();
  for (std::size_t k = 0; k < pieces.size(); ++k) {
    EXPECT_EQ(matrix_of(planar["pieces"][k]["matrix"]), pieces[k].matrix);
  }
}

TEST(JumpCommandTest, TriangulationIsPrintedAndAgreesWithAlgorithm) {
  Eigen::MatrixXd tangents(2, 3);
  tangents << 1.0, 0.0, -0.3,  //
      0.0, 1.0, 0.9;
  Json input = document(Eigen::MatrixXd::Identity(2, 2), planar_limits(), tangents);
  input["triangulation"] = true;
  const Json out = result_of(input);
  const Triangulation reference =
      JumpMap(Eigen::MatrixXd::Identity(2, 2), planar_limits()).triangulation();
  const Json& t = out["triangulation"];
  const std::vector<std::string> words = {"--", "+-", "-+", "++"};  // column b.bits()
  ASSERT_EQ(t["zeta"].size(), 4u);
  for (std::size_t w = 0; w < words.size(); ++w) {
    EXPECT_EQ(vector_of(t["zeta"][words[w]]), reference.zeta().col(static_cast<Eigen::Index>(w)));
    EXPECT_EQ(vector_of(t["zeta_image"][words[w]]),
              reference.zeta_image().col(static_cast<Eigen::Index>(w)));
  }
  // zeta_-- = -F_-- and zeta_++ = 0 ([B] (5.1)).
  EXPECT_THAT(t["zeta"]["--"].get<std::vector<double>>(), ElementsAre(-1.0, -1.0));
  EXPECT_THAT(t["zeta"]["++"].get<std::vector<double>>(), ElementsAre(0.0, 0.0));
  // L = span F_-- (ker eta = {0}): one unit column along (1, 1).
  ASSERT_EQ(t["lineality_basis"].size(), 1u);
  const Eigen::VectorXd l = vector_of(t["lineality_basis"][0]);
  EXPECT_NEAR(std::abs(l.dot(Eigen::Vector2d(1.0, 1.0).normalized())), 1.0, 4 * kEps);
  ASSERT_EQ(t["simplices"].size(), 2u);
  EXPECT_THAT(t["simplices"][0]["order"].get<std::vector<int>>(), ElementsAre(0, 1));
  EXPECT_THAT(t["simplices"][0]["words"].get<std::vector<std::string>>(),
              ElementsAre("--", "+-", "++"));
  EXPECT_THAT(t["simplices"][1]["words"].get<std::vector<std::string>>(),
              ElementsAre("--", "-+", "++"));
  for (const Json& r : out["results"]) {
    // Two independent evaluations of B; 2 x 2 solves of condition O(10).
    EXPECT_LE((vector_of(r["barycentric_image"]) - vector_of(r["image"])).norm(), 1e-14);
  }
}

TEST(JumpCommandTest, EmptyTangentsGiveEmptyResults) {
  const Json out =
      result_of(document(Eigen::MatrixXd::Identity(2, 2), planar_limits(), Eigen::MatrixXd(2, 0)));
  EXPECT_EQ(out, (Json{{"n", 2}, {"d", 2}, {"results", Json::array()}}));
}

TEST(JumpCommandTest, CompactOutputIsOneLineWithTheSameContent) {
  const Json input =
      document(Eigen::MatrixXd::Identity(2, 2), planar_limits(), Eigen::Vector2d(0.3, -0.2));
  const Outcome pretty = jump(input.dump());
  const Outcome compact = jump(input.dump(), JumpOptions{true});
  ASSERT_EQ(compact.code, 0);
  EXPECT_EQ(std::count(compact.out.begin(), compact.out.end(), '\n'), 1);
  EXPECT_EQ(Json::parse(compact.out), Json::parse(pretty.out));
  // Keys in the documented order.
  EXPECT_THAT(compact.out, StartsWith("{\"n\":2,\"d\":2,\"results\":[{\"image\":"));
}

TEST(JumpCommandTest, OverflowIsAFailureNotAnInfinity) {
  // eta . F_-+ = 1e-300 makes a crossing time overflow; nothing may be printed as inf or null.
  Eigen::MatrixXd limits = planar_limits();
  limits.col(0) << 1e-300, 1.0;
  limits.col(2) << 1e-300, 0.6;
  const Outcome o =
      jump(document(Eigen::MatrixXd::Identity(2, 2), limits, Eigen::Vector2d(1e10, -1e300)).dump());
  EXPECT_EQ(o.code, 1);
  EXPECT_EQ(o.out, "");
  EXPECT_EQ(o.err,
            "error: tangents[0]: apply: component 0 of B(dx) is about 2^1029, beyond the double "
            "range (about 1.8e308)\n");
}

// Numbers near the ends of the double range: the right answer where it is representable.
TEST(JumpCommandTest, LimitsNear1e308GiveTheRightImage) {
  // B = F+ / F- = 1.5 although eta . F- = 2e308 overflows and the crossing time is subnormal.
  Json r = result_of(Json::parse(
      R"({"normals":[[2]],"field_limits":{"-":[1e308],"+":[1.5e308]},"tangents":[[-1]]})"));
  EXPECT_EQ(r["results"][0]["image"][0].get<double>(), -1.5);
  EXPECT_EQ(r["results"][0]["crossing_times"][0].get<double>(), 1e-308);
  // B dx = dx + (F+ - F-) (eta . dx) / (eta . F-) = [-1, 0] - [0.35, 0.35].
  r = result_of(Json::parse(R"({"normals":[[1,1]],"field_limits":{"-":[1e308,1e308],
      "+":[1.7e308,1.7e308]},"tangents":[[-1,0]]})"));
  EXPECT_NEAR(r["results"][0]["image"][0].get<double>(), -1.35, 2 * kEps);
  EXPECT_NEAR(r["results"][0]["image"][1].get<double>(), -0.35, kEps);
  // Two surfaces: dx crosses surface 1 at t = 1, then surface 0 at once (0.5 / 1e308 later).
  const std::string two = R"({"normals":[[2,0],[0,2]],"field_limits":{"--":[0.5,1e307],
      "+-":[1,1e308],"-+":[1e308,1],"++":[1,1]},"tangents":[[-1,-1e307]])";
  r = result_of(Json::parse(two + "}"));
  EXPECT_EQ(r["results"][0]["image"], Json::parse("[-1.0, -1.0]"));
  EXPECT_EQ(r["results"][0]["order"], Json::parse("[1, 0]"));
  // The triangulation cannot evaluate that tangent (terms of 1e307 cancel to 1): a refusal
  // that says so, not a wrong number and not a crash.
  const Outcome o = jump(two + R"(, "triangulation": true})");
  EXPECT_EQ(o.code, 1);
  EXPECT_EQ(o.out, "");
  EXPECT_THAT(o.err, StartsWith("error: tangents[0]: barycentric_image: the triangulation "
                                "cannot evaluate this tangent in double precision"));
  EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1);
}

TEST(JumpCommandTest, NormalsOfAnyPositiveScaleGiveTheSameResult) {
  const Json reference = result_of(Json::parse(
      R"({"normals":[[1,0]],"field_limits":{"-":[1,0.5],"+":[2,1]},"tangents":[[-1,0.25]]})"));
  for (const char* scale : {"1e200", "1e-200", "1.7e308", "4.9e-324"}) {
    const Json r = result_of(Json::parse(std::string(R"({"normals":[[)") + scale +
                                         R"(,0]],"field_limits":{"-":[1,0.5],"+":[2,1]},
        "tangents":[[-1,0.25]], "pieces": true, "triangulation": true})"));
    EXPECT_EQ(r["results"][0]["image"], reference["results"][0]["image"]) << scale;
    EXPECT_EQ(r["results"][0]["jacobian"], reference["results"][0]["jacobian"]) << scale;
    EXPECT_EQ(r["pieces"][0]["matrix"], reference["results"][0]["jacobian"]) << scale;
  }
}

TEST(JumpCommandTest, ImagesBeyondTheRangeAreRefused) {
  // B = F+ / F- = 1e600.
  const Outcome o =
      jump(R"({"normals":[[1]],"field_limits":{"-":[1e-300],"+":[1e300]},"tangents":[[-1]]})");
  EXPECT_EQ(o.code, 1);
  EXPECT_EQ(o.out, "");
  EXPECT_EQ(o.err,
            "error: tangents[0]: apply: component 0 of B(dx) is about -2^1994, beyond the double "
            "range (about 1.8e308)\n");
}

// ---------------------------------------------------------------------------------------------
// Size limits: input and output are bounded before anything large is allocated.

Json identity_document(int n, bool pieces) {
  Json input =
      document(Eigen::MatrixXd::Identity(n, n), linear_limits(n, 0.2), Eigen::MatrixXd::Ones(n, 1));
  input["pieces"] = pieces;
  return input;
}

TEST(JumpCommandTest, TenSurfacesWithPiecesAreRefusedByTheOutputLimit) {
  // 10! pieces of 10 x 10 would print about 10 GB: refused from the sizes alone, at once.
  const Outcome o = jump(identity_document(10, true).dump());
  EXPECT_EQ(o.code, 2);
  EXPECT_EQ(o.out, "");
  EXPECT_THAT(o.err, StartsWith("error: pieces: the output would be about 10.5 GiB"));
  EXPECT_THAT(o.err, HasSubstr(" (n = 10, d = 10, n! = 3628800), above the limit of 1 GiB; "
                               "raise it with --max-output-bytes"));
  EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1);
  // The same limit applies to results alone; a raised limit lets a request through.
  JumpOptions tight;
  tight.max_output_bytes = 1000;
  EXPECT_EQ(jump(identity_document(4, false).dump(), tight).code, 2);
  tight.max_output_bytes = 1 << 20;
  EXPECT_EQ(jump(identity_document(4, true).dump(), tight).code, 0);
}

TEST(JumpCommandTest, LargePiecesAreStreamedAndMatchTheSaltationMatrices) {
  // 8! = 40320 pieces of 8 x 8: estimated above the in-memory threshold, so written piece by
  // piece; the text must still be one valid document with every piece right.
  for (bool compact : {false, true}) {
    JumpOptions options;
    options.compact = compact;
    const Outcome o = jump(identity_document(8, true).dump(), options);
    ASSERT_EQ(o.code, 0) << o.err;
    EXPECT_EQ(o.err, "");
    const Json r = Json::parse(o.out);
    ASSERT_EQ(r["pieces"].size(), 40320u);
    // Linear case: every piece is (1 - delta)/(1 + delta) I = 2/3 I.
    for (std::size_t k : {std::size_t{0}, std::size_t{12345}, std::size_t{40319}}) {
      const Eigen::MatrixXd m = matrix_of(r["pieces"][k]["matrix"]);
      EXPECT_LT((m - 2.0 / 3.0 * Eigen::MatrixXd::Identity(8, 8)).lpNorm<Eigen::Infinity>(),
                8 * kEps);
    }
    EXPECT_EQ(r["pieces"][40319]["order"], Json::parse("[7, 6, 5, 4, 3, 2, 1, 0]"));
    EXPECT_EQ(std::count(o.out.begin(), o.out.end(), '\n') == 1, compact);
  }
}

TEST(JumpCommandTest, InputLongerThanTheLimitIsRefused) {
  JumpOptions options;
  options.max_input_bytes = 100;
  const std::string padded = R"({"normals": [[1]], "field_limits": {"-": [1], "+": [2]},)" +
                             std::string(200, ' ') + R"("tangents": [[-1]]})";
  const Outcome o = jump(padded, options);
  EXPECT_EQ(o.code, 2);
  EXPECT_EQ(o.out, "");
  EXPECT_EQ(o.err,
            "error: input: the standard input is longer than 100 bytes (--max-input-bytes 100); "
            "raise the limit for a larger document\n");
  options.max_input_bytes = 1000;
  EXPECT_EQ(jump(padded, options).code, 0);
}

// ---------------------------------------------------------------------------------------------
// Malformed input: exit code 2, nothing on stdout, exactly one line on stderr naming the field.

struct BadInput {
  const char* name;
  std::string input;
  std::string expected;  // the start of the line after "error: "
};

void PrintTo(const BadInput& c, std::ostream* os) { *os << c.name; }

const std::string kNormals = R"("normals": [[1, 0], [0, 1]])";
const std::string kLimits =
    R"("field_limits": {"--": [1, 1], "+-": [0.5, 1.6], "-+": [1.7, 0.6], "++": [0.7, 0.7]})";
const std::string kTangents = R"("tangents": [[1, 0]])";

std::string with(const std::string& normals, const std::string& limits, const std::string& tangents,
                 const std::string& extra = "") {
  std::string text = "{" + normals;
  for (const std::string* part : {&limits, &tangents, &extra}) {
    if (!part->empty()) text += (text.size() > 1 ? ", " : "") + *part;
  }
  return text + "}";
}

class MalformedInputTest : public ::testing::TestWithParam<BadInput> {};

TEST_P(MalformedInputTest, ExitsWithCodeTwoAndOneLineNamingTheField) {
  const Outcome o = jump(GetParam().input);
  EXPECT_EQ(o.code, 2);
  EXPECT_EQ(o.out, "");
  EXPECT_THAT(o.err, StartsWith("error: " + GetParam().expected));
  EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1) << o.err;
  EXPECT_EQ(o.err.back(), '\n');
}

INSTANTIATE_TEST_SUITE_P(
    AllFields, MalformedInputTest,
    ::testing::Values(
        BadInput{"NotJson", "{\"normals\": [[1, 0]",
                 "input: not valid JSON: parse error at line 1"},
        BadInput{"Empty", "", "input: not valid JSON: parse error at line 1, column 1"},
        BadInput{"TrailingGarbage", with(kNormals, kLimits, kTangents) + " x",
                 "input: not valid JSON: parse error"},
        BadInput{"NumberOverflow", with(R"("normals": [[1, 0], [0, 1e999]])", kLimits, kTangents),
                 "input: not valid JSON: number overflow parsing '1e999'"},
        BadInput{"TopLevelArray", "[1, 2]", "input: expected a JSON object"},
        BadInput{"UnknownKey", with(kNormals, kLimits, R"("tangent": [[1, 0]])"),
                 "input: unknown key \"tangent\" (did you mean \"tangents\"?)"},
        BadInput{"UnknownKeyWithNewline", with(kNormals, kLimits, kTangents, R"("a\nb": 1)"),
                 "input: unknown key \"a\\u000ab\""},
        BadInput{"DuplicateKey", with(kNormals, kLimits, kTangents, kNormals),
                 "input: key \"normals\" appears twice"},
        BadInput{"MissingNormals", with(kLimits, kTangents, ""),
                 "normals: required field is missing"},
        BadInput{"MissingFieldLimits", with(kNormals, kTangents, ""),
                 "field_limits: required field is missing"},
        BadInput{"MissingTangents", with(kNormals, kLimits, ""),
                 "tangents: required field is missing"},
        BadInput{"NormalsString", with(R"("normals": "I")", kLimits, kTangents),
                 "normals: expected an array of rows"},
        BadInput{"NormalsEmpty", with(R"("normals": [])", kLimits, kTangents),
                 "normals: has no rows"},
        BadInput{"NormalsRowNotArray", with(R"("normals": [1, 0])", kLimits, kTangents),
                 "normals: row 0 is not an array of numbers (got a number)"},
        BadInput{"NormalsRowEmpty", with(R"("normals": [[]])", kLimits, kTangents),
                 "normals: row 0 is empty"},
        BadInput{"NormalsRagged", with(R"("normals": [[1, 0], [0, 1, 2]])", kLimits, kTangents),
                 "normals: row 1 has 3 numbers, expected 2"},
        BadInput{"NormalsStringEntry", with(R"("normals": [[1, 0], ["0", 1]])", kLimits, kTangents),
                 "normals[1][0]: expected a number, got string \"0\""},
        BadInput{"NormalsMoreThanD",
                 with(R"("normals": [[1, 0], [0, 1], [1, 1]])", kLimits, kTangents),
                 "normals: n = 3 surfaces in d = 2 dimensions"},
        BadInput{"NormalsRankDeficient", with(R"("normals": [[1, 0], [2, 0]])", kLimits, kTangents),
                 "normals: rank deficient"},
        BadInput{"NormalsZeroRow", with(R"("normals": [[1, 0], [0, 0]])", kLimits, kTangents),
                 "normals: row 1 is zero"},
        BadInput{"LimitsArray", with(kNormals, R"("field_limits": [[1, 1]])", kTangents),
                 "field_limits: expected an object mapping each sign word to d numbers"},
        BadInput{
            "LimitsMissingWord",
            with(kNormals, R"("field_limits": {"--": [1, 1], "+-": [0.5, 1.6], "++": [0.7, 0.7]})",
                 kTangents),
            "field_limits: missing word \"-+\""},
        BadInput{"LimitsBadCharacter",
                 with(kNormals,
                      R"("field_limits": {"--": [1, 1], "+-": [1, 1], "-x": [1, 1], "++": [1, 1]})",
                      kTangents),
                 "field_limits: sign word \"-x\" has \"x\" at position 1; only '-' and '+' are "
                 "allowed"},
        BadInput{
            "LimitsWordTooLong",
            with(kNormals,
                 R"("field_limits": {"--": [1, 1], "+-": [1, 1], "-+-": [1, 1], "++": [1, 1]})",
                 kTangents),
            "field_limits: word \"-+-\" has 3 characters, expected 2"},
        BadInput{
            "LimitsVectorSize",
            with(kNormals,
                 R"("field_limits": {"--": [1, 1], "+-": [1, 1, 1], "-+": [1, 1], "++": [1, 1]})",
                 kTangents),
            "field_limits[\"+-\"]: has 3 numbers, expected d = 2"},
        BadInput{
            "LimitsStringEntry",
            with(kNormals,
                 R"("field_limits": {"--": [1, 1], "+-": [1, "1"], "-+": [1, 1], "++": [1, 1]})",
                 kTangents),
            "field_limits[\"+-\"][1]: expected a number, got string \"1\""},
        BadInput{
            "LimitsDuplicateWord",
            with(
                kNormals,
                R"("field_limits": {"--": [1, 1], "--": [2, 2], "+-": [1, 1], "-+": [1, 1], "++": [1, 1]})",
                kTangents),
            "field_limits: key \"--\" appears twice"},
        BadInput{
            "LimitsNotTransversal",
            with(kNormals,
                 R"("field_limits": {"--": [1, 1], "+-": [-0.5, 1.6], "-+": [1, 1], "++": [1, 1]})",
                 kTangents),
            "field_limits: surface 0 is not transversal for word \"+-\""},
        BadInput{"TangentsObject", with(kNormals, kLimits, R"("tangents": {})"),
                 "tangents: expected an array of tangent vectors"},
        BadInput{"TangentNotArray", with(kNormals, kLimits, R"("tangents": [1, 0])"),
                 "tangents[0]: expected an array of d = 2 numbers, got a number"},
        BadInput{"TangentSize", with(kNormals, kLimits, R"("tangents": [[1, 2, 3]])"),
                 "tangents[0]: has 3 numbers, expected d = 2"},
        BadInput{"TangentStringEntry", with(kNormals, kLimits, R"("tangents": [[1, 0], ["1", 0]])"),
                 "tangents[1][0]: expected a number, got string \"1\""},
        BadInput{"TangentNull", with(kNormals, kLimits, R"("tangents": [[1, null]])"),
                 "tangents[0][1]: expected a number, got null"},
        BadInput{"TangentBoolean", with(kNormals, kLimits, R"("tangents": [[true, 0]])"),
                 "tangents[0][0]: expected a number, got boolean true"},
        BadInput{"PiecesNotBoolean", with(kNormals, kLimits, kTangents, R"("pieces": 1)"),
                 "pieces: expected true or false, got a number"},
        BadInput{"TriangulationNotBoolean",
                 with(kNormals, kLimits, kTangents, R"("triangulation": "yes")"),
                 "triangulation: expected true or false, got string \"yes\""}),
    [](const ::testing::TestParamInfo<BadInput>& param_info) {
      return std::string(param_info.param.name);
    });

TEST(JumpCommandTest, TooManySurfacesForPiecesNamesPieces) {
  // n = 11 is valid for B but pieces() enumerates at most n = 10 (11! matrices).
  Json input = document(Eigen::MatrixXd::Identity(11, 11), linear_limits(11, 0.2),
                        Eigen::MatrixXd::Ones(11, 1));
  input["pieces"] = true;
  const Outcome o = jump(input.dump());
  EXPECT_EQ(o.code, 2);
  EXPECT_EQ(o.out, "");
  EXPECT_THAT(o.err, StartsWith("error: pieces: n = 11 surfaces give n! pieces"));
  EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1);
}

// ---------------------------------------------------------------------------------------------
// Files and the command line.

TEST(JumpCommandTest, ReadsFilesAndReportsUnreadableOnes) {
  const std::filesystem::path dir = std::filesystem::path(::testing::TempDir()) / "jump_file";
  std::filesystem::create_directories(dir);
  const std::string good = (dir / "good.json").string();
  std::ofstream(good) << with(kNormals, kLimits, kTangents);
  std::istringstream no_stdin;
  std::ostringstream out, err;
  EXPECT_EQ(run_jump_file(good, no_stdin, out, err), 0) << err.str();
  EXPECT_EQ(Json::parse(out.str())["results"][0]["order"], Json({0, 1}));

  const std::string missing = (dir / "missing.json").string();
  const Outcome gone = command_line({"jump", "--input", missing});
  EXPECT_EQ(gone.code, 2);
  EXPECT_EQ(gone.out, "");
  EXPECT_EQ(gone.err, "error: input: cannot open \"" + missing + "\": No such file or directory\n");

  const Outcome directory = command_line({"jump", "--input", dir.string()});
  EXPECT_EQ(directory.code, 2);
  EXPECT_EQ(directory.err, "error: input: cannot read \"" + dir.string() + "\": Is a directory\n");
}

TEST(CommandLineTest, JumpReadsStandardInputForDash) {
  const Outcome o =
      command_line({"jump", "--input", "-", "--compact"}, with(kNormals, kLimits, kTangents));
  EXPECT_EQ(o.code, 0) << o.err;
  EXPECT_THAT(o.out, StartsWith("{\"n\":2,\"d\":2,\"results\":[{\"image\":[0.57"));
}

TEST(CommandLineTest, VersionAndHelp) {
  const Outcome version = command_line({"--version"});
  EXPECT_EQ(version.code, 0);
  EXPECT_EQ(version.out, "bflow 0.1.0\n");
  EXPECT_EQ(version_string(), "bflow 0.1.0");

  const Outcome help = command_line({"--help"});
  EXPECT_EQ(help.code, 0);
  EXPECT_THAT(help.out, HasSubstr("Usage: bflow"));
  EXPECT_THAT(help.out, HasSubstr("jump"));
  EXPECT_THAT(help.out, HasSubstr("demo"));
  EXPECT_THAT(help.out, HasSubstr("Exit codes"));

  const Outcome jump_help = command_line({"jump", "--help"});
  EXPECT_EQ(jump_help.code, 0);
  for (const char* phrase :
       {"--input FILE|-", "\"normals\"", "\"field_limits\"", "\"tangents\"", "\"pieces\"",
        "\"triangulation\"", "\"crossing_times\"", "\"jacobian\"", "\"barycentric_image\"",
        "Example", "error: tangents[0]: has 3 numbers, expected d = 2"}) {
    EXPECT_THAT(jump_help.out, HasSubstr(phrase));
  }
  const Outcome demo_help = command_line({"demo", "--help"});
  EXPECT_EQ(demo_help.code, 0);
  EXPECT_THAT(demo_help.out, HasSubstr("--no-plot"));
  EXPECT_THAT(demo_help.out, HasSubstr("bflow-demo"));
}

TEST(CommandLineTest, TheExampleInJumpHelpIsTrue) {
  const Outcome o = command_line(
      {"jump", "--input", "-", "--compact"},
      R"({"normals": [[1, 0]], "field_limits": {"-": [1, 0], "+": [2, 1]}, "tangents": [[-1, 0]]})");
  EXPECT_EQ(o.code, 0) << o.err;
  EXPECT_EQ(o.out,
            "{\"n\":1,\"d\":2,\"results\":[{\"image\":[-2.0,-1.0],\"order\":[0],"
            "\"crossing_times\":[1.0],\"jacobian\":[[2.0,0.0],[1.0,1.0]]}]}\n");
}

TEST(CommandLineTest, UsageErrorsAreOneLineWithCodeTwo) {
  for (const std::vector<std::string>& args :
       std::vector<std::vector<std::string>>{{},
                                             {"frobnicate"},
                                             {"jump"},
                                             {"jump", "--input"},
                                             {"jump", "--input", "-", "--frobnicate"},
                                             {"flow", "--dx"},
                                             {"demo", "--output"}}) {
    const Outcome o = command_line(args);
    SCOPED_TRACE(::testing::PrintToString(args));
    EXPECT_EQ(o.code, 2);
    EXPECT_EQ(o.out, "");
    EXPECT_THAT(o.err, StartsWith("error: "));
    EXPECT_EQ(std::count(o.err.begin(), o.err.end(), '\n'), 1) << o.err;
  }
  EXPECT_EQ(command_line({}).err,
            "error: a command is required: jump, flow, demo, fesd, ocp, sweep or orbit (see 'bflow "
            "--help')\n");
  EXPECT_EQ(command_line({"jump"}).err,
            "error: jump: --input is required (see 'bflow jump --help')\n");
}

// ---------------------------------------------------------------------------------------------
// The command's edges: bytes after the document, the byte limits as options, quoting.

// nlohmann reads a NUL as the end of the input; whatever follows the document is refused all the
// same, from the standard input and from a file (printf '{...}\0junk' > file).
TEST(JumpCommandTest, BytesAfterTheDocumentAreRefused) {
  const std::string document = with(kNormals, kLimits, kTangents);
  const std::string column = std::to_string(document.size() + 1);
  const Outcome junk = jump(document + std::string("\0junk", 5));
  EXPECT_EQ(junk.code, 2);
  EXPECT_EQ(junk.out, "");
  EXPECT_EQ(junk.err,
            "error: input: not valid JSON: a NUL byte follows the document at line 1, "
            "column " +
                column + " (5 trailing bytes); only whitespace may follow the document\n");
  const Outcome nul = jump(document + "\n" + std::string(1, '\0'));
  EXPECT_EQ(nul.code, 2);
  EXPECT_EQ(nul.err,
            "error: input: not valid JSON: a NUL byte follows the document at line 2, "
            "column 1 (1 trailing bytes); only whitespace may follow the document\n");

  const std::filesystem::path dir = std::filesystem::path(::testing::TempDir()) / "jump_nul";
  std::filesystem::create_directories(dir);
  const std::string file = (dir / "nul.json").string();
  std::ofstream(file, std::ios::binary) << document << std::string("\0junk", 5);
  const Outcome from_file = command_line({"jump", "--input", file});
  EXPECT_EQ(from_file.code, 2);
  EXPECT_EQ(from_file.out, "");
  EXPECT_EQ(from_file.err, junk.err);

  // Whitespace after the document is not a trailing byte; anything else is a syntax error.
  EXPECT_EQ(jump(document + " \n\t\r\n").code, 0);
  const Outcome text = jump(document + " junk");
  EXPECT_EQ(text.code, 2);
  EXPECT_THAT(text.err, StartsWith("error: input: not valid JSON: parse error at line 1, column " +
                                   std::to_string(document.size() + 2) + ": syntax error"));
}

TEST(CommandLineTest, ByteLimitsAreWholePositiveNumbersWithinSixtyFourBits) {
  const std::string document = with(kNormals, kLimits, kTangents);
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"--max-input-bytes", ""}, "--max-input-bytes: the value is empty"},
      {{"--max-output-bytes", ""}, "--max-output-bytes: the value is empty"},
      // 2^63 and 2^64 used to be clamped to 2^63 - 1 without a word.
      {{"--max-input-bytes", "9223372036854775808"},
       "--max-input-bytes: \"9223372036854775808\" is too large (at most 9223372036854775807)"},
      {{"--max-output-bytes", "18446744073709551616"},
       "--max-output-bytes: \"18446744073709551616\" is too large (at most "
       "9223372036854775807)"},
      {{"--max-input-bytes=-5"}, "--max-input-bytes: \"-5\" is too small (at least 1)"},
      {{"--max-output-bytes", "0"}, "--max-output-bytes: \"0\" is too small (at least 1)"},
      {{"--max-input-bytes", "1e6"}, "--max-input-bytes: \"1e6\" is not an integer"},
      {{"--max-output-bytes", "64MiB"}, "--max-output-bytes: \"64MiB\" is not an integer"},
  };
  for (const auto& [args, error] : cases) {
    std::vector<std::string> all = {"jump", "--input", "-"};
    all.insert(all.end(), args.begin(), args.end());
    const Outcome o = command_line(all, document);
    SCOPED_TRACE(::testing::PrintToString(all));
    EXPECT_EQ(o.code, 2);
    EXPECT_EQ(o.out, "");
    EXPECT_EQ(o.err, "error: " + error + "\n");
  }
  EXPECT_EQ(command_line({"jump", "-i", ""}).err, "error: --input: the value is empty\n");
  EXPECT_EQ(command_line({"jump", "--input", ""}).err, "error: --input: the value is empty\n");
  // The largest accepted, and the defaults.
  EXPECT_EQ(command_line({"jump", "--input", "-", "--max-input-bytes", "9223372036854775807",
                          "--max-output-bytes", "9223372036854775807"},
                         document)
                .code,
            0);
  const Outcome defaults = command_line({"jump", "--input", "-"}, document);
  EXPECT_EQ(defaults.code, 0) << defaults.err;
  EXPECT_EQ(Json::parse(defaults.out)["results"][0]["order"], Json({0, 1}));
  // In-process, the limits are checked where the file is read, naming the option.
  std::istringstream in(document);
  std::ostringstream out, err;
  JumpOptions negative;
  negative.max_output_bytes = -5;
  EXPECT_EQ(run_jump_file("-", in, out, err, negative), 2);
  EXPECT_EQ(err.str(), "error: --max-output-bytes: must be >= 1, got -5\n");
}

// "−" (U+2212, three bytes) is one character: the word "−+" has the right length for n = 2 and
// its first character is named, not a byte of it.
TEST(JumpCommandTest, SignWordsCountAndQuoteCharactersNotBytes) {
  const std::string limits =
      "\"field_limits\": {\"--\": [1, 1], \"+-\": [1, 1], \"-+\": [1, 1], \"\u2212+\": [1, 1]}";
  const Outcome minus = jump(with(kNormals, limits, kTangents));
  EXPECT_EQ(minus.code, 2);
  EXPECT_EQ(minus.out, "");
  EXPECT_EQ(
      minus.err,
      "error: field_limits: sign word \"\u2212+\" has \"\u2212\" (U+2212) at position 0; only "
      "'-' and '+' are allowed\n");
  const std::string long_word =
      "\"field_limits\": {\"--\": [1, 1], \"+-\": [1, 1], \"-+\": [1, 1], \"\u2212\u2212+\": [1, "
      "1]}";
  EXPECT_EQ(jump(with(kNormals, long_word, kTangents)).err,
            "error: field_limits: word \"\u2212\u2212+\" has 3 characters, expected 2 (one per "
            "surface)\n");
}

// What the user typed is quoted at a bounded length and printable: a key of 131 KB, a string
// whose bad byte ends 131 KB in, bytes that are not UTF-8 (which JSON refuses).
TEST(JumpCommandTest, OffendingTextIsQuotedShortAndPrintable) {
  const std::string huge(131072, 'k');
  const Outcome key = jump(with(kNormals, kLimits, kTangents, "\"" + huge + "\": 1"));
  EXPECT_EQ(key.code, 2);
  EXPECT_EQ(key.err, "error: input: unknown key \"" + std::string(60, 'k') +
                         "...\"; the keys are normals, field_limits, tangents, pieces, "
                         "triangulation\n");
  const Outcome duplicate =
      jump("{\"" + huge + "\": {\"a\": 1, \"a\": 2}}");  // the path names the outer key
  EXPECT_EQ(duplicate.code, 2);
  EXPECT_EQ(duplicate.err, "error: " + quote(huge, 40) + ": key \"a\" appears twice\n");
  const Outcome control = jump("{\"" + huge + "\n\": 1}");
  EXPECT_EQ(control.code, 2);
  EXPECT_THAT(control.err, StartsWith("error: input: not valid JSON: parse error at line 2, "
                                      "column 0: syntax error while parsing object key - invalid "
                                      "string: control character U+000A (LF) must be escaped"));
  EXPECT_THAT(control.err, HasSubstr("last read: '\"" + std::string(39, 'k') + "...'"));
  EXPECT_LT(control.err.size(), 300u);
  const Outcome overflow = jump(
      with("\"normals\": [[1, 0], [0, 1e" + std::string(131072, '9') + "]]", kLimits, kTangents));
  EXPECT_EQ(overflow.code, 2);
  EXPECT_EQ(overflow.err, "error: input: not valid JSON: number overflow parsing '1e" +
                              std::string(38, '9') + "...'\n");
  const Outcome bytes = jump("{\"normals\xff\xfe\": 1}");
  EXPECT_EQ(bytes.code, 2);
  EXPECT_THAT(bytes.err, HasSubstr("last read: '\"normals\\xff'"));
  EXPECT_EQ(bytes.err.find('\xff'), std::string::npos);
  EXPECT_EQ(std::count(bytes.err.begin(), bytes.err.end(), '\n'), 1);
}

// A stream that takes `capacity` bytes and then fails, as a closed pipe does.
class ClosingBuffer : public std::streambuf {
 public:
  explicit ClosingBuffer(std::size_t capacity) : capacity_(capacity) {}

 protected:
  int_type overflow(int_type c) override {
    if (traits_type::eq_int_type(c, traits_type::eof())) return traits_type::not_eof(c);
    const char ch = traits_type::to_char_type(c);
    return xsputn(&ch, 1) == 1 ? c : traits_type::eof();
  }
  std::streamsize xsputn(const char*, std::streamsize n) override {
    const auto taken = std::min<std::streamsize>(n, static_cast<std::streamsize>(capacity_));
    capacity_ -= static_cast<std::size_t>(taken);
    return taken;
  }

 private:
  std::size_t capacity_;
};

// Output that stops being written (8! pieces, streamed, into a reader that goes away after 1000
// bytes, or a small result buffered first) is a failed write: exit code 1, one line.
TEST(JumpCommandTest, OutputThatCannotBeWrittenIsOneLine) {
  for (const Json& input : {identity_document(8, true), identity_document(3, true)}) {
    ClosingBuffer closing(1000);
    std::ostream out(&closing);
    std::istringstream in(input.dump());
    std::ostringstream err;
    EXPECT_EQ(run_jump(in, out, err), 1);
    EXPECT_EQ(err.str(), "error: stdout: write failed\n");
  }
}

// Every command's error line is cut at 500 characters whatever its message holds (two quoted
// 200-character paths and a system reason, a library message): "..." marks the cut, which never
// falls inside a character; a shorter message is printed whole.
TEST(ReportErrorTest, TheLineIsCutAt500Characters) {
  std::ostringstream err;
  const std::string message = "x: " + std::string(300, 'a') + "\u2212" + std::string(600, 'b');
  report_error(err, message);
  const std::string line = err.str();
  ASSERT_EQ(line.back(), '\n');
  // "error: ", 490 characters of the message (3 + 300 + 1 + 186), "...": 500 in all.
  EXPECT_EQ(line,
            "error: x: " + std::string(300, 'a') + "\u2212" + std::string(186, 'b') + "...\n");
  std::ostringstream whole;
  report_error(whole, "x: " + std::string(400, 'a'));
  EXPECT_EQ(whole.str(), "error: x: " + std::string(400, 'a') + "\n");
}

}  // namespace
}  // namespace bflow::cli

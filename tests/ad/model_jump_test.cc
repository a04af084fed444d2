#include "bflow/ad/model_jump.h"

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/core/errors.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/model.h"
#include "bflow/core/signs.h"
#include "support/error_message.h"

namespace bflow::ad {
namespace {

using ::testing::HasSubstr;

// The piecewise-constant field of [B] (3.1) with Delta(b) = -delta * b and h(x) = x:
// F_b = 1 - delta * b (b_i = +-1), so [B] (3.2) gives B = (1 - delta) / (1 + delta) I.
struct PiecewiseConstant {
  static constexpr int kStates = kDynamic;
  static constexpr int kSurfaces = kDynamic;
  int d = 3;
  double delta = 0.4;
  int states() const { return d; }
  int surfaces() const { return d; }
  template <typename T>
  void field(const T*, Signs b, T* xdot) const {
    for (int i = 0; i < d; ++i) xdot[i] = T(1.0 - delta * b.sign(i));
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    for (int i = 0; i < d; ++i) h[i] = x[i];
  }
};

// Tangents in varied directions (so that every crossing order occurs for d = 3).
std::vector<Eigen::VectorXd> tangents(int d) {
  std::vector<Eigen::VectorXd> out;
  for (int k = 0; k < 12; ++k) {
    Eigen::VectorXd dx(d);
    for (int i = 0; i < d; ++i) dx[i] = std::sin(1.0 + 3.7 * k + 1.3 * i * (k + 1));
    out.push_back(dx);
  }
  out.push_back(Eigen::VectorXd::Zero(d));
  out.push_back(Eigen::VectorXd::Ones(d));
  return out;
}

void expect_scaled_identity(int d, double delta) {
  PiecewiseConstant model;
  model.d = d;
  model.delta = delta;
  std::vector<int> all(d);
  for (int i = 0; i < d; ++i) all[i] = i;
  const JumpMap jump = jump_map_at(model, Eigen::VectorXd::Zero(d), all);
  ASSERT_EQ(jump.surfaces(), d);
  ASSERT_EQ(jump.dim(), d);
  // h = x is crossed from - to + (F_b > 0): the normals are Dh = I, not flipped.
  EXPECT_EQ(jump.normals(), Eigen::MatrixXd::Identity(d, d));
  const double ratio = (1.0 - delta) / (1.0 + delta);
  for (const Eigen::VectorXd& dx : tangents(d)) {
    // Algorithm 2.1 does n rank-1 steps with O(1) numbers: rounding stays below
    // 1e-13 * max(1, |dx|).
    const Eigen::VectorXd image = jump.apply(dx);
    EXPECT_LT((image - ratio * dx).lpNorm<Eigen::Infinity>(),
              1e-13 * std::max(1.0, dx.lpNorm<Eigen::Infinity>()))
        << "d = " << d << ", dx = " << dx.transpose();
  }
}

TEST(ModelJumpTest, PiecewiseConstantFieldGivesScaledIdentity) {
  expect_scaled_identity(1, 0.4);
  expect_scaled_identity(3, 0.4);
  expect_scaled_identity(3, -0.3);
}

TEST(ModelJumpTest, PiecewiseConstantFieldWithMoreThanTwelveSurfaces) {
  // n = 13 > kCheckAllWordsMaxSurfaces: only 2n + 2 words are checked up front.
  static_assert(kCheckAllWordsMaxSurfaces == 12, "test assumes the documented threshold");
  expect_scaled_identity(13, 0.25);
}

// Surface h = -x0 - x1^2 / 4 crossed from + to - at rho = (-1/4, 1) (h(rho) = 0).
struct PlusToMinus {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    if (b.plus(0)) {  // before the crossing
      xdot[0] = T(1.0) + x[1] * x[1];
      xdot[1] = T(0.5) + sin(x[0]);
    } else {  // after
      xdot[0] = T(0.5) + T(0.1) * x[0];
      xdot[1] = T(1.0) + x[1] * x[0];
    }
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = -x[0] - T(0.25) * x[1] * x[1];
  }
};

TEST(ModelJumpTest, SurfaceCrossedFromPlusToMinusIsFlipped) {
  const Eigen::Vector2d rho(-0.25, 1.0);
  const Eigen::Vector2d before(1.0 + 1.0, 0.5 + std::sin(-0.25));  // F_+(rho)
  const Eigen::Vector2d after(0.5 - 0.025, 1.0 - 0.25);            // F_-(rho)
  const Eigen::Vector2d dh(-1.0, -0.5);                            // Dh(rho)
  ASSERT_LT(dh.dot(before), 0.0);  // h decreases on both sides: a + to - crossing
  ASSERT_LT(dh.dot(after), 0.0);

  const JumpMap jump = jump_map_at(PlusToMinus{}, rho, {0});
  // eta = -Dh, and the JumpMap's "before" word "-" is the model's "+".
  EXPECT_LT((jump.normals().row(0).transpose() + dh).lpNorm<Eigen::Infinity>(), 1e-15);
  EXPECT_LT((jump.limit(Signs::parse("-")) - before).lpNorm<Eigen::Infinity>(), 1e-15);
  EXPECT_LT((jump.limit(Signs::parse("+")) - after).lpNorm<Eigen::Infinity>(), 1e-15);
  EXPECT_GT(jump.transversality(Signs::parse("-"))[0], 0.0);

  // The classic saltation matrix (2.5), by hand; it does not depend on the sign of the normal.
  const Eigen::Matrix2d m =
      Eigen::Matrix2d::Identity() + (after - before) * dh.transpose() / dh.dot(before);
  // Entries O(1), one rank-1 update: 1e-14 bounds the rounding.
  EXPECT_LT((jump.saltation({0}) - m).lpNorm<Eigen::Infinity>(), 1e-14);
  for (const Eigen::VectorXd& dx : tangents(2)) {
    EXPECT_LT((jump.apply(dx) - m * dx).lpNorm<Eigen::Infinity>(),
              1e-14 * std::max(1.0, dx.lpNorm<Eigen::Infinity>()))
        << dx.transpose();
  }
}

// Three surfaces in d = 2: h0 = x0 (crossed - to +), h1 = -x1 (crossed + to -), and
// h2 = x0 + x1 - offset, not chosen. F_b encodes the model word b: F_b = (1 + bits / 10,
// 1 + bits / 100), so a limit tells which model word was evaluated.
struct ThreeSurfaces {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 3;
  double offset = 5.0;
  template <typename T>
  void field(const T*, Signs b, T* xdot) const {
    const double bits = static_cast<double>(b.bits());
    xdot[0] = T(1.0 + bits / 10.0);
    xdot[1] = T(1.0 + bits / 100.0);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
    h[1] = -x[1];
    h[2] = x[0] + x[1] - T(offset);
  }
};

Eigen::Vector2d three_surfaces_field(const char* model_word) {
  const double bits = static_cast<double>(Signs::parse(model_word).bits());
  return {1.0 + bits / 10.0, 1.0 + bits / 100.0};
}

TEST(ModelJumpTest, WordsMapToModelWordsWithFlipsOrderAndOthers) {
  const ThreeSurfaces model;
  const Eigen::Vector2d rho = Eigen::Vector2d::Zero();
  auto limit_is = [](const JumpMap& jump, const char* jump_word, const char* model_word) {
    EXPECT_EQ(jump.limit(Signs::parse(jump_word)), three_surfaces_field(model_word))
        << "JumpMap word " << jump_word << " should be model word " << model_word;
  };
  {
    // Surface 1 is flipped (before = its + side); surface 2 stays on its - side (h2 = -5).
    const JumpMap jump = jump_map_at(model, rho, {0, 1});
    EXPECT_EQ(jump.normals(), Eigen::Matrix2d::Identity());
    limit_is(jump, "--", "-+-");
    limit_is(jump, "+-", "++-");
    limit_is(jump, "-+", "---");
    limit_is(jump, "++", "+--");
  }
  {
    // `others` overrides the side of surface 2; its characters at chosen surfaces are ignored.
    const JumpMap jump = jump_map_at(model, rho, {0, 1}, Signs::parse("+-+"));
    limit_is(jump, "--", "-++");
    limit_is(jump, "++", "+-+");
  }
  {
    // JumpMap surface k is model surface surfaces[k].
    const JumpMap jump = jump_map_at(model, rho, {1, 0});
    Eigen::Matrix2d swapped;
    swapped << 0.0, 1.0, 1.0, 0.0;
    EXPECT_EQ(jump.normals(), swapped);
    limit_is(jump, "--", "-+-");
    limit_is(jump, "+-", "---");
    limit_is(jump, "-+", "++-");
    limit_is(jump, "++", "+--");
  }
}

// F_b = gain * (1 - 0.5 b) with the gain stored in a vector the model owns.
struct Owning {
  static constexpr int kStates = 1;
  static constexpr int kSurfaces = 1;
  std::vector<double> gain{2.0};
  template <typename T>
  void field(const T*, Signs b, T* xdot) const {
    xdot[0] = T(gain[0] * (1.0 - 0.5 * b.sign(0)));
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
  }
};

TEST(ModelJumpTest, JumpMapHoldsACopyOfTheModel) {
  std::optional<JumpMap> jump;
  {
    Owning model;
    jump.emplace(jump_map_at(model, Eigen::VectorXd::Zero(1), {0}));
    model.gain[0] = 100.0;  // later changes do not reach the JumpMap
  }                         // the model is gone; Gamma is evaluated lazily from the copy
  EXPECT_EQ(jump->limit(Signs::parse("-"))[0], 3.0);
  EXPECT_EQ(jump->limit(Signs::parse("+"))[0], 1.0);
  // n = 1: B = F+ / F- = 1/3 exactly up to rounding.
  EXPECT_NEAR(jump->apply(Eigen::VectorXd::Constant(1, 0.9))[0], 0.3, 1e-15);
}

// x' = F_b on the line with h = x; F_- = minus, F_+ = plus.
struct Line {
  static constexpr int kStates = 1;
  static constexpr int kSurfaces = 1;
  double minus = 1.0;
  double plus = -1.0;
  template <typename T>
  void field(const T*, Signs b, T* xdot) const {
    xdot[0] = T(b.plus(0) ? plus : minus);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
  }
};

using testing::message_of;

TEST(ModelJumpTest, RejectsNonTransversalCrossingsWithMessage) {
  const Eigen::VectorXd rho = Eigen::VectorXd::Zero(1);
  // Sliding: the flow points into the surface from both sides.
  const std::string sliding = message_of([&] { jump_map_at(Line{1.0, -1.0}, rho, {0}); });
  EXPECT_THAT(sliding, HasSubstr("jump_map_at: surface 0 is not crossed transversally at rho = "));
  EXPECT_THAT(sliding, HasSubstr("Dh_0(rho) . F_b(rho) = "));
  EXPECT_THAT(sliding, HasSubstr("for b = \"+\" but "));
  EXPECT_THAT(sliding, HasSubstr("for b = \"-\""));
  // Grazing: the flow is tangent on one side.
  const std::string grazing = message_of([&] { jump_map_at(Line{0.0, 1.0}, rho, {0}); });
  EXPECT_THAT(grazing, HasSubstr("surface 0 is not crossed transversally"));
  EXPECT_THAT(grazing, HasSubstr("for b = \"-\" (the flow is tangent to it)"));
  const std::string grazing_after = message_of([&] { jump_map_at(Line{1.0, 0.0}, rho, {0}); });
  EXPECT_THAT(grazing_after, HasSubstr("for b = \"+\" but "));
}

TEST(ModelJumpTest, RejectsBadSurfaceIndicesWithMessage) {
  const ThreeSurfaces model;
  const Eigen::Vector2d rho = Eigen::Vector2d::Zero();
  EXPECT_THAT(message_of([&] {
                jump_map_at(model, rho, {0, 3});
              }),
              HasSubstr("surface index 3 is out of range [0, 3) in surfaces {0, 3}"));
  EXPECT_THAT(message_of([&] { jump_map_at(model, rho, {-1}); }),
              HasSubstr("surface index -1 is out of range [0, 3)"));
  EXPECT_THAT(message_of([&] {
                jump_map_at(model, rho, {1, 0, 1});
              }),
              HasSubstr("surface index 1 appears more than once in surfaces {1, 0, 1}"));
  EXPECT_THAT(message_of([&] { jump_map_at(model, rho, {}); }), HasSubstr("no surfaces chosen"));
  EXPECT_THAT(message_of([&] { jump_map_at(model, rho, {0}, Signs::parse("--")); }),
              HasSubstr("others = \"--\" has 2 surfaces, the model has 3"));
}

TEST(ModelJumpTest, RequiresOthersWhenTheirSideIsUnknown) {
  ThreeSurfaces model;
  model.offset = 0.0;  // h2(0) = 0: rho is on surface 2 too, but it is not chosen
  const Eigen::Vector2d rho = Eigen::Vector2d::Zero();
  EXPECT_THAT(message_of([&] {
                jump_map_at(model, rho, {0, 1});
              }),
              HasSubstr("surface 2 is not among the chosen surfaces {0, 1} but h_2(rho) = 0"));
  const JumpMap jump = jump_map_at(model, rho, {0, 1}, Signs::parse("--+"));
  EXPECT_EQ(jump.limit(Signs::parse("--")), three_surfaces_field("-++"));
}

// F_+ is NaN.
struct NanField {
  static constexpr int kStates = 1;
  static constexpr int kSurfaces = 1;
  template <typename T>
  void field(const T*, Signs b, T* xdot) const {
    xdot[0] = T(b.plus(0) ? std::numeric_limits<double>::quiet_NaN() : 1.0);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
  }
};

TEST(ModelJumpTest, RejectsNonFiniteInputAndFieldWithMessage) {
  EXPECT_THAT(message_of([&] { jump_map_at(Line{}, Eigen::VectorXd::Constant(1, NAN), {0}); }),
              HasSubstr("jump_map_at: rho is not finite (entry 0 is "));
  EXPECT_THAT(message_of([&] { jump_map_at(Line{}, Eigen::Vector2d::Zero(), {0}); }),
              HasSubstr("jump_map_at: rho has 2 entries, expected 1"));
  const std::string nan_field =
      message_of([&] { jump_map_at(NanField{}, Eigen::VectorXd::Zero(1), {0}); });
  EXPECT_THAT(nan_field, HasSubstr("jump_map_at: F_b(x) row 0 is non-finite"));
  EXPECT_THAT(nan_field, HasSubstr("(b = \"+\")"));
}

}  // namespace
}  // namespace bflow::ad

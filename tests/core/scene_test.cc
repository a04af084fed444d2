#include "bflow/core/scene.h"

#include <cmath>
#include <cstdint>
#include <type_traits>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/ad/jet_bridge.h"
#include "bflow/ad/tangent_checker.h"
#include "bflow/core/errors.h"
#include "bflow/core/model.h"
#include "bflow/core/signs.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;
using Vector6 = Eigen::Matrix<double, 6, 1>;

using FreeBody = Scene<PlanarBody>;
using FreeFall = Scene<PlanarBody, Gravity>;
using Drop = Scene<PlanarBody, Gravity, SoftContact<FlatGround>>;
// Two grounds at different heights and a count-dependent damper.
using TwoGrounds = Scene<PlanarBody, Gravity, SoftContact<FlatGround>, SoftContact<FlatGround>,
                         ContactDependentDamping<2>>;

static_assert(FreeBody::kStates == 6 && FreeBody::kSurfaces == 0);
static_assert(FreeFall::kStates == 6 && FreeFall::kSurfaces == 0);
static_assert(Drop::kStates == 6 && Drop::kSurfaces == 1);
static_assert(TwoGrounds::kStates == 6 && TwoGrounds::kSurfaces == 2);

FreeFall free_fall() { return FreeFall(PlanarBody{2.0, 0.5}, Gravity{9.8}); }

Drop drop(double stiffness = 100.0, double damping = 3.0) {
  return Drop(PlanarBody{2.0, 0.5}, Gravity{9.8},
              SoftContact<FlatGround>{FlatGround{0.0}, stiffness, damping});
}

TwoGrounds two_grounds(double own_damping, double beta1, double beta2) {
  return TwoGrounds(PlanarBody{1.5, 0.25}, Gravity{9.8},
                    SoftContact<FlatGround>{FlatGround{0.0}, 40.0, own_damping},
                    SoftContact<FlatGround>{FlatGround{0.2}, 60.0, own_damping},
                    ContactDependentDamping<2>{{0.0, beta1, beta2}});
}

template <typename Model>
Vector6 field_of(const Model& model, const Vector6& x, Signs b) {
  Vector6 xdot;
  model.field(x.data(), b, xdot.data());
  return xdot;
}

std::vector<Signs> all_words(int n) {
  std::vector<Signs> words;
  for (std::uint64_t bits = 0; bits < (std::uint64_t{1} << n); ++bits) words.emplace_back(n, bits);
  return words;
}

std::vector<Vector6> sample_states() {
  std::vector<Vector6> states;
  Vector6 x;
  x << 0.3, -0.12, 0.7, 1.5, -0.25, 2.0;
  states.push_back(x);
  x << -1.1, 0.4, -2.3, -0.6, 0.9, -0.4;
  states.push_back(x);
  x << 0.0, 0.0, 0.0, 0.0, 0.0, 0.0;
  states.push_back(x);
  return states;
}

TEST(SceneTest, FreeBodyWithGravityHasNoSurfacesAndFallsAtG) {
  const FreeFall scene = free_fall();
  EXPECT_EQ(model_states(scene), 6);
  EXPECT_EQ(model_surfaces(scene), 0);
  Vector6 x;
  x << 0.3, -1.2, 0.7, 1.5, -0.25, 2.0;
  // m = 2 makes (m g) / m exact, so the field is compared exactly.
  Vector6 expected;
  expected << 1.5, -0.25, 2.0, 0.0, -9.8, 0.0;
  EXPECT_EQ(field_of(scene, x, Signs()), expected);
  // surfaces() writes nothing.
  double sentinel[2] = {123.0, 456.0};
  scene.surfaces(x.data(), sentinel);
  EXPECT_EQ(sentinel[0], 123.0);
  EXPECT_EQ(sentinel[1], 456.0);
  // DF = [0 I; 0 0] exactly.
  Eigen::MatrixXd df = Eigen::MatrixXd::Zero(6, 6);
  df.topRightCorner(3, 3).setIdentity();
  EXPECT_EQ(ad::field_jacobian(scene, x, Signs()), df);
  // Energy: kinetic + m g y.
  const double energy =
      0.5 * 2.0 * (1.5 * 1.5 + 0.25 * 0.25) + 0.5 * 0.5 * 2.0 * 2.0 + 2.0 * 9.8 * -1.2;
  EXPECT_NEAR(scene.energy(x.data(), Signs()), energy, 1e-14);
}

TEST(SceneTest, BodyAloneDrifts) {
  const FreeBody scene(PlanarBody{3.0, 7.0});
  Vector6 x;
  x << 1.0, 2.0, 3.0, 4.0, 5.0, 6.0;
  Vector6 expected;
  expected << 4.0, 5.0, 6.0, 0.0, 0.0, 0.0;
  EXPECT_EQ(field_of(scene, x, Signs()), expected);
}

TEST(SceneTest, SoftContactOnFlatGroundMatchesHandFormula) {
  const Drop scene = drop(100.0, 3.0);
  Vector6 x;
  x << 0.4, -0.1, 0.3, 0.5, -0.7, 1.1;
  double h[1];
  scene.surfaces(x.data(), h);
  EXPECT_EQ(h[0], 0.1);  // a = -y: 0.1 below the ground, side +
  // b = "+": a = -y, Da = (0, -1, 0), Da.qdot = -ydot; force = -(k a + beta Da.qdot) Da^T
  // = (0, -k y - beta ydot, 0) = (0, 10 + 2.1, 0): pushes up and opposes the fall.
  const double force_y = -100.0 * -0.1 - 3.0 * -0.7;
  EXPECT_NEAR(force_y, 12.1, 1e-14);
  const Vector6 plus = field_of(scene, x, Signs::parse("+"));
  EXPECT_EQ(plus.head<3>(), x.tail<3>());
  EXPECT_EQ(plus[3], 0.0);
  EXPECT_NEAR(plus[4], force_y / 2.0 - 9.8, 1e-14);
  EXPECT_EQ(plus[5], 0.0);
  // b = "-": no contact force although y < 0 (smooth extension, the engine decides b).
  const Vector6 minus = field_of(scene, x, Signs::parse("-"));
  EXPECT_EQ(minus[4], -9.8);
  // b = "+" above the ground: the extension pulls the body down (k a < 0).
  Vector6 above = x;
  above[1] = 0.05;
  above[4] = 0.0;
  EXPECT_NEAR(field_of(scene, above, Signs::parse("+"))[4], -100.0 * 0.05 / 2.0 - 9.8, 1e-14);
  // Energy with the spring: kinetic + m g y + k a^2 / 2 on side +.
  const double kinetic = 0.5 * 2.0 * (0.25 + 0.49) + 0.5 * 0.5 * 1.21;
  EXPECT_NEAR(scene.energy(x.data(), Signs::parse("+")), kinetic + 2.0 * 9.8 * -0.1 + 0.5, 1e-13);
  EXPECT_NEAR(scene.energy(x.data(), Signs::parse("-")), kinetic + 2.0 * 9.8 * -0.1, 1e-13);
}

TEST(SceneTest, ContactDependentDampingUsesCountOfActiveContacts) {
  // Count-dependent damping {0, b1, b2} must equal a constant damper of b1 on each contact
  // with one contact active, and b2 with two.
  const TwoGrounds counted = two_grounds(0.0, 0.5, 1.0);
  const TwoGrounds constant_half = two_grounds(0.5, 0.0, 0.0);
  const TwoGrounds constant_full = two_grounds(1.0, 0.0, 0.0);
  for (const Vector6& x : sample_states()) {
    for (const char* word : {"+-", "-+"}) {
      const Signs b = Signs::parse(word);
      EXPECT_LT((field_of(counted, x, b) - field_of(constant_half, x, b)).norm(), 1e-13) << word;
    }
    const Signs both = Signs::parse("++");
    EXPECT_LT((field_of(counted, x, both) - field_of(constant_full, x, both)).norm(), 1e-13);
    const Signs none = Signs::parse("--");
    const FreeFall no_contact(PlanarBody{1.5, 0.25}, Gravity{9.8});
    EXPECT_EQ(field_of(counted, x, none), field_of(no_contact, x, Signs()));
  }
}

TEST(SceneTest, LegThrustPushesAlongEachActiveContactsMotion) {
  // On flat ground (Da = (0, -1, 0), rate = -ydot) a thrust F with speed v0 adds, per active
  // contact, F tanh(-ydot / v0) (0, -1, 0): an upward force F tanh(ydot / v0) on yddot / m.
  using Thrusted =
      Scene<PlanarBody, Gravity, SoftContact<FlatGround>, SoftContact<FlatGround>, LegThrust<2>>;
  const double thrust = 3.0, speed = 0.4, mass = 1.5;
  const Thrusted with(
      PlanarBody{mass, 0.25}, Gravity{9.8}, SoftContact<FlatGround>{FlatGround{0.0}, 40.0, 0.7},
      SoftContact<FlatGround>{FlatGround{0.2}, 60.0, 0.7}, LegThrust<2>{thrust, speed});
  const Thrusted without(PlanarBody{mass, 0.25}, Gravity{9.8},
                         SoftContact<FlatGround>{FlatGround{0.0}, 40.0, 0.7},
                         SoftContact<FlatGround>{FlatGround{0.2}, 60.0, 0.7}, LegThrust<2>{});
  for (const Vector6& x : sample_states()) {
    for (const Signs b : all_words(2)) {
      const Vector6 difference = field_of(with, x, b) - field_of(without, x, b);
      const double expected = b.count_plus() * thrust * std::tanh(x[4] / speed) / mass;
      EXPECT_NEAR(difference[4], expected, 1e-13) << b.str();
      EXPECT_EQ(difference[3], 0.0);
      EXPECT_EQ(difference[5], 0.0);
      EXPECT_EQ(difference.head<3>().norm(), 0.0);
    }
  }
  EXPECT_EQ(testing::message_of([] {
              LegThrust<2>{-1.0, 0.1}.check();
            }),
            "LegThrust: thrust must be finite and >= 0, got -1");
  EXPECT_EQ(testing::message_of([] {
              LegThrust<2>{1.0, 0.0}.check();
            }),
            "LegThrust: speed must be finite and > 0, got 0");
}

// Counts evaluations of the constraint, to show that contact geometry runs only for contacts
// active in b (and surfaces()).
int ground_evaluations = 0;
struct CountingGround {
  double height = 0.0;
  template <typename T>
  T operator()(const T* q, T* grad) const {
    ++ground_evaluations;
    return FlatGround{height}(q, grad);
  }
};

TEST(SceneTest, ContactGeometryRunsOnlyForActiveContacts) {
  using Counted = Scene<PlanarBody, Gravity, SoftContact<CountingGround>,
                        SoftContact<CountingGround>, SoftContact<CountingGround>>;
  const Counted scene(PlanarBody{}, Gravity{}, SoftContact<CountingGround>{{0.0}, 1.0, 0.0},
                      SoftContact<CountingGround>{{0.1}, 1.0, 0.0},
                      SoftContact<CountingGround>{{0.2}, 1.0, 0.0});
  const Vector6 x = sample_states()[0];
  for (const Signs& b : all_words(3)) {
    ground_evaluations = 0;
    field_of(scene, x, b);
    EXPECT_EQ(ground_evaluations, b.count_plus()) << b.str();
  }
  ground_evaluations = 0;
  double h[3];
  scene.surfaces(x.data(), h);
  EXPECT_EQ(ground_evaluations, 3);
  EXPECT_NEAR(h[0], 0.12, 1e-15);
  EXPECT_NEAR(h[1], 0.22, 1e-15);
  EXPECT_NEAR(h[2], 0.32, 1e-15);
}

TEST(SceneTest, FlatGroundGradientMatchesAd) {
  const FlatGround ground{0.3};
  const ad::TangentChecker checker(ad::TangentCheckerOptions{1e-6, 1e-14});
  for (const Vector6& x : sample_states()) {
    const Eigen::Vector3d q = x.head<3>();
    Eigen::RowVector3d grad;
    ground(q.data(), grad.data());
    const auto a = [&ground](const auto* in, auto* out) {
      using T = std::remove_cv_t<std::remove_pointer_t<decltype(in)>>;
      out[0] = ground(in, static_cast<T*>(nullptr));
    };
    const ad::TangentReport r = checker.check_against_ad(a, 1, q, grad);
    EXPECT_TRUE(r.ok) << r.str();
  }
}

// AD Jacobians DF_b and Dh of every scene, for every word, against central differences.
template <typename Model>
void expect_ad_matches_differences(const Model& model, const char* name) {
  const ad::TangentChecker checker(ad::TangentCheckerOptions{std::cbrt(2.2e-16), 1e-7});
  for (const Vector6& x : sample_states()) {
    for (const Signs& b : all_words(Model::kSurfaces)) {
      const ad::TangentReport r = checker.check_field_jacobian(model, x, b);
      EXPECT_TRUE(r.ok) << name << ": " << r.str();
      EXPECT_LT(r.max_rel_error, 1e-7) << name;
    }
    if constexpr (Model::kSurfaces > 0) {
      const ad::TangentReport r = checker.check_normals(model, x);
      EXPECT_TRUE(r.ok) << name << ": " << r.str();
    }
  }
}

TEST(SceneTest, AdJacobiansOfEverySceneAndWordAgreeWithCentralDifferences) {
  expect_ad_matches_differences(FreeBody(PlanarBody{3.0, 7.0}), "FreeBody");
  expect_ad_matches_differences(free_fall(), "FreeFall");
  expect_ad_matches_differences(drop(), "Drop");
  expect_ad_matches_differences(two_grounds(0.3, 0.5, 1.0), "TwoGrounds");
}

TEST(SceneTest, ConstructorRejectsBadEffectParameters) {
  using testing::message_of;
  EXPECT_EQ(message_of([] {
              FreeFall(PlanarBody{-1.0, 1.0}, Gravity{});
            }),
            "PlanarBody: mass must be positive and finite, got -1");
  EXPECT_EQ(message_of([] {
              FreeFall(PlanarBody{1.0, 0.0}, Gravity{});
            }),
            "PlanarBody: inertia must be positive and finite, got 0");
  EXPECT_THAT(message_of([] { FreeFall(PlanarBody{}, Gravity{std::nan("")}); }),
              HasSubstr("Gravity: g must be finite, got nan"));
  EXPECT_EQ(message_of([] { drop(-2.0, 0.0); }),
            "SoftContact: stiffness must be finite and >= 0, got -2");
  EXPECT_EQ(message_of([] { drop(1.0, -0.5); }),
            "SoftContact: damping must be finite and >= 0, got -0.5");
  EXPECT_EQ(message_of([] { two_grounds(0.0, 0.5, -1.0); }),
            "ContactDependentDamping: every damping_by_count must be finite and >= 0, got -1");
}

}  // namespace
}  // namespace bflow

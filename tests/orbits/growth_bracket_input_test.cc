// growth_rate_bracket's inputs: the options that size its work (each bounded, max_products by an
// estimate of the memory its products take), a basis that does not span the map's images, and a
// basis with no columns. Each is refused with an InvalidArgument naming the values before any
// product is formed; find_periodic_orbit checks the same options with the same function.
#include <climits>
#include <cmath>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "bflow/core/flow_derivative.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/pronk.h"
#include "bflow/integrators/model_adapter.h"
#include "bflow/orbits/internal/growth_cones.h"
#include "bflow/orbits/periodic_orbit.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;
using ::testing::HasSubstr;
using testing::message_of;

// A map of R^3 with one event of two surfaces whose images all lie in the plane x_3 = 0 (the
// last transition's last row is 0): L on span(e_1, e_2) has two pieces, 1 cone row each.
FlowDerivative plane_map() {
  FlowDerivative map(3);
  MatrixXd phi0(3, 3);
  phi0 << 0.9, 0.2, 0.1, -0.3, 0.7, 0.4, 0.2, -0.1, 0.8;
  map.append_transition(phi0);
  MatrixXd eta(2, 3);
  eta << 1.0, 0.0, 0.2, 0.0, 1.0, -0.1;
  MatrixXd limits(3, 4);
  limits << 1.0, 1.3, 0.8, 1.2, 1.0, 0.7, 1.4, 1.1, 0.5, 0.4, 0.6, 0.3;
  map.append_jump(JumpMap(eta, limits), 1.0);
  MatrixXd phi1(3, 3);
  phi1 << 0.6, -0.2, 0.3, 0.1, 0.5, -0.4, 0.0, 0.0, 0.0;
  map.append_transition(phi1);
  return map;
}

MatrixXd plane_basis() { return MatrixXd::Identity(3, 3).leftCols(2); }

TEST(GrowthBracketInput, MaxProductsIsBoundedByItsMemoryEstimate) {
  const FlowDerivative map = plane_map();
  // m = 2 directions, products of up to 12 pieces, 1 cone row per piece.
  const double per_product = internal::growth_bytes_per_product(2, 12, 1);
  const long fit = static_cast<long>(std::floor(OrbitOptions::kMaxGrowthBytes / per_product));
  std::printf("estimate: %.0f bytes per product; %ld fit in %ld MiB\n", per_product, fit,
              OrbitOptions::kMaxGrowthBytes >> 20);
  OrbitOptions options;
  options.max_products = LONG_MAX;
  const std::string huge = message_of([&] { growth_rate_bracket(map, plane_basis(), options); });
  EXPECT_THAT(huge, HasSubstr("max_products = 9223372036854775807"));
  EXPECT_THAT(huge, HasSubstr("MiB"));
  EXPECT_THAT(huge, HasSubstr("at most " + std::to_string(fit) + " fit"));
  EXPECT_LE(huge.size(), 500u);
  options.max_products = fit + 1;
  EXPECT_THAT(message_of([&] { growth_rate_bracket(map, plane_basis(), options); }),
              HasSubstr("max_products = " + std::to_string(fit + 1)));
  // The most that fit is accepted (the tree stops where the products stop growing in number).
  options.max_products = fit;
  const GrowthBracket b = growth_rate_bracket(map, plane_basis(), options);
  EXPECT_LE(b.lower, b.upper);
  // Every product is at least its m x m matrix of doubles, twice (kept, and in the tree).
  EXPECT_GE(per_product, 2.0 * 12 * 8 * 2 * 2);
  options.max_products = 0;
  EXPECT_THAT(message_of([&] { growth_rate_bracket(map, plane_basis(), options); }),
              HasSubstr("max_products must be >= 1, got 0"));
}

TEST(GrowthBracketInput, EveryOptionThatSizesTheWorkIsBounded) {
  const FlowDerivative map = plane_map();
  const auto refused = [&](auto set, const std::string& expected) {
    OrbitOptions options;
    set(options);
    EXPECT_THAT(message_of([&] { growth_rate_bracket(map, plane_basis(), options); }),
                HasSubstr(expected));
  };
  refused([](OrbitOptions& o) { o.growth_directions = -1; },
          "growth_directions must be in [0, 100000], got -1");
  refused([](OrbitOptions& o) { o.growth_directions = INT_MAX; },
          "growth_directions must be in [0, 100000], got 2147483647");
  refused([](OrbitOptions& o) { o.growth_iterations = 0; },
          "growth_iterations must be in [1, 1000000], got 0");
  refused([](OrbitOptions& o) { o.growth_iterations = INT_MAX; },
          "growth_iterations must be in [1, 1000000], got 2147483647");
  refused([](OrbitOptions& o) { o.max_product_length = 0; },
          "max_product_length must be in [1, 64], got 0");
  refused([](OrbitOptions& o) { o.max_product_length = 65; },
          "max_product_length must be in [1, 64], got 65");
}

TEST(GrowthBracketInput, FindPeriodicOrbitChecksTheSameOptionsBeforeSimulating) {
  const auto model = adapt(make_pronk(PronkParams{}));
  const CoordinateSection apex{4, 0.0, -1.0};
  OrbitOptions options;
  options.max_products = LONG_MAX;
  EXPECT_THAT(message_of([&] { find_periodic_orbit(model, apex, pronk_initial_state(), options); }),
              HasSubstr("OrbitOptions: max_products = 9223372036854775807 may need"));
  options = OrbitOptions();
  options.growth_iterations = INT_MAX;
  EXPECT_THAT(message_of([&] { find_periodic_orbit(model, apex, pronk_initial_state(), options); }),
              HasSubstr("OrbitOptions: growth_iterations must be in [1, 1000000]"));
}

TEST(GrowthBracketInput, ABasisThatDoesNotSpanTheImagesIsRefused) {
  const FlowDerivative map = plane_map();
  // Its images lie in x_3 = 0; the plane orthogonal to (1, 1, 1) is another one.
  const MatrixXd tilted = orthogonal_complement(VectorXd::Ones(3));
  const std::string message = message_of([&] { growth_rate_bracket(map, tilted); });
  EXPECT_THAT(message, HasSubstr("the basis does not span the map's images"));
  EXPECT_THAT(message, HasSubstr("|(I - B B^T) M B|_F / |M B|_F = "));
  EXPECT_THAT(message, HasSubstr("(at most 1e-06)"));
  // All of R^3 spans them.
  EXPECT_NO_THROW(growth_rate_bracket(map, MatrixXd::Identity(3, 3)));
  EXPECT_NO_THROW(growth_rate_bracket(map, plane_basis()));
}

// The pronk's return map has its images in the section's tangent space (ydot = 0). Five columns
// of I, dropping x_0 instead of ydot, span another subspace: refused. The tangent basis the orbit
// carries spans it (by a residual measured and printed here).
TEST(GrowthBracketInput, PronkWithFiveColumnsOfTheIdentityIsRefused) {
  const auto model = adapt(make_pronk(PronkParams{}));
  OrbitOptions options;
  options.stability = false;
  const PeriodicOrbit orbit =
      find_periodic_orbit(model, CoordinateSection{4, 0.0, -1.0}, pronk_initial_state(), options);
  ASSERT_TRUE(orbit.converged) << orbit.message;
  const MatrixXd five = MatrixXd::Identity(6, 6).rightCols(5);
  const std::string message = message_of([&] { growth_rate_bracket(orbit.return_map, five); });
  EXPECT_THAT(message, HasSubstr("the basis does not span the map's images"));
  double worst = 0.0;
  for (const FlowPiece& piece : orbit.return_map.pieces()) {
    const MatrixXd image = piece.matrix * orbit.tangent_basis;
    const MatrixXd b = orbit.tangent_basis;
    worst = std::max(worst, (image - b * (b.transpose() * image)).norm() / image.norm());
  }
  int cone_rows = 0;
  for (const std::vector<int>& surfaces : orbit.return_map.event_surfaces()) {
    cone_rows += static_cast<int>(surfaces.size()) - 1;
  }
  const double per_product = internal::growth_bytes_per_product(5, 12, cone_rows);
  std::printf(
      "pronk: the tangent basis spans the images to %.1e; five columns of I: %s\n"
      "  max_products: %d cone rows per piece, %.0f bytes per product, %.0f fit\n",
      worst, message.c_str(), cone_rows, per_product,
      std::floor(OrbitOptions::kMaxGrowthBytes / per_product));
  EXPECT_LT(worst, internal::kSpanTolerance);
  EXPECT_NO_THROW(growth_rate_bracket(orbit.return_map, orbit.tangent_basis));
}

TEST(GrowthBracketInput, ABasisWithNoColumnsIsRefusedNotCalledStable) {
  const FlowDerivative map = plane_map();
  EXPECT_THAT(message_of([&] { growth_rate_bracket(map, MatrixXd(3, 0)); }),
              HasSubstr("the basis has 0 columns"));
}

}  // namespace
}  // namespace bflow

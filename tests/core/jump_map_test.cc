#include "bflow/core/jump_map.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/QR>
#include <Eigen/SVD>

#include "bflow/core/errors.h"
#include "bflow/core/flow_derivative.h"
#include "bflow/core/triangulation.h"
#include "support/error_message.h"
#include "support/random_jump.h"

namespace bflow {
namespace {

using testing::gaussian_vector;
using ::testing::HasSubstr;
using testing::JumpCaseOptions;

constexpr double kEps = 2.220446049250313e-16;

// Gamma(b) = 1 - delta * b for the piecewise-constant field of [B] (3.1), eta = I.
Eigen::MatrixXd linear_pwconst_limits(int d, double delta) {
  Eigen::MatrixXd limits(d, Eigen::Index{1} << d);
  for (Eigen::Index w = 0; w < limits.cols(); ++w) {
    for (int i = 0; i < d; ++i) limits(i, w) = ((w >> i) & 1) ? 1.0 - delta : 1.0 + delta;
  }
  return limits;
}

// A tangent that crosses surfaces in the order `sigma` at the non-decreasing `times`, plus
// kernel part `xi`; writes the image that the sampled flow gives by construction.
Eigen::VectorXd tangent_for_order(const JumpMap& jump, const std::vector<int>& sigma,
                                  const std::vector<double>& times, const Eigen::VectorXd& xi,
                                  Eigen::VectorXd* image) {
  const int n = jump.surfaces();
  const Eigen::MatrixXd& eta = jump.normals();
  // p1 is the position at time t_1; p(t_k) = p1 + sum_{i<k} (t_{i+1} - t_i) Gamma(b_i).
  Eigen::MatrixXd rows(n, jump.dim());
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n);
  Eigen::VectorXd drift = Eigen::VectorXd::Zero(jump.dim());
  Signs b(n);
  for (int k = 0; k < n; ++k) {
    const int j = sigma[static_cast<std::size_t>(k)];
    rows.row(k) = eta.row(j);
    rhs[k] = -eta.row(j).dot(drift);
    b = b.with_plus(j);
    if (k + 1 < n) {
      drift += (times[static_cast<std::size_t>(k) + 1] - times[static_cast<std::size_t>(k)]) *
               jump.limit(b);
    }
  }
  // Rows equilibrated: normals scaled by 1e+-3 must not cost accuracy here.
  const Eigen::VectorXd row_norms = rows.rowwise().norm();
  const Eigen::MatrixXd unit_rows = row_norms.cwiseInverse().asDiagonal() * rows;
  const Eigen::VectorXd p1 =
      unit_rows.completeOrthogonalDecomposition().solve(rhs.cwiseQuotient(row_norms)) + xi;
  *image = p1 + drift - times.back() * jump.limit(Signs::all_plus(n));
  return p1 - times.front() * jump.limit(Signs(n));
}

// Growth factor of the order sigma: the product of the spectral norms of the n factors of
// (6.4). Every partial product of M_sigma is bounded by it, so it bounds the rounding of the
// routes that go through matrices (pieces, triangulation), if loosely: for a vector, the scale
// of apply_factors below is up to 2e9 times smaller on the random cases.
double growth(const JumpMap& jump, const std::vector<int>& sigma) {
  const int d = jump.dim();
  double product = 1.0;
  Signs b(jump.surfaces());
  for (int j : sigma) {
    const Eigen::VectorXd before = jump.limit(b);
    b = b.with_plus(j);
    const Eigen::MatrixXd factor =
        Eigen::MatrixXd::Identity(d, d) +
        (jump.limit(b) - before) * jump.normals().row(j) / jump.normals().row(j).dot(before);
    product *= Eigen::JacobiSVD<Eigen::MatrixXd>(factor).singularValues()[0];
  }
  return product;
}

// M_sigma dx of (6.4) evaluated factor by factor on the vector, y_0 = dx, y_k = F_k y_{k-1}
// with F_k = I + (F_after - F_before) eta_j^T / (eta_j . F_before): an independent route to
// B(dx), and the rounding-error scale of any route that forms these y_k.
//
// Why this scale: step k forms eta_j . y_{k-1} (d products), divides by eta_j . F_before and
// adds the multiple of F_after - F_before, so its rounding error is a relative perturbation of
// about (d + 2) eps of the rank-one part of F_k applied to y_{k-1}, at most
// (d + 2) eps |F_k| |y_{k-1}| (F_k = I + rank one, |F_k| >= 1). The remaining factors carry it
// to the end, multiplied by at most |F_n ... F_{k+1}|. To first order the error of y_n is thus
// below (d + 2) eps sum_k |F_n ... F_{k+1}| |F_k| |y_{k-1}| (spectral norms) = (d + 2) eps
// `error_scale`. The largest partial product max_k |y_k| alone is not enough: a rounding error
// made at step k lies in no particular direction, and later factors amplify it by their norm
// (up to 7e4 eps max_k |y_k| observed in the stiff cases below), while the product of all n
// factor norms overestimates by up to 2e9. Algorithm 2.1 forms the same quantities along the
// same order (eta_j . perturbation, divided by eta_j . F_b, then multiples of F_b added).
struct FactorChain {
  Eigen::VectorXd image;
  double error_scale = 0;
};

FactorChain apply_factors(const JumpMap& jump, const std::vector<int>& sigma,
                          const Eigen::VectorXd& dx) {
  const int d = jump.dim();
  std::vector<Eigen::MatrixXd> factors;
  std::vector<double> sizes;  // |y_{k-1}|
  FactorChain chain{dx, 0.0};
  Signs b(jump.surfaces());
  for (int j : sigma) {
    const Eigen::VectorXd before = jump.limit(b);
    b = b.with_plus(j);
    const Eigen::VectorXd after = jump.limit(b);
    const double ratio = jump.normals().row(j).dot(chain.image) / jump.normals().row(j).dot(before);
    sizes.push_back(chain.image.norm());
    chain.image += ratio * (after - before);
    factors.push_back(Eigen::MatrixXd::Identity(d, d) +
                      (after - before) * jump.normals().row(j) / jump.normals().row(j).dot(before));
  }
  Eigen::MatrixXd suffix = Eigen::MatrixXd::Identity(d, d);  // F_n ... F_{k+1}
  for (int k = static_cast<int>(factors.size()) - 1; k >= 0; --k) {
    const auto i = static_cast<std::size_t>(k);
    chain.error_scale += Eigen::JacobiSVD<Eigen::MatrixXd>(suffix).singularValues()[0] *
                         Eigen::JacobiSVD<Eigen::MatrixXd>(factors[i]).singularValues()[0] *
                         sizes[i];
    suffix *= factors[i];
  }
  return chain;
}

// Inverse transversality margin: max over j, b of |eta_j| |F_b| / (eta_j . F_b) >= 1.
double margin_condition(const Eigen::MatrixXd& eta, const Eigen::MatrixXd& limits) {
  const Eigen::MatrixXd dots = eta * limits;
  double worst = 1.0;
  for (Eigen::Index j = 0; j < eta.rows(); ++j) {
    for (Eigen::Index w = 0; w < limits.cols(); ++w) {
      worst = std::max(worst, eta.row(j).norm() * limits.col(w).norm() / dots(j, w));
    }
  }
  return worst;
}

// A random vector of ker eta, from the Householder QR of eta^T: eta_j . xi is then of order
// eps |eta_j| |xi| whatever the scaling of the rows (the projector I - P eta goes through
// eta eta^T and loses the square of the condition number), and xi = 0 when n = d.
Eigen::VectorXd kernel_vector(std::mt19937_64& rng, const Eigen::MatrixXd& eta) {
  const Eigen::Index n = eta.rows();
  const Eigen::Index d = eta.cols();
  const Eigen::MatrixXd q = Eigen::HouseholderQR<Eigen::MatrixXd>(eta.transpose()).householderQ() *
                            Eigen::MatrixXd::Identity(d, d);
  const Eigen::MatrixXd kernel = q.rightCols(d - n);
  return kernel * (kernel.transpose() * gaussian_vector(rng, d));
}

// ---------------------------------------------------------------------------------------
// Closed form (3.2): Delta(b) = -delta b gives B = (1 - delta)/(1 + delta) I for every piece.
TEST(JumpMapTest, ClosedFormOfPiecewiseConstantField) {
  std::mt19937_64 rng(1);
  for (int d = 2; d <= 10; ++d) {
    for (double delta : {-0.6, -0.1, 0.25, 0.8}) {
      const JumpMap jump(Eigen::MatrixXd::Identity(d, d), linear_pwconst_limits(d, delta));
      const double gain = (1 - delta) / (1 + delta);
      for (int trial = 0; trial < 20; ++trial) {
        const Eigen::VectorXd dx = gaussian_vector(rng, d);
        // Each step adds O(eps |Gamma| |tau|) with |Gamma| <= 2 and |tau| <= |dx| / 0.2.
        EXPECT_LE((jump.apply(dx) - gain * dx).norm(), 100 * d * kEps * dx.norm())
            << "d=" << d << " delta=" << delta;
        EXPECT_LE((jump.active_jacobian(dx) - gain * Eigen::MatrixXd::Identity(d, d)).norm(),
                  100 * d * kEps);
      }
      if (d <= 5) {
        for (const Piece& piece : jump.pieces()) {
          EXPECT_LE((piece.matrix - gain * Eigen::MatrixXd::Identity(d, d)).norm(), 100 * d * kEps);
        }
        const Triangulation tri = jump.triangulation();
        const Eigen::VectorXd dx = gaussian_vector(rng, d);
        EXPECT_LE((tri.apply_barycentric(dx).image - gain * dx).norm(), 1e-12 * dx.norm());
      }
    }
  }
}

// n = 1: B is the classic saltation matrix (2.5), I + (F+ - F-) eta^T / (eta . F-).
// The saltation matrix of one surface, I + (F+ - F-) eta / (eta . F-), limits = (F-, F+).
Eigen::MatrixXd classic_saltation(const Eigen::MatrixXd& eta, const Eigen::MatrixXd& limits) {
  const Eigen::Index d = eta.cols();
  return Eigen::MatrixXd::Identity(d, d) +
         (limits.col(1) - limits.col(0)) * eta / eta.row(0).dot(limits.col(0));
}

TEST(JumpMapTest, OneSurfaceIsClassicSaltationMatrix) {
  std::mt19937_64 rng(2);
  for (int d = 1; d <= 6; ++d) {
    const Eigen::MatrixXd eta = testing::random_normals(rng, 1, d, false);
    const Eigen::MatrixXd limits = testing::random_limits(rng, eta, {});
    const JumpMap jump(eta, limits);
    const Eigen::MatrixXd classic = classic_saltation(eta, limits);
    EXPECT_LE((jump.saltation({0}) - classic).norm(), 1e-13 * classic.norm());
    for (int trial = 0; trial < 10; ++trial) {
      const Eigen::VectorXd dx = gaussian_vector(rng, d);
      EXPECT_LE((jump.apply(dx) - classic * dx).norm(), 1e-13 * classic.norm() * dx.norm());
      EXPECT_LE((jump.triangulation().apply_barycentric(dx).image - classic * dx).norm(),
                1e-12 * classic.norm() * dx.norm());
    }
  }
}

// apply_block on one surface takes the block path (eta X and two rank-one updates, in chunks of
// 128 columns) instead of a walk per column: the same images as apply() and as the classic
// saltation matrix, in place too, across chunk boundaries; a column the walk would send to its
// scaled path (a subnormal tangent) leaves its chunk to the walks, with the same answer; a
// non-finite column is refused naming it, as apply() does.
TEST(JumpMapTest, OneSurfaceBlockMatchesTheWalkAndTheSaltationMatrix) {
  std::mt19937_64 rng(21);
  for (int d : {1, 6, 40}) {
    const Eigen::MatrixXd eta = testing::random_normals(rng, 1, d, false);
    const Eigen::MatrixXd limits = testing::random_limits(rng, eta, {});
    const JumpMap jump(eta, limits);
    const Eigen::MatrixXd classic = classic_saltation(eta, limits);
    Eigen::MatrixXd block(d, 300);
    for (Eigen::Index k = 0; k < block.cols(); ++k) block.col(k) = gaussian_vector(rng, d);
    block.col(200) *= 1e-309;  // subnormal: eta . x loses precision, the scaled path
    const Eigen::MatrixXd images = jump.apply_block(block);
    for (Eigen::Index k = 0; k < block.cols(); ++k) {
      const Eigen::VectorXd walk = jump.apply(block.col(k));
      // The walk and the block differ only in the summation order of eta . x.
      EXPECT_LE((images.col(k) - walk).norm(), 1e-14 * classic.norm() * block.col(k).norm())
          << "d=" << d << " column " << k;
      EXPECT_LE((images.col(k) - classic * block.col(k)).norm(),
                1e-13 * classic.norm() * block.col(k).norm())
          << "d=" << d << " column " << k;
    }
    Eigen::MatrixXd in_place = block;
    jump.apply_block(in_place, in_place);
    EXPECT_LE((in_place - images).cwiseAbs().maxCoeff(), 0.0) << "d=" << d;
    Eigen::MatrixXd bad = block.leftCols(10);
    bad(0, 7) = std::numeric_limits<double>::quiet_NaN();
    Eigen::MatrixXd out(d, 10);
    EXPECT_THAT([&] { jump.apply_block(bad, out); },
                ::testing::ThrowsMessage<InvalidArgument>(
                    ::testing::HasSubstr("apply_block: tangent is not finite")));
  }
}

// One surface in R^2 whose crossing shears: eta = e_0, Gamma(-) = (1, 0), Gamma(+) = (1, 1e10),
// so B x = (x_0, x_1 + 1e10 x_0) (closed form), beyond the double range for x_0 = 1e300.
JumpMap shearing_jump() {
  Eigen::MatrixXd limits(2, 2);
  limits << 1.0, 1.0, 0.0, 1e10;
  return JumpMap(Eigen::RowVector2d(1.0, 0.0), limits);
}

// d x cols Gaussian tangents.
Eigen::MatrixXd random_block(std::mt19937_64& rng, int d, Eigen::Index cols) {
  Eigen::MatrixXd block(d, cols);
  for (Eigen::Index k = 0; k < cols; ++k) block.col(k) = testing::gaussian_vector(rng, d);
  return block;
}

// A column apply_block must refuse (not finite, or an image beyond the double range) is found
// before any column is written: the block mapped in place keeps its numbers, a separate output
// keeps what it held, for the one-surface block path and for the walks (n = 3), whichever column
// is bad.
TEST(JumpMapTest, ApplyBlockRefusesABadColumnBeforeWritingAny) {
  std::mt19937_64 rng(42);
  for (int n : {1, 3}) {
    const int d = 5;
    const Eigen::MatrixXd eta = testing::random_normals(rng, n, d, false);
    const JumpMap jump(eta, testing::random_limits(rng, eta, {}));
    for (Eigen::Index bad : {Eigen::Index{0}, Eigen::Index{150}, Eigen::Index{299}}) {
      Eigen::MatrixXd block = random_block(rng, d, 300);
      block(2, bad) = std::numeric_limits<double>::infinity();
      const Eigen::MatrixXd before = block;
      EXPECT_THAT([&] { jump.apply_block(block, block); },
                  ::testing::ThrowsMessage<InvalidArgument>(HasSubstr(
                      "apply_block: tangent is not finite in column " + std::to_string(bad))));
      EXPECT_TRUE(block.cwiseEqual(before).all()) << "n=" << n << " bad column " << bad;
      Eigen::MatrixXd out = Eigen::MatrixXd::Constant(d, 300, -7.0);
      EXPECT_THROW(jump.apply_block(before, out), InvalidArgument);
      EXPECT_TRUE((out.array() == -7.0).all()) << "n=" << n << " bad column " << bad;
    }
  }
  const JumpMap shear = shearing_jump();
  Eigen::MatrixXd block = random_block(rng, 2, 300);
  block.col(250) << 1e300, 0.0;
  const Eigen::MatrixXd before = block;
  EXPECT_THAT([&] { shear.apply_block(block, block); },
              ::testing::ThrowsMessage<InvalidArgument>(
                  HasSubstr("apply_block: column 250: component 1 of B(dx) is about 2^")));
  EXPECT_TRUE(block.cwiseEqual(before).all());
  // Just inside the range the same column is mapped, in place, to the closed form.
  block(0, 250) = 1e297;
  const Eigen::MatrixXd inside = block;
  shear.apply_block(block, block);
  for (Eigen::Index k = 0; k < block.cols(); ++k) {
    EXPECT_EQ(block(0, k), inside(0, k));
    EXPECT_NEAR(block(1, k), inside(1, k) + 1e10 * inside(0, k),
                4 * kEps * std::abs(1e10 * inside(0, k)) + 4 * kEps * std::abs(inside(1, k)))
        << "column " << k;
  }
}

// apply() with a separate output: an image beyond the double range leaves the output as it was
// (the walk used to form the image in it before finding the overflow).
TEST(JumpMapTest, ApplyRefusingAnImageLeavesTheOutputUnwritten) {
  const JumpMap shear = shearing_jump();
  Eigen::VectorXd out = Eigen::Vector2d(-7.0, -7.0);
  EXPECT_THAT([&] { shear.apply(Eigen::Vector2d(1e300, 0.0), out); },
              ::testing::ThrowsMessage<InvalidArgument>(HasSubstr("apply: component 1 of B(dx)")));
  EXPECT_EQ(out, Eigen::Vector2d(-7.0, -7.0));
}

// A lazy source whose word "-+" is not transversal (eta_1 . Gamma(-+) = -1): only tangents that
// cross surface 1 first meet it; the others are mapped, (1, 0.5) to (2, 0.5), not to themselves. A
// block whose column 40 does is refused naming the word, and no column is written.
TEST(JumpMapTest, ApplyBlockWithALazySourceRefusesAWordBeforeWritingAny) {
  const JumpMap jump(Eigen::Matrix2d::Identity(), [](Signs b, Eigen::Ref<Eigen::VectorXd> out) {
    out << (b.plus(0) ? 2.0 : 1.0), b.str() == "-+" ? -1.0 : 1.0;
  });
  Eigen::MatrixXd block(2, 60);
  for (Eigen::Index k = 0; k < block.cols(); ++k) block.col(k) << 1.0, 0.5;  // surface 0 first
  block.col(40) << 0.5, 1.0;                                                 // surface 1 first
  const Eigen::MatrixXd before = block;
  EXPECT_THAT([&] { jump.apply_block(block, block); },
              ::testing::ThrowsMessage<InvalidArgument>(HasSubstr("for word \"-+\"")));
  EXPECT_TRUE(block.cwiseEqual(before).all());
}

// Input and output that share memory without being the same block are refused before anything
// is written (they used to be mixed: a column read after an earlier one was written over it);
// the same block in place and interleaved blocks of one matrix that share no number are mapped.
TEST(JumpMapTest, ApplyBlockRefusesPartlyOverlappingBlocks) {
  std::mt19937_64 rng(43);
  for (int n : {1, 2}) {
    const int d = 4;
    const Eigen::MatrixXd eta = testing::random_normals(rng, n, d, false);
    const JumpMap jump(eta, testing::random_limits(rng, eta, {}));
    Eigen::MatrixXd m = random_block(rng, d, 11);
    const Eigen::MatrixXd before = m;
    // Shifted by a column, or by a row (each column of out straddles two of dx).
    EXPECT_THAT([&] { jump.apply_block(m.leftCols(10), m.rightCols(10)); },
                ::testing::ThrowsMessage<InvalidArgument>(
                    HasSubstr("apply_block: the output overlaps the tangents without being the "
                              "same block")));
    EXPECT_THROW(jump.apply_block(m.rightCols(10), m.leftCols(10)), InvalidArgument);
    Eigen::MatrixXd tall = random_block(rng, d + 1, 10);
    const Eigen::MatrixXd tall_before = tall;
    EXPECT_THROW(jump.apply_block(tall.topRows(d), tall.bottomRows(d)), InvalidArgument);
    EXPECT_TRUE(m.cwiseEqual(before).all()) << "n=" << n;
    EXPECT_TRUE(tall.cwiseEqual(tall_before).all()) << "n=" << n;
    // Interleaved but disjoint: rows 0..d-1 into rows d..2d-1 of the same matrix.
    Eigen::MatrixXd stacked(2 * d, 10);
    stacked.topRows(d) = random_block(rng, d, 10);
    const Eigen::MatrixXd expected = jump.apply_block(Eigen::MatrixXd(stacked.topRows(d)));
    jump.apply_block(stacked.topRows(d), stacked.bottomRows(d));
    EXPECT_TRUE(stacked.bottomRows(d).cwiseEqual(expected).all()) << "n=" << n;
    // The vector form: an output one number past the tangent.
    Eigen::VectorXd v = testing::gaussian_vector(rng, d + 1);
    const Eigen::VectorXd v_before = v;
    EXPECT_THAT([&] { jump.apply(v.head(d), v.tail(d)); },
                ::testing::ThrowsMessage<InvalidArgument>(
                    HasSubstr("apply: the output overlaps the tangent without being the same")));
    EXPECT_EQ(v, v_before);
  }
}

// FlowDerivative: a tangent carried beyond the double range by a transition is refused (it used
// to come back as inf), and apply_block checks the shape and every column before mapping any,
// naming the bad column (a block of the wrong height and no columns used to pass).
TEST(FlowDerivativeTest, RefusesTangentsBeyondTheRangeAndBadBlocks) {
  FlowDerivative derivative(2);
  derivative.append_transition(1e200 * Eigen::Matrix2d::Identity());
  EXPECT_EQ(derivative.apply(Eigen::Vector2d(1.0, -2.0)), Eigen::Vector2d(1e200, -2e200));
  EXPECT_THAT([&] { derivative.apply(Eigen::Vector2d(1e200, 0.0)); },
              ::testing::ThrowsMessage<InvalidArgument>(
                  HasSubstr("FlowDerivative::apply: the tangent at the final time is beyond the "
                            "double range")));
  derivative.append_jump(shearing_jump(), 0.5);
  EXPECT_THAT([&] { derivative.apply(Eigen::Vector2d(1e200, 0.0)); },
              ::testing::ThrowsMessage<InvalidArgument>(
                  HasSubstr("the tangent arriving at event 0 is beyond the double range")));
  EXPECT_THAT([&] { derivative.apply_block(Eigen::MatrixXd(3, 0)); },
              ::testing::ThrowsMessage<InvalidArgument>(
                  HasSubstr("FlowDerivative::apply_block: tangents must have 2 rows, got 3 x 0")));
  Eigen::MatrixXd block = Eigen::MatrixXd::Ones(2, 5);
  block(1, 3) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THAT([&] { derivative.apply_block(block); },
              ::testing::ThrowsMessage<InvalidArgument>(HasSubstr(
                  "FlowDerivative::apply_block: tangent is not finite in column 3 of 5")));
}

// The properties of B on random transversal data, 1000 cases.
//
// apply() is checked against M_sigma dx evaluated factor by factor (apply_factors) and against
// saltation(sigma) dx, to within kChainTol (d + 2) eps error_scale, error_scale being the
// first-order rounding bound in apply_factors' comment; the factor 2 leaves room for the
// rounding of eta_j . F_b and for second-order terms. Observed worst error / tolerance (printed
// below): apply 0.17 non-stiff, 0.41 stiff; saltation(sigma) dx 0.08, 0.41. The same bound,
// summed over the evaluations involved, covers homogeneity (worst 0.08 of it), the kernel
// shift (0.07) and B(F_-) = F_+ (0.002: the F_+ - F_- directions of the rounding errors there
// are amplified far less than the suffix norms allow).
//
// The prescribed-order cases start from a tangent built by a least-squares solve with drift
// terms of size |t| |F_b| (tangent_for_order), and crossing times are quantities divided by
// eta_j . F_b, so their tolerance is kappa (1 + |dx|) error_scale / |dx| times the same unit,
// kappa being the inverse transversality margin. Observed worst, in units of
// eps kappa (1 + |dx|) error_scale / |dx|: times 0.06, image 0.12, ties 0.05 (against a unit
// of at least 8); without kappa the ties reach 10, so kappa cannot be dropped. The
// barycentric route goes through pseudo-inverses of Z-_sigma and of eta and gets
// kBaryTol = 1e-11 of growth |dx| (observed worst 2e-13, or 512 eps error_scale).
constexpr double kChainTol = 2.0;
constexpr double kApplyTol = 1e3 * kEps;  // for matrices, in units of growth (lazy pieces)
constexpr double kBaryTol = 1e-11;

struct CaseStats {
  double worst_apply[2] = {0, 0};  // error / tolerance, [stiff]
  double worst_saltation[2] = {0, 0};
  double worst_barycentric = 0;
  double worst_time = 0;
  int cases = 0;
};

void check_case(std::mt19937_64& rng, int n, int d, JumpCaseOptions options, CaseStats& stats) {
  const Eigen::MatrixXd eta = testing::random_normals(rng, n, d, options.scaled_normals);
  const Eigen::MatrixXd limits = testing::random_limits(rng, eta, options);
  const JumpMap jump(eta, limits);
  const Triangulation tri = jump.triangulation();
  const double kappa = margin_condition(eta, limits);
  const std::string where = "n=" + std::to_string(n) + " d=" + std::to_string(d) +
                            " stiff=" + std::to_string(options.stiff) +
                            " scaled=" + std::to_string(options.scaled_normals);
  const int half = options.stiff ? 1 : 0;
  ++stats.cases;
  // Rounding tolerance for B(v) computed along the order v crosses the surfaces in.
  const double unit = kChainTol * (d + 2) * kEps;
  auto tolerance = [&](const Eigen::VectorXd& v) {
    return unit * apply_factors(jump, jump.order(v).order, v).error_scale;
  };

  for (int trial = 0; trial < 4; ++trial) {
    const Eigen::VectorXd dx = gaussian_vector(rng, d);
    const Eigen::VectorXd image = jump.apply(dx);
    const CrossingOrder o = jump.order(dx);
    ASSERT_TRUE(std::is_sorted(o.times.begin(), o.times.end())) << where;
    const FactorChain chain = apply_factors(jump, o.order, dx);
    const double tol = unit * chain.error_scale;
    const double apply_ratio = (image - chain.image).norm() / tol;
    stats.worst_apply[half] = std::max(stats.worst_apply[half], apply_ratio);
    EXPECT_LE(apply_ratio, 1.0) << where;
    const double saltation_ratio = (jump.saltation(o.order) * dx - chain.image).norm() / tol;
    stats.worst_saltation[half] = std::max(stats.worst_saltation[half], saltation_ratio);
    EXPECT_LE(saltation_ratio, 1.0) << where;

    // Independent route: triangulation and barycentric coordinates.
    const double scale = growth(jump, o.order) * dx.norm();
    const BarycentricEvaluation bary = tri.apply_barycentric(dx);
    const double bary_error = (bary.image - image).norm() / scale;
    stats.worst_barycentric = std::max(stats.worst_barycentric, bary_error);
    EXPECT_LE(bary_error, kBaryTol) << where;
    EXPECT_GE(bary.coordinates.minCoeff(), -kBaryTol * bary.coordinates.norm()) << where;

    // Positive homogeneity: both sides err by up to alpha tol.
    for (double alpha : {1e-3, 7.5, 1e3}) {
      EXPECT_LE((jump.apply(alpha * dx) - alpha * image).norm(), 2 * alpha * tol) << where;
    }
    // Kernel directions pass through unchanged.
    const Eigen::VectorXd xi = kernel_vector(rng, eta);
    EXPECT_LE((jump.apply(dx + xi) - image - xi).norm(), tolerance(dx + xi) + tol) << where;
  }

  // The nominal flow direction maps to the post-event field: B(F_-) = F_+. All crossing
  // times tie at -1, so rounding picks the order; B is continuous, so any order will do.
  const Eigen::VectorXd f_minus = limits.col(0);
  const Eigen::VectorXd f_plus = limits.col(limits.cols() - 1);
  EXPECT_LE((jump.apply(f_minus) - f_plus).norm(), tolerance(f_minus)) << where;

  // Prescribed order and times, including negative ones.
  std::vector<int> sigma(static_cast<std::size_t>(n));
  std::iota(sigma.begin(), sigma.end(), 0);
  std::shuffle(sigma.begin(), sigma.end(), rng);
  std::uniform_real_distribution<double> gap(0.05, 1.0);
  std::vector<double> times(static_cast<std::size_t>(n));
  times[0] = -0.5 + gap(rng);
  for (int k = 1; k < n; ++k) times[k] = times[k - 1] + gap(rng);
  Eigen::VectorXd expected;
  const Eigen::VectorXd dx =
      tangent_for_order(jump, sigma, times, kernel_vector(rng, eta), &expected);
  const CrossingOrder o = jump.order(dx);
  EXPECT_EQ(o.order, sigma) << where;
  const double prescribed_tol =
      unit * kappa * (1 + dx.norm()) * apply_factors(jump, sigma, dx).error_scale / dx.norm();
  for (int k = 0; k < n; ++k) {
    const double ratio = std::abs(o.times[k] - times[k]) / prescribed_tol;
    stats.worst_time = std::max(stats.worst_time, ratio);
    EXPECT_LE(ratio, 1.0) << where << " k=" << k;
  }
  EXPECT_LE((jump.apply(dx) - expected).norm(), prescribed_tol) << where;

  // Continuity across a cone boundary: make surfaces sigma(k) and sigma(k+1) tie exactly.
  // Both neighbouring pieces must give the same value, equal to apply().
  const int k = static_cast<int>(rng() % static_cast<unsigned>(n - 1));
  times[k + 1] = times[k];
  for (int i = k + 2; i < n; ++i) times[i] = std::max(times[i], times[i - 1]);
  const Eigen::VectorXd tie =
      tangent_for_order(jump, sigma, times, Eigen::VectorXd::Zero(d), &expected);
  std::vector<int> swapped = sigma;
  std::swap(swapped[k], swapped[k + 1]);
  const Eigen::VectorXd image = jump.apply(tie);
  const double tie_scale = unit * kappa * (1 + tie.norm()) *
                           std::max(apply_factors(jump, sigma, tie).error_scale,
                                    apply_factors(jump, swapped, tie).error_scale) /
                           tie.norm();
  EXPECT_LE((jump.saltation(sigma) * tie - image).norm(), tie_scale) << where;
  EXPECT_LE((jump.saltation(swapped) * tie - image).norm(), tie_scale) << where;
  EXPECT_LE((expected - image).norm(), tie_scale) << where;
}

TEST(JumpMapTest, RandomTransversalCasesSatisfyEveryProperty) {
  std::mt19937_64 rng(3);
  CaseStats stats;
  for (int seed = 0; seed < 10; ++seed) {
    for (int n = 2; n <= 6; ++n) {
      for (int d = n; d <= n + 4; ++d) {
        for (int variant = 0; variant < 4; ++variant) {
          check_case(rng, n, d, {(variant & 1) != 0, (variant & 2) != 0}, stats);
        }
      }
    }
  }
  EXPECT_EQ(stats.cases, 1000);
  std::printf(
      "worst error / tolerance over %d cases (non-stiff, stiff): apply vs M_sigma dx factor by "
      "factor %.3g, %.3g; saltation(sigma) dx %.3g, %.3g\n",
      stats.cases, stats.worst_apply[0], stats.worst_apply[1], stats.worst_saltation[0],
      stats.worst_saltation[1]);
  std::printf(
      "worst barycentric error %.3g (in units of growth |dx|); crossing times %.3g of their "
      "tolerance\n",
      stats.worst_barycentric, stats.worst_time);
  RecordProperty("worst_apply_error_over_tolerance",
                 std::to_string(std::max(stats.worst_apply[0], stats.worst_apply[1])));
}

// Exact ties are resolved by the lowest index; B is the same from both sides.
TEST(JumpMapTest, ExactTiesTakeTheLowestIndex) {
  const JumpMap jump(Eigen::MatrixXd::Identity(3, 3), linear_pwconst_limits(3, 0.3));
  const CrossingOrder o = jump.order(Eigen::Vector3d(-1.0, -1.0, -1.0));
  EXPECT_EQ(o.order, (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(o.times, (std::vector<double>{1.0 / 1.3, 1.0 / 1.3, 1.0 / 1.3}));
}

// Large n with a lazily evaluated Gamma: apply keeps every property; enumeration refuses.
TEST(JumpMapTest, LargeNumbersOfSurfaces) {
  std::mt19937_64 rng(4);
  const int d = 256;
  for (int n : {32, 64}) {
    const Eigen::MatrixXd eta = testing::random_normals(rng, n, d, false);
    const JumpMap jump(eta, testing::HashedLimits(rng, eta));
    for (int trial = 0; trial < 3; ++trial) {
      const Eigen::VectorXd dx = gaussian_vector(rng, d);
      const Eigen::VectorXd image = jump.apply(dx);
      const Eigen::MatrixXd m = jump.active_jacobian(dx);
      const double scale = std::max(1.0, m.norm()) * dx.norm();
      EXPECT_LE((image - m * dx).norm(), 500 * kEps * scale) << "n=" << n;
      EXPECT_LE((jump.apply(3.0 * dx) - 3.0 * image).norm(), 500 * kEps * 3 * scale);
      const Eigen::VectorXd xi = kernel_vector(rng, eta);
      EXPECT_LE((jump.apply(dx + xi) - image - xi).norm(), 1e-12 * (scale + m.norm() * xi.norm()));
    }
    const Eigen::VectorXd f_minus = jump.limit(Signs(n));
    const Eigen::VectorXd f_plus = jump.limit(Signs::all_plus(n));
    EXPECT_LE((jump.apply(f_minus) - f_plus).norm(), 1e-12 * (f_minus.norm() + f_plus.norm()));

    std::vector<int> sigma(static_cast<std::size_t>(n));
    std::iota(sigma.begin(), sigma.end(), 0);
    std::shuffle(sigma.begin(), sigma.end(), rng);
    std::vector<double> times(static_cast<std::size_t>(n));
    for (int k = 0; k < n; ++k) times[k] = -0.3 + 0.1 * k;
    Eigen::VectorXd expected;
    const Eigen::VectorXd dx =
        tangent_for_order(jump, sigma, times, kernel_vector(rng, eta), &expected);
    EXPECT_EQ(jump.order(dx).order, sigma);
    EXPECT_LE((jump.apply(dx) - expected).norm(), 1e-9 * jump.saltation(sigma).norm() * dx.norm());

    try {
      jump.pieces();
      FAIL() << "pieces() must refuse n = " << n;
    } catch (const InvalidArgument& e) {
      EXPECT_THAT(e.what(), HasSubstr("n = " + std::to_string(n) + " surfaces give n! pieces"));
      EXPECT_THAT(e.what(), HasSubstr("n <= 10"));
    }
    EXPECT_THROW(jump.triangulation(), InvalidArgument);
  }
}

TEST(JumpMapTest, PiecesAreAllOrdersWithTheirSaltationMatrices) {
  std::mt19937_64 rng(5);
  for (int n = 1; n <= 6; ++n) {
    const Eigen::MatrixXd eta = testing::random_normals(rng, n, n + 2, false);
    const JumpMap jump(eta, testing::random_limits(rng, eta, {}));
    const Pieces pieces = jump.pieces();
    int expected_count = 1;
    for (int k = 2; k <= n; ++k) expected_count *= k;
    ASSERT_EQ(static_cast<int>(pieces.size()), expected_count);
    std::vector<int> sigma(static_cast<std::size_t>(n));
    std::iota(sigma.begin(), sigma.end(), 0);
    std::size_t i = 0;
    do {
      ASSERT_EQ(pieces[i].order, sigma);
      // Prefix sharing changes only the order of floating-point operations.
      EXPECT_LE((pieces[i].matrix - jump.saltation(sigma)).norm(), 1e-13 * pieces[i].matrix.norm());
      ++i;
    } while (std::next_permutation(sigma.begin(), sigma.end()));
    // The visitor sees the same pieces, in the same order, with the same bits.
    std::size_t visited = 0;
    jump.for_each_piece(
        [&](const std::vector<int>& order, const Eigen::Ref<const Eigen::MatrixXd>& m) {
          EXPECT_EQ(order, pieces.order(visited));
          EXPECT_EQ(m, pieces.matrix(visited));
          ++visited;
        });
    EXPECT_EQ(visited, pieces.size());
  }
}

TEST(JumpMapTest, TriangulationMatchesTheDefinitions) {
  std::mt19937_64 rng(6);
  const int n = 3;
  const int d = 5;
  const Eigen::MatrixXd eta = testing::random_normals(rng, n, d, false);
  const Eigen::MatrixXd limits = testing::random_limits(rng, eta, {});
  const Triangulation tri = JumpMap(eta, limits).triangulation();
  const Eigen::MatrixXd kernel = testing::NormalFactors(eta).kernel_projector;
  for (Eigen::Index w = 0; w < 8; ++w) {
    // (5.1), and zeta_b in the row space of eta.
    for (int j = 0; j < n; ++j) {
      const double lhs = ((w >> j) & 1) ? eta.row(j).dot(tri.zeta().col(w))
                                        : eta.row(j).dot(tri.zeta().col(w) + limits.col(w));
      EXPECT_NEAR(lhs, 0.0, 1e-13 * eta.row(j).norm() * limits.col(w).norm());
    }
    EXPECT_LE((kernel * tri.zeta().col(w)).norm(), 1e-13 * limits.col(w).norm());
    EXPECT_LE((tri.zeta_image().col(w) - tri.zeta().col(w) - limits.col(w)).norm(), 1e-15 * 8);
    // The sampled flow of zeta_b: B(zeta_b) = zeta_b + F_b - F_+.
    const Eigen::VectorXd expected = tri.zeta().col(w) + limits.col(w) - limits.col(7);
    EXPECT_LE((tri.apply_barycentric(tri.zeta().col(w)).image - expected).norm(), 1e-12);
  }
  EXPECT_EQ(tri.simplices().size(), 6u);
  EXPECT_EQ(tri.simplices()[1].order, (std::vector<int>{0, 2, 1}));
  EXPECT_EQ(tri.simplices()[1].words[2].str(), "+-+");
  // L = ker eta + span F_-: orthonormal, dimension d - n + 1, holds F_- and the kernel.
  const Eigen::MatrixXd& basis = tri.lineality_basis();
  ASSERT_EQ(basis.cols(), d - n + 1);
  EXPECT_LE((basis.transpose() * basis - Eigen::MatrixXd::Identity(d - n + 1, d - n + 1)).norm(),
            1e-14 * d);
  const Eigen::VectorXd f_minus = limits.col(0);
  EXPECT_LE((f_minus - basis * (basis.transpose() * f_minus)).norm(), 1e-13 * f_minus.norm());
  // B on L: kernel vectors unchanged, F_- to F_+ (the printed (6.3) fails the first).
  const Eigen::VectorXd xi = kernel * gaussian_vector(rng, d);
  EXPECT_LE((tri.apply_linear_part(xi) - xi).norm(), 1e-13 * xi.norm());
  EXPECT_LE((tri.apply_linear_part(f_minus) - limits.col(7)).norm(), 1e-13 * f_minus.norm());
}

TEST(JumpMapTest, LazyLimitsAgreeWithTheTableEvenWhenTheCacheOverflows) {
  std::mt19937_64 rng(7);
  const int n = 6;
  const int d = 9;
  const Eigen::MatrixXd eta = testing::random_normals(rng, n, d, true);
  const Eigen::MatrixXd limits = testing::random_limits(rng, eta, {true, true});
  const JumpMap table(eta, limits);
  int evaluations = 0;
  const JumpMap lazy(
      eta,
      [&](Signs b, Eigen::Ref<Eigen::VectorXd> out) {
        ++evaluations;
        out = limits.col(static_cast<Eigen::Index>(b.bits()));
      },
      JumpMapOptions{n + 1});  // the smallest cache: cleared often
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::VectorXd dx = gaussian_vector(rng, d);
    // eta . Gamma is one product per word here and one for the whole table there: equal up
    // to rounding.
    // Both are within kChainTol (d + 2) eps error_scale of M_sigma dx (observed worst
    // difference 0.005 of the sum: the two runs differ only in the rounding of eta . Gamma).
    const Eigen::VectorXd image = table.apply(dx);
    const double tol = 2 * kChainTol * (d + 2) * kEps *
                       apply_factors(table, table.order(dx).order, dx).error_scale;
    EXPECT_LE((image - lazy.apply(dx)).norm(), tol);
    EXPECT_EQ(table.order(dx).order, lazy.order(dx).order);
  }
  EXPECT_GT(evaluations, 0);
  const Eigen::MatrixXd block = Eigen::MatrixXd::Random(d, 5);
  const Eigen::MatrixXd images = lazy.apply_block(block);
  // Equal up to the alignment-dependent summation order of Eigen's dot products.
  for (int k = 0; k < 5; ++k) {
    EXPECT_LE((images.col(k) - lazy.apply(block.col(k))).norm(), 1e-12 * images.col(k).norm());
  }
  const Pieces lazy_pieces = lazy.pieces();
  const Pieces table_pieces = table.pieces();
  for (std::size_t i = 0; i < table_pieces.size(); ++i) {
    EXPECT_LE((lazy_pieces[i].matrix - table_pieces[i].matrix).norm(),
              kApplyTol * growth(table, table_pieces[i].order));
  }
  // In place.
  Eigen::VectorXd x = block.col(0);
  lazy.apply(x, x);
  EXPECT_LE((x - images.col(0)).norm(), 1e-12 * x.norm());
}

// ---------------------------------------------------------------------------------------
// Validation: every message names the problem and quotes the values.
using testing::message_of;

TEST(JumpMapTest, ValidationMessagesNameTheProblem) {
  const Eigen::MatrixXd eye = Eigen::MatrixXd::Identity(2, 2);
  const Eigen::MatrixXd good = linear_pwconst_limits(2, 0.3);
  EXPECT_THAT(message_of([&] { JumpMap(eye, Eigen::MatrixXd::Ones(3, 4)); }),
              HasSubstr("expected a 2 x 4 table (d x 2^n), got 3 x 4"));
  EXPECT_THAT(message_of([&] { JumpMap(Eigen::MatrixXd::Identity(3, 2), good); }),
              HasSubstr("n = 3 surfaces in d = 2 dimensions"));
  Eigen::MatrixXd parallel(2, 3);
  parallel << 1, 0, 0, 2, 0, 1e-12;
  EXPECT_THAT(message_of([&] { JumpMap(parallel, Eigen::MatrixXd::Ones(3, 4)); }),
              HasSubstr("rank deficient"));
  EXPECT_THAT(
      message_of([&] { JumpMap(parallel, Eigen::MatrixXd::Ones(3, 4)); }),
      HasSubstr(
          "singular values of the row-normalised normals are [1.4142135623730951, 3.5355339"));
  Eigen::MatrixXd nan_eta = eye;
  nan_eta(1, 0) = std::nan("");
  EXPECT_THAT(message_of([&] { JumpMap(nan_eta, good); }),
              HasSubstr("normals: row 1 is not finite: [nan, 1]"));
  Eigen::MatrixXd inf_limits = good;
  inf_limits(0, 2) = INFINITY;
  EXPECT_THAT(message_of([&] { JumpMap(eye, inf_limits); }),
              HasSubstr("F_-+ is not finite: [inf, 0.7]"));
  Eigen::MatrixXd bad = good;
  bad(1, 1) = -0.25;  // word "+-", surface 1
  EXPECT_THAT(message_of([&] { JumpMap(eye, bad); }),
              HasSubstr("surface 1 is not transversal for word \"+-\": eta_1 . F_+- = -0.25"));
  EXPECT_THAT(message_of([&] { JumpMap(Eigen::MatrixXd::Identity(65, 65), Eigen::MatrixXd()); }),
              HasSubstr("n = 65 surfaces; at most 64"));
  const JumpMap jump(eye, good);
  EXPECT_THAT(message_of([&] { jump.apply(Eigen::VectorXd::Ones(3)); }),
              HasSubstr("apply: tangent has 3 numbers, expected d = 2"));
  EXPECT_THAT(message_of([&] { jump.apply(Eigen::Vector2d(1, NAN)); }),
              HasSubstr("apply: tangent is not finite: [1, nan]"));
  EXPECT_THAT(message_of([&] {
                jump.saltation({0, 0});
              }),
              HasSubstr("order [0, 0] is not a permutation of 0..1"));
  // A lazy Gamma is checked word by word as it is evaluated.
  const JumpMap lazy(eye, [](Signs b, Eigen::Ref<Eigen::VectorXd> out) {
    out << 1.0, b.str() == "++" ? -2.0 : 1.0;
  });
  EXPECT_THAT(message_of([&] { lazy.apply(Eigen::Vector2d(1, 1)); }),
              HasSubstr("surface 1 is not transversal for word \"++\": eta_1 . F_++ = -2"));
  // Missing words in the text form.
  std::map<std::string, Eigen::VectorXd> words = {
      {"--", Eigen::Vector2d(1, 1)}, {"+-", Eigen::Vector2d(1, 1)}, {"++", Eigen::Vector2d(1, 1)}};
  EXPECT_THAT(message_of([&] { limits_table_from_words(2, 2, words); }),
              HasSubstr("missing word \"-+\" (3 of 4 words given)"));
  words["-+"] = Eigen::Vector3d(1, 1, 1);
  EXPECT_THAT(message_of([&] { limits_table_from_words(2, 2, words); }),
              HasSubstr("word \"-+\" has 3 numbers, expected 2"));
  words["-+"] = Eigen::Vector2d(1, 1);
  words["-+-"] = Eigen::Vector2d(1, 1);
  EXPECT_THAT(message_of([&] { limits_table_from_words(2, 2, words); }),
              HasSubstr("word \"-+-\" has 3 characters, expected 2"));
}

}  // namespace
}  // namespace bflow

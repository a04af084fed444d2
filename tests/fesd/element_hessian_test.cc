// The exact Hessian of one FESD element's Lagrangian sum_r lambda_r residual_r plus a stage cost,
// assembled by pieces (element.h, hessian_blocks.h, HessianJet), against central differences of
// its exact gradient (Jet chunks: lambda^T of the residual's Jacobian), for every formulation, both
// collocation schemes, cross and standard complementarity, with a control and time scaling; on
// the structure the transcription declares, which also holds the Jacobian's nonzeros.
#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Core>

#include "bflow/fesd/dcs.h"
#include "bflow/fesd/element.h"
#include "bflow/fesd/hessian_blocks.h"

namespace bflow {
namespace {

// Two states and one control, seen by the element as three states ([x; u]), two switching
// functions; nonlinear in x, u and (multi-affinely) in a, so every kind of second derivative is
// nonzero somewhere.
struct Coupled {
  static constexpr int kStates = 3, kSwitches = 2;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0] * x[1] - x[2];
    c[1] = sin(x[0]) + x[2] * x[2] - 0.3;
  }
  template <typename T>
  void field(const T* x, const T* a, T* xdot) const {
    xdot[0] = a[0] * x[1] * x[1] + (1.0 - a[0]) * sin(x[0] * x[2]) + a[0] * a[1] * x[0];
    xdot[1] = exp(0.3 * x[0]) * a[1] - x[2] * x[1] * a[0] + cos(x[1]) * (1.0 - a[1]);
    xdot[2] = T(0.0);  // the control's rate (ignored by the element)
  }
};

// A stage cost of the state and the control, nonlinear in both.
class Cost final : public fesd::StageCostTerm {
 public:
  template <typename T>
  static T of(const T* x, const T* u) {
    return x[0] * x[0] * u[0] + sin(x[1]);
  }
  JetChunk value(const JetChunk* x, const JetChunk* u) const override { return of(x, u); }
  HessianScalar value(const HessianScalar* x, const HessianScalar* u) const override {
    return of(x, u);
  }
};

struct Config {
  DcsFormulation formulation;
  int lifting_depth;
  CollocationScheme scheme;
  bool standard;
  bool point_pairs = false;
  bool point_sums = false;
  CollocationForm form = CollocationForm::kIntegral;
  std::string name() const {
    return std::string(to_string(formulation)) + " n_d " + std::to_string(lifting_depth) + " " +
           to_string(scheme) + " " + to_string(form) +
           (standard      ? " standard"
            : point_pairs ? " point-pair cross"
            : point_sums  ? " point-sum cross"
                          : " cross");
  }
};

class ElementHessianTest : public ::testing::TestWithParam<Config> {};

TEST_P(ElementHessianTest, PiecesMatchCentralDifferencesOfTheExactGradient) {
  const Config c = GetParam();
  const auto model = adapt_step(Coupled{});
  const fesd::PointDcs dcs(model, c.formulation, c.lifting_depth);
  const ButcherTableau tab = collocation_tableau(c.scheme, 2);
  fesd::ElementShape l(dcs, 2, 2, tab, 1, true, false, c.form);
  if (c.point_pairs) l.cross = CrossComplementarity::kPointPairs;
  if (c.point_sums) l.cross = CrossComplementarity::kPointSums;
  const int n = l.local;
  std::mt19937 gen(11);
  std::uniform_real_distribution<double> uniform(0.1, 0.9);
  std::vector<double> local(static_cast<std::size_t>(n));
  for (double& v : local) v = uniform(gen);
  std::vector<double> lambda(static_cast<std::size_t>(l.rows_per_element()));
  for (double& v : lambda) v = uniform(gen) - 0.5;

  // With a stage cost sum_k cost_weights[k] h T L(X_k, u), which add_element_hessian takes in
  // the field pieces' passes.
  const Cost cost;
  const double cost_weights[2] = {0.8, -0.6};
  const int u0 = l.d + l.npairs;
  // The exact gradient of the Lagrangian and the cost at a local vector.
  const auto gradient = [&](const std::vector<double>& at) {
    Eigen::MatrixXd jac, cost_jac;
    fesd::dense_jacobian(at, l.rows_per_element(), jac, [&](const JetChunk* in, JetChunk* out) {
      fesd::element_residual(l, c.standard, in, out);
    });
    fesd::dense_jacobian(at, 1, cost_jac, [&](const JetChunk* in, JetChunk* out) {
      const JetChunk h = in[l.own()] * in[u0 + l.nu];  // h T
      out[0] = JetChunk(0.0);
      for (int k = 0; k < l.s; ++k)
        out[0] += cost_weights[k] * (h * Cost::of(in + l.own() + 1 + k * l.d, in + u0));
    });
    const Eigen::Map<const Eigen::VectorXd> w(lambda.data(), l.rows_per_element());
    return Eigen::VectorXd(jac.transpose() * w + cost_jac.transpose());
  };
  Eigen::MatrixXd differences(n, n);
  const double eps = 1e-5;
  for (int j = 0; j < n; ++j) {
    std::vector<double> plus = local, minus = local;
    plus[static_cast<std::size_t>(j)] += eps;
    minus[static_cast<std::size_t>(j)] -= eps;
    differences.col(j) = (gradient(plus) - gradient(minus)) / (2.0 * eps);
  }

  std::vector<int> globals(static_cast<std::size_t>(n));
  for (int k = 0; k < n; ++k) globals[static_cast<std::size_t>(k)] = k;
  // The structure the transcription declares (by construction): every pair of the field and
  // algebraic pieces, and of the complementarity piece the pairs its products multiply.
  const std::vector<std::vector<int>> pieces = fesd::element_hessian_pieces(l);
  fesd::HessianBlocks blocks;
  for (std::size_t p = 0; p + 1 < pieces.size(); ++p) blocks.add_block(pieces[p]);
  fesd::ComplementarityHessian comp;
  fesd::complementarity_hessian(l, c.standard, comp);
  std::vector<std::pair<int, int>> comp_pairs;
  for (const auto& [a, b] : comp.pairs) {
    comp_pairs.emplace_back(pieces.back()[static_cast<std::size_t>(a)],
                            pieces.back()[static_cast<std::size_t>(b)]);
  }
  blocks.add_pairs(comp_pairs);
  std::vector<double> values(blocks.size(), 0.0);
  fesd::add_element_hessian(l, pieces, comp, globals, local, lambda.data(), blocks, values.data(),
                            &cost, cost_weights);
  EXPECT_EQ(blocks.missed(), 0) << c.name();
  Eigen::MatrixXd exact = Eigen::MatrixXd::Zero(n, n);
  for (std::size_t k = 0; k < blocks.size(); ++k) {
    exact(blocks.rows()[k], blocks.cols()[k]) = values[k];
    exact(blocks.cols()[k], blocks.rows()[k]) = values[k];
  }
  // Central differences of an exact gradient: truncation eps^2 f''' / 6 and round-off
  // 1e-16 |grad| / eps, about 1e-11 here (measured worst 4.5e-11, Stewart with Gauss-Legendre
  // in the derivative form, with the stage cost): the bound 1e-9 leaves a factor 22, while an
  // error of 1e-9 in any entry fails.
  const double scale = std::max(1.0, differences.cwiseAbs().maxCoeff());
  const double worst = (exact - differences).cwiseAbs().maxCoeff();
  EXPECT_LT(worst, 1e-9 * scale) << c.name();
  // Not vacuous: the Hessian has second derivatives in x, in a (or theta) and across.
  EXPECT_GT(exact.cwiseAbs().maxCoeff(), 0.1) << c.name();
  // The Jacobian pattern (element_jacobian_pattern) holds every nonzero of the dense Jacobian,
  // and leaves some out of every row kind (not every row against every input).
  Eigen::MatrixXd jac;
  fesd::dense_jacobian(local, l.rows_per_element(), jac, [&](const JetChunk* in, JetChunk* out) {
    fesd::element_residual(l, c.standard, in, out);
  });
  const std::vector<std::vector<int>> pattern = fesd::element_jacobian_pattern(l, c.standard);
  int unlisted_nonzeros = 0;
  for (int r = 0; r < l.rows_per_element(); ++r) {
    const std::vector<int>& row = pattern[static_cast<std::size_t>(r)];
    EXPECT_LT(row.size(), static_cast<std::size_t>(n)) << c.name() << " row " << r;
    for (int col = 0; col < n; ++col) {
      if (jac(r, col) != 0.0 && std::find(row.begin(), row.end(), col) == row.end())
        ++unlisted_nonzeros;
    }
  }
  EXPECT_EQ(unlisted_nonzeros, 0) << c.name();
  std::printf("%s: %d unknowns, %zu Hessian entries, largest difference %.2e (scale %.2f)\n",
              c.name().c_str(), n, blocks.size(), worst, scale);
}

// The element of a configuration as the Jacobian tests take it: its end apart or not, the
// configuration's cross complementarity.
fesd::ElementShape element_of(const Config& c, const fesd::PointDcs& dcs, const ButcherTableau& tab,
                              bool apart) {
  fesd::ElementShape l(dcs, 2, 2, tab, 1, true, apart, c.form);
  if (c.point_pairs) l.cross = CrossComplementarity::kPointPairs;
  if (c.point_sums) l.cross = CrossComplementarity::kPointSums;
  return l;
}

// The element's Jacobian by its pieces (fesd::element_jacobian: narrow Jets per stage and point,
// closed forms for the rest) is the dense Jet Jacobian of element_residual entry for entry, with
// the same residual, in both layouts of a Radau IIA element's end (the last stage, or unknowns
// of its own); the same numbers by the same operations, so equality is exact.
TEST_P(ElementHessianTest, JacobianByPiecesIsTheDenseJetJacobian) {
  const Config c = GetParam();
  const auto model = adapt_step(Coupled{});
  const fesd::PointDcs dcs(model, c.formulation, c.lifting_depth);
  const ButcherTableau tab = collocation_tableau(c.scheme, 2);
  for (const bool apart : {false, true}) {
    const fesd::ElementShape l = element_of(c, dcs, tab, apart);
    EXPECT_EQ(l.shared_end, !apart && c.scheme == CollocationScheme::kRadauIIA) << c.name();
    std::mt19937 gen(5);
    std::uniform_real_distribution<double> uniform(0.1, 0.9);
    std::vector<double> local(static_cast<std::size_t>(l.local));
    for (double& v : local) v = uniform(gen);
    Eigen::MatrixXd dense, pieces;
    Eigen::VectorXd dense_values, piece_values;
    fesd::dense_jacobian(
        local, l.rows_per_element(), dense,
        [&](const JetChunk* in, JetChunk* out) { fesd::element_residual(l, c.standard, in, out); },
        &dense_values);
    fesd::element_jacobian(l, c.standard, local, pieces, &piece_values);
    ASSERT_EQ(pieces.rows(), dense.rows());
    ASSERT_EQ(pieces.cols(), dense.cols());
    EXPECT_EQ((pieces - dense).cwiseAbs().maxCoeff(), 0.0) << c.name() << " apart " << apart;
    EXPECT_EQ((piece_values - dense_values).cwiseAbs().maxCoeff(), 0.0) << c.name();
    EXPECT_GT(dense.cwiseAbs().maxCoeff(), 0.1) << c.name();
  }
}

// The element's Jacobian as a program (fesd::JacobianProgram: element_residual traced at one
// point, differentiated once) at three other points: the dense Jet Jacobian's every entry to
// rounding (1e-14 of the largest), in both layouts of the element's end.
TEST_P(ElementHessianTest, JacobianProgramIsTheDenseJetJacobianElsewhere) {
  const Config c = GetParam();
  const auto model = adapt_step(Coupled{});
  const fesd::PointDcs dcs(model, c.formulation, c.lifting_depth);
  const ButcherTableau tab = collocation_tableau(c.scheme, 2);
  for (const bool apart : {false, true}) {
    const fesd::ElementShape l = element_of(c, dcs, tab, apart);
    std::vector<std::pair<int, int>> entries;
    for (int r = 0; r < l.rows_per_element(); ++r) {
      for (int col = 0; col < l.local; ++col) entries.emplace_back(r, col);
    }
    std::mt19937 gen(11);
    std::uniform_real_distribution<double> uniform(0.1, 0.9);
    std::vector<double> local(static_cast<std::size_t>(l.local));
    for (double& v : local) v = uniform(gen);
    auto eval = [&](const auto* in, auto* out) { fesd::element_residual(l, c.standard, in, out); };
    const auto program =
        fesd::JacobianProgram::trace(l.local, l.rows_per_element(), entries, local.data(), eval);
    for (int point = 0; point < 3; ++point) {
      for (double& v : local) v = uniform(gen);
      Eigen::MatrixXd dense;
      fesd::dense_jacobian(local, l.rows_per_element(), dense,
                           [&](const JetChunk* in, JetChunk* out) {
                             fesd::element_residual(l, c.standard, in, out);
                           });
      std::vector<double> values(entries.size());
      ASSERT_EQ(program->run(local.data(), values.data()), fesd::HessianProgram::Outcome::kDone)
          << c.name();
      double worst = 0.0;
      for (std::size_t k = 0; k < entries.size(); ++k) {
        worst = std::max(worst, std::abs(values[k] - dense(entries[k].first, entries[k].second)));
      }
      EXPECT_LE(worst, 1e-14 * dense.cwiseAbs().maxCoeff()) << c.name() << " apart " << apart;
      EXPECT_GT(dense.cwiseAbs().maxCoeff(), 0.1) << c.name();
    }
    // The entries that are identically zero or constant cost nothing per run.
    EXPECT_LT(program->operations(), entries.size()) << c.name();
  }
}

// The algebraic guesses that favour no side (AlgebraicGuess, fesd.h): in Stewart's formulation
// [theta (n_f), lambda (n_f), mu] at theta = 1/n_f with lambda = 1, mu = 0 (kNeutral) or as
// nosnoc's problem.py initialises them at its sigma_0 = 1, theta = lambda = 1/n_f and mu = 1
// (kNosnoc); in the step formulation a = lambda+ = lambda- = 1/2 for both.
TEST(NeutralGuess, StewartsIsNosnocsOrBflowsAndTheStepFormulationsIsTheSame) {
  const auto model = adapt_step(Coupled{});
  const fesd::PointDcs stewart(model, DcsFormulation::kStewart, 0);
  const int nf = (stewart.size() - 1) / 2;
  ASSERT_EQ(stewart.size(), 2 * nf + 1);
  ASSERT_EQ(nf, 4);  // two switching functions: four regions
  std::vector<double> z(static_cast<std::size_t>(stewart.size()), -7.0);
  stewart.neutral(z.data(), AlgebraicGuess::kNosnoc);
  for (int i = 0; i < nf; ++i) {
    EXPECT_EQ(z[static_cast<std::size_t>(i)], 0.25) << i;
    EXPECT_EQ(z[static_cast<std::size_t>(nf + i)], 0.25) << i;
  }
  EXPECT_EQ(z[static_cast<std::size_t>(2 * nf)], 1.0);
  stewart.neutral(z.data(), AlgebraicGuess::kNeutral);
  for (int i = 0; i < nf; ++i) {
    EXPECT_EQ(z[static_cast<std::size_t>(i)], 0.25) << i;
    EXPECT_EQ(z[static_cast<std::size_t>(nf + i)], 1.0) << i;
  }
  EXPECT_EQ(z[static_cast<std::size_t>(2 * nf)], 0.0);
  const fesd::PointDcs step(model, DcsFormulation::kStep, 0);
  std::vector<double> a(static_cast<std::size_t>(step.size()), -7.0), b = a;
  step.neutral(a.data(), AlgebraicGuess::kNosnoc);
  step.neutral(b.data(), AlgebraicGuess::kNeutral);
  EXPECT_EQ(a, b);
  for (const double v : a) EXPECT_EQ(v, 0.5);
}

// Radau IIA's end as its last stage: b is A's last row, so with x_{n+1} = X_s the end rows of the
// layout that keeps the end apart are, in the integral form, its last collocation rows (b and A's
// last row agree to rounding), and in the derivative form x_{n+1} - X_s (e = b^T A^-1 the unit
// vector, butcher.h), exactly 0; the shared layout's rows are the apart layout's without them
// (the same residual, d unknowns and d rows fewer).
TEST(ElementEnd, TheLastRadauStageIsTheEnd) {
  const auto model = adapt_step(Coupled{});
  for (const auto& [formulation, form] :
       {std::make_pair(DcsFormulation::kStep, CollocationForm::kIntegral),
        std::make_pair(DcsFormulation::kStewart, CollocationForm::kIntegral),
        std::make_pair(DcsFormulation::kStep, CollocationForm::kDerivative),
        std::make_pair(DcsFormulation::kStewart, CollocationForm::kDerivative)}) {
    const fesd::PointDcs dcs(model, formulation, 0);
    for (const int stages : {1, 2, 3}) {
      const ButcherTableau tab = collocation_tableau(CollocationScheme::kRadauIIA, stages);
      const fesd::ElementShape shared(dcs, 2, 2, tab, 1, true, false, form);
      const fesd::ElementShape apart(dcs, 2, 2, tab, 1, true, /*end_apart=*/true, form);
      ASSERT_TRUE(shared.shared_end);
      ASSERT_FALSE(apart.shared_end);
      EXPECT_EQ(apart.local - shared.local, 2);
      EXPECT_EQ(apart.rows_per_element() - shared.rows_per_element(), 2);
      std::mt19937 gen(3);
      std::uniform_real_distribution<double> uniform(0.1, 0.9);
      std::vector<double> in(static_cast<std::size_t>(shared.local));
      for (double& v : in) v = uniform(gen);
      // The apart layout's inputs: the same, with x_{n+1} = X_s inserted before z.
      std::vector<double> wide(in.begin(), in.begin() + shared.own() + shared.off_z);
      for (int i = 0; i < 2; ++i) {
        wide.push_back(in[static_cast<std::size_t>(shared.own() + shared.off_x + i)]);
      }
      wide.insert(wide.end(), in.begin() + shared.own() + shared.off_z, in.end());
      ASSERT_EQ(static_cast<int>(wide.size()), apart.local);
      std::vector<double> a(static_cast<std::size_t>(shared.rows_per_element()));
      std::vector<double> b(static_cast<std::size_t>(apart.rows_per_element()));
      fesd::element_residual(shared, false, in.data(), a.data());
      fesd::element_residual(apart, false, wide.data(), b.data());
      const int sd = shared.dynamics;
      for (int r = 0; r < sd; ++r) EXPECT_EQ(a[r], b[r]) << r;
      for (int i = 0; i < 2; ++i) {
        if (form == CollocationForm::kDerivative) {
          EXPECT_EQ(b[sd + i], 0.0) << stages;
        } else {
          EXPECT_NEAR(b[sd + i], b[sd - 2 + i], 1e-15) << stages;
        }
      }
      for (std::size_t r = sd; r < a.size(); ++r) EXPECT_EQ(a[r], b[r + 2]) << r;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(
    AllFormulations, ElementHessianTest,
    ::testing::Values(
        Config{DcsFormulation::kStep, 0, CollocationScheme::kRadauIIA, false},
        Config{DcsFormulation::kStep, 0, CollocationScheme::kGaussLegendre, false},
        Config{DcsFormulation::kStep, 0, CollocationScheme::kRadauIIA, true},
        Config{DcsFormulation::kStep, 2, CollocationScheme::kRadauIIA, false},
        Config{DcsFormulation::kStep, 2, CollocationScheme::kGaussLegendre, true},
        Config{DcsFormulation::kStewart, 0, CollocationScheme::kRadauIIA, false},
        Config{DcsFormulation::kStewart, 0, CollocationScheme::kGaussLegendre, false},
        Config{DcsFormulation::kStewart, 0, CollocationScheme::kGaussLegendre, true},
        Config{DcsFormulation::kStep, 2, CollocationScheme::kRadauIIA, false, true},
        Config{DcsFormulation::kStewart, 0, CollocationScheme::kRadauIIA, false, true},
        Config{DcsFormulation::kStewart, 0, CollocationScheme::kGaussLegendre, false, true},
        Config{DcsFormulation::kStep, 0, CollocationScheme::kRadauIIA, false, false, true},
        Config{DcsFormulation::kStep, 2, CollocationScheme::kGaussLegendre, false, false, true},
        Config{DcsFormulation::kStewart, 0, CollocationScheme::kRadauIIA, false, false, true},
        // The derivative form (butcher.h) over each scheme, formulation and row kind.
        Config{DcsFormulation::kStep, 0, CollocationScheme::kRadauIIA, false, false, false,
               CollocationForm::kDerivative},
        Config{DcsFormulation::kStep, 0, CollocationScheme::kGaussLegendre, true, false, false,
               CollocationForm::kDerivative},
        Config{DcsFormulation::kStep, 2, CollocationScheme::kRadauIIA, false, true, false,
               CollocationForm::kDerivative},
        Config{DcsFormulation::kStewart, 0, CollocationScheme::kRadauIIA, false, false, false,
               CollocationForm::kDerivative},
        Config{DcsFormulation::kStewart, 0, CollocationScheme::kGaussLegendre, false, false, true,
               CollocationForm::kDerivative}));

// The point-pair cross complementarity (kPointPairs) against the aggregated rows: pair k's
// P (P + 1) products sum to its aggregated product (sum_r u_r)(v_0 + sum_m v_m) exactly by
// the distributive law, each product equals the two members read from the local vector, and
// the Jacobian pattern lists every nonzero of the rows' dense Jacobian.
TEST(PointPairComplementarity, RowsSumToTheAggregatedProductsAndThePatternHoldsTheJacobian) {
  const auto model = adapt_step(Coupled{});
  for (const DcsFormulation formulation : {DcsFormulation::kStep, DcsFormulation::kStewart}) {
    const fesd::PointDcs dcs(model, formulation, 0);
    const ButcherTableau tab = collocation_tableau(CollocationScheme::kGaussLegendre, 2);
    fesd::ElementShape sums(dcs, 2, 2, tab, 1, true);
    fesd::ElementShape pairs = sums;
    pairs.cross = CrossComplementarity::kPointPairs;
    const int P = pairs.points;
    ASSERT_EQ(P, 3);  // Gauss-Legendre: two stages and the end point
    ASSERT_EQ(pairs.comp_rows(), sums.npairs * P * (P + 1));
    std::mt19937 gen(5);
    std::uniform_real_distribution<double> uniform(0.1, 0.9);
    std::vector<double> local(static_cast<std::size_t>(sums.local));
    for (double& v : local) v = uniform(gen);
    std::vector<double> aggregated(static_cast<std::size_t>(sums.rows_per_element()));
    std::vector<double> products(static_cast<std::size_t>(pairs.rows_per_element()));
    fesd::element_residual(sums, false, local.data(), aggregated.data());
    fesd::element_residual(pairs, false, local.data(), products.data());
    const double* z = local.data() + pairs.own() + pairs.off_z;
    for (int k = 0; k < pairs.npairs; ++k) {
      const fesd::Pair& pair = dcs.pairs()[static_cast<std::size_t>(k)];
      double sum = 0.0;
      for (int m = 0; m <= P; ++m) {
        const double v =
            m == 0 ? local[static_cast<std::size_t>(pairs.d + k)] : z[(m - 1) * pairs.nz + pair.v];
        for (int r = 0; r < P; ++r) {
          const double u = pair.flipped ? 1.0 - z[r * pairs.nz + pair.u] : z[r * pairs.nz + pair.u];
          const double row =
              products[static_cast<std::size_t>(pairs.equalities + k * P * (P + 1) + m * P + r)];
          EXPECT_EQ(row, u * v) << to_string(formulation) << " pair " << k << " m " << m;
          sum += row;
        }
      }
      const double whole = aggregated[static_cast<std::size_t>(sums.equalities + k)];
      EXPECT_NEAR(sum, whole, 1e-15 * std::abs(whole) * P * (P + 1)) << to_string(formulation);
    }
    // Every other row is the same.
    for (int r = 0; r < sums.equalities; ++r) {
      EXPECT_EQ(products[static_cast<std::size_t>(r)], aggregated[static_cast<std::size_t>(r)]);
    }
    Eigen::MatrixXd jac;
    fesd::dense_jacobian(
        local, pairs.rows_per_element(), jac,
        [&](const JetChunk* in, JetChunk* out) { fesd::element_residual(pairs, false, in, out); });
    const std::vector<std::vector<int>> pattern = fesd::element_jacobian_pattern(pairs, false);
    int listed = 0;
    for (int r = pairs.equalities; r < pairs.rows_per_element(); ++r) {
      const std::vector<int>& row = pattern[static_cast<std::size_t>(r)];
      EXPECT_EQ(row.size(), 2u);
      for (int c = 0; c < pairs.local; ++c) {
        const bool in_pattern = std::find(row.begin(), row.end(), c) != row.end();
        if (!in_pattern) {
          EXPECT_EQ(jac(r, c), 0.0) << "row " << r << " column " << c;
        }
        listed += in_pattern ? 1 : 0;
      }
    }
    EXPECT_EQ(listed, 2 * pairs.comp_rows());
  }
}

// The point-sum cross complementarity (kPointSums, nosnoc's Python default): pair k's row r is
// u_r (v_0 + sum_m v_m), read from the local vector; the P rows sum to the aggregated product
// (sum_r u_r)(v_0 + sum_m v_m); the Jacobian pattern (u_r and the P + 1 v's) holds every nonzero
// of the rows' dense Jacobian.
TEST(PointSumComplementarity, RowsSumToTheAggregatedProductsAndThePatternHoldsTheJacobian) {
  const auto model = adapt_step(Coupled{});
  for (const DcsFormulation formulation : {DcsFormulation::kStep, DcsFormulation::kStewart}) {
    const fesd::PointDcs dcs(model, formulation, 0);
    const ButcherTableau tab = collocation_tableau(CollocationScheme::kGaussLegendre, 2);
    fesd::ElementShape sums(dcs, 2, 2, tab, 1, true);
    fesd::ElementShape points = sums;
    points.cross = CrossComplementarity::kPointSums;
    const int P = points.points;
    ASSERT_EQ(P, 3);
    ASSERT_EQ(points.comp_rows(), sums.npairs * P);
    std::mt19937 gen(7);
    std::uniform_real_distribution<double> uniform(0.1, 0.9);
    std::vector<double> local(static_cast<std::size_t>(sums.local));
    for (double& v : local) v = uniform(gen);
    std::vector<double> aggregated(static_cast<std::size_t>(sums.rows_per_element()));
    std::vector<double> rows(static_cast<std::size_t>(points.rows_per_element()));
    fesd::element_residual(sums, false, local.data(), aggregated.data());
    fesd::element_residual(points, false, local.data(), rows.data());
    const double* z = local.data() + points.own() + points.off_z;
    for (int k = 0; k < points.npairs; ++k) {
      const fesd::Pair& pair = dcs.pairs()[static_cast<std::size_t>(k)];
      double v = local[static_cast<std::size_t>(points.d + k)];
      for (int m = 0; m < P; ++m) v += z[m * points.nz + pair.v];
      double sum = 0.0;
      for (int r = 0; r < P; ++r) {
        const double u = pair.flipped ? 1.0 - z[r * points.nz + pair.u] : z[r * points.nz + pair.u];
        const double row = rows[static_cast<std::size_t>(points.equalities + k * P + r)];
        EXPECT_NEAR(row, u * v, 1e-15 * std::abs(u * v)) << to_string(formulation) << " " << k;
        sum += row;
      }
      const double whole = aggregated[static_cast<std::size_t>(sums.equalities + k)];
      EXPECT_NEAR(sum, whole, 1e-15 * std::abs(whole) * P) << to_string(formulation);
    }
    for (int r = 0; r < sums.equalities; ++r) {
      EXPECT_EQ(rows[static_cast<std::size_t>(r)], aggregated[static_cast<std::size_t>(r)]);
    }
    Eigen::MatrixXd jac;
    fesd::dense_jacobian(
        local, points.rows_per_element(), jac,
        [&](const JetChunk* in, JetChunk* out) { fesd::element_residual(points, false, in, out); });
    const std::vector<std::vector<int>> pattern = fesd::element_jacobian_pattern(points, false);
    for (int r = points.equalities; r < points.rows_per_element(); ++r) {
      const std::vector<int>& row = pattern[static_cast<std::size_t>(r)];
      EXPECT_EQ(row.size(), static_cast<std::size_t>(P + 2));
      for (int c = 0; c < points.local; ++c) {
        const bool in_pattern = std::find(row.begin(), row.end(), c) != row.end();
        if (in_pattern) {
          EXPECT_NE(jac(r, c), 0.0) << "row " << r << " column " << c;
        } else {
          EXPECT_EQ(jac(r, c), 0.0) << "row " << r << " column " << c;
        }
      }
    }
  }
}

}  // namespace
}  // namespace bflow

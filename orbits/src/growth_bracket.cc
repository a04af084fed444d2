// The growth-rate bracket of a piecewise-linear map restricted to a subspace (periodic_orbit.h).
#include <algorithm>
#include <cmath>
#include <complex>
#include <limits>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Dense>

#include "bflow/core/errors.h"
#include "bflow/orbits/periodic_orbit.h"

namespace bflow {
namespace {

using Eigen::MatrixXcd;
using Eigen::MatrixXd;
using Eigen::VectorXd;

void check_growth_options(const OrbitOptions& o) {
  if (o.growth_directions < 0 || o.growth_iterations < 1 || o.max_product_length < 1 ||
      o.max_products < 1) {
    throw InvalidArgument(
        "OrbitOptions: growth_directions >= 0, growth_iterations >= 1, max_product_length >= 1 "
        "and max_products >= 1 are required, got " +
        std::to_string(o.growth_directions) + ", " + std::to_string(o.growth_iterations) + ", " +
        std::to_string(o.max_product_length) + ", " + std::to_string(o.max_products));
  }
}

// The distinct pieces of map restricted to span(basis).
std::vector<MatrixXd> restricted_pieces(const FlowDerivative& map, const MatrixXd& basis) {
  std::vector<MatrixXd> out;
  for (const FlowPiece& piece : map.pieces()) {
    const MatrixXd a = basis.transpose() * piece.matrix * basis;
    bool seen = false;
    for (const MatrixXd& b : out) {
      if ((a - b).norm() <= FlowDerivative::kLinearTolerance * (1.0 + b.norm())) seen = true;
    }
    if (!seen) out.push_back(a);
  }
  return out;
}

struct LowerCandidate {
  double rate = 0.0;
  int period = 0;
};

// Checks whether L^p z is a positive multiple of z for p = 1, 2; returns the growth c^(1/p).
LowerCandidate periodic_direction(const FlowDerivative& map, const MatrixXd& basis,
                                  const VectorXd& z, double tolerance) {
  LowerCandidate found;
  if (!(z.norm() > 0.0)) return found;
  VectorXd w = z;
  for (int p = 1; p <= 2; ++p) {
    w = basis.transpose() * map.apply(basis * w);
    const double c = z.dot(w) / z.squaredNorm();
    if (c > 0.0 && (w - c * z).norm() <= tolerance * w.norm()) {
      found.rate = std::pow(c, 1.0 / p);
      found.period = p;
      return found;
    }
  }
  return found;
}

// The largest singular value of a complex matrix.
double operator_norm(const MatrixXcd& a) {
  if (a.size() == 0) return 0.0;
  Eigen::JacobiSVD<MatrixXcd> svd(a);
  return svd.singularValues()(0);
}

// A unitary Q whose leading columns span a flag the pieces share as far as they share one: at
// each level the unit vector of the remaining subspace that is closest to an eigenvector of every
// piece (among the pieces' own eigenvectors there) is taken next. Where the pieces are
// simultaneously triangularisable, Q^H A Q is upper triangular for every piece.
MatrixXcd common_flag(const std::vector<MatrixXd>& pieces) {
  const int m = static_cast<int>(pieces.front().rows());
  MatrixXcd q = MatrixXcd::Identity(m, m);
  for (int level = 0; level + 1 < m; ++level) {
    const int size = m - level;
    const MatrixXcd sub = q.rightCols(size);
    std::vector<MatrixXcd> local;
    for (const MatrixXd& a : pieces)
      local.push_back(sub.adjoint() * a.cast<std::complex<double>>() * sub);
    Eigen::VectorXcd best = Eigen::VectorXcd::Unit(size, 0);
    double best_miss = std::numeric_limits<double>::infinity();
    for (const MatrixXcd& c : local) {
      const Eigen::ComplexEigenSolver<MatrixXcd> eig(c);
      for (int i = 0; i < size; ++i) {
        Eigen::VectorXcd v = eig.eigenvectors().col(i);
        if (!(v.norm() > 0.0)) continue;
        v.normalize();
        double miss = 0.0;
        for (const MatrixXcd& other : local) {
          const Eigen::VectorXcd w = other * v;
          miss = std::max(miss, (w - v.dot(w) * v).norm() / (1.0 + other.norm()));
        }
        if (miss < best_miss) {
          best_miss = miss;
          best = v;
        }
      }
    }
    // A unitary matrix of the subspace whose first column is `best`.
    MatrixXcd basis(size, size);
    basis.col(0) = best;
    basis.rightCols(size - 1) = MatrixXcd::Identity(size, size).rightCols(size - 1);
    const MatrixXcd h = Eigen::HouseholderQR<MatrixXcd>(basis).householderQ();
    q.rightCols(size) = sub * h;
  }
  return q;
}

// min over k <= max_length of max over products of k pieces of |product|^(1/k), the pieces
// already in the norm's coordinates.
std::pair<double, int> product_bound(const std::vector<MatrixXcd>& pieces, int max_length,
                                     long max_products) {
  const int count = static_cast<int>(pieces.size());
  const int m = static_cast<int>(pieces.front().rows());
  double best = std::numeric_limits<double>::infinity();
  int best_length = 0;
  std::vector<MatrixXcd> level{MatrixXcd::Identity(m, m)};
  for (int k = 1; k <= max_length; ++k) {
    if (static_cast<double>(level.size()) * count > static_cast<double>(max_products)) break;
    std::vector<MatrixXcd> next;
    next.reserve(level.size() * static_cast<std::size_t>(count));
    double worst = 0.0;
    for (const MatrixXcd& prefix : level) {
      for (const MatrixXcd& piece : pieces) {
        next.push_back(piece * prefix);
        worst = std::max(worst, operator_norm(next.back()));
      }
    }
    const double bound = std::pow(worst, 1.0 / k);
    if (bound < best) {
      best = bound;
      best_length = k;
    }
    level = std::move(next);
  }
  return {best, best_length};
}

}  // namespace

OrbitStability classify(const GrowthBracket& bracket) {
  if (bracket.upper < 1.0) return OrbitStability::kStable;
  if (bracket.lower > 1.0) return OrbitStability::kUnstable;
  return OrbitStability::kUndecided;
}

GrowthBracket growth_rate_bracket(const FlowDerivative& map, const MatrixXd& basis,
                                  const OrbitOptions& options) {
  check_growth_options(options);
  GrowthBracket bracket;
  const int m = static_cast<int>(basis.cols());
  if (m == 0) return bracket;
  const std::vector<MatrixXd> pieces = restricted_pieces(map, basis);
  bracket.pieces = static_cast<int>(pieces.size());
  if (pieces.size() == 1) {
    Eigen::EigenSolver<MatrixXd> eig(pieces.front());
    for (Eigen::Index i = 0; i < eig.eigenvalues().size(); ++i) {
      bracket.multipliers.push_back(eig.eigenvalues()[i]);
    }
    std::sort(bracket.multipliers.begin(), bracket.multipliers.end(),
              [](const std::complex<double>& a, const std::complex<double>& b) {
                return std::abs(a) > std::abs(b);
              });
    bracket.lower = bracket.upper = std::abs(bracket.multipliers.front());
    bracket.lower_period = bracket.upper_length = 1;
    return bracket;
  }
  // Lower: directions that L maps (in one or two steps) onto positive multiples of themselves.
  const double check = 1e-7;
  auto consider = [&](const VectorXd& z) {
    const LowerCandidate c = periodic_direction(map, basis, z, check);
    if (c.period > 0 && c.rate > bracket.lower) {
      bracket.lower = c.rate;
      bracket.lower_period = c.period;
    }
  };
  for (const MatrixXd& a : pieces) {
    Eigen::EigenSolver<MatrixXd> eig(a);
    for (Eigen::Index i = 0; i < eig.eigenvalues().size(); ++i) {
      if (std::abs(eig.eigenvalues()[i].imag()) > 1e-12 * std::abs(eig.eigenvalues()[i])) continue;
      const VectorXd v = eig.eigenvectors().col(i).real();
      consider(v);
      consider(-v);
    }
  }
  std::mt19937 random(12345);
  std::normal_distribution<double> normal;
  for (int k = 0; k < options.growth_directions; ++k) {
    VectorXd z(m);
    if (k < 2 * m) {
      z.setZero();
      z[k / 2] = (k % 2 == 0) ? 1.0 : -1.0;
    } else {
      for (int i = 0; i < m; ++i) z[i] = normal(random);
    }
    for (int it = 0; it < options.growth_iterations; ++it) {
      const VectorXd w = basis.transpose() * map.apply(basis * z);
      const double norm = w.norm();
      if (!(norm > 0.0) || !std::isfinite(norm)) break;
      z = w / norm;
    }
    consider(z);
  }
  // Upper: the joint spectral radius bound in several norms.
  bracket.upper = std::numeric_limits<double>::infinity();
  std::vector<MatrixXcd> frames{MatrixXcd::Identity(m, m)};
  for (const MatrixXd& a : pieces) {
    Eigen::ComplexSchur<MatrixXcd> schur(a.cast<std::complex<double>>());
    for (double t : {1.0, 1e-2, 1e-4}) {
      MatrixXcd frame = schur.matrixU();
      double scale = 1.0;
      for (int j = 0; j < m; ++j) {
        frame.col(j) *= scale;
        scale *= t;
      }
      frames.push_back(frame);
    }
  }
  // A common flag of the pieces, when they have one (a common triangular form): in it, scaled,
  // every piece's norm tends to its diagonal's largest entry, so single pieces (k = 1) bound
  // rho(L) tightly.
  {
    const MatrixXcd q = common_flag(pieces);
    for (double t : {1e-2, 1e-4, 1e-6, 1e-8}) {
      MatrixXcd frame = q;
      double scale = 1.0;
      for (int j = 0; j < m; ++j) {
        frame.col(j) *= scale;
        scale *= t;
      }
      const Eigen::FullPivLU<MatrixXcd> lu(frame);
      if (!lu.isInvertible()) continue;
      const MatrixXcd inverse = lu.inverse();
      double worst = 0.0;
      for (const MatrixXd& b : pieces) {
        worst = std::max(worst, operator_norm(inverse * b.cast<std::complex<double>>() * frame));
      }
      if (worst < bracket.upper) {
        bracket.upper = worst;
        bracket.upper_length = 1;
      }
    }
  }
  for (const MatrixXcd& frame : frames) {
    const Eigen::FullPivLU<MatrixXcd> lu(frame);
    if (!lu.isInvertible()) continue;
    const MatrixXcd inverse = lu.inverse();
    std::vector<MatrixXcd> local;
    for (const MatrixXd& a : pieces)
      local.push_back(inverse * a.cast<std::complex<double>>() * frame);
    const auto [bound, length] =
        product_bound(local, options.max_product_length, options.max_products);
    if (bound < bracket.upper) {
      bracket.upper = bound;
      bracket.upper_length = length;
    }
  }
  bracket.upper = std::max(bracket.upper, bracket.lower);
  return bracket;
}

}  // namespace bflow

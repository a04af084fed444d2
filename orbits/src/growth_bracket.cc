// The growth-rate bracket of a piecewise-linear map restricted to a subspace (periodic_orbit.h).
//
// L z = B^T DP(B z) has one linear piece per combination of the events' crossing orders, each
// active on a polyhedral cone of z (internal::cone_pieces). The lower end is the rate of a
// direction cycle L^p z = c z found on the map and then computed exactly from the product of
// the pieces along it; the upper end is the largest norm of the products of pieces that some
// direction realises, found as a tree pruned by a small linear program.
#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdint>
#include <limits>
#include <map>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Dense>

#include "bflow/core/errors.h"
#include "bflow/orbits/internal/growth_cones.h"
#include "bflow/orbits/periodic_orbit.h"

namespace bflow {
namespace {

using Eigen::MatrixXcd;
using Eigen::MatrixXd;
using Eigen::VectorXd;

// A direction is in a piece's cone when every unit row r has r . z >= -kConeTolerance |z|; the
// same slack decides whether a product is realisable. Rounding then only admits more products
// (a looser upper end) or a cycle the map itself confirms (the lower end).
constexpr double kConeTolerance = 1e-9;
// L^p z = c z must hold on the map to this relative error for a cycle to count.
constexpr double kCycleCheck = 1e-8;
// The unit roundoff.
constexpr double kUnit = std::numeric_limits<double>::epsilon() / 2.0;

// The rounding error of an m x m product of `factors` matrices formed left to right: each
// product AB is off by at most gamma_m |A| |B| entrywise (gamma_m = m u / (1 - m u), Higham,
// Accuracy and Stability, 3.5), so in the Frobenius norm by (factors - 1) gamma_m prod |M_i|_F
// to first order; 1.01 covers the higher orders while (factors - 1) m u < 0.01.
double product_error(int factors, int m, double factor_norms) {
  return 1.01 * static_cast<double>(std::max(factors - 1, 0)) * m * kUnit * factor_norms;
}

// A bound on how far the eigenvalues of an m x m matrix A (the pieces' product as computed) lie
// from the eigenvalues the eigensolver returns, given `error`, a bound on |E|_F for the backward
// error E of the eigensolver plus any error of A itself. Two bounds, the smaller taken:
//  - Bauer-Fike: the eigenvalues of A + E lie within kappa(X) |E|_2 of those of A, X the
//    eigenvectors; kappa of the computed X, doubled for its own rounding. Infinite when X is
//    numerically singular (a defective A).
//  - Henrici (Golub and Van Loan, Matrix Computations, 7.2.3): within max(theta, theta^(1/m)),
//    theta = |E|_2 sum_{j<m} |N|_2^j, N the strictly upper part of a Schur form of A
//    (|N|_F^2 = |A|_F^2 - sum |lambda|^2, taken with the rounding of the difference and |E|
//    added so that it is never underestimated).
// The root is what a defective A costs: a perturbation eps moves an m-fold eigenvalue by about
// eps^(1/m), so for a Jordan block the margin is about (u |A|)^(1/m), not u |A|.
double eigenvalue_margin(const MatrixXd& a, const Eigen::EigenSolver<MatrixXd>& eig, double error) {
  const int m = static_cast<int>(a.rows());
  const double total = a.squaredNorm();
  const double departure =
      std::sqrt(std::max(0.0, total - eig.eigenvalues().squaredNorm()) + 4.0 * m * kUnit * total) +
      error;
  double theta = 0.0;
  double power = 1.0;
  for (int j = 0; j < m; ++j) {
    theta += power;
    power *= departure;
  }
  theta *= error;
  const double henrici = std::max(theta, std::pow(theta, 1.0 / static_cast<double>(m)));
  const Eigen::JacobiSVD<MatrixXcd> svd(eig.eigenvectors());
  const Eigen::VectorXd& sigma = svd.singularValues();
  const double kappa =
      sigma[m - 1] > 0.0 ? sigma[0] / sigma[m - 1] : std::numeric_limits<double>::infinity();
  return std::min(henrici, 2.0 * kappa * error);
}

// The eigensolver's backward error for an m x m matrix (the QR algorithm's, a modest multiple of
// u |A|, Golub and Van Loan 7.5.6), taken as 4 m^2 u |A|_F.
double eigensolver_error(const MatrixXd& a) {
  return 4.0 * static_cast<double>(a.rows() * a.rows()) * kUnit * a.norm();
}

// The distinct matrices among the pieces: only equal matrices are merged. Pieces that differ by
// less than rounding still differ in L (a Jordan block perturbed by 1e-10 has eigenvalues
// 1e-5 apart), so none is dropped.
std::vector<MatrixXd> distinct_matrices(const std::vector<internal::ConePiece>& pieces) {
  std::vector<MatrixXd> out;
  for (const internal::ConePiece& piece : pieces) {
    bool seen = false;
    for (const MatrixXd& b : out) seen = seen || piece.matrix == b;
    if (!seen) out.push_back(piece.matrix);
  }
  return out;
}

// Rows scaled to unit length. A row below 1e-12 times its scale (the size of the terms it was
// formed from: rounding of a row that vanishes on the subspace) or not finite is dropped, which
// only enlarges the cone.
MatrixXd unit_rows(const MatrixXd& rows, const VectorXd& scale) {
  MatrixXd out(rows.rows(), rows.cols());
  Eigen::Index kept = 0;
  for (Eigen::Index i = 0; i < rows.rows(); ++i) {
    const double norm = rows.row(i).norm();
    if (!std::isfinite(norm) || !(norm > 1e-12 * scale[i])) continue;
    out.row(kept++) = rows.row(i) / norm;
  }
  out.conservativeResize(kept, rows.cols());
  return out;
}

// Whether z is in the closed cone {rows z >= 0}, to kConeTolerance.
bool in_cone(const MatrixXd& rows, const VectorXd& z) {
  if (rows.rows() == 0) return true;
  return (rows * z).minCoeff() >= -kConeTolerance * z.norm();
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

// ---------------------------------------------------------------------------------------------
// The upper end: the products some direction realises.
//
// Why max over realisable products bounds rho(L). Take any z and k. The pieces that L applies to
// z, L z, ..., L^{k-1} z form a product P = M_k ... M_1 with L^k z = P z, and z lies in the
// cone of that sequence (z in C_1, M_1 z in C_2, ...): P is realised by z. L^{nk} z is n such
// blocks, the j-th realised by L^{(j-1)k} z, so in any norm
//     |L^{nk} z| <= (max over realisable P of length k |P|)^n |z|,
// and lim |L^j z|^(1/j) <= (max |P|)^(1/k): a bound for every k and every norm, of which the
// least found is taken. Counting a product no direction realises only loosens it, so every
// doubt (a cone nonempty within the tolerance, an LP that does not finish) counts the product.

struct Node {
  MatrixXd product;      // P, m x m
  MatrixXd cone;         // unit rows R: P is realised by z exactly when R z >= 0
  VectorXd witness;      // a z in the cone (empty at the root)
  double factors = 1.0;  // prod |M_i|_F over P's pieces, for P's rounding error
};

// A product counted for the upper end.
struct Product {
  MatrixXd matrix;
  double factors = 1.0;  // prod |M_i|_F over its pieces
};

// The realisable products of length 1, 2, ... up to max_length. A length with more than
// max_products of them, or whose candidates (the previous length's products times the pieces)
// exceed kCandidatesPerProduct max_products, ends the list: its products would be incomplete.
constexpr double kCandidatesPerProduct = 64.0;

std::vector<std::vector<Product>> realisable_products(
    const std::vector<internal::ConePiece>& pieces, int m, int max_length, long max_products) {
  std::vector<std::vector<Product>> levels;
  std::vector<Node> level{Node{MatrixXd::Identity(m, m), MatrixXd(0, m), VectorXd(), 1.0}};
  for (int k = 1; k <= max_length; ++k) {
    if (static_cast<double>(level.size()) * static_cast<double>(pieces.size()) >
        kCandidatesPerProduct * static_cast<double>(max_products)) {
      break;
    }
    std::vector<Node> next;
    bool complete = true;
    for (const Node& node : level) {
      const double product_scale = node.product.norm();
      for (const internal::ConePiece& piece : pieces) {
        // The piece's cone pulled back through the prefix: R_piece P z >= 0.
        VectorXd scale(piece.cone.rows());
        for (Eigen::Index i = 0; i < piece.cone.rows(); ++i) scale[i] = product_scale;
        const MatrixXd rows = unit_rows(piece.cone * node.product, scale);
        Node child{MatrixXd(), MatrixXd(node.cone.rows() + rows.rows(), m), VectorXd(),
                   node.factors * piece.matrix.norm()};
        child.cone << node.cone, rows;
        bool realised = false;
        if (node.witness.size() > 0 && in_cone(rows, node.witness)) {
          realised = true;
          child.witness = node.witness;
        } else {
          realised = internal::cone_is_nontrivial(child.cone, kConeTolerance, &child.witness);
        }
        if (!realised) continue;
        child.product = piece.matrix * node.product;
        next.push_back(std::move(child));
        if (static_cast<long>(next.size()) > max_products) {
          complete = false;
          break;
        }
      }
      if (!complete) break;
    }
    if (!complete) break;
    // Every direction realises some product: none at all would be an error of the cones.
    if (next.empty()) {
      throw std::logic_error("growth_rate_bracket: no product of " + std::to_string(k) +
                             " pieces is realisable, yet every direction realises one");
    }
    std::vector<Product> products;
    products.reserve(next.size());
    for (const Node& node : next) products.push_back(Product{node.product, node.factors});
    levels.push_back(std::move(products));
    level = std::move(next);
  }
  return levels;
}

// A frame F = Q D of C^m: Q unitary (as computed), D = diag(1, t, t^2, ...), 0 < t <= 1. The
// bound uses F^-1 = D^-1 Q^H; Q^H is Q^-1 up to the rounding of Q's columns.
struct Frame {
  MatrixXcd q;
  double t = 1.0;
};

// |F^-1 P F|_2 as computed, and an upper bound on its exact value for the product of the pieces
// (P as computed is off by p_error in the Frobenius norm). The rounding of P, of Q^H P Q
// (2 gamma_m |Q|_F^2 |P|_F = 2 m^2 u |P|_F) and Q's departure from unitarity (a few m u) are
// amplified by the scaling, at most kappa(D) = t^-(m-1) (the entry (i, j) is multiplied by
// t^(j-i)); together taken as kappa(D) (p_error + 8 m^2 u |P|_F). The SVD adds m u |.|
// (backward stable), doubled.
struct FrameNorm {
  double value = 0.0;
  double bound = 0.0;
};

FrameNorm frame_norm(const Frame& frame, const MatrixXd& p, double p_error, double floor) {
  const int m = static_cast<int>(p.rows());
  MatrixXcd local = frame.q.adjoint() * p.cast<std::complex<double>>() * frame.q;
  double kappa = 1.0;
  if (frame.t != 1.0) {
    VectorXd scale(m);
    double power = 1.0;
    for (int j = 0; j < m; ++j) {
      scale[j] = power;
      power *= frame.t;
    }
    for (int j = 0; j < m; ++j) {
      for (int i = 0; i < m; ++i) local(i, j) *= scale[j] / scale[i];
    }
    kappa = 1.0 / scale[m - 1];
  }
  const double error = kappa * (p_error + 8.0 * m * m * kUnit * p.norm());
  // |A|_2 <= |A|_F: the SVD only where the Frobenius norm leaves the maximum in doubt.
  const double frobenius = local.norm();
  if (frobenius + error + 2.0 * m * kUnit * frobenius <= floor) return {0.0, 0.0};
  const double value = operator_norm(local);
  return {value, value + error + 2.0 * m * kUnit * value};
}

// The least over the lengths k of (max over the products P of length k of a bound on
// |F^-1 P F|_2)^(1/k), the length, and the same with the computed norms (no rounding margin; a
// product whose bound is below the maximum is not computed, so this may be low).
struct Bound {
  double value = std::numeric_limits<double>::infinity();  // with the rounding margin
  double computed = std::numeric_limits<double>::infinity();
  int length = 0;
};

// pow(x, 1/k) rounded up: std::pow is within a few ulps.
double root_up(double x, int k) {
  return std::pow(x, 1.0 / static_cast<double>(k)) * (1.0 + 8.0 * kUnit);
}

Bound frame_bound(const std::vector<std::vector<Product>>& levels, const Frame& frame) {
  Bound best;
  for (std::size_t k = 0; k < levels.size(); ++k) {
    const int length = static_cast<int>(k + 1);
    FrameNorm worst;
    for (const Product& product : levels[k]) {
      const int m = static_cast<int>(product.matrix.rows());
      const FrameNorm n =
          frame_norm(frame, product.matrix, product_error(length, m, product.factors), worst.bound);
      worst.value = std::max(worst.value, n.value);
      worst.bound = std::max(worst.bound, n.bound);
    }
    const double bound = root_up(worst.bound, length);
    if (bound < best.value) best = Bound{bound, std::pow(worst.value, 1.0 / length), length};
  }
  return best;
}

// ---------------------------------------------------------------------------------------------
// The lower end: direction cycles.

struct Cycle {
  double rate = 0.0;      // with the rounding margin
  double computed = 0.0;  // without
  int period = 0;
  VectorXd direction;
};

class CycleFinder {
 public:
  CycleFinder(const FlowDerivative& map, const MatrixXd& basis,
              const std::vector<internal::ConePiece>& pieces)
      : map_(map), basis_(basis), pieces_(pieces) {
    for (std::size_t i = 0; i < pieces.size(); ++i) index_[pieces[i].orders] = static_cast<int>(i);
  }

  VectorXd apply(const VectorXd& z) const { return basis_.transpose() * map_.apply(basis_ * z); }

  // The piece L applies at z (the crossing orders its tangents take).
  int active(const VectorXd& z) const {
    std::vector<std::vector<int>> orders;
    for (const CrossingOrder& o : map_.crossing_orders(basis_ * z)) orders.push_back(o.order);
    const auto it = index_.find(orders);
    BFLOW_ASSERT(it != index_.end());
    return it->second;
  }

  // Follows z for up to max_period steps. At every p where L^p z is close to a positive multiple
  // of z (a loose test: z need not be exactly periodic), the product P of the pieces active along
  // those p steps is formed, and each real eigenvalue c > 0 of P whose eigenvector v lies in the
  // closed cones of that sequence (so that L^p v = P v = c v exactly) and satisfies L^p v = c v
  // on the map is a cycle of rate c^(1/p). Returns the first p that gives one (its best rate).
  Cycle find(const VectorXd& start, int max_period) const {
    Cycle best;
    if (!(start.norm() > 0.0) || !start.allFinite()) return best;
    std::vector<VectorXd> path{start.normalized()};
    std::vector<int> active_pieces;
    for (int p = 1; p <= max_period; ++p) {
      active_pieces.push_back(active(path.back()));
      const VectorXd w = apply(path.back());
      const double norm = w.norm();
      if (!(norm > 0.0) || !std::isfinite(norm)) break;
      path.push_back(w / norm);
      if ((path.back() - path.front()).norm() > 1e-2) continue;
      best = certify(path.front(), active_pieces);
      if (best.period > 0) break;
    }
    return best;
  }

  // The rate of the cycle through the pieces `sequence` near z (see find()): c^(1/p) for the
  // eigenvalue c of their product, lowered by the eigenvalue's rounding margin.
  Cycle certify(const VectorXd& z, const std::vector<int>& sequence) const {
    Cycle best;
    const int m = static_cast<int>(z.size());
    const int p = static_cast<int>(sequence.size());
    MatrixXd product = MatrixXd::Identity(m, m);
    double factors = 1.0;
    for (int i : sequence) {
      product = pieces_[static_cast<std::size_t>(i)].matrix * product;
      factors *= pieces_[static_cast<std::size_t>(i)].matrix.norm();
    }
    const Eigen::EigenSolver<MatrixXd> eig(product);
    double margin = -1.0;  // computed once it is needed
    for (Eigen::Index e = 0; e < eig.eigenvalues().size(); ++e) {
      const std::complex<double> lambda = eig.eigenvalues()[e];
      if (!(lambda.real() > 0.0) || std::abs(lambda.imag()) > 1e-12 * std::abs(lambda)) continue;
      const double c = lambda.real();
      VectorXd v = eig.eigenvectors().col(e).real();
      if (!(v.norm() > 0.0)) continue;
      v.normalize();
      if (v.dot(z) < 0.0) v = -v;  // the sign near z first; -v is as much an eigenvector
      for (const VectorXd& u : {v, VectorXd(-v)}) {
        if (!in_cones(u, sequence)) continue;
        VectorXd w = u;
        for (int j = 0; j < p; ++j) w = apply(w);
        if (!((w - c * u).norm() <= kCycleCheck * c)) continue;
        if (margin < 0.0) {
          margin = eigenvalue_margin(product, eig,
                                     product_error(p, m, factors) + eigensolver_error(product));
        }
        const double rate = std::pow(std::max(c - margin, 0.0), 1.0 / p) * (1.0 - 8.0 * kUnit);
        if (rate > best.rate) best = Cycle{rate, std::pow(c, 1.0 / p), p, u};
        break;
      }
    }
    return best;
  }

 private:
  // Whether v, L v, ... lie in the closed cones of the pieces of `sequence` in turn.
  bool in_cones(const VectorXd& v, const std::vector<int>& sequence) const {
    VectorXd y = v;
    for (int i : sequence) {
      const internal::ConePiece& piece = pieces_[static_cast<std::size_t>(i)];
      if (!in_cone(piece.cone, y)) return false;
      y = piece.matrix * y;
    }
    return true;
  }

  const FlowDerivative& map_;
  const MatrixXd& basis_;
  const std::vector<internal::ConePiece>& pieces_;
  std::map<std::vector<std::vector<int>>, int> index_;
};

}  // namespace

// ---------------------------------------------------------------------------------------------

namespace internal {

SimplexResult simplex_from_origin(const MatrixXd& g, const VectorXd& h, const VectorXd& c,
                                  double target) {
  const Eigen::Index r = g.rows();
  const Eigen::Index n = g.cols();
  if (h.size() != r || c.size() != n || !g.allFinite() || !h.allFinite() || !c.allFinite() ||
      (r > 0 && h.minCoeff() < 0.0)) {
    throw InvalidArgument(
        "simplex_from_origin: expected G (r x n), h (r) >= 0 and c (n), finite; "
        "got G " +
        std::to_string(r) + " x " + std::to_string(n) + ", h of " + std::to_string(h.size()) +
        " (least " + format_number(r > 0 && h.size() > 0 ? h.minCoeff() : 0.0) + "), c of " +
        std::to_string(c.size()));
  }
  // Tableau [G I h; -c 0 0]: the last row holds the reduced costs and c . x.
  MatrixXd t = MatrixXd::Zero(r + 1, n + r + 1);
  t.topLeftCorner(r, n) = g;
  t.block(0, n, r, r).setIdentity();
  t.col(n + r).head(r) = h;
  t.row(r).head(n) = -c.transpose();
  std::vector<Eigen::Index> basic(static_cast<std::size_t>(r));
  for (Eigen::Index i = 0; i < r; ++i) basic[static_cast<std::size_t>(i)] = n + i;
  const double scale = 1.0 + std::max(g.size() > 0 ? g.cwiseAbs().maxCoeff() : 0.0,
                                      c.size() > 0 ? c.cwiseAbs().maxCoeff() : 0.0);
  const double pivot_tolerance = 1e-11 * scale;
  const double cost_tolerance = 1e-12 * scale;
  const int max_pivots = static_cast<int>(50 * (r + n) + 100);
  SimplexResult result;
  bool bland = false;
  int degenerate = 0;
  const auto finish = [&](SimplexResult::Status status) {
    result.status = status;
    result.value = t(r, n + r);
    result.x = VectorXd::Zero(n);
    for (Eigen::Index i = 0; i < r; ++i) {
      const Eigen::Index j = basic[static_cast<std::size_t>(i)];
      if (j < n) result.x[j] = std::max(0.0, t(i, n + r));
    }
    return result;
  };
  for (;;) {
    if (t(r, n + r) >= target) return finish(SimplexResult::Status::kTargetReached);
    if (result.pivots >= max_pivots) return finish(SimplexResult::Status::kIterationLimit);
    // Entering column: the most negative reduced cost (Dantzig), or the first one (Bland).
    Eigen::Index enter = -1;
    for (Eigen::Index j = 0; j < n + r; ++j) {
      if (t(r, j) >= -cost_tolerance) continue;
      if (enter < 0 || (!bland && t(r, j) < t(r, enter))) enter = j;
      if (bland) break;
    }
    if (enter < 0) return finish(SimplexResult::Status::kOptimal);
    // Leaving row: the least ratio; ties to the smallest basic index (Bland).
    Eigen::Index leave = -1;
    double ratio = 0.0;
    for (Eigen::Index i = 0; i < r; ++i) {
      if (t(i, enter) <= pivot_tolerance) continue;
      const double q = std::max(0.0, t(i, n + r)) / t(i, enter);
      if (leave < 0 || q < ratio ||
          (q == ratio &&
           basic[static_cast<std::size_t>(i)] < basic[static_cast<std::size_t>(leave)])) {
        leave = i;
        ratio = q;
      }
    }
    if (leave < 0) return finish(SimplexResult::Status::kUnbounded);
    degenerate = ratio > 0.0 ? 0 : degenerate + 1;
    if (degenerate > r + n) bland = true;
    t.row(leave) /= t(leave, enter);
    for (Eigen::Index i = 0; i <= r; ++i) {
      if (i != leave && t(i, enter) != 0.0) t.row(i) -= t(i, enter) * t.row(leave);
    }
    basic[static_cast<std::size_t>(leave)] = enter;
    ++result.pivots;
  }
}

// The cone {z : A z >= 0} with A injective is pointed, so it holds a z != 0 exactly when the LP
//     maximise 1 . A z  subject to  A z >= -tolerance, A z <= 1
// (z = z+ - z-, started from z = 0) reaches 1/2: a z != 0 in the cone, scaled to max(A z) = 1,
// reaches at least 1, whatever the rounding; a solution reaching 1/2 has max(A z) >= 1/(2 r)
// against entries >= -tolerance, so it lies in the cone relaxed by 2 r tolerance. With a
// (numerical) kernel any kernel vector is in the cone.
bool cone_is_nontrivial(const MatrixXd& rows, double tolerance, VectorXd* witness) {
  const Eigen::Index r = rows.rows();
  const Eigen::Index m = rows.cols();
  if (m == 0) return false;
  if (r < m) {
    if (witness != nullptr) {
      const Eigen::JacobiSVD<MatrixXd> svd(rows, Eigen::ComputeFullV);
      *witness = svd.matrixV().col(m - 1);
    }
    return true;
  }
  const Eigen::JacobiSVD<MatrixXd> svd(rows, Eigen::ComputeFullV);
  const VectorXd& sigma = svd.singularValues();
  if (!(sigma[m - 1] > 1e-9 * sigma[0])) {
    if (witness != nullptr) *witness = svd.matrixV().col(m - 1);
    return true;
  }
  MatrixXd g(2 * r, 2 * m);
  g << -rows, rows, rows, -rows;
  VectorXd h(2 * r);
  h << VectorXd::Constant(r, tolerance), VectorXd::Ones(r);
  const VectorXd column_sums = rows.transpose() * VectorXd::Ones(r);
  VectorXd c(2 * m);
  c << column_sums, -column_sums;
  const SimplexResult lp = simplex_from_origin(g, h, c, 0.5);
  const bool nontrivial = lp.status != SimplexResult::Status::kOptimal || lp.value >= 0.5;
  if (nontrivial && witness != nullptr) {
    const VectorXd z = lp.x.head(m) - lp.x.tail(m);
    *witness = z.norm() > 0.0 ? VectorXd(z.normalized()) : VectorXd();
  }
  return nontrivial;
}

std::vector<ConePiece> cone_pieces(const FlowDerivative& map, const MatrixXd& basis) {
  const std::vector<FlowPiece> flow_pieces = map.pieces();
  const std::vector<JumpMap>& jumps = map.jumps();
  const std::vector<MatrixXd>& transitions = map.transitions();
  const int events = map.events();
  // Per event, the saltation matrix and cone of each order (in the jump's own indices).
  std::vector<std::map<std::vector<int>, std::pair<MatrixXd, MatrixXd>>> cache(
      static_cast<std::size_t>(events));
  std::vector<ConePiece> out;
  out.reserve(flow_pieces.size());
  for (const FlowPiece& flow_piece : flow_pieces) {
    const MatrixXd image = flow_piece.matrix * basis;
    ConePiece piece{flow_piece.orders, basis.transpose() * image, MatrixXd(), 0.0, image.norm()};
    piece.outside = (image - basis * piece.matrix).norm();
    MatrixXd v = transitions[0] * basis;  // the tangent arriving at the event, as a map of z
    std::vector<MatrixXd> blocks;
    for (int e = 0; e < events; ++e) {
      const std::size_t ei = static_cast<std::size_t>(e);
      const std::vector<int>& surfaces = map.event_surfaces()[ei];
      std::vector<int> local;
      for (int s : flow_piece.orders[ei]) {
        local.push_back(
            static_cast<int>(std::find(surfaces.begin(), surfaces.end(), s) - surfaces.begin()));
      }
      auto it = cache[ei].find(local);
      if (it == cache[ei].end()) {
        it = cache[ei]
                 .emplace(local, std::make_pair(jumps[ei].saltation(local),
                                                crossing_order_cone(jumps[ei], local)))
                 .first;
      }
      const MatrixXd& rows = it->second.second;
      if (rows.rows() > 0) {
        VectorXd scale(rows.rows());
        for (Eigen::Index i = 0; i < rows.rows(); ++i) scale[i] = rows.row(i).norm() * v.norm();
        blocks.push_back(unit_rows(rows * v, scale));
      }
      v = transitions[ei + 1] * it->second.first * v;
    }
    Eigen::Index count = 0;
    for (const MatrixXd& b : blocks) count += b.rows();
    piece.cone.resize(count, basis.cols());
    count = 0;
    for (const MatrixXd& b : blocks) {
      piece.cone.middleRows(count, b.rows()) = b;
      count += b.rows();
    }
    out.push_back(std::move(piece));
  }
  return out;
}

void finish_bracket(GrowthBracket& bracket) {
  // Both ends bound the same number: upper < lower means one of them is wrong, and lifting upper
  // to lower would hide which.
  if (!(bracket.upper >= bracket.lower)) {
    throw std::logic_error("growth_rate_bracket: the upper end " + format_number(bracket.upper) +
                           " (products of " + std::to_string(bracket.upper_length) +
                           " pieces) is below the lower end " + format_number(bracket.lower) +
                           " (a cycle of period " + std::to_string(bracket.lower_period) +
                           "): the bracket contradicts itself");
  }
}

// The largest heap use of realisable_products(), per product allowed (max_products): every
// length's products are kept (Product: an m x m matrix, its header and the allocator's
// overhead), and while a length is built the previous length's nodes and the new ones live
// together (Node: P, the cone's rows, at most k R at length k for R rows per piece, and a
// witness: three allocations; std::vector's doubling counted as a second header), plus a copy
// of the new products.
double growth_bytes_per_product(int m, int max_length, int cone_rows) {
  constexpr double kAllocation = 32.0;  // malloc's header and rounding, per block
  const double md = m;
  const double matrix = 8.0 * md * md + kAllocation;
  const double product = static_cast<double>(sizeof(Product)) + matrix;
  const double node = 2.0 * static_cast<double>(sizeof(Node)) + matrix +
                      (8.0 * static_cast<double>(max_length) * cone_rows * md + kAllocation) +
                      (8.0 * md + kAllocation);
  return static_cast<double>(max_length) * product + 2.0 * node + product;
}

void check_growth_options(const OrbitOptions& o, int dimension, int cone_rows) {
  auto bad = [](const std::string& what) { throw InvalidArgument("OrbitOptions: " + what); };
  if (o.growth_directions < 0 || o.growth_directions > OrbitOptions::kMaxGrowthDirections)
    bad("growth_directions must be in [0, " + std::to_string(OrbitOptions::kMaxGrowthDirections) +
        "], got " + std::to_string(o.growth_directions));
  if (o.growth_iterations < 1 || o.growth_iterations > OrbitOptions::kMaxGrowthIterations)
    bad("growth_iterations must be in [1, " + std::to_string(OrbitOptions::kMaxGrowthIterations) +
        "], got " + std::to_string(o.growth_iterations));
  if (o.max_product_length < 1 || o.max_product_length > OrbitOptions::kMaxProductLength)
    bad("max_product_length must be in [1, " + std::to_string(OrbitOptions::kMaxProductLength) +
        "], got " + std::to_string(o.max_product_length));
  if (o.max_products < 1) bad("max_products must be >= 1, got " + std::to_string(o.max_products));
  const double per_product =
      growth_bytes_per_product(std::max(dimension, 1), o.max_product_length, cone_rows);
  const double bytes = per_product * static_cast<double>(o.max_products);
  if (!(bytes <= static_cast<double>(OrbitOptions::kMaxGrowthBytes))) {
    const double cap = std::floor(static_cast<double>(OrbitOptions::kMaxGrowthBytes) / per_product);
    bad("max_products = " + std::to_string(o.max_products) + " may need " +
        format_number(bytes / 1048576.0) + " MiB (" + format_number(per_product) +
        " bytes per product for " + std::to_string(std::max(dimension, 1)) +
        " directions, products of up to " + std::to_string(o.max_product_length) + " pieces, " +
        std::to_string(cone_rows) + " cone rows per piece), more than the " +
        std::to_string(OrbitOptions::kMaxGrowthBytes >> 20) + " MiB allowed; at most " +
        format_number(cap) + " fit");
  }
}

}  // namespace internal

MatrixXd crossing_order_cone(const JumpMap& jump, const std::vector<int>& sigma) {
  const int n = jump.surfaces();
  std::uint64_t seen = 0;
  bool valid = static_cast<int>(sigma.size()) == n;
  for (std::size_t k = 0; valid && k < sigma.size(); ++k) {
    const int j = sigma[k];
    valid = j >= 0 && j < n && !((seen >> j) & 1u);
    if (valid) seen |= std::uint64_t{1} << j;
  }
  if (!valid) {
    std::string text;
    for (int j : sigma) text += (text.empty() ? "" : ", ") + std::to_string(j);
    throw InvalidArgument("crossing_order_cone: order [" + text + "] is not a permutation of 0.." +
                          std::to_string(n - 1));
  }
  // [B] (6.8)-(6.9): c_j = eta_j . (the perturbation, moved along the fields crossed so far),
  // linear in dx; the next surface sigma(k) is crossed after tau_k = -c_sigma(k) / eta . F, and
  // every uncrossed c_j moves by tau_k eta_j . F. sigma is the order taken exactly when each
  // tau_k >= 0 for k >= 2 (then every uncrossed surface's own time is later as well: its c_j
  // only grows towards 0 as the taus are added).
  MatrixXd c = jump.normals();
  MatrixXd rows(std::max(n - 1, 0), jump.dim());
  Eigen::Index kept = 0;
  std::uint64_t crossed = 0;
  for (int k = 0; k < n; ++k) {
    const VectorXd g = jump.transversality(Signs(n, crossed));
    const int s = sigma[static_cast<std::size_t>(k)];
    const Eigen::RowVectorXd tau = -c.row(s) / g[s];
    if (k > 0 && tau.allFinite()) rows.row(kept++) = tau;
    for (int j = 0; j < n; ++j) {
      if (!((crossed >> j) & 1u) && j != s) c.row(j) += tau * g[j];
    }
    crossed |= std::uint64_t{1} << s;
  }
  rows.conservativeResize(kept, jump.dim());
  return rows;
}

OrbitStability classify(const GrowthBracket& bracket) {
  if (bracket.upper < 1.0) return OrbitStability::kStable;
  if (bracket.lower > 1.0) return OrbitStability::kUnstable;
  return OrbitStability::kUndecided;
}

namespace {

// rho(c L) = c rho(L), while the bracket's parts (the cones' slack, the norms' rounding, the
// power iteration's steps) work in absolute numbers that under- or overflow for pieces far from
// 1 (a map scaled by 1e-150 has products of 12 pieces of 1e-1800). With `rescale`, a map whose
// pieces' largest entry is not in [1, 2) is brought there by a power of two, which is exact, and
// the ends are scaled back.
GrowthBracket unit_bracket(const FlowDerivative& map, const MatrixXd& basis,
                           const OrbitOptions& options, bool rescale);

GrowthBracket rescaled_bracket(const FlowDerivative& map, const MatrixXd& basis,
                               const OrbitOptions& options, double size) {
  if (!std::isfinite(size)) {
    throw InvalidArgument(
        "growth_rate_bracket: a piece of the map has an entry that is not finite (its largest "
        "entry in the basis is " +
        format_number(size) + "): no growth rate can be bracketed");
  }
  const int exponent = std::ilogb(size);
  if (exponent < std::numeric_limits<double>::min_exponent) {
    throw InvalidArgument("growth_rate_bracket: the map's pieces are at most " +
                          format_number(size) +
                          " in size, below the normal double range: their growth cannot be "
                          "bracketed (scale the map)");
  }
  FlowDerivative scaled = map;
  scaled.append_transition(MatrixXd::Identity(map.dim(), map.dim()) * std::ldexp(1.0, -exponent));
  GrowthBracket b = unit_bracket(scaled, basis, options, false);
  const auto up = [exponent](double v) { return std::ldexp(v, exponent); };
  b.lower = up(b.lower);
  b.upper = up(b.upper);
  b.lower_margin = up(b.lower_margin);
  b.upper_margin = up(b.upper_margin);
  for (std::complex<double>& mu : b.multipliers) mu = {up(mu.real()), up(mu.imag())};
  return b;
}

}  // namespace

GrowthBracket growth_rate_bracket(const FlowDerivative& map, const MatrixXd& basis,
                                  const OrbitOptions& options) {
  return unit_bracket(map, basis, options, true);
}

namespace {

GrowthBracket unit_bracket(const FlowDerivative& map, const MatrixXd& basis,
                           const OrbitOptions& options, bool rescale) {
  if (basis.rows() != map.dim() || basis.cols() > basis.rows() || !basis.allFinite()) {
    throw InvalidArgument("growth_rate_bracket: the basis is " + std::to_string(basis.rows()) +
                          " x " + std::to_string(basis.cols()) + " for a map of dimension " +
                          std::to_string(map.dim()) +
                          " (expected d x m with m <= d, finite, orthonormal columns)");
  }
  const int m = static_cast<int>(basis.cols());
  if (m == 0) {
    throw InvalidArgument("growth_rate_bracket: the basis has 0 columns (a map of dimension " +
                          std::to_string(map.dim()) +
                          "): there is no direction whose growth could be bracketed");
  }
  int cone_rows = 0;
  for (const std::vector<int>& surfaces : map.event_surfaces()) {
    cone_rows += std::max(static_cast<int>(surfaces.size()) - 1, 0);
  }
  internal::check_growth_options(options, m, cone_rows);
  const double off = (basis.transpose() * basis - MatrixXd::Identity(m, m)).cwiseAbs().maxCoeff();
  if (!(off <= 1e-8)) {
    throw InvalidArgument(
        "growth_rate_bracket: the basis's columns are not orthonormal "
        "(|B^T B - I|_max = " +
        format_number(off) + ")");
  }
  const std::vector<internal::ConePiece> pieces = internal::cone_pieces(map, basis);
  // L z = B^T DP(B z) is the map's restriction to span(B) only where DP's images stay in it.
  {
    double worst = 0.0;
    std::size_t worst_piece = 0;
    for (std::size_t i = 0; i < pieces.size(); ++i) {
      const double r = pieces[i].outside / std::max(pieces[i].image_norm, 1e-300);
      if (pieces[i].image_norm > 0.0 && !(r <= worst)) {
        worst = std::isfinite(r) ? r : std::numeric_limits<double>::infinity();
        worst_piece = i;
      }
    }
    if (!(worst <= internal::kSpanTolerance)) {
      throw InvalidArgument(
          "growth_rate_bracket: the basis does not span the map's images: piece " +
          std::to_string(worst_piece) + " of " + std::to_string(pieces.size()) +
          " maps span(B) out of it by |(I - B B^T) M B|_F / |M B|_F = " + format_number(worst) +
          " (at most " + format_number(internal::kSpanTolerance) + ")");
    }
  }
  if (rescale) {
    double size = 0.0;
    for (const internal::ConePiece& piece : pieces) {
      size = std::max(size, piece.matrix.cwiseAbs().maxCoeff());
    }
    if (!std::isfinite(size) || (size > 0.0 && std::ilogb(size) != 0)) {
      return rescaled_bracket(map, basis, options, size);
    }
  }
  GrowthBracket bracket;
  const std::vector<MatrixXd> distinct = distinct_matrices(pieces);
  bracket.pieces = static_cast<int>(distinct.size());
  if (distinct.size() == 1) {
    // L is linear: its rate is the spectral radius, within the eigenvalues' rounding margin.
    const MatrixXd& a = distinct.front();
    const Eigen::EigenSolver<MatrixXd> eig(a);
    for (Eigen::Index i = 0; i < eig.eigenvalues().size(); ++i) {
      bracket.multipliers.push_back(eig.eigenvalues()[i]);
    }
    std::sort(bracket.multipliers.begin(), bracket.multipliers.end(),
              [](const std::complex<double>& x, const std::complex<double>& y) {
                return std::abs(x) > std::abs(y);
              });
    const double radius = std::abs(bracket.multipliers.front());
    const double margin = eigenvalue_margin(a, eig, eigensolver_error(a));
    bracket.lower = std::max(radius - margin, 0.0) * (1.0 - 4.0 * kUnit);
    bracket.upper = (radius + margin) * (1.0 + 4.0 * kUnit);
    bracket.lower_margin = radius - bracket.lower;
    bracket.upper_margin = bracket.upper - radius;
    bracket.lower_period = bracket.upper_length = 1;
    internal::finish_bracket(bracket);
    return bracket;
  }

  // Lower: direction cycles, from the eigenvectors of every piece and from the ends of a
  // normalised power iteration of L from many directions.
  const CycleFinder cycles(map, basis, pieces);
  double lower_computed = 0.0;
  auto consider = [&](const VectorXd& z) {
    const Cycle c = cycles.find(z, options.max_product_length);
    if (c.period > 0 && c.rate > bracket.lower) {
      bracket.lower = c.rate;
      lower_computed = c.computed;
      bracket.lower_period = c.period;
      bracket.lower_direction = c.direction;
    }
  };
  for (const MatrixXd& a : distinct) {
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
      const VectorXd w = cycles.apply(z);
      const double norm = w.norm();
      if (!(norm > 0.0) || !std::isfinite(norm)) break;
      z = w / norm;
    }
    consider(z);
  }
  bracket.lower_margin = lower_computed - bracket.lower;

  // Upper: the realisable products, in several norms.
  const std::vector<std::vector<Product>> levels =
      realisable_products(pieces, m, options.max_product_length, options.max_products);
  for (const std::vector<Product>& level : levels) {
    bracket.realisable_products.push_back(static_cast<long>(level.size()));
  }
  Bound upper;
  std::vector<Frame> frames{Frame{MatrixXcd::Identity(m, m), 1.0}};
  for (const MatrixXd& a : distinct) {
    const Eigen::ComplexSchur<MatrixXcd> schur(a.cast<std::complex<double>>());
    for (double t : {1.0, 1e-2, 1e-4}) frames.push_back(Frame{schur.matrixU(), t});
  }
  // A common flag of the pieces, when they have one (a common triangular form): in it, scaled,
  // every piece's norm tends to its diagonal's largest entry, so single pieces (k = 1: every
  // distinct piece, realisable or not) bound rho(L) tightly.
  {
    const MatrixXcd q = common_flag(distinct);
    for (double t : {1e-2, 1e-4, 1e-6, 1e-8}) {
      const Frame frame{q, t};
      FrameNorm worst;
      for (const MatrixXd& b : distinct) {
        const FrameNorm n = frame_norm(frame, b, 0.0, worst.bound);
        worst.value = std::max(worst.value, n.value);
        worst.bound = std::max(worst.bound, n.bound);
      }
      const double bound = root_up(worst.bound, 1);
      if (bound < upper.value) upper = Bound{bound, worst.value, 1};
    }
  }
  for (const Frame& frame : frames) {
    const Bound b = frame_bound(levels, frame);
    if (b.value < upper.value) upper = b;
  }
  bracket.upper = upper.value;
  bracket.upper_length = upper.length;
  bracket.upper_margin = upper.value - upper.computed;
  internal::finish_bracket(bracket);
  return bracket;
}

}  // namespace

}  // namespace bflow

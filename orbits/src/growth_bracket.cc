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
// The ends computed in floating point are moved outwards by this relative margin (products,
// norms and eigenvalues carry rounding errors of a few 1e-16 times the condition of the frames);
// a bracket that still has upper < lower is an error of bflow's, not rounding.
constexpr double kRoundingMargin = 1e-11;

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

// The distinct matrices among the pieces.
std::vector<MatrixXd> distinct_matrices(const std::vector<internal::ConePiece>& pieces) {
  std::vector<MatrixXd> out;
  for (const internal::ConePiece& piece : pieces) {
    bool seen = false;
    for (const MatrixXd& b : out) {
      if ((piece.matrix - b).norm() <= FlowDerivative::kLinearTolerance * (1.0 + b.norm())) {
        seen = true;
      }
    }
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
  MatrixXd product;  // P, m x m
  MatrixXd cone;     // unit rows R: P is realised by z exactly when R z >= 0
  VectorXd witness;  // a z in the cone (empty at the root)
};

// The realisable products of length 1, 2, ... up to max_length. A length with more than
// max_products of them, or whose candidates (the previous length's products times the pieces)
// exceed kCandidatesPerProduct max_products, ends the list: its products would be incomplete.
constexpr double kCandidatesPerProduct = 64.0;

std::vector<std::vector<MatrixXd>> realisable_products(
    const std::vector<internal::ConePiece>& pieces, int m, int max_length, long max_products) {
  std::vector<std::vector<MatrixXd>> levels;
  std::vector<Node> level{Node{MatrixXd::Identity(m, m), MatrixXd(0, m), VectorXd()}};
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
        Node child{MatrixXd(), MatrixXd(node.cone.rows() + rows.rows(), m), VectorXd()};
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
    std::vector<MatrixXd> products;
    products.reserve(next.size());
    for (const Node& node : next) products.push_back(node.product);
    levels.push_back(std::move(products));
    level = std::move(next);
  }
  return levels;
}

// min over the lengths k of (max over the products of length k of |F^-1 P F|_2)^(1/k).
std::pair<double, int> frame_bound(const std::vector<std::vector<MatrixXd>>& levels,
                                   const MatrixXcd& frame, const MatrixXcd& inverse) {
  double best = std::numeric_limits<double>::infinity();
  int best_length = 0;
  for (std::size_t k = 0; k < levels.size(); ++k) {
    double worst = 0.0;
    for (const MatrixXd& product : levels[k]) {
      const MatrixXcd local = inverse * product.cast<std::complex<double>>() * frame;
      // |A|_2 <= |A|_F: the SVD only where the Frobenius norm leaves the maximum in doubt.
      if (local.norm() <= worst) continue;
      worst = std::max(worst, operator_norm(local));
    }
    const double bound = std::pow(worst, 1.0 / static_cast<double>(k + 1));
    if (bound < best) {
      best = bound;
      best_length = static_cast<int>(k + 1);
    }
  }
  return {best, best_length};
}

// ---------------------------------------------------------------------------------------------
// The lower end: direction cycles.

struct Cycle {
  double rate = 0.0;
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

  // The exact rate of the cycle through the pieces `sequence` near z (see find()).
  Cycle certify(const VectorXd& z, const std::vector<int>& sequence) const {
    Cycle best;
    const int m = static_cast<int>(z.size());
    const int p = static_cast<int>(sequence.size());
    MatrixXd product = MatrixXd::Identity(m, m);
    for (int i : sequence) product = pieces_[static_cast<std::size_t>(i)].matrix * product;
    const Eigen::EigenSolver<MatrixXd> eig(product);
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
        const double rate = std::pow(c, 1.0 / p);
        if (rate > best.rate) best = Cycle{rate, p, u};
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
    ConePiece piece{flow_piece.orders, basis.transpose() * flow_piece.matrix * basis, MatrixXd()};
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
  bracket.lower *= 1.0 - kRoundingMargin;
  bracket.upper *= 1.0 + kRoundingMargin;
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

GrowthBracket growth_rate_bracket(const FlowDerivative& map, const MatrixXd& basis,
                                  const OrbitOptions& options) {
  check_growth_options(options);
  if (basis.rows() != map.dim() || basis.cols() > basis.rows() || !basis.allFinite()) {
    throw InvalidArgument("growth_rate_bracket: the basis is " + std::to_string(basis.rows()) +
                          " x " + std::to_string(basis.cols()) + " for a map of dimension " +
                          std::to_string(map.dim()) +
                          " (expected d x m with m <= d, finite, orthonormal columns)");
  }
  if (basis.cols() > 0) {
    const double off =
        (basis.transpose() * basis - Eigen::MatrixXd::Identity(basis.cols(), basis.cols()))
            .cwiseAbs()
            .maxCoeff();
    if (!(off <= 1e-8)) {
      throw InvalidArgument(
          "growth_rate_bracket: the basis's columns are not orthonormal "
          "(|B^T B - I|_max = " +
          format_number(off) + ")");
    }
  }
  GrowthBracket bracket;
  const int m = static_cast<int>(basis.cols());
  if (m == 0) return bracket;
  const std::vector<internal::ConePiece> pieces = internal::cone_pieces(map, basis);
  const std::vector<MatrixXd> distinct = distinct_matrices(pieces);
  bracket.pieces = static_cast<int>(distinct.size());
  if (distinct.size() == 1) {
    Eigen::EigenSolver<MatrixXd> eig(distinct.front());
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

  // Lower: direction cycles, from the eigenvectors of every piece and from the ends of a
  // normalised power iteration of L from many directions.
  const CycleFinder cycles(map, basis, pieces);
  auto consider = [&](const VectorXd& z) {
    const Cycle c = cycles.find(z, options.max_product_length);
    if (c.period > 0 && c.rate > bracket.lower) {
      bracket.lower = c.rate;
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

  // Upper: the realisable products, in several norms.
  const std::vector<std::vector<MatrixXd>> levels =
      realisable_products(pieces, m, options.max_product_length, options.max_products);
  for (const std::vector<MatrixXd>& level : levels) {
    bracket.realisable_products.push_back(static_cast<long>(level.size()));
  }
  bracket.upper = std::numeric_limits<double>::infinity();
  std::vector<MatrixXcd> frames{MatrixXcd::Identity(m, m)};
  for (const MatrixXd& a : distinct) {
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
  // every piece's norm tends to its diagonal's largest entry, so single pieces (k = 1: every
  // piece, realisable or not) bound rho(L) tightly.
  {
    const MatrixXcd q = common_flag(distinct);
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
      for (const MatrixXd& b : distinct) {
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
    const auto [bound, length] = frame_bound(levels, frame, lu.inverse());
    if (bound < bracket.upper) {
      bracket.upper = bound;
      bracket.upper_length = length;
    }
  }
  internal::finish_bracket(bracket);
  return bracket;
}

}  // namespace bflow

#include "bflow/core/triangulation.h"

#include <algorithm>
#include <limits>
#include <numeric>
#include <string>

#include <Eigen/QR>

#include "bflow/core/errors.h"
#include "bflow/core/jump_map.h"

namespace bflow {

namespace {
// Words sigma({0..k}) for k = 0..n.
std::vector<std::uint64_t> prefix_words(const std::vector<int>& sigma) {
  std::vector<std::uint64_t> words(sigma.size() + 1, 0);
  for (std::size_t k = 0; k < sigma.size(); ++k) {
    words[k + 1] = words[k] | (std::uint64_t{1} << sigma[k]);
  }
  return words;
}
}  // namespace

Triangulation::Triangulation(const Eigen::Ref<const Eigen::MatrixXd>& normals,
                             const Eigen::Ref<const Eigen::MatrixXd>& limits)
    : normals_(normals), limits_(limits) {
  const Eigen::Index n = normals.rows();
  const Eigen::Index d = normals.cols();
  if (n < 1 || n > JumpMap::kMaxEnumeratedSurfaces || n > d) {
    throw InvalidArgument("triangulation: need 1 <= n <= min(d, " +
                          std::to_string(JumpMap::kMaxEnumeratedSurfaces) +
                          "), got n = " + std::to_string(n) + ", d = " + std::to_string(d));
  }
  const Eigen::Index count = Eigen::Index{1} << n;
  if (limits.rows() != d || limits.cols() != count) {
    throw InvalidArgument("triangulation: expected a " + std::to_string(d) + " x " +
                          std::to_string(count) + " table of limits, got " +
                          std::to_string(limits.rows()) + " x " + std::to_string(limits.cols()));
  }
  // eta^T = Q R: the first n columns of Q span the row space, the rest the kernel.
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(normals.transpose());
  const Eigen::MatrixXd q = qr.householderQ();
  const Eigen::MatrixXd r = qr.matrixQR().topLeftCorner(n, n).triangularView<Eigen::Upper>();
  const Eigen::MatrixXd eta_limits = normals * limits;

  // (5.1): zeta_b = Q_n y with R^T y = rhs, rhs_j = -(eta_j . F_b) where b_j = -, else 0.
  zeta_.resize(d, count);
  for (Eigen::Index w = 0; w < count; ++w) {
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n);
    for (Eigen::Index j = 0; j < n; ++j) {
      if (!((w >> j) & 1)) rhs[j] = -eta_limits(j, w);
    }
    const Eigen::VectorXd y = r.transpose().triangularView<Eigen::Lower>().solve(rhs);
    zeta_.col(w) = q.leftCols(n) * y;
  }
  zeta_image_ = zeta_ + limits_;

  // L = ker eta + span F_-: the kernel columns of Q and the normalised rest of F_-.
  lineality_.resize(d, d - n + 1);
  lineality_.leftCols(d - n) = q.rightCols(d - n);
  Eigen::VectorXd f = limits_.col(0);
  f -= q.rightCols(d - n) * (q.rightCols(d - n).transpose() * f);
  lineality_.col(d - n) = f.normalized();

  vertex_minus_.resize(d, count);
  vertex_plus_.resize(d, count);
  const Eigen::VectorXd f_plus = limits_.col(count - 1);
  for (Eigen::Index w = 0; w < count; ++w) {
    const Eigen::VectorXd along = lineality_ * (lineality_.transpose() * zeta_.col(w));
    vertex_minus_.col(w) = zeta_.col(w) - along;
    // B(zeta_b) = zeta_b + F_b - F_+, and B is linear along L.
    vertex_plus_.col(w) = zeta_.col(w) + limits_.col(w) - f_plus - apply_linear_part(along);
  }
}

std::vector<Simplex> Triangulation::simplices() const {
  const int n = surfaces();
  std::vector<Simplex> result;
  std::vector<int> sigma(static_cast<std::size_t>(n));
  std::iota(sigma.begin(), sigma.end(), 0);
  do {
    Simplex s;
    s.order = sigma;
    for (std::uint64_t w : prefix_words(sigma)) s.words.push_back(Signs(n, w));
    result.push_back(std::move(s));
  } while (std::next_permutation(sigma.begin(), sigma.end()));
  return result;
}

Eigen::VectorXd Triangulation::apply_linear_part(
    const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  if (dx.size() != dim()) {
    throw InvalidArgument("apply_linear_part: tangent has " + std::to_string(dx.size()) +
                          " numbers, expected d = " + std::to_string(dim()));
  }
  const Eigen::VectorXd l = lineality_ * (lineality_.transpose() * dx);
  const Eigen::Index all_plus = limits_.cols() - 1;
  // l = k + a F_- with eta k = 0, so a = (eta_0 . l) / (eta_0 . F_-) and B(l) = k + a F_+.
  const double a = normals_.row(0).dot(l) / normals_.row(0).dot(limits_.col(0));
  return l + a * (limits_.col(all_plus) - limits_.col(0));
}

BarycentricEvaluation Triangulation::apply_barycentric(
    const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  if (dx.size() != dim() || !dx.allFinite()) {
    throw InvalidArgument("apply_barycentric: tangent must have d = " + std::to_string(dim()) +
                          " finite numbers, got " + format_vector(dx));
  }
  const int n = surfaces();
  BarycentricEvaluation result;
  result.image = apply_linear_part(dx);
  const Eigen::VectorXd p = dx - lineality_ * (lineality_.transpose() * dx);
  std::vector<int> sigma(static_cast<std::size_t>(n));
  std::iota(sigma.begin(), sigma.end(), 0);
  if (n == 1) {
    result.order = sigma;
    return result;
  }
  double best = -std::numeric_limits<double>::infinity();
  Eigen::MatrixXd z_minus(dim(), n - 1);
  Eigen::MatrixXd best_plus(dim(), n - 1);
  do {
    const std::vector<std::uint64_t> words = prefix_words(sigma);
    for (int k = 1; k < n; ++k) {
      z_minus.col(k - 1) = vertex_minus_.col(static_cast<Eigen::Index>(words[k]));
    }
    const Eigen::VectorXd lambda = z_minus.colPivHouseholderQr().solve(p);
    const double smallest = lambda.minCoeff();
    if (smallest > best) {
      best = smallest;
      result.order = sigma;
      result.coordinates = lambda;
      for (int k = 1; k < n; ++k) {
        best_plus.col(k - 1) = vertex_plus_.col(static_cast<Eigen::Index>(words[k]));
      }
    }
  } while (std::next_permutation(sigma.begin(), sigma.end()));
  result.image += best_plus * result.coordinates;
  return result;
}

}  // namespace bflow

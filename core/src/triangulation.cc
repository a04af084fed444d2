#include "bflow/core/triangulation.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <string>

#include <Eigen/QR>

#include "bflow/core/errors.h"
#include "bflow/core/jump_map.h"
#include "scaled_number.h"

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
  if (!limits.allFinite()) throw InvalidArgument("triangulation: the limits are not all finite");
  // Positive scaling of a normal, and of all limits together (a change of time unit), leave B
  // unchanged: normals beyond 2^+-300 and limits beyond 2^+-500 get a power-of-two scale.
  for (Eigen::Index j = 0; j < n; ++j) {
    if (!normals.row(j).allFinite() || normals.row(j).cwiseAbs().maxCoeff() == 0.0) {
      throw InvalidArgument("triangulation: normal " + std::to_string(j) +
                            " is zero or not finite: " + format_vector(normals.row(j).transpose()));
    }
    internal::rescale_row(normals_.row(j));
  }
  const double largest = limits.cwiseAbs().maxCoeff();
  if (largest > std::ldexp(1.0, kScaleThreshold) || largest < std::ldexp(1.0, -kScaleThreshold)) {
    std::frexp(largest, &scale_exponent_);
    for (Eigen::Index w = 0; w < count; ++w) {
      for (Eigen::Index i = 0; i < d; ++i) {
        limits_(i, w) = std::ldexp(limits(i, w), -scale_exponent_);
      }
    }
  }
  // eta^T = Q R: the first n columns of Q span the row space, the rest the kernel.
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(normals.transpose());
  const Eigen::MatrixXd q = qr.householderQ();
  const Eigen::MatrixXd r = qr.matrixQR().topLeftCorner(n, n).triangularView<Eigen::Upper>();
  const Eigen::MatrixXd eta_limits = normals_ * limits_;

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
    vertex_plus_.col(w) = zeta_.col(w) + limits_.col(w) - f_plus - linear_part(along);
  }
  if (!zeta_.allFinite() || !lineality_.allFinite() || !vertex_minus_.allFinite() ||
      !vertex_plus_.allFinite()) {
    throw InvalidArgument(
        "triangulation: the vertices are not finite (normals nearly rank deficient, or limits "
        "whose ratio exceeds the double range)");
  }
}

int Triangulation::tangent_exponent(const Eigen::Ref<const Eigen::VectorXd>& dx) {
  const double largest = dx.size() == 0 ? 0.0 : dx.cwiseAbs().maxCoeff();
  int e = 0;
  if (largest > std::ldexp(1.0, kScaleThreshold) || largest < std::ldexp(1.0, -kScaleThreshold)) {
    std::frexp(largest, &e);
  }
  return e;
}

Eigen::VectorXd Triangulation::linear_part(const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  const Eigen::VectorXd l = lineality_ * (lineality_.transpose() * dx);
  const Eigen::Index all_plus = limits_.cols() - 1;
  // l = k + a F_- with eta k = 0, so a = (eta_0 . l) / (eta_0 . F_-) and B(l) = k + a F_+.
  const double a = normals_.row(0).dot(l) / normals_.row(0).dot(limits_.col(0));
  return l + a * (limits_.col(all_plus) - limits_.col(0));
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
  if (dx.size() != dim() || !dx.allFinite()) {
    throw InvalidArgument("apply_linear_part: tangent must have d = " + std::to_string(dim()) +
                          " finite numbers, got " + format_vector(dx));
  }
  // B is positively homogeneous: a huge or tiny dx is scaled by a power of two and back.
  const int e = tangent_exponent(dx);
  Eigen::VectorXd image = linear_part(std::ldexp(1.0, -e) * dx);
  image *= std::ldexp(1.0, e);
  if (!image.allFinite()) {
    throw InvalidArgument("apply_linear_part: the image exceeds the double range");
  }
  return image;
}

BarycentricEvaluation Triangulation::apply_barycentric(
    const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  if (dx.size() != dim() || !dx.allFinite()) {
    throw InvalidArgument("apply_barycentric: tangent must have d = " + std::to_string(dim()) +
                          " finite numbers, got " + format_vector(dx));
  }
  const int n = surfaces();
  const int e = tangent_exponent(dx);
  const Eigen::VectorXd x = std::ldexp(1.0, -e) * dx;
  BarycentricEvaluation result;
  result.image = linear_part(x);
  const Eigen::Index all_plus = limits_.cols() - 1;
  double magnitude = x.cwiseAbs().maxCoeff() + result.image.cwiseAbs().maxCoeff() +
                     std::abs(normals_.row(0).dot(x) / normals_.row(0).dot(limits_.col(0))) *
                         (limits_.col(all_plus) - limits_.col(0)).cwiseAbs().maxCoeff();
  const Eigen::VectorXd p = x - lineality_ * (lineality_.transpose() * x);
  std::vector<int> sigma(static_cast<std::size_t>(n));
  std::iota(sigma.begin(), sigma.end(), 0);
  if (n == 1) {
    result.order = sigma;
  } else {
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
    if (result.order.empty()) {
      throw InvalidArgument(
          "apply_barycentric: no simplex holds dx (the barycentric coordinates are not finite "
          "for any order): dx = " +
          format_vector(dx));
    }
    result.image += best_plus * result.coordinates;
    for (int k = 1; k < n; ++k) {
      magnitude += std::abs(result.coordinates[k - 1]) * best_plus.col(k - 1).cwiseAbs().maxCoeff();
    }
  }
  result.image *= std::ldexp(1.0, e);
  result.error_estimate =
      16.0 * (n + dim()) * std::numeric_limits<double>::epsilon() * std::ldexp(magnitude, e);
  if (!result.image.allFinite()) {
    throw InvalidArgument("apply_barycentric: the image exceeds the double range: dx = " +
                          format_vector(dx));
  }
  return result;
}

}  // namespace bflow

// Random transversal jump data for tests and benchmarks.
//
// Normals eta are Gaussian (optionally each row scaled by 10^U(-3,3)). Limits are built so
// that eta . Gamma(b) is exactly what we ask for: Gamma(b) = P g(b) + K w(b), with P the
// pseudo-inverse of eta (so eta P = I), K the projector onto ker eta, g_j(b) = |eta_j| m_j(b)
// with m_j(b) in [0.2, 2] (or log-uniform in [1e-4, 1] when stiff) and w(b) Gaussian.
#ifndef BFLOW_TESTS_SUPPORT_RANDOM_JUMP_H_
#define BFLOW_TESTS_SUPPORT_RANDOM_JUMP_H_

#include <cmath>
#include <cstdint>
#include <random>

#include <Eigen/Core>
#include <Eigen/LU>
#include <Eigen/QR>

#include "bflow/core/field_limits.h"
#include "bflow/core/signs.h"

namespace bflow::testing {

struct JumpCaseOptions {
  bool stiff = false;           // eta_j . F_b / (|eta_j| ...) down to 1e-4
  bool scaled_normals = false;  // rows of eta scaled by 10^U(-3,3)
};

inline Eigen::VectorXd gaussian_vector(std::mt19937_64& rng, Eigen::Index size) {
  std::normal_distribution<double> normal;
  Eigen::VectorXd v(size);
  for (Eigen::Index i = 0; i < size; ++i) v[i] = normal(rng);
  return v;
}

inline Eigen::MatrixXd random_normals(std::mt19937_64& rng, int n, int d, bool scaled) {
  std::normal_distribution<double> normal;
  std::uniform_real_distribution<double> exponent(-3.0, 3.0);
  Eigen::MatrixXd eta(n, d);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < d; ++i) eta(j, i) = normal(rng);
    if (scaled) eta.row(j) *= std::pow(10.0, exponent(rng));
  }
  return eta;
}

/** Pseudo-inverse P (d x n) of full-row-rank eta and the kernel projector K (d x d). */
struct NormalFactors {
  Eigen::MatrixXd pinv;
  Eigen::MatrixXd kernel_projector;
  explicit NormalFactors(const Eigen::MatrixXd& eta) {
    const Eigen::MatrixXd gram = eta * eta.transpose();
    pinv = eta.transpose() * gram.inverse();
    kernel_projector = Eigen::MatrixXd::Identity(eta.cols(), eta.cols()) - pinv * eta;
  }
};

/** The full d x 2^n table for random normals. */
inline Eigen::MatrixXd random_limits(std::mt19937_64& rng, const Eigen::MatrixXd& eta,
                                     JumpCaseOptions options) {
  const auto n = eta.rows();
  const auto d = eta.cols();
  const NormalFactors factors(eta);
  std::uniform_real_distribution<double> uniform(0.2, 2.0);
  std::uniform_real_distribution<double> exponent(-4.0, 0.0);
  Eigen::MatrixXd limits(d, Eigen::Index{1} << n);
  for (Eigen::Index w = 0; w < limits.cols(); ++w) {
    Eigen::VectorXd g(n);
    for (Eigen::Index j = 0; j < n; ++j) {
      const double m = options.stiff ? std::pow(10.0, exponent(rng)) : uniform(rng);
      g[j] = eta.row(j).norm() * m;
    }
    limits.col(w) = factors.pinv * g + factors.kernel_projector * gaussian_vector(rng, d);
  }
  return limits;
}

/** A lazily evaluated Gamma for large n: g_j(b) from a hash of (b, j), plus a fixed kernel
    direction scaled by another hash of b. O(n d) per word. */
class HashedLimits {
 public:
  HashedLimits(std::mt19937_64& rng, const Eigen::MatrixXd& eta)
      : eta_norms_(eta.rowwise().norm()), pinv_(NormalFactors(eta).pinv) {
    const NormalFactors factors(eta);
    kernel_ = factors.kernel_projector * gaussian_vector(rng, eta.cols());
    offset_ = gaussian_vector(rng, eta.cols());
    offset_ = factors.kernel_projector * offset_;
  }
  void operator()(Signs b, Eigen::Ref<Eigen::VectorXd> out) const {
    double g[Signs::kMaxSurfaces];
    for (int j = 0; j < b.size(); ++j) g[j] = eta_norms_[j] * (0.2 + 1.8 * unit(b.bits(), j));
    out.noalias() = pinv_ * Eigen::Map<const Eigen::VectorXd>(g, b.size());
    out += offset_ + (unit(b.bits(), 99) - 0.5) * kernel_;
  }

 private:
  static double unit(std::uint64_t bits, int salt) {
    std::uint64_t z =
        bits * 0x9E3779B97F4A7C15ull + static_cast<std::uint64_t>(salt) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return static_cast<double>(z >> 11) * 0x1.0p-53;
  }
  Eigen::VectorXd eta_norms_;
  Eigen::MatrixXd pinv_;
  Eigen::VectorXd kernel_;
  Eigen::VectorXd offset_;
};

}  // namespace bflow::testing

#endif  // BFLOW_TESTS_SUPPORT_RANDOM_JUMP_H_

// Triangulation of the B-derivative ([B] Section 5): an independent representation of the
// map that JumpMap::apply evaluates by Algorithm 2.1.
//
// With rho = 0 in tangent coordinates, each word b has a point zeta_b in the row space of eta
// ([B] (5.1)):  eta_j . zeta_b = 0 if b_j = +,  eta_j . (zeta_b + F_b) = 0 if b_j = -.
// zeta_b flows in unit time to zeta_b + F_b under the sampled system, so Z- = {zeta_b} and
// Z+ = {zeta_b + F_b} ([B] (5.3)). The n-simplices are Delta_sigma = {sigma({0..k})}_{k=0..n}
// ([B] (5.5)), one per order sigma. The lineality space is L = ker eta + span F_{-...-}
// (Lemma 5.2), on which B is linear.
//
// Evaluation ([B] (6.3) + (6.5)): B(dx) = B_L(P_L dx) + Z+_sigma (Z-_sigma)^+ P_Lperp dx, where
// sigma is the simplex whose cone holds P_Lperp dx, located here by barycentric coordinates
// alone (never by the crossing order of Algorithm 2.1).
//
// Two deliberate differences from the printed formulas, both checked by tests:
//  * B on L. The printed (6.3) uses the orthogonal projection onto span F_-, which maps a
//    kernel vector k to k + (F_+ - F_-)(F_- . k)/|F_-|^2 instead of k whenever F_- is not
//    orthogonal to ker eta. We use the oblique form B_L(l) = l + (F_+ - F_-)(eta_0 . l) /
//    (eta_0 . F_-), which is exact for every l = k + a F_- in L.
//  * Vertex images. z+_b = B(z-_b) = zeta_b + F_b - F_+ - B_L(P_L zeta_b), from
//    B(zeta_b) = zeta_b + F_b - F_+ (the sampled flow of zeta_b) and linearity along L.
#ifndef BFLOW_CORE_TRIANGULATION_H_
#define BFLOW_CORE_TRIANGULATION_H_

#include <vector>

#include <Eigen/Core>

#include "bflow/core/signs.h"

namespace bflow {

/** One maximal simplex Delta_sigma: the n + 1 words sigma({0..k}), k = 0..n. */
struct Simplex {
  std::vector<int> order;
  std::vector<Signs> words;
};

/** B(dx) by barycentric coordinates, with the simplex that was used. */
struct BarycentricEvaluation {
  Eigen::VectorXd image;
  /** Order sigma of the simplex whose cone holds the L-perp part of dx. */
  std::vector<int> order;
  /** Coordinates of P_Lperp dx on z-_{sigma({0..k})}, k = 1..n-1 (all >= 0 up to rounding). */
  Eigen::VectorXd coordinates;
  /** First-order estimate of the rounding error in `image` (max norm): 16 (n + d) eps times
      the sizes of the terms summed (|dx|, the linear part, sum_k |lambda_k| |z+_k|). Large
      against |image| when the terms cancel, e.g. dx = (-1, -1e307) mapped to (-1, -1). */
  double error_estimate = 0.0;
};

class Triangulation {
 public:
  /** From normals (n x d, oriented, full rank) and the full table of limits (d x 2^n).
      Normal rows beyond 2^+-300 and limits whose largest entry lies outside
      2^-500 ... 2^500 are scaled by a power of two (scale_exponent()), which leaves B unchanged.
      @throws InvalidArgument on mismatched sizes, n > 10, a zero or non-finite normal,
      non-finite limits, or vertices that come out non-finite (nearly rank-deficient normals).
      Transversality is the JumpMap's to check; build through JumpMap::triangulation() for
      validated input. */
  Triangulation(const Eigen::Ref<const Eigen::MatrixXd>& normals,
                const Eigen::Ref<const Eigen::MatrixXd>& limits);

  int surfaces() const { return static_cast<int>(normals_.rows()); }
  int dim() const { return static_cast<int>(normals_.cols()); }

  /** The limits are used as Gamma * 2^-scale_exponent() (0 unless they are beyond 2^+-500);
      zeta() and zeta_image() are in that scale. */
  int scale_exponent() const { return scale_exponent_; }
  /** Z-: column b.bits() is zeta_b ([B] (5.1)), rho = 0. */
  const Eigen::MatrixXd& zeta() const { return zeta_; }
  /** Z+: column b.bits() is zeta_b + F_b ([B] (5.3)). */
  const Eigen::MatrixXd& zeta_image() const { return zeta_image_; }
  /** The n! simplices Delta_sigma of [B] (5.5), sigma in lexicographic order. */
  std::vector<Simplex> simplices() const;
  /** Orthonormal basis of the lineality space L, d x (d - n + 1). */
  const Eigen::MatrixXd& lineality_basis() const { return lineality_; }

  /** B restricted to L, applied to the orthogonal projection of dx onto L.
      @throws InvalidArgument on a size mismatch, non-finite dx or an image beyond the double
      range. */
  Eigen::VectorXd apply_linear_part(const Eigen::Ref<const Eigen::VectorXd>& dx) const;
  /** B(dx) through (6.3) + (6.5); the simplex is found by trying all n! cones and taking the
      one whose smallest barycentric coordinate is largest. O(n! n^2 d). A dx beyond 2^+-500 is
      scaled by a power of two and the image scaled back (B is positively homogeneous).
      @throws InvalidArgument on a size mismatch, non-finite dx, no cone with finite
      coordinates, or an image beyond the double range. */
  BarycentricEvaluation apply_barycentric(const Eigen::Ref<const Eigen::VectorXd>& dx) const;

 private:
  // Limits or tangents whose largest entry is beyond 2^+-kScaleThreshold are rescaled.
  static constexpr int kScaleThreshold = 500;
  static int tangent_exponent(const Eigen::Ref<const Eigen::VectorXd>& dx);
  Eigen::VectorXd linear_part(const Eigen::Ref<const Eigen::VectorXd>& dx) const;
  int scale_exponent_ = 0;
  Eigen::MatrixXd normals_;  // rows beyond 2^+-300 rescaled by powers of two
  Eigen::MatrixXd limits_;
  Eigen::MatrixXd zeta_;
  Eigen::MatrixXd zeta_image_;
  Eigen::MatrixXd lineality_;
  Eigen::MatrixXd vertex_minus_;  // z-_b = P_Lperp zeta_b, column b.bits()
  Eigen::MatrixXd vertex_plus_;   // z+_b = B(z-_b), column b.bits()
};

}  // namespace bflow

#endif  // BFLOW_CORE_TRIANGULATION_H_

// Butcher tableaus of the collocation methods used by FESD: Radau IIA and Gauss-Legendre with
// 1 to 9 stages, computed rather than tabulated.
//
// Nodes. Gauss-Legendre: the s roots of the shifted Legendre polynomial P_s(2c - 1), all inside
// (0, 1). Radau IIA: the s roots of P_s(2c - 1) - P_{s-1}(2c - 1), the last one c_s = 1 (so the
// end of a step is a stage point). The roots are bracketed on a fine grid and bisected in long
// double.
//
// Weights. With the nodes fixed, collocation fixes the rest: A from C(s),
//   sum_j a_ij c_j^(k-1) = c_i^k / k,  k = 1..s,
// and b from B(s), sum_j b_j c_j^(k-1) = 1 / k; both are Vandermonde solves in long double.
//
// What a tableau guarantees (tests/fesd/butcher_test.cc checks all of it):
//   Gauss-Legendre: order 2s, B(2s), C(s), D(s); Radau IIA: order 2s - 1, B(2s - 1), C(s), D(s - 1)
// (B, C, D are Butcher's simplifying assumptions). Example, Radau IIA with s = 2:
//   c = (1/3, 1), A = [5/12 -1/12; 3/4 1/4], b = (3/4, 1/4), order 3.
#ifndef BFLOW_FESD_BUTCHER_H_
#define BFLOW_FESD_BUTCHER_H_

#include <string>

#include <Eigen/Core>

namespace bflow {

enum class CollocationScheme { kRadauIIA, kGaussLegendre };

/** "radau" or "gauss". */
const char* to_string(CollocationScheme scheme);
/** Parses "radau" or "gauss". @throws InvalidArgument naming the text and the choices. */
CollocationScheme parse_collocation_scheme(const std::string& text);

struct ButcherTableau {
  CollocationScheme scheme = CollocationScheme::kRadauIIA;
  int stages = 0;
  Eigen::MatrixXd a;  ///< s x s
  Eigen::VectorXd b;  ///< s
  Eigen::VectorXd c;  ///< s, increasing
  int order = 0;      ///< classical order: 2s (Gauss-Legendre), 2s - 1 (Radau IIA)
  /** True when the last node is 1 (Radau IIA): the step's end is a stage point. */
  bool stiffly_accurate() const { return scheme == CollocationScheme::kRadauIIA; }
};

inline constexpr int kMaxCollocationStages = 9;

/** The s-stage collocation tableau. @throws InvalidArgument unless 1 <= stages <= 9. */
ButcherTableau collocation_tableau(CollocationScheme scheme, int stages);

}  // namespace bflow

#endif  // BFLOW_FESD_BUTCHER_H_

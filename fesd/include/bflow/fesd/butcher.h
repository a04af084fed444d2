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
//
//
// Two forms of the same collocation equations (CollocationForm). The integral form writes each
// stage as X_m = x_n + h sum_k A(m, k) f(X_k) and the step's end as x_{n+1} = x_n + h b^T F.
// The derivative form asks the polynomial through (0, x_n) and (c_k, X_k) to have the rate
// f(X_m) at each node; with D = A^-1 that is, row by row,
//   D_0(m) x_n + sum_k D(m, k) X_k = h f(X_m),   D_0 = -D 1
// (D is the Lagrange basis's derivative at the nodes, the form nosnoc writes), and the step's end
// is x_{n+1} = e_0 x_n + sum_k e_k X_k with e = b^T D, e_0 = 1 - sum_k e_k. Radau IIA: b is A's
// last row, so e is exactly the unit vector of X_s and e_0 = 0. Each derivative row is a
// combination of the integral rows (D times them): the same solutions, but each row reads the
// field at one stage only, so the Jacobian and the Hessian of the Lagrangian are sparser. D, D_0,
// e and e_0 are computed in long double from the same Vandermonde solves as A.
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
  Eigen::MatrixXd a;             ///< s x s
  Eigen::VectorXd b;             ///< s
  Eigen::VectorXd c;             ///< s, increasing
  int order = 0;                 ///< classical order: 2s (Gauss-Legendre), 2s - 1 (Radau IIA)
  Eigen::MatrixXd derivative;    ///< D = A^-1, s x s (the derivative form, above)
  Eigen::VectorXd derivative_0;  ///< D_0 = -D 1, s: the weight of x_n in each stage's row
  Eigen::VectorXd end;           ///< e = b^T A^-1, s: x_{n+1} = e_0 x_n + sum_k e_k X_k
  double end_0 = 0.0;            ///< e_0 = 1 - sum_k e_k (exactly 0 for Radau IIA)
  /** True when the last node is 1 (Radau IIA): the step's end is a stage point. */
  bool stiffly_accurate() const { return scheme == CollocationScheme::kRadauIIA; }
};

/** How a finite element's collocation equations are written (above): kIntegral, X = x_n 1 +
    h A F; kDerivative, D (X - x_n 1) = h F, nosnoc's form. */
enum class CollocationForm { kIntegral, kDerivative };

const char* to_string(CollocationForm form);
/** "integral" or "derivative". @throws InvalidArgument naming the text otherwise. */
CollocationForm parse_collocation_form(const std::string& text);

/** The weights of one element's collocation rows in either form: row (m, i) is
      start(m) x_n,i + sum_k state(m, k) X_k,i - h sum_k rate(m, k) f_i(X_k),
    and the end row i (where the end is an unknown of its own)
      x_{n+1},i - (end_start x_n,i + sum_k end_state(k) X_k,i) - h sum_k end_rate(k) f_i(X_k).
    Integral: state = I, start = -1, rate = A; end_start = 1, end_state = 0, end_rate = b.
    Derivative: state = D, start = D_0, rate = I; end_start = e_0, end_state = e, end_rate = 0.
    A weight that is exactly 0 is read by nobody (the rows' sparsity). */
struct CollocationRows {
  CollocationForm form = CollocationForm::kIntegral;
  Eigen::MatrixXd state;  ///< s x s
  Eigen::VectorXd start;  ///< s
  Eigen::MatrixXd rate;   ///< s x s
  double end_start = 1.0;
  Eigen::VectorXd end_state;  ///< s
  Eigen::VectorXd end_rate;   ///< s
};

CollocationRows collocation_rows(const ButcherTableau& tableau, CollocationForm form);

inline constexpr int kMaxCollocationStages = 9;

/** The s-stage collocation tableau. @throws InvalidArgument unless 1 <= stages <= 9. */
ButcherTableau collocation_tableau(CollocationScheme scheme, int stages);

}  // namespace bflow

#endif  // BFLOW_FESD_BUTCHER_H_

// Filippov systems for the FESD engine ([F] Sections 2.3-2.6 and 6.2-6.4).
//
// A piecewise-smooth system (PSS) has n_c switching functions c(x) and n_f modes f_i(x). Which
// mode holds where is a sign matrix S (rows r, n_c columns, entries -1, 0, +1) and a map from
// rows to modes: row r describes the set {x : S_rj c_j(x) > 0 for every j with S_rj != 0}, and
// mode i holds on the union of the rows mapped to it. With every entry nonzero and one row per
// mode, the rows are the 2^n_c base regions of [F] Definition 1; zeros and several rows per mode
// are the unions of [F] Section 6.2 (Table 3).
//
// Two ways to make the Filippov inclusion algebraic:
//  * Heaviside step ([F] (20)-(22)): selections a_j in gamma(c_j(x)) in [0, 1] and the convex
//    multipliers
//        theta_i(a) = sum over rows r of mode i of prod over j with S_rj != 0 of
//                     ((1 - S_rj) / 2 + S_rj a_j),
//    which are >= 0 and sum to 1 for a in [0, 1]^n_c ([F] Proposition 5; unions: Section 6.2).
//  * Stewart ([F] (25)-(28)): theta from the LP with indicator g(x) = -S c(x) ([F] (26)), which
//    needs every base region as a row (no zeros, one row per mode).
//
// Example ([F] Example 4): n_c = 2, rows (+1, 0), (-1, +1), (-1, -1), modes {0, 0, 1}: mode 0 on
// {c_1 > 0} u {c_1 < 0, c_2 > 0}, theta_0 = a_1 + (1 - a_1) a_2, theta_1 = (1 - a_1)(1 - a_2).
#ifndef BFLOW_CORE_FILIPPOV_H_
#define BFLOW_CORE_FILIPPOV_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace bflow {

/** S and the mode of each row. */
class SignMatrix {
 public:
  /** Base regions: all 2^n_c sign patterns, row r has S_rj = +1 iff bit (n_c - 1 - j) of r is 0
      (so row 0 is all +, the last row all -, as [F] (9)), one mode per row.
      @throws InvalidArgument unless 1 <= n_c <= 16. */
  static SignMatrix dense(int n_c);

  /** @throws InvalidArgument if an entry is not -1, 0 or +1, two rows describe intersecting
      sets (rows that no sign pattern tells apart), modes.size() != rows, a mode index is out of
      [0, n_f) or some mode has no row. */
  SignMatrix(Eigen::MatrixXi s, std::vector<int> mode_of_row);

  int rows() const { return static_cast<int>(s_.rows()); }
  int switches() const { return static_cast<int>(s_.cols()); }
  int modes() const { return modes_; }
  const Eigen::MatrixXi& matrix() const { return s_; }
  const std::vector<int>& mode_of_row() const { return mode_of_row_; }
  /** True when the rows are exactly the 2^n_c base regions, one per mode (Stewart applies). */
  bool is_dense() const;

  /** theta(a) of the step representation, n_f values. */
  template <typename T>
  void multipliers(const T* a, T* theta) const {
    for (int i = 0; i < modes_; ++i) theta[i] = T(0.0);
    for (int r = 0; r < rows(); ++r) {
      T term(1.0);
      for (int j = 0; j < switches(); ++j) {
        const int sign = s_(r, j);
        if (sign > 0) term *= a[j];
        if (sign < 0) term *= 1.0 - a[j];
      }
      theta[mode_of_row_[static_cast<std::size_t>(r)]] += term;
    }
  }

  /** Stewart's indicator g(x) = -S c ([F] (26)), one entry per row.
      @pre is_dense() */
  template <typename T>
  void indicator(const T* c, T* g) const {
    for (int r = 0; r < rows(); ++r) {
      T sum(0.0);
      for (int j = 0; j < switches(); ++j) sum -= double(s_(r, j)) * c[j];
      g[r] = sum;
    }
  }

  /** One factor of a lifted product: a_j, 1 - a_j or beta_k. */
  struct Factor {
    enum Kind { kAlpha, kOneMinusAlpha, kBeta } kind;
    int index;
    template <typename T>
    T value(const T* a, const T* beta) const {
      return kind == kAlpha ? a[index] : kind == kOneMinusAlpha ? T(1.0) - a[index] : beta[index];
    }
  };
  using Product = std::vector<Factor>;

  /** The lifted multipliers of [F] Algorithm 1 with depth n_d:
        beta_k = prod of beta_products[k],   theta_i = sum over rows r of mode i of
        prod of row_products[r],
      with at most n_d factors in any product. Columns are taken in order; a row is finished at
      its last nonzero column, and after column j (n_d <= j <= n_c - 1, 1-based) the
      unfinished rows that share the prefix S_{r, 1..j} share one new beta, which replaces
      their product so far. Dense S: 2^n_c - 2^n_d betas ([F] Table 4, Example 5). n_d <= 0 or
      n_d >= n_c: no betas, each row its full product (the unlifted (21)).
      @throws InvalidArgument for n_d == 1 (a product of one factor cannot be lifted). */
  struct Lifting {
    std::vector<Product> beta_products;
    std::vector<Product> row_products;
    int betas() const { return static_cast<int>(beta_products.size()); }
    /** beta from a, in order (each beta_k uses only earlier betas). */
    template <typename T>
    void betas(const T* a, T* beta) const {
      for (std::size_t k = 0; k < beta_products.size(); ++k) {
        beta[k] = product(beta_products[k], a, beta);
      }
    }
    template <typename T>
    static T product(const Product& factors, const T* a, const T* beta) {
      T value(1.0);
      for (const Factor& f : factors) value *= f.value(a, beta);
      return value;
    }
  };
  Lifting lifting(int depth) const;

  /** lifting(depth).betas(): the lifting variables of Algorithm 1. */
  int lifting_variables(int depth) const;

  /** A selection vector in row r's region (a_j = 1 where S_rj = +1, else 0): f(x, vertex)
      is mode_of_row()[r]'s field for any model of the form sum_i theta_i(a) f_i(x). */
  std::vector<double> vertex(int row) const;

 private:
  Eigen::MatrixXi s_;
  std::vector<int> mode_of_row_;
  int modes_ = 0;
};

enum class DcsFormulation { kStep, kStewart };
const char* to_string(DcsFormulation formulation);
/** "step" or "stewart". @throws InvalidArgument naming the text. */
DcsFormulation parse_dcs_formulation(const std::string& text);

/** Per-stage algebraic problem size of a DCS ([F] Table 4), in 64 bits: the closed forms grow
    like 2^n_c. */
struct DcsSize {
  std::int64_t modes = 0;            ///< n_f
  std::int64_t lifting = 0;          ///< n_beta
  std::int64_t algebraic = 0;        ///< n_alg
  std::int64_t complementarity = 0;  ///< n_comp
  std::int64_t equalities = 0;       ///< n_eq
};

/** Table 4 for S: Stewart needs is_dense(); step uses S's own n_f and lifting depth n_d
    (0 = no lifting). @throws InvalidArgument for Stewart on a non-dense S or n_d == 1. */
DcsSize dcs_size(const SignMatrix& s, DcsFormulation formulation, int lifting_depth = 0);

/** The largest n_c dcs_size_dense() takes: every size of Table 4 then fits in std::int64_t
    (Stewart's n_alg = 2^(n_c + 1) + 1 <= 2^62 + 1). */
inline constexpr int kMaxTable4Switches = 61;

/** Table 4 in closed form for the dense S of n_c switching functions (every base region a mode),
    without building S: equal to dcs_size(SignMatrix::dense(n_c), ...) where that exists
    (n_c <= 16), and defined up to kMaxTable4Switches. With n_f = 2^n_c:
      Stewart  n_alg = 2 n_f + 1, n_comp = n_f, n_eq = n_f + 1;
      step     n_beta = 2^n_c - 2^n_d (2 <= n_d < n_c, else 0), n_alg = n_f + 3 n_c + n_beta,
               n_comp = 2 n_c, n_eq = n_c + n_beta + n_f.
    E.g. n_c = 40, n_d = 2: n_beta = 1099511627772, n_alg = 2199023255668.
    @throws InvalidArgument unless 1 <= n_c <= kMaxTable4Switches, or for n_d == 1. */
DcsSize dcs_size_dense(int n_c, DcsFormulation formulation, int lifting_depth = 0);

/** The deepest lifting depth that changes the lifted step DCS of n_c switching functions:
    max(2, n_c). From n_d = n_c on every depth gives the products of theta without beta (the
    library takes any n_d >= 2 so, as n_c); the commands accept n_d up to this only. */
inline int deepest_lifting_depth(int switches) { return switches > 2 ? switches : 2; }

/** "" when n_d = `depth` is 0 (no lifting) or in [2, deepest_lifting_depth(switches)]; else the
    reason, naming `model`: "the lifting depth must be 0 (none) or in [2, 3] for irma (larger
    depths are the same as 3), got 1000000". The one bound `bflow fesd` and `bflow ocp` apply. */
std::string lifting_depth_error(int depth, int switches, const std::string& model);

}  // namespace bflow

#endif  // BFLOW_CORE_FILIPPOV_H_

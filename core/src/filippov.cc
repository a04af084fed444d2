#include "bflow/core/filippov.h"

#include <algorithm>
#include <cstdint>
#include <map>

#include "bflow/core/errors.h"

namespace bflow {

namespace {

// Two rows describe intersecting sets unless some column has opposite nonzero signs.
bool rows_intersect(const Eigen::MatrixXi& s, int r, int q) {
  for (int j = 0; j < s.cols(); ++j) {
    if (s(r, j) * s(q, j) < 0) return false;
  }
  return true;
}

std::string row_text(const Eigen::MatrixXi& s, int r) {
  std::string text = "(";
  for (int j = 0; j < s.cols(); ++j) {
    text += (j ? ", " : "") + std::to_string(s(r, j));
  }
  return text + ")";
}

}  // namespace

SignMatrix SignMatrix::dense(int n_c) {
  if (n_c < 1 || n_c > 16) {
    throw InvalidArgument("SignMatrix::dense: need 1 <= n_c <= 16 switching functions, got " +
                          std::to_string(n_c));
  }
  const int rows = 1 << n_c;
  Eigen::MatrixXi s(rows, n_c);
  std::vector<int> modes(static_cast<std::size_t>(rows));
  for (int r = 0; r < rows; ++r) {
    for (int j = 0; j < n_c; ++j) s(r, j) = ((r >> (n_c - 1 - j)) & 1) ? -1 : 1;
    modes[static_cast<std::size_t>(r)] = r;
  }
  return SignMatrix(std::move(s), std::move(modes));
}

SignMatrix::SignMatrix(Eigen::MatrixXi s, std::vector<int> mode_of_row)
    : s_(std::move(s)), mode_of_row_(std::move(mode_of_row)) {
  if (s_.rows() < 1 || s_.cols() < 1) {
    throw InvalidArgument("SignMatrix: S must have at least one row and one column, got " +
                          std::to_string(s_.rows()) + " x " + std::to_string(s_.cols()));
  }
  if (static_cast<Eigen::Index>(mode_of_row_.size()) != s_.rows()) {
    throw InvalidArgument("SignMatrix: " + std::to_string(mode_of_row_.size()) +
                          " modes given for " + std::to_string(s_.rows()) + " rows of S");
  }
  for (int r = 0; r < rows(); ++r) {
    for (int j = 0; j < switches(); ++j) {
      if (s_(r, j) < -1 || s_(r, j) > 1) {
        throw InvalidArgument("SignMatrix: entries must be -1, 0 or +1, got S(" +
                              std::to_string(r) + ", " + std::to_string(j) +
                              ") = " + std::to_string(s_(r, j)));
      }
    }
    for (int q = 0; q < r; ++q) {
      if (rows_intersect(s_, r, q)) {
        throw InvalidArgument("SignMatrix: rows " + std::to_string(q) + " " + row_text(s_, q) +
                              " and " + std::to_string(r) + " " + row_text(s_, r) +
                              " describe overlapping sets (no column has opposite signs)");
      }
    }
  }
  modes_ = 1 + *std::max_element(mode_of_row_.begin(), mode_of_row_.end());
  std::vector<bool> seen(static_cast<std::size_t>(modes_), false);
  for (int r = 0; r < rows(); ++r) {
    const int mode = mode_of_row_[static_cast<std::size_t>(r)];
    if (mode < 0) {
      throw InvalidArgument("SignMatrix: row " + std::to_string(r) + " has mode " +
                            std::to_string(mode) + " < 0");
    }
    seen[static_cast<std::size_t>(mode)] = true;
  }
  for (int i = 0; i < modes_; ++i) {
    if (!seen[static_cast<std::size_t>(i)]) {
      throw InvalidArgument("SignMatrix: mode " + std::to_string(i) + " of " +
                            std::to_string(modes_) + " has no row of S");
    }
  }
}

bool SignMatrix::is_dense() const {
  // rows() is an int: 2^n_c rows cannot exist from n_c = 31 on (and the shift would overflow).
  if (switches() >= 31 || rows() != (1 << switches()) || modes_ != rows()) return false;
  return (s_.array() != 0).all();  // no two rows overlap, so 2^n_c full rows are all patterns
}

SignMatrix::Lifting SignMatrix::lifting(int depth) const {
  if (depth == 1) {
    throw InvalidArgument("lifting depth n_d must be >= 2 (or 0 for none), got 1");
  }
  const int n_c = switches();
  const bool lift = depth >= 2 && depth < n_c;
  Lifting out;
  out.row_products.resize(static_cast<std::size_t>(rows()));
  std::vector<Product> partial(static_cast<std::size_t>(rows()));
  std::vector<bool> finished(static_cast<std::size_t>(rows()), false);
  std::vector<int> last(static_cast<std::size_t>(rows()), -1);
  for (int r = 0; r < rows(); ++r) {
    for (int j = 0; j < n_c; ++j) {
      if (s_(r, j) != 0) last[static_cast<std::size_t>(r)] = j;
    }
  }
  for (int j = 0; j < n_c; ++j) {
    for (int r = 0; r < rows(); ++r) {
      const auto ur = static_cast<std::size_t>(r);
      if (finished[ur]) continue;
      if (s_(r, j) != 0) {
        partial[ur].push_back({s_(r, j) > 0 ? Factor::kAlpha : Factor::kOneMinusAlpha, j});
      }
      if (last[ur] <= j) {
        out.row_products[ur] = partial[ur];
        finished[ur] = true;
      }
    }
    if (!lift || j + 1 < depth || j + 1 > n_c - 1) continue;
    std::map<std::vector<int>, int> beta_of_prefix;
    for (int r = 0; r < rows(); ++r) {
      const auto ur = static_cast<std::size_t>(r);
      if (finished[ur]) continue;
      std::vector<int> prefix;
      for (int k = 0; k <= j; ++k) prefix.push_back(s_(r, k));
      auto [it, fresh] = beta_of_prefix.emplace(prefix, out.betas());
      if (fresh) out.beta_products.push_back(partial[ur]);
      partial[ur] = {{Factor::kBeta, it->second}};
    }
  }
  return out;
}

int SignMatrix::lifting_variables(int depth) const { return lifting(depth).betas(); }

std::vector<double> SignMatrix::vertex(int row) const {
  std::vector<double> a(static_cast<std::size_t>(switches()));
  for (int j = 0; j < switches(); ++j) a[static_cast<std::size_t>(j)] = s_(row, j) > 0 ? 1.0 : 0.0;
  return a;
}

const char* to_string(DcsFormulation formulation) {
  return formulation == DcsFormulation::kStep ? "step" : "stewart";
}

DcsFormulation parse_dcs_formulation(const std::string& text) {
  if (text == "step") return DcsFormulation::kStep;
  if (text == "stewart") return DcsFormulation::kStewart;
  throw InvalidArgument("unknown formulation \"" + text + "\": use step or stewart");
}

DcsSize dcs_size(const SignMatrix& s, DcsFormulation formulation, int lifting_depth) {
  DcsSize size;
  const std::int64_t n_c = s.switches();
  if (formulation == DcsFormulation::kStewart) {
    if (!s.is_dense()) {
      throw InvalidArgument(
          "Stewart's reformulation needs every base region as its own mode (a dense S with "
          "2^n_c rows); this S has " +
          std::to_string(s.rows()) + " rows for " + std::to_string(n_c) +
          " switching functions and " + std::to_string(s.modes()) + " modes");
    }
    size.modes = std::int64_t{1} << n_c;
    size.algebraic = 2 * size.modes + 1;  // theta, lambda, mu
    size.complementarity = size.modes;
    size.equalities = size.modes + 1;
    return size;
  }
  size.modes = s.modes();
  size.lifting = s.lifting_variables(lifting_depth);
  size.algebraic = size.modes + 3 * n_c + size.lifting;  // theta, alpha, lambda+, lambda-, beta
  size.complementarity = 2 * n_c;
  size.equalities = n_c + size.lifting + size.modes;
  return size;
}

std::string lifting_depth_error(int depth, int switches, const std::string& model) {
  const int deepest = deepest_lifting_depth(switches);
  if (depth == 0 || (depth >= 2 && depth <= deepest)) return "";
  const std::string depths = deepest == 2 ? "2" : "in [2, " + std::to_string(deepest) + "]";
  return "the lifting depth must be 0 (none) or " + depths + " for " + model +
         " (larger depths are the same as " + std::to_string(deepest) + "), got " +
         std::to_string(depth);
}

DcsSize dcs_size_dense(int n_c, DcsFormulation formulation, int lifting_depth) {
  if (n_c < 1 || n_c > kMaxTable4Switches) {
    throw InvalidArgument("dcs_size_dense: need 1 <= n_c <= " + std::to_string(kMaxTable4Switches) +
                          " switching functions, got " + std::to_string(n_c));
  }
  if (lifting_depth == 1) {
    throw InvalidArgument("lifting depth n_d must be >= 2 (or 0 for none), got 1");
  }
  DcsSize size;
  size.modes = std::int64_t{1} << n_c;
  if (formulation == DcsFormulation::kStewart) {
    size.algebraic = 2 * size.modes + 1;
    size.complementarity = size.modes;
    size.equalities = size.modes + 1;
    return size;
  }
  // One beta per distinct prefix of length j after each column j = n_d .. n_c - 1 (1-based).
  if (lifting_depth >= 2 && lifting_depth < n_c) {
    size.lifting = size.modes - (std::int64_t{1} << lifting_depth);
  }
  size.algebraic = size.modes + 3 * std::int64_t{n_c} + size.lifting;
  size.complementarity = 2 * std::int64_t{n_c};
  size.equalities = n_c + size.lifting + size.modes;
  return size;
}

}  // namespace bflow

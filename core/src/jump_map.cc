#include "bflow/core/jump_map.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <Eigen/SVD>

#include "bflow/core/errors.h"
#include "bflow/core/triangulation.h"

namespace bflow {

namespace {

std::string word_str(int n, std::uint64_t bits) { return Signs(n, bits).str(); }

void check_normals(const Eigen::Ref<const Eigen::MatrixXd>& eta) {
  const Eigen::Index n = eta.rows();
  const Eigen::Index d = eta.cols();
  if (n < 1 || d < 1) {
    throw InvalidArgument("normals: need at least one surface and one dimension, got " +
                          std::to_string(n) + " x " + std::to_string(d));
  }
  if (n > Signs::kMaxSurfaces) {
    throw InvalidArgument("normals: n = " + std::to_string(n) +
                          " surfaces; at most 64 surfaces can meet at one event");
  }
  if (n > d) {
    throw InvalidArgument("normals: n = " + std::to_string(n) +
                          " surfaces in d = " + std::to_string(d) +
                          " dimensions; at most d surfaces can meet transversally");
  }
  for (Eigen::Index j = 0; j < n; ++j) {
    if (!eta.row(j).allFinite()) {
      throw InvalidArgument("normals: row " + std::to_string(j) +
                            " is not finite: " + format_vector(eta.row(j).transpose()));
    }
    if (eta.row(j).squaredNorm() == 0.0) {
      throw InvalidArgument("normals: row " + std::to_string(j) + " is zero");
    }
  }
  Eigen::MatrixXd unit = eta;
  for (Eigen::Index j = 0; j < n; ++j) unit.row(j).normalize();
  const Eigen::VectorXd s = Eigen::JacobiSVD<Eigen::MatrixXd>(unit).singularValues();
  if (!(s[n - 1] > JumpMap::kRankTolerance * s[0])) {
    throw InvalidArgument(
        "normals: rank deficient (the surfaces do not meet transversally); singular values "
        "of the row-normalised normals are " +
        format_vector(s) + ", smallest/largest = " + format_number(s[n - 1] / s[0]) +
        " <= " + format_number(JumpMap::kRankTolerance));
  }
}

}  // namespace

struct JumpMap::Impl {
  int n = 0;
  int d = 0;
  Eigen::MatrixXd eta;        // n x d
  Eigen::MatrixXd gamma;      // d x columns: the table, or the cache slots
  Eigen::MatrixXd eta_gamma;  // n x columns: eta * gamma, all > 0
  // Lazy source and its cache (open addressing; cleared wholesale when full).
  FieldLimitFunction function;
  std::vector<std::uint64_t> keys;
  std::vector<std::uint32_t> stamps;
  std::uint32_t generation = 1;
  int used = 0;
  int capacity = 0;
  std::uint64_t mask = 0;

  bool lazy() const { return static_cast<bool>(function); }

  void check_transversal(Eigen::Index column, std::uint64_t bits) const {
    for (int j = 0; j < n; ++j) {
      const double value = eta_gamma(j, column);
      if (!(value > 0.0)) {
        throw InvalidArgument("field_limits: surface " + std::to_string(j) +
                              " is not transversal for word \"" + word_str(n, bits) + "\": eta_" +
                              std::to_string(j) + " . F_" + word_str(n, bits) + " = " +
                              format_number(value) +
                              " (must be > 0: the flow must cross every surface from - to +)");
      }
    }
  }

  // Column of gamma / eta_gamma holding Gamma(bits). No allocation.
  Eigen::Index fetch(std::uint64_t bits) {
    if (!lazy()) return static_cast<Eigen::Index>(bits);
    for (;;) {
      std::uint64_t slot = (bits * 0x9E3779B97F4A7C15ull) >> 17 & mask;
      while (stamps[slot] == generation) {
        if (keys[slot] == bits) return static_cast<Eigen::Index>(slot);
        slot = (slot + 1) & mask;
      }
      if (used < capacity) {
        fill(static_cast<Eigen::Index>(slot), bits);
        keys[slot] = bits;
        stamps[slot] = generation;
        ++used;
        return static_cast<Eigen::Index>(slot);
      }
      used = 0;
      if (++generation == 0) {
        std::fill(stamps.begin(), stamps.end(), 0u);
        generation = 1;
      }
    }
  }

  void fill(Eigen::Index column, std::uint64_t bits) {
    const Signs b(n, bits);
    function(b, gamma.col(column));
    if (!gamma.col(column).allFinite()) {
      throw InvalidArgument("field_limits: F_" + b.str() +
                            " is not finite: " + format_vector(gamma.col(column)));
    }
    eta_gamma.col(column).noalias() = eta * gamma.col(column);
    check_transversal(column, bits);
  }

  // The full d x 2^n table (evaluating every word for a lazy source).
  Eigen::MatrixXd table() {
    if (!lazy()) return gamma;
    const Eigen::Index count = Eigen::Index{1} << n;
    Eigen::MatrixXd full(d, count);
    for (Eigen::Index w = 0; w < count; ++w) {
      full.col(w) = gamma.col(fetch(static_cast<std::uint64_t>(w)));
    }
    return full;
  }
};

JumpMap::JumpMap(const Eigen::Ref<const Eigen::MatrixXd>& normals,
                 const Eigen::Ref<const Eigen::MatrixXd>& limits)
    : impl_(std::make_unique<Impl>()) {
  check_normals(normals);
  Impl& m = *impl_;
  m.n = static_cast<int>(normals.rows());
  m.d = static_cast<int>(normals.cols());
  if (m.n > kMaxTableSurfaces) {
    throw InvalidArgument("field_limits: a table of 2^" + std::to_string(m.n) +
                          " words is too large (at most 2^" + std::to_string(kMaxTableSurfaces) +
                          "); give the limits as a function instead");
  }
  const Eigen::Index count = Eigen::Index{1} << m.n;
  if (limits.rows() != m.d || limits.cols() != count) {
    throw InvalidArgument("field_limits: expected a " + std::to_string(m.d) + " x " +
                          std::to_string(count) + " table (d x 2^n), got " +
                          std::to_string(limits.rows()) + " x " + std::to_string(limits.cols()));
  }
  for (Eigen::Index w = 0; w < count; ++w) {
    if (!limits.col(w).allFinite()) {
      throw InvalidArgument("field_limits: F_" + word_str(m.n, static_cast<std::uint64_t>(w)) +
                            " is not finite: " + format_vector(limits.col(w)));
    }
  }
  m.eta = normals;
  m.gamma = limits;
  m.eta_gamma.noalias() = m.eta * m.gamma;
  for (Eigen::Index w = 0; w < count; ++w) m.check_transversal(w, static_cast<std::uint64_t>(w));
}

JumpMap::JumpMap(const Eigen::Ref<const Eigen::MatrixXd>& normals, FieldLimitFunction limits,
                 JumpMapOptions options, LazyTag)
    : impl_(std::make_unique<Impl>()) {
  check_normals(normals);
  if (!limits) throw InvalidArgument("field_limits: the limit function is empty");
  if (options.cache_words < 0) {
    throw InvalidArgument("cache_words must be >= 0, got " + std::to_string(options.cache_words));
  }
  Impl& m = *impl_;
  m.n = static_cast<int>(normals.rows());
  m.d = static_cast<int>(normals.cols());
  m.eta = normals;
  m.function = std::move(limits);
  // n + 1 words per apply() must fit at once.
  m.capacity = std::max(options.cache_words == 0 ? 8 * (m.n + 1) : options.cache_words, m.n + 1);
  std::uint64_t slots = 1;
  while (slots < 2 * static_cast<std::uint64_t>(m.capacity)) slots <<= 1;
  m.mask = slots - 1;
  m.keys.assign(slots, 0);
  m.stamps.assign(slots, 0);
  m.gamma.setZero(m.d, static_cast<Eigen::Index>(slots));
  m.eta_gamma.setZero(m.n, static_cast<Eigen::Index>(slots));
}

JumpMap::JumpMap(const JumpMap& other) : impl_(std::make_unique<Impl>(*other.impl_)) {}
JumpMap& JumpMap::operator=(const JumpMap& other) {
  if (this != &other) impl_ = std::make_unique<Impl>(*other.impl_);
  return *this;
}
JumpMap::JumpMap(JumpMap&&) noexcept = default;
JumpMap& JumpMap::operator=(JumpMap&&) noexcept = default;
JumpMap::~JumpMap() = default;

int JumpMap::surfaces() const { return impl_->n; }
int JumpMap::dim() const { return impl_->d; }
const Eigen::MatrixXd& JumpMap::normals() const { return impl_->eta; }

Eigen::VectorXd JumpMap::limit(Signs b) const {
  if (b.size() != impl_->n) {
    throw InvalidArgument("limit: word \"" + b.str() + "\" has " + std::to_string(b.size()) +
                          " surfaces, expected " + std::to_string(impl_->n));
  }
  return impl_->gamma.col(impl_->fetch(b.bits()));
}

Eigen::VectorXd JumpMap::transversality(Signs b) const {
  if (b.size() != impl_->n) {
    throw InvalidArgument("transversality: word \"" + b.str() + "\" has " +
                          std::to_string(b.size()) + " surfaces, expected " +
                          std::to_string(impl_->n));
  }
  return impl_->eta_gamma.col(impl_->fetch(b.bits()));
}

void JumpMap::walk(const double* dx, double* out, int* order, double* times) const {
  Impl& m = *impl_;
  const int n = m.n;
  double c[Signs::kMaxSurfaces];  // eta_j . (current perturbation), j uncrossed
  Eigen::Map<const Eigen::VectorXd> x(dx, m.d);
  Eigen::Map<Eigen::VectorXd>(c, n).noalias() = m.eta * x;
  if (out != nullptr && out != dx) Eigen::Map<Eigen::VectorXd>(out, m.d) = x;

  std::uint64_t bits = 0;
  double t = 0.0;
  for (int k = 0; k < n; ++k) {
    const Eigen::Index column = m.fetch(bits);
    const double* g = m.eta_gamma.col(column).data();
    // Next surface to cross: smallest time, lowest index on exact ties.
    int next = -1;
    double tau = 0.0;
    for (int j = 0; j < n; ++j) {
      if ((bits >> j) & 1u) continue;
      const double tj = -c[j] / g[j];
      if (next < 0 || tj < tau) {
        next = j;
        tau = tj;
      }
    }
    t += tau;
    if (out != nullptr) Eigen::Map<Eigen::VectorXd>(out, m.d) += tau * m.gamma.col(column);
    for (int j = 0; j < n; ++j) {
      if (!((bits >> j) & 1u)) c[j] += tau * g[j];
    }
    c[next] = 0.0;
    bits |= std::uint64_t{1} << next;
    if (order != nullptr) order[k] = next;
    if (times != nullptr) times[k] = t;
  }
  if (out != nullptr) {
    Eigen::Map<Eigen::VectorXd>(out, m.d) -= t * m.gamma.col(m.fetch(bits));
  }
}

namespace {
void check_tangent(const char* what, const Eigen::Ref<const Eigen::VectorXd>& dx, int d) {
  if (dx.size() != d) {
    throw InvalidArgument(std::string(what) + ": tangent has " + std::to_string(dx.size()) +
                          " numbers, expected d = " + std::to_string(d));
  }
  if (!dx.allFinite()) {
    throw InvalidArgument(std::string(what) + ": tangent is not finite: " + format_vector(dx));
  }
}
}  // namespace

void JumpMap::apply(const Eigen::Ref<const Eigen::VectorXd>& dx,
                    Eigen::Ref<Eigen::VectorXd> out) const {
  check_tangent("apply", dx, impl_->d);
  if (out.size() != impl_->d) {
    throw InvalidArgument("apply: output has " + std::to_string(out.size()) +
                          " numbers, expected d = " + std::to_string(impl_->d));
  }
  walk(dx.data(), out.data(), nullptr, nullptr);
}

Eigen::VectorXd JumpMap::apply(const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  Eigen::VectorXd out(impl_->d);
  apply(dx, out);
  return out;
}

void JumpMap::apply_block(const Eigen::Ref<const Eigen::MatrixXd>& dx,
                          Eigen::Ref<Eigen::MatrixXd> out) const {
  if (dx.rows() != impl_->d || out.rows() != impl_->d || out.cols() != dx.cols()) {
    throw InvalidArgument("apply_block: expected d = " + std::to_string(impl_->d) +
                          " rows in and out and equal columns, got " + std::to_string(dx.rows()) +
                          " x " + std::to_string(dx.cols()) + " -> " + std::to_string(out.rows()) +
                          " x " + std::to_string(out.cols()));
  }
  for (Eigen::Index k = 0; k < dx.cols(); ++k) {
    check_tangent("apply_block", dx.col(k), impl_->d);
    walk(dx.col(k).data(), out.col(k).data(), nullptr, nullptr);
  }
}

Eigen::MatrixXd JumpMap::apply_block(const Eigen::Ref<const Eigen::MatrixXd>& dx) const {
  Eigen::MatrixXd out(impl_->d, dx.cols());
  apply_block(dx, out);
  return out;
}

CrossingOrder JumpMap::order(const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  check_tangent("order", dx, impl_->d);
  CrossingOrder result;
  result.order.resize(static_cast<std::size_t>(impl_->n));
  result.times.resize(static_cast<std::size_t>(impl_->n));
  walk(dx.data(), nullptr, result.order.data(), result.times.data());
  return result;
}

namespace {
// One factor of (6.4): M <- (I + v eta_j^T) M with v = (F_after - F_before) / (eta_j . F_before).
void left_multiply_factor(const Eigen::Ref<const Eigen::RowVectorXd>& eta_j,
                          const Eigen::Ref<const Eigen::VectorXd>& before,
                          const Eigen::Ref<const Eigen::VectorXd>& after, double eta_before,
                          Eigen::MatrixXd& m) {
  const Eigen::RowVectorXd w = eta_j * m;
  m.noalias() += ((after - before) / eta_before) * w;
}
}  // namespace

Eigen::MatrixXd JumpMap::saltation(const std::vector<int>& sigma) const {
  Impl& m = *impl_;
  std::uint64_t seen = 0;
  bool valid = static_cast<int>(sigma.size()) == m.n;
  for (std::size_t k = 0; valid && k < sigma.size(); ++k) {
    const int j = sigma[k];
    valid = j >= 0 && j < m.n && !((seen >> j) & 1u);
    if (valid) seen |= std::uint64_t{1} << j;
  }
  if (!valid) {
    std::string text;
    for (int j : sigma) text += (text.empty() ? "" : ", ") + std::to_string(j);
    throw InvalidArgument("saltation: order [" + text + "] is not a permutation of 0.." +
                          std::to_string(m.n - 1));
  }
  Eigen::MatrixXd result = Eigen::MatrixXd::Identity(m.d, m.d);
  std::uint64_t bits = 0;
  Eigen::VectorXd before = m.gamma.col(m.fetch(bits));
  for (int j : sigma) {
    const double eta_before = m.eta_gamma(j, m.fetch(bits));
    bits |= std::uint64_t{1} << j;
    const Eigen::VectorXd after = m.gamma.col(m.fetch(bits));
    left_multiply_factor(m.eta.row(j), before, after, eta_before, result);
    before = after;
  }
  return result;
}

Eigen::MatrixXd JumpMap::active_jacobian(const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  return saltation(order(dx).order);
}

std::vector<Piece> JumpMap::pieces() const {
  Impl& m = *impl_;
  if (m.n > kMaxEnumeratedSurfaces) {
    throw InvalidArgument(
        "pieces: n = " + std::to_string(m.n) + " surfaces give n! pieces; " +
        "enumeration is limited to n <= " + std::to_string(kMaxEnumeratedSurfaces) +
        " (use apply() or active_jacobian() for one direction)");
  }
  double count = 1;
  for (int k = 2; k <= m.n; ++k) count *= k;
  const double bytes = count * m.d * m.d * sizeof(double);
  if (bytes > static_cast<double>(kMaxPiecesBytes)) {
    throw InvalidArgument("pieces: n! = " + format_number(count) + " matrices of " +
                          std::to_string(m.d) + " x " + std::to_string(m.d) + " need " +
                          format_number(bytes) + " bytes, more than the limit of " +
                          format_number(static_cast<double>(kMaxPiecesBytes)));
  }
  const Eigen::MatrixXd table = m.table();
  const Eigen::MatrixXd eta_table = m.eta * table;
  std::vector<Piece> result;
  result.reserve(static_cast<std::size_t>(count));
  // prefix[k] is the product of the first k factors of the current order; leaves are written
  // straight into the result.
  std::vector<Eigen::MatrixXd> prefix(static_cast<std::size_t>(m.n));
  prefix[0].setIdentity(m.d, m.d);
  std::vector<int> sigma(static_cast<std::size_t>(m.n));
  Eigen::VectorXd v(m.d);
  Eigen::RowVectorXd w(m.d);
  auto descend = [&](auto&& self, int depth, std::uint64_t bits) -> void {
    const auto before = static_cast<Eigen::Index>(bits);
    const Eigen::MatrixXd& product = prefix[static_cast<std::size_t>(depth)];
    for (int j = 0; j < m.n; ++j) {
      if ((bits >> j) & 1u) continue;
      const std::uint64_t next = bits | (std::uint64_t{1} << j);
      sigma[static_cast<std::size_t>(depth)] = j;
      v = (table.col(static_cast<Eigen::Index>(next)) - table.col(before)) / eta_table(j, before);
      w.noalias() = m.eta.row(j) * product;
      if (depth + 1 == m.n) {
        result.push_back(Piece{sigma, product});
        result.back().matrix.noalias() += v * w;
      } else {
        Eigen::MatrixXd& extended = prefix[static_cast<std::size_t>(depth) + 1];
        extended = product;
        extended.noalias() += v * w;
        self(self, depth + 1, next);
      }
    }
  };
  descend(descend, 0, 0);
  return result;
}

Triangulation JumpMap::triangulation() const {
  if (impl_->n > kMaxEnumeratedSurfaces) {
    throw InvalidArgument(
        "triangulation: n = " + std::to_string(impl_->n) +
        " surfaces give n! simplices; limited to n <= " + std::to_string(kMaxEnumeratedSurfaces));
  }
  return Triangulation(impl_->eta, impl_->table());
}

}  // namespace bflow

#include "bflow/core/jump_map.h"

#include <algorithm>
#include <cstdlib>
#include <new>

#include <sys/mman.h>
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

namespace {

double factorial(int n) {
  double count = 1;
  for (int k = 2; k <= n; ++k) count *= k;
  return count;
}

// Depth-first enumeration of all orders with shared prefixes. Along the current order the
// prefix product P and the rows R = eta P (n x d) are kept per depth: a child is
// P + v_j R_j with R + (eta v_j) R_j, so a step costs d^2 + 2 n d multiply-adds. With two
// surfaces left, both leaves are written directly as rank-2 updates of P.
class PieceEnumerator {
 public:
  PieceEnumerator(const Eigen::MatrixXd& eta, const Eigen::MatrixXd& table)
      : eta_(eta),
        table_(table),
        eta_table_(eta * table),
        n_(static_cast<int>(eta.rows())),
        d_(static_cast<int>(eta.cols())),
        prefix_(static_cast<std::size_t>(n_)),
        rows_(static_cast<std::size_t>(n_)),
        sigma_(static_cast<std::size_t>(n_)),
        v_(d_),
        v_b_(d_),
        eta_v_(n_),
        w_a_(d_),
        u_(d_) {
    prefix_[0].setIdentity(d_, d_);
    rows_[0] = eta_;
  }

  // target(sigma) returns where the d x d matrix of sigma goes; done(sigma, leaf) follows.
  template <typename Target, typename Done>
  void run(Target&& target, Done&& done) {
    descend(0, 0, target, done);
  }

 private:
  // Writes (F_after - F_before) / (eta_j . F_before) for crossing j from `bits` into `v`.
  void jump_vector(int j, std::uint64_t bits, Eigen::VectorXd& v) const {
    const auto before = static_cast<Eigen::Index>(bits);
    const auto after = static_cast<Eigen::Index>(bits | (std::uint64_t{1} << j));
    v = (table_.col(after) - table_.col(before)) / eta_table_(j, before);
  }

  // leaf = P + v_a w_a^T + v_b w_b^T, column by column (vectorised axpys, no temporaries).
  void write_leaf(const Eigen::MatrixXd& product, const Eigen::VectorXd& v_a,
                  const Eigen::RowVectorXd& w_a, const Eigen::VectorXd& v_b,
                  const Eigen::RowVectorXd& w_b, double* out) const {
    Eigen::Map<Eigen::MatrixXd> leaf(out, d_, d_);
    for (int c = 0; c < d_; ++c) {
      leaf.col(c) = product.col(c) + w_a[c] * v_a + w_b[c] * v_b;
    }
  }

  template <typename Target, typename Done>
  void descend(int depth, std::uint64_t bits, Target& target, Done& done) {
    const auto k = static_cast<std::size_t>(depth);
    const Eigen::MatrixXd& product = prefix_[k];
    const Eigen::MatrixXd& rows = rows_[k];  // rows.row(j) = eta_j P
    int remaining[Signs::kMaxSurfaces];
    int r = 0;
    for (int j = 0; j < n_; ++j) {
      if (!((bits >> j) & 1u)) remaining[r++] = j;
    }
    if (r == 1) {  // n == 1
      sigma_[k] = remaining[0];
      jump_vector(remaining[0], bits, v_);
      double* out = target(sigma_);
      Eigen::Map<Eigen::MatrixXd> leaf(out, d_, d_);
      leaf.noalias() = product + v_ * rows.row(remaining[0]);
      done(sigma_, Eigen::Map<const Eigen::MatrixXd>(out, d_, d_));
      return;
    }
    if (r == 2) {
      for (int first = 0; first < 2; ++first) {
        const int a = remaining[first];
        const int b = remaining[1 - first];
        sigma_[k] = a;
        sigma_[k + 1] = b;
        jump_vector(a, bits, v_);
        jump_vector(b, bits | (std::uint64_t{1} << a), v_b_);
        // eta_b (I + v_a eta_a^T) P = eta_b P + (eta_b . v_a) eta_a P.
        w_a_ = rows.row(a);
        u_ = rows.row(b) + eta_.row(b).dot(v_) * w_a_;
        double* out = target(sigma_);
        write_leaf(product, v_, w_a_, v_b_, u_, out);
        done(sigma_, Eigen::Map<const Eigen::MatrixXd>(out, d_, d_));
      }
      return;
    }
    for (int i = 0; i < r; ++i) {
      const int j = remaining[i];
      sigma_[k] = j;
      jump_vector(j, bits, v_);
      Eigen::MatrixXd& child = prefix_[k + 1];
      child.noalias() = product + v_ * rows.row(j);
      eta_v_.noalias() = eta_ * v_;
      Eigen::MatrixXd& child_rows = rows_[k + 1];
      child_rows.noalias() = rows + eta_v_ * rows.row(j);
      descend(depth + 1, bits | (std::uint64_t{1} << j), target, done);
    }
  }

  const Eigen::MatrixXd& eta_;
  const Eigen::MatrixXd& table_;
  const Eigen::MatrixXd eta_table_;
  const int n_;
  const int d_;
  std::vector<Eigen::MatrixXd> prefix_;
  std::vector<Eigen::MatrixXd> rows_;
  std::vector<int> sigma_;
  Eigen::VectorXd v_;
  Eigen::VectorXd v_b_;
  Eigen::VectorXd eta_v_;
  Eigen::RowVectorXd w_a_;
  Eigen::RowVectorXd u_;
};

void check_enumerable(const char* what, int n) {
  if (n > JumpMap::kMaxEnumeratedSurfaces) {
    throw InvalidArgument(std::string(what) + ": n = " + std::to_string(n) +
                          " surfaces give n! pieces; enumeration is limited to n <= " +
                          std::to_string(JumpMap::kMaxEnumeratedSurfaces) +
                          " (use apply() or active_jacobian() for one direction)");
  }
}

}  // namespace

void Pieces::Free::operator()(double* p) const { std::free(p); }

Pieces::Pieces(int n, int d, std::size_t count)
    : n_(n), d_(d), count_(count), orders_(count * static_cast<std::size_t>(n)) {
  const std::size_t bytes = count * static_cast<std::size_t>(d) * d * sizeof(double);
  // Large results go on transparent huge pages where the kernel allows: faulting in 4 KiB
  // pages one at a time costs more than computing the pieces.
  constexpr std::size_t kHugePage = std::size_t{2} << 20;
  const std::size_t alignment = bytes >= 2 * kHugePage ? kHugePage : 64;
  const std::size_t rounded = (bytes + alignment - 1) / alignment * alignment;
  matrices_.reset(static_cast<double*>(
      std::aligned_alloc(alignment, std::max<std::size_t>(rounded, alignment))));
  if (!matrices_) throw std::bad_alloc();
#ifdef MADV_HUGEPAGE
  if (alignment == kHugePage) madvise(matrices_.get(), rounded, MADV_HUGEPAGE);
#endif
}

std::vector<int> Pieces::order(std::size_t i) const {
  const auto first =
      orders_.begin() + static_cast<std::ptrdiff_t>(i * static_cast<std::size_t>(n_));
  return std::vector<int>(first, first + n_);
}

Eigen::Map<const Eigen::MatrixXd> Pieces::matrix(std::size_t i) const {
  return Eigen::Map<const Eigen::MatrixXd>(
      matrices_.get() + i * static_cast<std::size_t>(d_) * static_cast<std::size_t>(d_), d_, d_);
}

Pieces JumpMap::pieces() const {
  Impl& m = *impl_;
  check_enumerable("pieces", m.n);
  const double count = factorial(m.n);
  const double bytes = count * m.d * m.d * sizeof(double);
  if (bytes > static_cast<double>(kMaxPiecesBytes)) {
    throw InvalidArgument("pieces: n! = " + format_number(count) + " matrices of " +
                          std::to_string(m.d) + " x " + std::to_string(m.d) + " need " +
                          format_number(bytes) + " bytes, more than the limit of " +
                          format_number(static_cast<double>(kMaxPiecesBytes)) +
                          " (for_each_piece() visits them without storing)");
  }
  Pieces result(m.n, m.d, static_cast<std::size_t>(count));
  const Eigen::MatrixXd table = m.table();
  PieceEnumerator enumerator(m.eta, table);
  std::size_t next = 0;
  const std::size_t stride = static_cast<std::size_t>(m.d) * static_cast<std::size_t>(m.d);
  enumerator.run(
      [&](const std::vector<int>& sigma) {
        std::copy(sigma.begin(), sigma.end(),
                  result.orders_.begin() + static_cast<std::ptrdiff_t>(next * sigma.size()));
        return result.matrices_.get() + next * stride;
      },
      [&](const std::vector<int>&, const Eigen::Map<const Eigen::MatrixXd>&) { ++next; });
  BFLOW_ASSERT(next == result.size());
  return result;
}

void JumpMap::for_each_piece(const PieceVisitor& visit) const {
  Impl& m = *impl_;
  check_enumerable("for_each_piece", m.n);
  const Eigen::MatrixXd table = m.table();
  PieceEnumerator enumerator(m.eta, table);
  Eigen::MatrixXd scratch(m.d, m.d);
  enumerator.run([&](const std::vector<int>&) { return scratch.data(); },
                 [&](const std::vector<int>& sigma,
                     const Eigen::Map<const Eigen::MatrixXd>& matrix) { visit(sigma, matrix); });
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

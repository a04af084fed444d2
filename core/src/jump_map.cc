#include "bflow/core/jump_map.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <new>
#include <stdexcept>
#include <string>

#include <sys/mman.h>

#include <Eigen/SVD>

#include "bflow/core/errors.h"
#include "bflow/core/triangulation.h"
#include "scaled_number.h"

namespace bflow {

namespace {

std::string word_str(int n, std::uint64_t bits) { return Signs(n, bits).str(); }

using internal::full_precision;
using internal::max_exponent;
using internal::scaled_dot;
using internal::ScaledNumber;

// Checks the normals and returns them, rows outside 2^-300 ... 2^300 rescaled by powers of two
// (exactly: positive scaling of a normal does not change B), with the exponents in `shifts`.
Eigen::MatrixXd working_normals(const Eigen::Ref<const Eigen::MatrixXd>& eta,
                                std::vector<int>& shifts) {
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
  Eigen::MatrixXd working = eta;
  Eigen::MatrixXd unit = eta;
  shifts.assign(static_cast<std::size_t>(n), 0);
  for (Eigen::Index j = 0; j < n; ++j) {
    if (!eta.row(j).allFinite()) {
      throw InvalidArgument("normals: row " + std::to_string(j) +
                            " is not finite: " + format_vector(eta.row(j).transpose()));
    }
    if (eta.row(j).cwiseAbs().maxCoeff() == 0.0) {
      throw InvalidArgument("normals: row " + std::to_string(j) + " is zero");
    }
    shifts[static_cast<std::size_t>(j)] = internal::rescale_row(working.row(j));
    internal::normalize_row(unit.row(j));
  }
  // One nonzero row has rank one (its singular value is 1 once normalised): no SVD.
  if (n == 1) return working;
  const Eigen::VectorXd s = Eigen::JacobiSVD<Eigen::MatrixXd>(unit).singularValues();
  if (!(s[n - 1] > JumpMap::kRankTolerance * s[0])) {
    throw InvalidArgument(
        "normals: rank deficient (the surfaces do not meet transversally); singular values "
        "of the row-normalised normals are " +
        format_vector(s) + ", smallest/largest = " + format_number(s[n - 1] / s[0]) +
        " <= " + format_number(JumpMap::kRankTolerance));
  }
  return working;
}

// "3.5", or "about 2^1100" for a value outside the double range.
std::string format_scaled(const ScaledNumber& x) {
  const double value = x.to_double();
  if (full_precision(value)) return format_number(value);
  return std::string("about ") + (x.sign() < 0 ? "-" : "") + "2^" + std::to_string(x.exponent());
}

// v = (after - before) / (eta_j . before) for a working row eta_j, the jump vector of one factor of
// (6.4); g is eta_j . before as a double. When g or the quotient leaves the double range the
// quotient is taken in scaled form, so that v is right wherever it is representable.
void jump_vector(const internal::RowRef& eta_j, const Eigen::Ref<const Eigen::VectorXd>& before,
                 const Eigen::Ref<const Eigen::VectorXd>& after, double g,
                 Eigen::Ref<Eigen::VectorXd> v) {
  if (g > 0.0 && full_precision(g)) {
    v = (after - before) / g;
    if (v.allFinite()) return;
  }
  const ScaledNumber scaled_g = scaled_dot(eta_j, before);
  for (Eigen::Index i = 0; i < v.size(); ++i) {
    const double difference = after[i] - before[i];
    const ScaledNumber numerator =
        std::isfinite(difference)
            ? ScaledNumber(difference)
            : ScaledNumber::from_parts(std::ldexp(after[i], -2) - std::ldexp(before[i], -2), 2);
    v[i] = (numerator / scaled_g).to_double();
  }
}

std::string order_text(const std::vector<int>& sigma) {
  std::string text;
  for (int j : sigma) text += (text.empty() ? "" : ", ") + std::to_string(j);
  return "[" + text + "]";
}

void check_piece(const char* what, const std::vector<int>& sigma,
                 const Eigen::Ref<const Eigen::MatrixXd>& m) {
  if (!m.allFinite()) {
    throw InvalidArgument(std::string(what) + ": M_sigma for sigma = " + order_text(sigma) +
                          " has entries beyond the double range (about 1.8e308); the field "
                          "limits differ by too much to represent this piece");
  }
}

}  // namespace

struct JumpMap::Impl {
  int n = 0;
  int d = 0;
  Eigen::MatrixXd user_eta;  // n x d, as given
  // n x d, used by every computation: the rows as given, or rescaled by 2^-shifts[j] when
  // their entries are beyond 2^+-300.
  Eigen::MatrixXd eta;
  std::vector<int> shifts;
  Eigen::MatrixXd gamma;      // d x columns: the table, or the cache slots
  Eigen::MatrixXd eta_gamma;  // n x columns: eta * gamma
  Eigen::VectorXd gamma_max;  // max |gamma| per column
  // Per column: eta_gamma left the double range or lost precision (huge or tiny limits), so
  // walks through it take the scaled path.
  std::vector<char> scaled;
  // For a table: an upper bound on |B x|_inf / |x|_inf over every piece; +inf for a lazy source
  // or a table with a word on the scaled path. Below it apply_block() cannot meet an image
  // beyond the double range, so it needs no pass that only checks.
  double growth_bound = std::numeric_limits<double>::infinity();
  // Lazy source and its cache (open addressing; cleared wholesale when full).
  FieldLimitFunction function;
  std::vector<std::uint64_t> keys;
  std::vector<std::uint32_t> stamps;
  std::uint32_t generation = 1;
  int used = 0;
  int capacity = 0;
  std::uint64_t mask = 0;

  bool lazy() const { return static_cast<bool>(function); }

  void resize_columns(Eigen::Index columns) {
    eta_gamma.setZero(n, columns);
    gamma_max.setZero(columns);
    scaled.assign(static_cast<std::size_t>(columns), 0);
  }

  // Fills eta_gamma, gamma_max and scaled for one column and checks transversality there, in
  // scaled form where the plain product over- or underflows.
  void prepare_column(Eigen::Index column, std::uint64_t bits) {
    const auto g = gamma.col(column);
    eta_gamma.col(column).noalias() = eta * g;
    gamma_max[column] = g.cwiseAbs().maxCoeff();
    bool plain = true;
    for (int j = 0; j < n; ++j) {
      const double value = eta_gamma(j, column);
      if (value > 0.0 && full_precision(value)) continue;
      plain = false;
      const ScaledNumber exact = scaled_dot(eta.row(j), g);
      if (exact.sign() <= 0) {
        throw InvalidArgument("field_limits: surface " + std::to_string(j) +
                              " is not transversal for word \"" + word_str(n, bits) + "\": eta_" +
                              std::to_string(j) + " . F_" + word_str(n, bits) + " = " +
                              format_scaled(ScaledNumber::from_parts(
                                  exact.mantissa(), static_cast<long>(exact.exponent()) +
                                                        shifts[static_cast<std::size_t>(j)])) +
                              " (must be > 0: the flow must cross every surface from - to +)");
      }
    }
    scaled[static_cast<std::size_t>(column)] = plain ? 0 : 1;
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
    prepare_column(column, bits);
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
  Impl& m = *impl_;
  m.eta = working_normals(normals, m.shifts);
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
  m.user_eta = normals;
  m.gamma = limits;
  m.resize_columns(count);
  for (Eigen::Index w = 0; w < count; ++w) m.prepare_column(w, static_cast<std::uint64_t>(w));
  // Each factor I + v eta_j^T of (6.4) has infinity norm at most 1 + |v|_inf |eta_j|_1, and
  // |v|_inf <= 2 max|Gamma| / min_b eta_j . Gamma(b) over the words b before surface j is
  // crossed; every surface is crossed once, so the product over j bounds every piece.
  if (std::none_of(m.scaled.begin(), m.scaled.end(), [](char c) { return c != 0; })) {
    const double largest = m.gamma_max.maxCoeff();
    double bound = 1.0;
    for (int j = 0; j < m.n; ++j) {
      double smallest = std::numeric_limits<double>::infinity();
      for (Eigen::Index w = 0; w < count; ++w) {
        if (!((w >> j) & 1)) smallest = std::min(smallest, m.eta_gamma(j, w));
      }
      bound *= 1.0 + 2.0 * largest * m.eta.row(j).lpNorm<1>() / smallest;
    }
    if (bound < std::numeric_limits<double>::infinity()) m.growth_bound = bound;
  }
}

JumpMap::JumpMap(const Eigen::Ref<const Eigen::MatrixXd>& normals, FieldLimitFunction limits,
                 JumpMapOptions options, LazyTag)
    : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.eta = working_normals(normals, m.shifts);
  if (!limits) throw InvalidArgument("field_limits: the limit function is empty");
  if (options.cache_words < 0) {
    throw InvalidArgument("cache_words must be >= 0, got " + std::to_string(options.cache_words));
  }
  m.n = static_cast<int>(normals.rows());
  m.d = static_cast<int>(normals.cols());
  m.user_eta = normals;
  m.function = std::move(limits);
  // n + 1 words per apply() must fit at once.
  m.capacity = std::max(options.cache_words == 0 ? 8 * (m.n + 1) : options.cache_words, m.n + 1);
  std::uint64_t slots = 1;
  while (slots < 2 * static_cast<std::uint64_t>(m.capacity)) slots <<= 1;
  m.mask = slots - 1;
  m.keys.assign(slots, 0);
  m.stamps.assign(slots, 0);
  m.gamma.setZero(m.d, static_cast<Eigen::Index>(slots));
  m.resize_columns(static_cast<Eigen::Index>(slots));
}

JumpMap::JumpMap(const JumpMap& other)
    : impl_(other.impl_ ? std::make_unique<Impl>(*other.impl_) : nullptr) {}
JumpMap& JumpMap::operator=(const JumpMap& other) {
  if (this != &other) impl_ = other.impl_ ? std::make_unique<Impl>(*other.impl_) : nullptr;
  return *this;
}
JumpMap::JumpMap(JumpMap&&) noexcept = default;
JumpMap& JumpMap::operator=(JumpMap&&) noexcept = default;
JumpMap::~JumpMap() = default;

JumpMap::Impl& JumpMap::impl() const {
  if (!impl_) {
    throw std::logic_error(
        "JumpMap: this object was moved from; assign a JumpMap to it before using it");
  }
  return *impl_;
}

int JumpMap::surfaces() const { return impl().n; }
int JumpMap::dim() const { return impl().d; }
const Eigen::MatrixXd& JumpMap::normals() const { return impl().user_eta; }

Eigen::VectorXd JumpMap::limit(Signs b) const {
  Impl& m = impl();
  if (b.size() != m.n) {
    throw InvalidArgument("limit: word \"" + b.str() + "\" has " + std::to_string(b.size()) +
                          " surfaces, expected " + std::to_string(m.n));
  }
  return m.gamma.col(m.fetch(b.bits()));
}

Eigen::VectorXd JumpMap::transversality(Signs b) const {
  Impl& m = impl();
  if (b.size() != m.n) {
    throw InvalidArgument("transversality: word \"" + b.str() + "\" has " +
                          std::to_string(b.size()) + " surfaces, expected " + std::to_string(m.n));
  }
  const Eigen::Index column = m.fetch(b.bits());
  Eigen::VectorXd out(m.n);
  for (int j = 0; j < m.n; ++j) {
    const ScaledNumber value = scaled_dot(m.eta.row(j), m.gamma.col(column));
    out[j] = ScaledNumber::from_parts(value.mantissa(), static_cast<long>(value.exponent()) +
                                                            m.shifts[static_cast<std::size_t>(j)])
                 .to_double();
  }
  return out;
}

bool JumpMap::walk(const double* dx, double* out, int* order, double* times) const {
  Impl& m = *impl_;
  const int n = m.n;
  double c[Signs::kMaxSurfaces];  // eta_j . (current perturbation), j uncrossed
  double tau_k[Signs::kMaxSurfaces];
  int order_k[Signs::kMaxSurfaces];
  Eigen::Index columns[Signs::kMaxSurfaces + 1];
  Eigen::Map<const Eigen::VectorXd> x(dx, m.d);
  Eigen::Map<Eigen::VectorXd>(c, n).noalias() = m.eta * x;
  for (int j = 0; j < n; ++j) {
    if (!full_precision(c[j])) return false;
  }
  const std::uint32_t generation = m.generation;
  // Bound on every partial sum of the image: below it no sum can overflow.
  double bound = x.cwiseAbs().maxCoeff();
  std::uint64_t bits = 0;
  double t = 0.0;
  for (int k = 0; k < n; ++k) {
    const Eigen::Index column = m.fetch(bits);
    if (m.scaled[static_cast<std::size_t>(column)]) return false;
    columns[k] = column;
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
    // A subnormal time (fields near 1e308) has lost its relative precision.
    if (!full_precision(tau)) return false;
    t += tau;
    bound += std::abs(tau) * m.gamma_max[column];
    for (int j = 0; j < n; ++j) {
      if (!((bits >> j) & 1u)) c[j] += tau * g[j];
    }
    c[next] = 0.0;
    bits |= std::uint64_t{1} << next;
    tau_k[k] = tau;
    order_k[k] = next;
    if (order != nullptr) order[k] = next;
    if (times != nullptr) times[k] = t;
  }
  columns[n] = m.fetch(bits);
  if (m.scaled[static_cast<std::size_t>(columns[n])]) return false;
  bound += std::abs(t) * m.gamma_max[columns[n]];
  if (!std::isfinite(t) || !(bound < 0.25 * std::numeric_limits<double>::max())) return false;
  if (out == nullptr) return true;
  // The image is formed only once the walk has succeeded, so that a fallback finds `out` (and
  // dx, which it may alias) untouched. A full lazy cache may have been cleared during the walk:
  // then the columns are looked up again (the limits are deterministic, so they refill
  // identically).
  Eigen::Map<Eigen::VectorXd> image(out, m.d);
  const bool refetch = generation != m.generation;
  bits = 0;
  for (int k = 0; k < n; ++k) {
    const auto gamma_k = m.gamma.col(refetch ? m.fetch(bits) : columns[k]);
    if (k == 0 && out != dx) {
      image = x + tau_k[0] * gamma_k;  // the copy of dx fused with the first term
    } else {
      image += tau_k[k] * gamma_k;
    }
    bits |= std::uint64_t{1} << order_k[k];
  }
  columns[n] = refetch ? m.fetch(bits) : columns[n];
  image -= t * m.gamma.col(columns[n]);
  return true;
}

void JumpMap::walk_scaled(const char* what, const double* dx, double* out, int* order,
                          double* times, bool check_image) const {
  Impl& m = *impl_;
  const int n = m.n;
  ScaledNumber c[Signs::kMaxSurfaces];
  ScaledNumber g[Signs::kMaxSurfaces];
  ScaledNumber tau_k[Signs::kMaxSurfaces];
  std::uint64_t words[Signs::kMaxSurfaces + 1];
  const Eigen::Map<const Eigen::VectorXd> x(dx, m.d);
  for (int j = 0; j < n; ++j) c[j] = scaled_dot(m.eta.row(j), x);
  std::uint64_t bits = 0;
  ScaledNumber t;
  for (int k = 0; k < n; ++k) {
    words[k] = bits;
    const Eigen::Index column = m.fetch(bits);
    int next = -1;
    ScaledNumber tau;
    for (int j = 0; j < n; ++j) {
      if ((bits >> j) & 1u) continue;
      g[j] = scaled_dot(m.eta.row(j), m.gamma.col(column));
      const ScaledNumber tj = -c[j] / g[j];
      if (next < 0 || tj < tau) {
        next = j;
        tau = tj;
      }
    }
    t = t + tau;
    for (int j = 0; j < n; ++j) {
      if (!((bits >> j) & 1u)) c[j] = c[j] + tau * g[j];
    }
    c[next] = ScaledNumber();
    bits |= std::uint64_t{1} << next;
    tau_k[k] = tau;
    if (order != nullptr) order[k] = next;
    if (times != nullptr) {
      times[k] = t.to_double();
      if (!std::isfinite(times[k])) {
        throw InvalidArgument(std::string(what) + ": the crossing time of surface " +
                              std::to_string(next) + " is " + format_scaled(t) +
                              ", beyond the double range (dx is huge against the field limits)");
      }
    }
  }
  words[n] = bits;
  if (out == nullptr && !check_image) return;
  // Component i of the image is x_i + sum_k tau_k Gamma(b_k)_i - t Gamma(b_n)_i. All are checked
  // before any is written, so that dx (which out may alias) survives a refusal.
  const auto component = [&](Eigen::Index i) {
    ScaledNumber sum(x[i]);
    for (int k = 0; k < n; ++k) {
      sum = sum + tau_k[k] * ScaledNumber(m.gamma(i, m.fetch(words[k])));
    }
    return sum - t * ScaledNumber(m.gamma(i, m.fetch(words[n])));
  };
  for (Eigen::Index i = 0; i < m.d; ++i) {
    const ScaledNumber value = component(i);
    if (!std::isfinite(value.to_double())) {
      throw InvalidArgument(std::string(what) + ": component " + std::to_string(i) +
                            " of B(dx) is " + format_scaled(value) +
                            ", beyond the double range (about 1.8e308)");
    }
  }
  if (out == nullptr) return;
  for (Eigen::Index i = 0; i < m.d; ++i) out[i] = component(i).to_double();
}

namespace {

// floor(a / b) for b > 0.
std::int64_t floor_div(std::int64_t a, std::int64_t b) { return a / b - (a % b < 0 ? 1 : 0); }

// Whether two column-major blocks of `rows` x `cols` doubles, at `a` and `b` with outer strides
// `stride_a` and `stride_b` (in doubles), share a byte. O(1) when their address ranges are
// disjoint, else O(cols): blocks of one matrix that interleave (its top and bottom rows) do not
// overlap.
bool blocks_overlap(const double* a, Eigen::Index stride_a, const double* b, Eigen::Index stride_b,
                    Eigen::Index rows, Eigen::Index cols) {
  if (rows == 0 || cols == 0) return false;
  constexpr auto kSize = static_cast<std::int64_t>(sizeof(double));
  const auto pa = static_cast<std::int64_t>(reinterpret_cast<std::uintptr_t>(a));
  const auto pb = static_cast<std::int64_t>(reinterpret_cast<std::uintptr_t>(b));
  const std::int64_t length = rows * kSize;
  const std::int64_t step_a = stride_a * kSize;
  const std::int64_t step_b = stride_b * kSize;
  const std::int64_t end_a = pa + (cols - 1) * step_a + length;
  const std::int64_t end_b = pb + (cols - 1) * step_b + length;
  if (end_a <= pb || end_b <= pa) return false;
  // Columns of a that overlap one another cover one range, which meets b.
  if (step_a < length || cols == 1) return true;
  for (Eigen::Index c = 0; c < cols; ++c) {
    // Column j of a, [pa + j step_a, + length), meets [lo, lo + length) when
    // lo - length < pa + j step_a < lo + length: the smallest such j is j0.
    const std::int64_t lo = pb + c * step_b;
    const std::int64_t j0 = std::max<std::int64_t>(0, floor_div(lo - length - pa, step_a) + 1);
    if (j0 < cols && pa + j0 * step_a < lo + length) return true;
  }
  return false;
}

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
  const Impl& m = impl();
  check_tangent("apply", dx, m.d);
  if (out.size() != m.d) {
    throw InvalidArgument("apply: output has " + std::to_string(out.size()) +
                          " numbers, expected d = " + std::to_string(m.d));
  }
  if (out.data() != dx.data() && blocks_overlap(dx.data(), m.d, out.data(), m.d, m.d, 1)) {
    throw InvalidArgument(
        "apply: the output overlaps the tangent without being the same vector (its first number "
        "is number " +
        std::to_string(out.data() - dx.data()) +
        " of the tangent); pass one vector as both to map in place, or separate vectors");
  }
  if (!walk(dx.data(), out.data(), nullptr, nullptr)) {
    walk_scaled("apply", dx.data(), out.data(), nullptr, nullptr);
  }
}

Eigen::VectorXd JumpMap::apply(const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  Eigen::VectorXd out(impl().d);
  apply(dx, out);
  return out;
}

void JumpMap::apply_block(const Eigen::Ref<const Eigen::MatrixXd>& dx,
                          Eigen::Ref<Eigen::MatrixXd> out) const {
  const Impl& m = impl();
  if (dx.rows() != m.d || out.rows() != m.d || out.cols() != dx.cols()) {
    throw InvalidArgument("apply_block: expected d = " + std::to_string(m.d) +
                          " rows in and out and equal columns, got " + std::to_string(dx.rows()) +
                          " x " + std::to_string(dx.cols()) + " -> " + std::to_string(out.rows()) +
                          " x " + std::to_string(out.cols()));
  }
  if (out.cols() > 1 && out.outerStride() < out.rows()) {
    throw InvalidArgument("apply_block: the output's columns overlap one another (outer stride " +
                          std::to_string(out.outerStride()) + " < " + std::to_string(out.rows()) +
                          " rows)");
  }
  const bool in_place = out.data() == dx.data() && out.outerStride() == dx.outerStride();
  if (!in_place &&
      blocks_overlap(dx.data(), dx.outerStride(), out.data(), out.outerStride(), m.d, dx.cols())) {
    throw InvalidArgument(
        "apply_block: the output overlaps the tangents without being the same block (outer "
        "strides " +
        std::to_string(out.outerStride()) + " and " + std::to_string(dx.outerStride()) +
        ", first numbers " + std::to_string(out.data() - dx.data()) +
        " apart); pass one block as both to map in place, or separate blocks");
  }
  // Everything that can refuse the block is checked before a column is written, so that a
  // refusal leaves `out` (and dx, which it may alias) as it was: the numbers first, in one
  // vectorised pass (a sum of magnitudes, NaN or inf when a number is not finite, or when finite
  // numbers near the top of the range add up beyond it) ...
  const double total = dx.cwiseAbs().sum();
  if (!(total <= std::numeric_limits<double>::max())) {
    for (Eigen::Index k = 0; k < dx.cols(); ++k) {
      if (!dx.col(k).allFinite()) {
        throw InvalidArgument("apply_block: tangent is not finite in column " + std::to_string(k) +
                              " of " + std::to_string(dx.cols()) + ": " + format_vector(dx.col(k)));
      }
    }
  }
  // ... then images beyond the double range and, for a lazy source, words that break
  // transversality: a walk per column that writes nothing, unless the growth bound of a table
  // times the sum (at least the largest |dx|) rules both out (the common case, at no cost).
  if (!(total * m.growth_bound < 0.125 * std::numeric_limits<double>::max())) {
    for (Eigen::Index k = 0; k < dx.cols(); ++k) {
      if (!walk(dx.col(k).data(), nullptr, nullptr, nullptr)) {
        const std::string what = "apply_block: column " + std::to_string(k);
        walk_scaled(what.c_str(), dx.col(k).data(), nullptr, nullptr, nullptr, true);
      }
    }
  }
  Eigen::Index first = 0;
  if (m.n == 1) first = apply_linear_block(dx, out);
  for (Eigen::Index k = first; k < dx.cols(); ++k) {
    if (!walk(dx.col(k).data(), out.col(k).data(), nullptr, nullptr)) {
      walk_scaled("apply_block", dx.col(k).data(), out.col(k).data(), nullptr, nullptr);
    }
  }
}

Eigen::Index JumpMap::apply_linear_block(const Eigen::Ref<const Eigen::MatrixXd>& dx,
                                         Eigen::Ref<Eigen::MatrixXd> out) const {
  // One surface: B is linear (the saltation matrix), B x = x + tau (Gamma(-) - Gamma(+)) with
  // tau = -(eta x) / (eta Gamma(-)), the walk of one crossing. A chunk of columns takes two
  // passes over the block instead of a walk per column: eta X, then the two rank-one updates,
  // in the walk's order of operations (the tangents are finite: apply_block checked them). A
  // chunk with a number the walk would send to its scaled path (not of full precision, an image
  // near overflow) is left to the walks, from its first column on: the return value.
  Impl& m = *impl_;
  const Eigen::Index minus = m.fetch(0);
  const Eigen::Index plus = m.fetch(1);
  if (m.scaled[static_cast<std::size_t>(minus)] || m.scaled[static_cast<std::size_t>(plus)]) {
    return 0;
  }
  const double g = m.eta_gamma(0, minus);
  const double growth = m.gamma_max[minus] + m.gamma_max[plus];
  constexpr Eigen::Index kChunk = 128;
  double taus[kChunk];
  Eigen::Index start = 0;
  for (; start < dx.cols(); start += kChunk) {
    const Eigen::Index width = std::min(kChunk, dx.cols() - start);
    const auto x = dx.middleCols(start, width);
    Eigen::Map<Eigen::RowVectorXd> tau(taus, width);
    tau.noalias() = m.eta.row(0) * x;
    for (Eigen::Index k = 0; k < width; ++k) {
      const double c = taus[k];
      taus[k] = -c / g;
      const double bound = x.col(k).cwiseAbs().maxCoeff() + std::abs(taus[k]) * growth;
      if (!full_precision(c) || !full_precision(taus[k]) ||
          !(bound < 0.25 * std::numeric_limits<double>::max())) {
        return start;
      }
    }
    auto image = out.middleCols(start, width);
    image = x;
    image.noalias() += m.gamma.col(minus) * tau;
    image.noalias() -= m.gamma.col(plus) * tau;
  }
  return start;
}

Eigen::MatrixXd JumpMap::apply_block(const Eigen::Ref<const Eigen::MatrixXd>& dx) const {
  Eigen::MatrixXd out(impl().d, dx.cols());
  apply_block(dx, out);
  return out;
}

CrossingOrder JumpMap::order(const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  const Impl& m = impl();
  check_tangent("order", dx, m.d);
  CrossingOrder result;
  result.order.resize(static_cast<std::size_t>(m.n));
  result.times.resize(static_cast<std::size_t>(m.n));
  if (!walk(dx.data(), nullptr, result.order.data(), result.times.data())) {
    walk_scaled("order", dx.data(), nullptr, result.order.data(), result.times.data());
  }
  return result;
}

Eigen::MatrixXd JumpMap::saltation(const std::vector<int>& sigma) const {
  Impl& m = impl();
  std::uint64_t seen = 0;
  bool valid = static_cast<int>(sigma.size()) == m.n;
  for (std::size_t k = 0; valid && k < sigma.size(); ++k) {
    const int j = sigma[k];
    valid = j >= 0 && j < m.n && !((seen >> j) & 1u);
    if (valid) seen |= std::uint64_t{1} << j;
  }
  if (!valid) {
    throw InvalidArgument("saltation: order " + order_text(sigma) + " is not a permutation of 0.." +
                          std::to_string(m.n - 1));
  }
  // One factor of (6.4) per crossing: M <- (I + v eta_j^T) M, v = (F_after - F_before) /
  // (eta_j . F_before).
  Eigen::MatrixXd result = Eigen::MatrixXd::Identity(m.d, m.d);
  std::uint64_t bits = 0;
  Eigen::VectorXd before = m.gamma.col(m.fetch(bits));
  Eigen::VectorXd v(m.d);
  for (int j : sigma) {
    const double eta_before = m.eta_gamma(j, m.fetch(bits));
    bits |= std::uint64_t{1} << j;
    const Eigen::VectorXd after = m.gamma.col(m.fetch(bits));
    jump_vector(m.eta.row(j), before, after, eta_before, v);
    const Eigen::RowVectorXd w = m.eta.row(j) * result;
    result.noalias() += v * w;
    before = after;
  }
  check_piece("saltation", sigma, result);
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
    bflow::jump_vector(eta_.row(j), table_.col(before), table_.col(after), eta_table_(j, before),
                       v);
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

// Whether some piece could leave the double range. Each factor I + v eta_j^T of (6.4) has
// infinity norm at most 1 + |v|_inf |eta_j|_1, so n factors of at most `largest` each bound every
// entry of every piece; below 1e300 no leaf needs checking (the common case, at no cost per
// piece). n 2^(n-1) jump vectors, far fewer than the n! d^2 entries of the pieces.
bool pieces_may_overflow(const Eigen::MatrixXd& eta, const Eigen::MatrixXd& table) {
  const int n = static_cast<int>(eta.rows());
  const Eigen::MatrixXd eta_table = eta * table;
  Eigen::VectorXd v(eta.cols());
  double largest = 1.0;
  for (Eigen::Index w = 0; w < table.cols(); ++w) {
    for (int j = 0; j < n; ++j) {
      if ((w >> j) & 1) continue;
      jump_vector(eta.row(j), table.col(w), table.col(w | (Eigen::Index{1} << j)), eta_table(j, w),
                  v);
      largest = std::max(largest, 1.0 + v.lpNorm<Eigen::Infinity>() * eta.row(j).lpNorm<1>());
    }
  }
  return !(std::pow(largest, n) < 1e300);
}

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
  Impl& m = impl();
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
  const bool check = pieces_may_overflow(m.eta, table);
  std::size_t next = 0;
  const std::size_t stride = static_cast<std::size_t>(m.d) * static_cast<std::size_t>(m.d);
  enumerator.run(
      [&](const std::vector<int>& sigma) {
        std::copy(sigma.begin(), sigma.end(),
                  result.orders_.begin() + static_cast<std::ptrdiff_t>(next * sigma.size()));
        return result.matrices_.get() + next * stride;
      },
      [&](const std::vector<int>& sigma, const Eigen::Map<const Eigen::MatrixXd>& matrix) {
        if (check) check_piece("pieces", sigma, matrix);
        ++next;
      });
  BFLOW_ASSERT(next == result.size());
  return result;
}

void JumpMap::for_each_piece(const PieceVisitor& visit) const {
  Impl& m = impl();
  check_enumerable("for_each_piece", m.n);
  const Eigen::MatrixXd table = m.table();
  PieceEnumerator enumerator(m.eta, table);
  const bool check = pieces_may_overflow(m.eta, table);
  Eigen::MatrixXd scratch(m.d, m.d);
  enumerator.run(
      [&](const std::vector<int>&) { return scratch.data(); },
      [&](const std::vector<int>& sigma, const Eigen::Map<const Eigen::MatrixXd>& matrix) {
        if (check) check_piece("for_each_piece", sigma, matrix);
        visit(sigma, matrix);
      });
}

Triangulation JumpMap::triangulation() const {
  Impl& m = impl();
  if (m.n > kMaxEnumeratedSurfaces) {
    throw InvalidArgument(
        "triangulation: n = " + std::to_string(m.n) +
        " surfaces give n! simplices; limited to n <= " + std::to_string(kMaxEnumeratedSurfaces));
  }
  return Triangulation(m.eta, m.table());
}

}  // namespace bflow

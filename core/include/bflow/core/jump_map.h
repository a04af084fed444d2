// JumpMap: the B-derivative B of the flow across a point rho where n switching surfaces meet
// ([B] Sections 2.3, 5, 6).
//
// Inputs at rho: normals eta (n x d, rows eta_j, full row rank), oriented so that
// eta_j . Gamma(b) > 0 for every surface j and every word b, and the field limits
// Gamma(b) = F_b(rho) (see field_limits.h). The tangent dx = delta rho^- is a perturbation
// before the event; B(dx) = delta rho^+ is the perturbation after it, both at time 0.
//
// Worked example, the piecewise-constant field of [B] (3.1)-(3.2) with d = n = 2 and
// Delta(b) = -delta * b: every Gamma(b) = 1 - delta * b, eta = I, and B = (1-delta)/(1+delta) I.
//
//   Eigen::MatrixXd eta = Eigen::MatrixXd::Identity(2, 2);
//   Eigen::MatrixXd limits(2, 4);                     // column b.bits() is Gamma(b)
//   for (int w = 0; w < 4; ++w)
//     for (int i = 0; i < 2; ++i) limits(i, w) = ((w >> i) & 1) ? 1 - delta : 1 + delta;
//   bflow::JumpMap jump(eta, limits);
//   Eigen::VectorXd image = jump.apply(dx);           // == (1-delta)/(1+delta) * dx
//   bflow::CrossingOrder o = jump.order(dx);          // which surface is crossed first
//   Eigen::MatrixXd m = jump.active_jacobian(dx);     // M_sigma for that order
//
// Exact ties. When two surfaces would be crossed at the same time, the lower index is taken
// first. B is continuous, so the value of apply() is the same either way; only the reported
// order (and so active_jacobian) depends on the rule.
//
// Threads. apply(), order(), ... are const but a lazily evaluated Gamma is cached inside the
// object; use one JumpMap per thread (copies are independent).
//
// Range. B does not change when a normal is scaled by a positive number, so rows of eta beyond
// 2^+-300 are rescaled by an exact power of two: normals of 1e200 or 1e-200 are as good as
// normals of 1. Quantities that leave the double range on the way while the answer
// does not (eta . F for limits near 1e308, crossing times below 1e-308, partial sums of the
// image) are computed with a separate binary exponent, so the result is right wherever it is
// representable; where the image, a crossing time or a piece itself exceeds the double range,
// the call throws InvalidArgument saying so. Inputs within about 1e-300 ... 1e300 never take
// that path and cost nothing extra.
//
// Moving. A moved-from JumpMap may be assigned to or destroyed; any other call throws
// std::logic_error.
#ifndef BFLOW_CORE_JUMP_MAP_H_
#define BFLOW_CORE_JUMP_MAP_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <type_traits>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/field_limits.h"
#include "bflow/core/signs.h"

namespace bflow {

class Triangulation;

/** Crossing order sigma and cumulative crossing times of [B] (6.8)-(6.9). */
struct CrossingOrder {
  /** Surface indices, first crossed first. */
  std::vector<int> order;
  /** times[k] is when surface order[k] is crossed; time 0 is dx itself on the F_{-...-} line.
      Non-decreasing; may be negative (dx already past some surfaces). */
  std::vector<double> times;
};

/** One linear piece of B: the saltation matrix M_sigma active on the cone of order sigma. */
struct Piece {
  std::vector<int> order;
  Eigen::MatrixXd matrix;
};

/** All n! pieces of B, stored contiguously (orders n ints each, matrices d x d each).
    Read-only; indexing copies a Piece out, matrix(i) is a view without a copy. */
class Pieces {
 public:
  class Iterator {
   public:
    Iterator(const Pieces* pieces, std::size_t i) : pieces_(pieces), i_(i) {}
    Piece operator*() const { return (*pieces_)[i_]; }
    Iterator& operator++() {
      ++i_;
      return *this;
    }
    bool operator!=(const Iterator& other) const { return i_ != other.i_; }

   private:
    const Pieces* pieces_;
    std::size_t i_;
  };

  std::size_t size() const { return count_; }
  int surfaces() const { return n_; }
  int dim() const { return d_; }
  /** Order sigma of piece i (surface indices, first crossed first). */
  std::vector<int> order(std::size_t i) const;
  /** M_sigma of piece i, a view into this object. */
  Eigen::Map<const Eigen::MatrixXd> matrix(std::size_t i) const;
  /** Piece i, copied out. */
  Piece operator[](std::size_t i) const { return Piece{order(i), matrix(i)}; }
  Iterator begin() const { return Iterator(this, 0); }
  Iterator end() const { return Iterator(this, count_); }

 private:
  friend class JumpMap;
  struct Free {
    void operator()(double* p) const;
  };
  Pieces(int n, int d, std::size_t count);

  int n_ = 0;
  int d_ = 0;
  std::size_t count_ = 0;
  std::vector<int> orders_;
  std::unique_ptr<double[], Free> matrices_;
};

/** Receives one piece: its order sigma and M_sigma (valid only during the call). */
using PieceVisitor =
    std::function<void(const std::vector<int>& order, const Eigen::Ref<const Eigen::MatrixXd>& m)>;

struct JumpMapOptions {
  /** Capacity of the cache of a lazily evaluated Gamma, in words; 0 chooses 8 (n + 1).
      The cache never allocates after construction: when full it is cleared. */
  int cache_words = 0;
};

class JumpMap {
 public:
  /** Largest n for which pieces() and triangulation() enumerate (n! pieces). */
  static constexpr int kMaxEnumeratedSurfaces = 10;
  /** Largest memory, in bytes, pieces() may return (n! d^2 doubles). */
  static constexpr std::int64_t kMaxPiecesBytes = std::int64_t{4} << 30;
  /** Normals count as rank deficient when, after scaling each row to unit length, the
      smallest singular value is at most this times the largest. */
  static constexpr double kRankTolerance = 1e-10;

  /** Gamma given as a table: `limits` is d x 2^n, column b.bits() is Gamma(b). Checks every
      word for transversality (the sign of eta_j . Gamma(b), evaluated without overflow).
      @throws InvalidArgument on empty or mismatched sizes, n > d, n > 64 (or > 24 for a
      table), rank-deficient normals (quoting the singular values), non-finite numbers, or
      eta_j . Gamma(b) <= 0 (quoting j, b and the value). */
  JumpMap(const Eigen::Ref<const Eigen::MatrixXd>& normals,
          const Eigen::Ref<const Eigen::MatrixXd>& limits);

  /** Gamma evaluated lazily: n + 1 words per apply(), cached. Each word is checked when it is
      first evaluated; a violation throws from the call that needed it.
      @throws InvalidArgument as above (for the words evaluated). */
  template <
      typename Function,
      typename = std::enable_if_t<
          !std::is_base_of_v<Eigen::EigenBase<std::decay_t<Function>>, std::decay_t<Function>> &&
          std::is_invocable_v<Function&, Signs, Eigen::Ref<Eigen::VectorXd>>>>
  JumpMap(const Eigen::Ref<const Eigen::MatrixXd>& normals, Function&& limits,
          JumpMapOptions options = {})
      : JumpMap(normals, FieldLimitFunction(std::forward<Function>(limits)), options, LazyTag{}) {}

  JumpMap(const JumpMap&);
  JumpMap& operator=(const JumpMap&);
  JumpMap(JumpMap&&) noexcept;
  JumpMap& operator=(JumpMap&&) noexcept;
  ~JumpMap();

  int surfaces() const;
  int dim() const;
  const Eigen::MatrixXd& normals() const;
  /** Gamma(b) = F_b(rho). */
  Eigen::VectorXd limit(Signs b) const;
  /** eta . Gamma(b) with the normals as given (n numbers, all > 0; +inf where the product
      exceeds the double range, which the computations of B never form). */
  Eigen::VectorXd transversality(Signs b) const;

  /** B(dx) by Algorithm 2.1. O(n d + n^2) time with Gamma cached (O(n^2 d) when each of the
      n + 1 words is evaluated afresh), O(1) extra space, no heap allocation. `out` may be `dx`
      itself (in place). @throws InvalidArgument on a size mismatch, an `out` that overlaps `dx`
      without being it, non-finite dx, or an image beyond the double range; on any throw `out`
      is not written. */
  void apply(const Eigen::Ref<const Eigen::VectorXd>& dx, Eigen::Ref<Eigen::VectorXd> out) const;
  Eigen::VectorXd apply(const Eigen::Ref<const Eigen::VectorXd>& dx) const;
  /** B applied to each column of a d x k block; no heap allocation. For one surface (B linear)
      the block is mapped in two passes (eta X, two rank-one updates) rather than a walk per
      column: 18 ns per tangent at d = 6 against 50 (docs/peers.md, the jump alone). `out` may be
      `dx` itself (the same block: same first number and outer stride), mapped in place.
      Every column is checked before any is written: for a table whose growth bound (a product
      over the surfaces of 1 + 2 max|Gamma| |eta_j|_1 / min eta_j . Gamma) times the sum of
      all |dx| stays below 2^1021 no image can leave the double range, and the check is one pass
      over the numbers; otherwise (a lazy source, extreme limits or tangents) each column is also
      walked once without writing.
      @throws InvalidArgument on a size mismatch, an `out` that overlaps `dx` without being the
      same block or whose columns overlap one another, a non-finite number (naming its column),
      an image beyond the double range, or (lazy source) a word that is not transversal; on any
      throw `out` is not written. */
  void apply_block(const Eigen::Ref<const Eigen::MatrixXd>& dx,
                   Eigen::Ref<Eigen::MatrixXd> out) const;
  Eigen::MatrixXd apply_block(const Eigen::Ref<const Eigen::MatrixXd>& dx) const;

  /** The order in which dx crosses the surfaces, and when ([B] (6.8)-(6.9)).
      @throws InvalidArgument when a crossing time exceeds the double range. */
  CrossingOrder order(const Eigen::Ref<const Eigen::VectorXd>& dx) const;

  /** M_sigma of [B] (6.4) by n rank-1 updates, O(n d^2); the first crossing is the right-most
      factor. @throws InvalidArgument unless sigma is a permutation of 0..n-1, or when an
      entry of M_sigma exceeds the double range. */
  Eigen::MatrixXd saltation(const std::vector<int>& sigma) const;
  /** M_sigma for sigma = order(dx): the linear piece active at dx. */
  Eigen::MatrixXd active_jacobian(const Eigen::Ref<const Eigen::VectorXd>& dx) const;

  /** All n! pieces (sigma, M_sigma), sigma in lexicographic order. A common prefix of sigma is
      multiplied once, and the last two factors are applied together as one rank-2 update:
      about 2 e n! d^2 multiply-adds. @throws InvalidArgument for n > kMaxEnumeratedSurfaces or
      when the result would exceed kMaxPiecesBytes (the message gives n!, d and the bytes), or
      when an entry of a piece exceeds the double range. */
  Pieces pieces() const;
  /** The same n! pieces, in the same order, handed to `visit` one at a time without storing
      them (memory O(n d^2)). @throws InvalidArgument for n > kMaxEnumeratedSurfaces, or
      before visiting a piece with an entry beyond the double range. */
  void for_each_piece(const PieceVisitor& visit) const;

  /** The triangulation of [B] Section 5: an independent representation of B.
      @throws InvalidArgument for n > kMaxEnumeratedSurfaces. */
  Triangulation triangulation() const;

 private:
  struct Impl;
  struct LazyTag {};
  JumpMap(const Eigen::Ref<const Eigen::MatrixXd>& normals, FieldLimitFunction limits,
          JumpMapOptions options, LazyTag);
  // The Impl, or std::logic_error for a moved-from object.
  Impl& impl() const;
  // Runs Algorithm 2.1 in doubles. Writes the image to `out` (if not null) and the order and
  // times (if not null). No allocation. Returns false, with `out` untouched, when a quantity
  // leaves the range where doubles keep full relative precision (limits near 1e308, subnormal
  // crossing times, an image near overflow): then walk_scaled() gives the answer.
  bool walk(const double* dx, double* out, int* order, double* times) const;
  // apply_block for n = 1 (B linear), chunk by chunk: the columns before the returned index are
  // done; from it on, the walks take over (a chunk with a number the walk would not take).
  Eigen::Index apply_linear_block(const Eigen::Ref<const Eigen::MatrixXd>& dx,
                                  Eigen::Ref<Eigen::MatrixXd> out) const;
  // Algorithm 2.1 with every scalar a number with its own binary exponent: right wherever the
  // image and the times are representable as doubles; otherwise throws InvalidArgument (`what`
  // names the caller) without writing `out`.
  // With `check_image` and no `out`, the image is formed and checked but not written.
  void walk_scaled(const char* what, const double* dx, double* out, int* order, double* times,
                   bool check_image = false) const;
  std::unique_ptr<Impl> impl_;
};

}  // namespace bflow

#endif  // BFLOW_CORE_JUMP_MAP_H_

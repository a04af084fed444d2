// Signs: the side of each switching surface, one bit per surface.
//
// Bit j set means side `+` of surface j (h_j > 0); clear means `-`. A word has at most
// kMaxSurfaces = 64 surfaces. The text form is a string of n characters, character j being
// '-' or '+' for surface j:
//
//   Signs b = Signs::parse("-+-");   // only surface 1 on its + side
//   b.plus(1) == true;  b.bits() == 0b010;  b.str() == "-+-";
//   b.with_plus(0).str() == "++-";
#ifndef BFLOW_CORE_SIGNS_H_
#define BFLOW_CORE_SIGNS_H_

#include <cstdint>
#include <string>
#include <string_view>

namespace bflow {

class Signs {
 public:
  static constexpr int kMaxSurfaces = 64;

  /** The empty word (no surfaces). */
  Signs() = default;
  /** All n surfaces on their `-` side. @throws InvalidArgument unless 0 <= n <= 64. */
  explicit Signs(int n);
  /** n surfaces with sides given by the low n bits of `bits`; higher bits must be zero.
      @throws InvalidArgument on n outside [0, 64] or stray high bits. */
  Signs(int n, std::uint64_t bits);

  static Signs all_minus(int n) { return Signs(n); }
  static Signs all_plus(int n);
  /** Parses the text form ("+-+"). @throws InvalidArgument naming the word and the bad
      character, or a word longer than 64. */
  static Signs parse(std::string_view word);

  int size() const { return n_; }
  std::uint64_t bits() const { return bits_; }
  bool plus(int j) const { return (bits_ >> j) & 1u; }
  bool minus(int j) const { return !plus(j); }
  /** +1 or -1 for surface j. */
  int sign(int j) const { return plus(j) ? 1 : -1; }
  int count_plus() const;
  bool is_all_minus() const { return bits_ == 0; }
  bool is_all_plus() const;

  Signs with_plus(int j) const { return Signs(n_, bits_ | (std::uint64_t{1} << j), Unchecked{}); }
  Signs with_minus(int j) const { return Signs(n_, bits_ & ~(std::uint64_t{1} << j), Unchecked{}); }
  /** Flips the sides of the surfaces whose bit is set in `mask` (mask must fit in n bits). */
  Signs flipped(std::uint64_t mask) const { return Signs(n_, bits_ ^ mask, Unchecked{}); }

  /** The text form, n characters of '-' and '+'. */
  std::string str() const;

  friend bool operator==(Signs a, Signs b) { return a.n_ == b.n_ && a.bits_ == b.bits_; }
  friend bool operator!=(Signs a, Signs b) { return !(a == b); }

 private:
  struct Unchecked {};
  Signs(int n, std::uint64_t bits, Unchecked) : bits_(bits), n_(n) {}

  std::uint64_t bits_ = 0;
  int n_ = 0;
};

/** Mask with the low n bits set (n in [0, 64]). */
constexpr std::uint64_t low_bits(int n) {
  return n >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << n) - 1;
}

}  // namespace bflow

#endif  // BFLOW_CORE_SIGNS_H_

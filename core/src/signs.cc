#include "bflow/core/signs.h"

#include <bitset>

#include "bflow/core/errors.h"
#include "bflow/core/text.h"

namespace bflow {

namespace {
void check_count(int n) {
  if (n < 0 || n > Signs::kMaxSurfaces) {
    throw InvalidArgument("Signs: the number of surfaces must be in [0, 64], got " +
                          std::to_string(n));
  }
}
}  // namespace

Signs::Signs(int n) : n_(n) { check_count(n); }

Signs::Signs(int n, std::uint64_t bits) : bits_(bits), n_(n) {
  check_count(n);
  if ((bits & ~low_bits(n)) != 0) {
    throw InvalidArgument("Signs: bits " + std::to_string(bits) + " do not fit in " +
                          std::to_string(n) + " surfaces");
  }
}

Signs Signs::all_plus(int n) {
  check_count(n);
  return Signs(n, low_bits(n), Unchecked{});
}

Signs Signs::parse(std::string_view word) {
  if (word.size() > static_cast<std::size_t>(kMaxSurfaces)) {
    throw InvalidArgument("sign word has " + std::to_string(word.size()) +
                          " characters; at most 64 surfaces are supported");
  }
  std::uint64_t bits = 0;
  for (std::size_t j = 0; j < word.size(); ++j) {
    if (word[j] == '+') {
      bits |= std::uint64_t{1} << j;
    } else if (word[j] != '-') {
      throw InvalidArgument("sign word " + quote(std::string(word)) + " has " +
                            quote(std::string(1, word[j])) + " at position " + std::to_string(j) +
                            "; only '-' and '+' are allowed");
    }
  }
  return Signs(static_cast<int>(word.size()), bits, Unchecked{});
}

int Signs::count_plus() const { return static_cast<int>(std::bitset<64>(bits_).count()); }

bool Signs::is_all_plus() const { return bits_ == low_bits(n_); }

std::string Signs::str() const {
  std::string word(static_cast<std::size_t>(n_), '-');
  for (int j = 0; j < n_; ++j) {
    if (plus(j)) word[static_cast<std::size_t>(j)] = '+';
  }
  return word;
}

}  // namespace bflow

#include "bflow/core/field_limits.h"

#include <algorithm>
#include <cstdint>
#include <vector>

#include "bflow/core/errors.h"

namespace bflow {

Eigen::MatrixXd limits_table_from_words(int surfaces, int dim,
                                        const std::map<std::string, Eigen::VectorXd>& words) {
  if (surfaces < 1 || surfaces > kMaxTableSurfaces) {
    throw InvalidArgument("field_limits: a table needs 1 to " + std::to_string(kMaxTableSurfaces) +
                          " surfaces, got " + std::to_string(surfaces));
  }
  if (dim < 1)
    throw InvalidArgument("field_limits: dimension must be positive, got " + std::to_string(dim));
  const Eigen::Index count = Eigen::Index{1} << surfaces;
  // Every word is checked, and the first missing one found, before the table is allocated: a
  // short list for many surfaces must not cost a 2^n column allocation to refuse.
  std::vector<std::uint64_t> given;
  given.reserve(words.size());
  for (const auto& [word, value] : words) {
    if (static_cast<int>(word.size()) != surfaces) {
      throw InvalidArgument("field_limits: word \"" + word + "\" has " +
                            std::to_string(word.size()) + " characters, expected " +
                            std::to_string(surfaces) + " (one per surface)");
    }
    const Signs b = Signs::parse(word);
    if (value.size() != dim) {
      throw InvalidArgument("field_limits: word \"" + word + "\" has " +
                            std::to_string(value.size()) + " numbers, expected " +
                            std::to_string(dim));
    }
    if (!value.allFinite()) {
      throw InvalidArgument("field_limits: word \"" + word + "\" has non-finite numbers " +
                            format_vector(value));
    }
    // std::map keys are unique, so a repeated word cannot reach here.
    given.push_back(b.bits());
  }
  std::sort(given.begin(), given.end());
  for (std::size_t w = 0; w < static_cast<std::size_t>(count); ++w) {
    if (w >= given.size() || given[w] != w) {
      throw InvalidArgument(
          "field_limits: missing word \"" + Signs(surfaces, static_cast<std::uint64_t>(w)).str() +
          "\" (" + std::to_string(words.size()) + " of " + std::to_string(count) + " words given)");
    }
  }
  Eigen::MatrixXd table(dim, count);
  for (const auto& [word, value] : words) {
    table.col(static_cast<Eigen::Index>(Signs::parse(word).bits())) = value;
  }
  return table;
}

}  // namespace bflow

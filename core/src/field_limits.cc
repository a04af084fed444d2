#include "bflow/core/field_limits.h"

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
  Eigen::MatrixXd table(dim, count);
  std::vector<bool> seen(static_cast<std::size_t>(count), false);
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
    table.col(static_cast<Eigen::Index>(b.bits())) = value;
    seen[b.bits()] = true;
  }
  for (Eigen::Index w = 0; w < count; ++w) {
    if (!seen[static_cast<std::size_t>(w)]) {
      throw InvalidArgument(
          "field_limits: missing word \"" + Signs(surfaces, static_cast<std::uint64_t>(w)).str() +
          "\" (" + std::to_string(words.size()) + " of " + std::to_string(count) + " words given)");
    }
  }
  return table;
}

}  // namespace bflow

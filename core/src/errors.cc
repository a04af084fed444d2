#include "bflow/core/errors.h"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

namespace bflow {

std::string format_number(double value) {
  if (std::isnan(value)) return "nan";
  if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
  // Shortest form that reads back to the same double.
  char buffer[32];
  const auto end = std::to_chars(buffer, buffer + sizeof buffer, value).ptr;
  return std::string(buffer, end);
}

std::string format_vector(const Eigen::Ref<const Eigen::VectorXd>& v) {
  constexpr Eigen::Index kShown = 8;
  std::ostringstream out;
  out << '[';
  for (Eigen::Index i = 0; i < v.size(); ++i) {
    if (v.size() > kShown && i == kShown / 2) {
      out << "... (" << v.size() - kShown << " more), ";
      i = v.size() - kShown / 2;
    }
    out << format_number(v[i]) << (i + 1 < v.size() ? ", " : "");
  }
  out << ']';
  return out.str();
}

namespace internal {
void assert_fail(const char* condition, const char* file, int line) {
  std::fprintf(stderr, "bflow: internal invariant failed: %s at %s:%d\n", condition, file, line);
  std::abort();
}
}  // namespace internal

}  // namespace bflow

// Errors and invariant checks shared by every bflow component.
//
// bflow has three kinds of failure:
//  * misuse of a template is a static_assert with a readable message;
//  * bad input (dimensions, non-finite numbers, non-transversal surfaces, ...) throws
//    bflow::InvalidArgument whose message names the problem and quotes the values;
//  * a broken internal invariant is a BFLOW_ASSERT, which aborts with file and line.
#ifndef BFLOW_CORE_ERRORS_H_
#define BFLOW_CORE_ERRORS_H_

#include <stdexcept>
#include <string>

#include <Eigen/Core>

namespace bflow {

/** Thrown for bad input. The message names the problem and quotes the offending values. */
class InvalidArgument : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/** Formats a number round-trip exactly (shortest form that reads back to the same double). */
std::string format_number(double value);

/** Formats a vector as "[a, b, c]", eliding the middle of long vectors. */
std::string format_vector(const Eigen::Ref<const Eigen::VectorXd>& v);

namespace internal {
[[noreturn]] void assert_fail(const char* condition, const char* file, int line);
}  // namespace internal

}  // namespace bflow

/// Internal invariant: aborts with the failed condition, file and line. Never for user input.
#define BFLOW_ASSERT(condition)                                                       \
  do {                                                                                \
    if (!(condition)) ::bflow::internal::assert_fail(#condition, __FILE__, __LINE__); \
  } while (false)

#endif  // BFLOW_CORE_ERRORS_H_

// The message of the bflow::InvalidArgument a call throws, for asserting error texts.
#ifndef BFLOW_TESTS_SUPPORT_ERROR_MESSAGE_H_
#define BFLOW_TESTS_SUPPORT_ERROR_MESSAGE_H_

#include <string>

#include <gtest/gtest.h>

#include "bflow/core/errors.h"

namespace bflow::testing {

/** Runs `call`; returns the message of the InvalidArgument it throws, or records a test
    failure and returns "" when it throws nothing. */
template <typename Call>
std::string message_of(Call&& call) {
  try {
    call();
  } catch (const InvalidArgument& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected bflow::InvalidArgument";
  return "";
}

}  // namespace bflow::testing

#endif  // BFLOW_TESTS_SUPPORT_ERROR_MESSAGE_H_

#include "bflow/integrators/segment.h"

namespace bflow {

const char* to_string(IntegrationStatus status) {
  switch (status) {
    case IntegrationStatus::kReachedEnd:
      return "reached the end";
    case IntegrationStatus::kCrossing:
      return "surface crossing";
    case IntegrationStatus::kStepSizeUnderflow:
      return "step-size underflow";
    case IntegrationStatus::kTooManySteps:
      return "too many steps";
    case IntegrationStatus::kNonFinite:
      return "non-finite state";
    case IntegrationStatus::kSolverFailure:
      return "solver failure";
    case IntegrationStatus::kTooManyEvents:
      return "too many events";
    case IntegrationStatus::kOverflow:
      return "overflow";
  }
  return "unknown";
}

}  // namespace bflow

// IPOPT options given by a caller of fesd_simulate or ocp_solve, set on an IpoptApplication
// after bflow's own so that they win. A template over the application type: no IPOPT header
// is needed to include this one.
#ifndef BFLOW_FESD_IPOPT_OPTIONS_H_
#define BFLOW_FESD_IPOPT_OPTIONS_H_

#include <string>

#include "bflow/core/errors.h"

namespace bflow {
namespace fesd {

// The caller's IPOPT options (set after bflow's, so they win).
// @throws InvalidArgument "<who>: IPOPT does not take the <type> option <name> = <value>".
template <typename App, typename Options>
void apply_ipopt_options(App& app, const Options& options, const std::string& who) {
  for (const auto& [name, value] : options.ipopt_string_options) {
    if (!app.Options()->SetStringValue(name, value)) {
      throw InvalidArgument(who + ": IPOPT does not take the string option " + name + " = " +
                            value);
    }
  }
  for (const auto& [name, value] : options.ipopt_numeric_options) {
    if (!app.Options()->SetNumericValue(name, value)) {
      throw InvalidArgument(who + ": IPOPT does not take the numeric option " + name + " = " +
                            format_number(value));
    }
  }
  for (const auto& [name, value] : options.ipopt_integer_options) {
    if (!app.Options()->SetIntegerValue(name, value)) {
      throw InvalidArgument(who + ": IPOPT does not take the integer option " + name + " = " +
                            std::to_string(value));
    }
  }
}

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_IPOPT_OPTIONS_H_

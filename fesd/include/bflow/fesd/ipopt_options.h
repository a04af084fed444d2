// IPOPT options given by a caller of fesd_simulate or ocp_solve, set on an IpoptApplication
// after bflow's own so that they win. A template over the application type: no IPOPT header
// is needed to include this one.
#ifndef BFLOW_FESD_IPOPT_OPTIONS_H_
#define BFLOW_FESD_IPOPT_OPTIONS_H_

#include <string>

#include "bflow/core/errors.h"

namespace bflow {
namespace fesd {

/** bflow's own IPOPT options, the same for fesd_simulate's step NLPs and ocp_solve's NLP (set
    before the caller's, which win): exact or limited-memory Hessians, the linear solver, the
    iteration limit, the adaptive barrier update and no relaxation of the bounds (the
    complementarity pairs sit on them). By default the KKT systems are factorised by MUMPS with
    IPOPT's defaults (its automatic ordering, pivot tolerance 1e-6): docs/ocp.md measures the
    alternatives on the monoped, the turbo car and the braking block; the faster AMD ordering
    changes round-off enough to send the small examples' homotopies along paths up to four times
    longer (the turbo car at N = 10: 1494 IPOPT iterations against 359, both with OpenBLAS), so
    it is left to the caller ({"mumps_pivot_order", 0}, {"mumps_mem_percent", 200}). Another
    linear solver (HSL's, from libhsl.so) is the caller's choice, checked before it gets here
    (check_linear_solver, linear_solver.h). */
template <typename App>
void set_ipopt_defaults(App& app, int print_level, bool exact_hessian, int max_iterations,
                        const std::string& linear_solver) {
  app.Options()->SetIntegerValue("print_level", print_level);
  app.Options()->SetStringValue("linear_solver", linear_solver);
  app.Options()->SetStringValue("sb", "yes");
  app.Options()->SetStringValue("hessian_approximation",
                                exact_hessian ? "exact" : "limited-memory");
  app.Options()->SetIntegerValue("max_iter", max_iterations);
  app.Options()->SetStringValue("mu_strategy", "adaptive");
  app.Options()->SetNumericValue("bound_relax_factor", 0.0);
}

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

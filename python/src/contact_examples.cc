// Optimal control of the built-in contact examples through time-freezing: the monoped (nosnoc's
// benchmark behind [F] Figure 10, examples/monoped_ocp.h) and the hopper (examples/hopper.h),
// with the options and data each example comes with, as the bflow ocp command runs them.
#include <string>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/stl/function.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include "bflow/core/errors.h"
#include "bflow/examples/hopper.h"
#include "bflow/examples/monoped_ocp.h"
#include "bflow/ocp/ocp.h"
#include "bindings.h"
#include "interrupt.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace bflow::python {
namespace {

void check_name(const std::string& name) {
  if (name != "monoped" && name != "hopper") {
    throw InvalidArgument("unknown contact example \"" + name + "\"; use monoped or hopper");
  }
}

examples::MonopedTask monoped_task(const std::string& setup) {
  examples::MonopedTask task;
  task.setup = examples::parse_monoped_setup(setup);
  return task;
}

}  // namespace

void bind_contact_examples(nb::module_& m) {
  m.def(
      "_contact_options",
      [](const std::string& name, int stages, const std::string& setup,
         const std::string& formulation) {
        check_name(name);
        const DcsFormulation f = parse_dcs_formulation(formulation);
        if (name == "monoped") {
          if (stages < 1) {
            throw InvalidArgument("ocp_solve: the monoped needs N >= 1 control stages, got " +
                                  std::to_string(stages));
          }
          OcpOptions o = monoped_task(setup).options(stages, f);
          o.formulation = f;
          return o;
        }
        if (setup != "nosnoc") {
          throw InvalidArgument("ocp_solve: only the monoped has setups, not the hopper (setup \"" +
                                setup + "\")");
        }
        OcpOptions o = examples::HopperTask(stages).options();
        o.formulation = f;
        return o;
      },
      "name"_a, "stages"_a, "setup"_a, "formulation"_a);
  m.def(
      "_contact_solve",
      [](const std::string& name, const std::string& setup, OcpOptions options) {
        check_name(name);
        options.cancelled = interrupt_check();
        const auto solve = [&](const auto& model, const OcpProblem& problem) {
          return ocp_solve(model, problem, options);
        };
        if (name == "monoped") {
          return examples::with_monoped(monoped_task(setup), options.formulation, options.stages,
                                        solve);
        }
        const OcpProblem problem = examples::HopperTask(options.stages).problem();
        if (options.formulation == DcsFormulation::kStewart) {
          return solve(adapt_ocp(examples::hopper_model<TimeFreezingRegions::kBaseSets>()),
                       problem);
        }
        return solve(adapt_ocp(examples::hopper_model<TimeFreezingRegions::kUnions>()), problem);
      },
      "name"_a, "setup"_a, "options"_a, nb::call_guard<nb::gil_scoped_release>());
}

}  // namespace bflow::python

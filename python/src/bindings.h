// The parts of the extension module bflow._bflow, one per area of the C++ API.
#ifndef BFLOW_PYTHON_BINDINGS_H_
#define BFLOW_PYTHON_BINDINGS_H_

#include <string>

#include <nanobind/nanobind.h>

namespace bflow::python {

/** Gives a result class a __reduce__ that refuses pickling with a reason and what to do. */
template <typename Class>
void refuse_pickle(nanobind::class_<Class>& c, const std::string& name, const std::string& advice) {
  const std::string message = name + " does not pickle: " + advice;
  c.def("__reduce__", [message](const Class&) -> nanobind::object {
    throw nanobind::type_error(message.c_str());
  });
}

void bind_jump(nanobind::module_& m);    // JumpMap, CrossingOrder (jump.cc)
void bind_flow(nanobind::module_& m);    // Model, simulate, flow_derivative, fd (flow.cc)
void bind_orbits(nanobind::module_& m);  // find_periodic_orbit, continue_orbits (orbits.cc)
void bind_fesd(nanobind::module_& m);    // fesd_simulate of the built-in examples (fesd.cc)
void bind_ocp(nanobind::module_& m);     // ocp_solve of the built-in examples (ocp.cc)
void bind_contact_examples(
    nanobind::module_& m);              // the monoped and the hopper (contact_examples.cc)
void bind_sweep(nanobind::module_& m);  // sweeps over initial states (sweep.cc)

}  // namespace bflow::python

#endif  // BFLOW_PYTHON_BINDINGS_H_

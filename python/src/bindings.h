// The parts of the extension module bflow._bflow, one per area of the C++ API.
#ifndef BFLOW_PYTHON_BINDINGS_H_
#define BFLOW_PYTHON_BINDINGS_H_

#include <nanobind/nanobind.h>

namespace bflow::python {

void bind_jump(nanobind::module_& m);    // JumpMap, CrossingOrder (jump.cc)
void bind_flow(nanobind::module_& m);    // Model, simulate, flow_derivative, fd (flow.cc)
void bind_orbits(nanobind::module_& m);  // find_periodic_orbit, continue_orbits (orbits.cc)

}  // namespace bflow::python

#endif  // BFLOW_PYTHON_BINDINGS_H_

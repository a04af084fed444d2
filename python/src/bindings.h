// The parts of the extension module bflow._bflow, one per area of the C++ API.
#ifndef BFLOW_PYTHON_BINDINGS_H_
#define BFLOW_PYTHON_BINDINGS_H_

#include <nanobind/nanobind.h>

namespace bflow::python {

void bind_jump(nanobind::module_& m);  // JumpMap, CrossingOrder (jump.cc)
void bind_flow(nanobind::module_& m);  // Model, simulate, flow_derivative, fd (flow.cc)

}  // namespace bflow::python

#endif  // BFLOW_PYTHON_BINDINGS_H_

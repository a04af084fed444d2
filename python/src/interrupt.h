// Ctrl-C during a long C++ call that runs without the GIL: the cancellation hook of OcpOptions
// and FesdOptions, polled by the engines after every IPOPT iteration and between steps.
#ifndef BFLOW_PYTHON_INTERRUPT_H_
#define BFLOW_PYTHON_INTERRUPT_H_

#include <functional>

#include <nanobind/nanobind.h>

namespace bflow::python {

/** A hook that takes the GIL and runs Python's pending signal handlers (PyErr_CheckSignals;
    only the main thread has any): true when one raised (SIGINT's raises KeyboardInterrupt). The
    exception is cleared here, and the Python wrapper raises KeyboardInterrupt with the partial
    result once the call has returned (bflow/__init__.py). */
inline std::function<bool()> interrupt_check() {
  return [] {
    nanobind::gil_scoped_acquire gil;
    if (PyErr_CheckSignals() == 0) return false;
    PyErr_Clear();
    return true;
  };
}

}  // namespace bflow::python

#endif  // BFLOW_PYTHON_INTERRUPT_H_

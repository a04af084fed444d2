// Ctrl-C during a long C++ call that runs without the GIL: the cancellation hook of OcpOptions
// and FesdOptions, polled by the engines after every IPOPT iteration and between steps.
#ifndef BFLOW_PYTHON_INTERRUPT_H_
#define BFLOW_PYTHON_INTERRUPT_H_

#include <functional>

#include <nanobind/nanobind.h>

namespace bflow::python {

/** The identifier (PyThread_get_thread_ident) of the interpreter's main thread, the only thread
    whose signal handlers Python runs; set when the module is imported. */
inline unsigned long& main_thread_ident() {
  static unsigned long ident = 0;
  return ident;
}

/** A hook that takes the GIL and runs Python's pending signal handlers (PyErr_CheckSignals):
    true when one raised (SIGINT's raises KeyboardInterrupt). The exception is cleared here, and
    the Python wrapper raises KeyboardInterrupt with the partial result once the call has
    returned (bflow/__init__.py). Called from another thread than the main one (a thread pool's
    worker), where no handler ever runs, it is empty: the run is not slowed by taking the GIL
    after every iteration. Needs no GIL to be made. */
inline std::function<bool()> interrupt_check() {
  if (PyThread_get_thread_ident() != main_thread_ident()) return {};
  return [] {
    nanobind::gil_scoped_acquire gil;
    if (PyErr_CheckSignals() == 0) return false;
    PyErr_Clear();
    return true;
  };
}

}  // namespace bflow::python

#endif  // BFLOW_PYTHON_INTERRUPT_H_

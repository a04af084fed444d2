// bflow._bflow: the extension module behind the Python package (python/bflow). bflow's bad-input
// exceptions (bflow::InvalidArgument) reach Python as ValueError with the C++ message.
#include <nanobind/nanobind.h>

#include "bflow/core/errors.h"
#include "bindings.h"
#include "interrupt.h"

namespace nb = nanobind;

NB_MODULE(_bflow, m) {
  m.doc() = "bflow's C++ API (use the package bflow, which wraps it)";
  bflow::python::main_thread_ident() = nb::cast<unsigned long>(
      nb::module_::import_("threading").attr("main_thread")().attr("ident"));
  nb::register_exception_translator([](const std::exception_ptr& p, void*) {
    try {
      std::rethrow_exception(p);
    } catch (const bflow::InvalidArgument& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    }
  });
  bflow::python::bind_jump(m);
  bflow::python::bind_flow(m);
  bflow::python::bind_orbits(m);
  bflow::python::bind_fesd(m);
  bflow::python::bind_ocp(m);
  bflow::python::bind_contact_examples(m);
  bflow::python::bind_sweep(m);
}

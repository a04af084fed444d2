// A model behind the SegmentModel interface, with what keeps it alive: the Python package's
// bflow._bflow.Model (flow.cc), shared by the bindings of the flow and of orbits.
#ifndef BFLOW_PYTHON_MODEL_HANDLE_H_
#define BFLOW_PYTHON_MODEL_HANDLE_H_

#include <memory>
#include <string>

#include "bflow/integrators/segment.h"

namespace bflow::python {

struct Model {
  std::shared_ptr<const SegmentModel> model;
  std::string path;  ///< the compiled library, or the built-in scene's name
  int states() const { return model->states(); }
  int surfaces() const { return model->surfaces(); }
};

}  // namespace bflow::python

#endif  // BFLOW_PYTHON_MODEL_HANDLE_H_

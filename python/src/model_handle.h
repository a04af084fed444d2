// Models behind the engines' virtual interfaces, with what keeps them alive: the Python
// package's bflow._bflow.Model (a SegmentModel, flow.cc), shared by the bindings of the flow, of
// orbits and of sweeps; and the loader of the libraries bflow.Model compiles from SymPy (one per
// engine: the flow's SegmentModel, FESD's StepModel, ocp_solve's OcpModel).
#ifndef BFLOW_PYTHON_MODEL_HANDLE_H_
#define BFLOW_PYTHON_MODEL_HANDLE_H_

#include <dlfcn.h>

#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "bflow/core/errors.h"
#include "bflow/integrators/segment.h"

namespace bflow::python {

/** Parameter values by name, the overrides of one sample of a parameter sweep. */
using ParameterValues = std::vector<std::pair<std::string, double>>;

struct Model {
  std::shared_ptr<const SegmentModel> model;
  std::string path;  ///< the compiled library, or the built-in scene's name
  /** The same model with some parameters changed (thread-safe; throws InvalidArgument naming an
      unknown parameter or a bad value); empty for a model without parameters. */
  std::function<std::shared_ptr<const SegmentModel>(const ParameterValues&)> with_parameters;
  int states() const { return model->states(); }
  int surfaces() const { return model->surfaces(); }
};

/** The Interface object of the compiled library at path, made by its extern "C" functions
    bflow_<engine>_model_create(parameters, count, error, size) and _destroy. The library stays
    loaded for the life of the process: models and results may outlive the Python object that
    loaded it.
    @pre path is a library of bflow's model cache, named model_<key>.so or model_<key>.<tag>.so,
    whose string bflow_model_key holds <key> (bflow/model.py writes both). The key is checked
    after dlopen, so that a library of another model copied under the key is never used (its
    checksum, checked before dlopen by the cache, catches a damaged file).
    @throws InvalidArgument if the library cannot be loaded, is not the model its name states,
    lacks the functions, or refuses the parameters (its message). */
template <typename Interface>
std::shared_ptr<const Interface> load_compiled(const std::string& path, const std::string& engine,
                                               const std::vector<double>& parameters) {
  const std::size_t slash = path.find_last_of('/');
  const std::string file = slash == std::string::npos ? path : path.substr(slash + 1);
  const std::string prefix = "model_";
  if (file.compare(0, prefix.size(), prefix) != 0 || file.find('.') == std::string::npos) {
    throw InvalidArgument("the library " + path +
                          " is not named model_<key>.so as bflow's model cache names them");
  }
  const std::string expected = file.substr(prefix.size(), file.find('.') - prefix.size());
  void* library = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (library == nullptr) {
    throw InvalidArgument("cannot load the compiled model " + path + ": " + dlerror());
  }
  const auto* key = static_cast<const char*>(dlsym(library, "bflow_model_key"));
  if (key == nullptr || expected != key) {
    const std::string found =
        key == nullptr ? std::string("no key") : "the key " + std::string(key);
    dlclose(library);
    throw InvalidArgument("the library " + path + " holds " + found + ", not the model " +
                          expected + " its name states");
  }
  using Create = Interface* (*)(const double*, int, char*, int);
  using Destroy = void (*)(Interface*);
  const std::string create_name = "bflow_" + engine + "_model_create";
  const std::string destroy_name = "bflow_" + engine + "_model_destroy";
  const auto create = reinterpret_cast<Create>(dlsym(library, create_name.c_str()));
  const auto destroy = reinterpret_cast<Destroy>(dlsym(library, destroy_name.c_str()));
  if (create == nullptr || destroy == nullptr) {
    throw InvalidArgument("the library " + path + " is not a bflow " + engine + " model (" +
                          create_name + " or " + destroy_name + " missing)");
  }
  char error[512] = {0};
  Interface* raw = create(parameters.data(), static_cast<int>(parameters.size()), error,
                          static_cast<int>(sizeof error));
  if (raw == nullptr) throw InvalidArgument(error);
  return std::shared_ptr<const Interface>(
      raw, [destroy](const Interface* p) { destroy(const_cast<Interface*>(p)); });
}

}  // namespace bflow::python

#endif  // BFLOW_PYTHON_MODEL_HANDLE_H_

// Models compiled at run time (python/bflow/model.py), the hybrid flow driver and finite
// differences. A compiled model is a shared library that exports
//   bflow::SegmentModel* bflow_flow_model_create(const double* parameters, int count,
//                                           char* error, int error_size);
//   void bflow_flow_model_destroy(bflow::SegmentModel*);
// and holds the user's functor behind bflow::ModelAdapter, so every engine sees it exactly as it
// sees a C++ model (Jets for DF and Dh).

#include <algorithm>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/stl/map.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/shared_ptr.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include "bflow/core/biped.h"
#include "bflow/core/errors.h"
#include "bflow/core/flow_derivative.h"
#include "bflow/core/pronk.h"
#include "bflow/integrators/finite_differences.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "bindings.h"
#include "model_handle.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace bflow::python {
namespace {

using ConstMatrix = Eigen::Ref<const Eigen::MatrixXd>;
using ConstVector = Eigen::Ref<const Eigen::VectorXd>;

Model load_model(const std::string& path, const std::vector<double>& parameters,
                 const std::vector<std::string>& names) {
  Model m{load_compiled<SegmentModel>(path, "flow", parameters), path, {}};
  m.with_parameters = [path, parameters, names](const ParameterValues& changes) {
    std::vector<double> values = parameters;
    for (const auto& [name, value] : changes) {
      const auto at = std::find(names.begin(), names.end(), name);
      if (at == names.end()) {
        std::string known;
        for (const std::string& n : names) known += (known.empty() ? "" : ", ") + n;
        throw InvalidArgument("the model has no parameter \"" + name +
                              "\" (its parameters: " + (known.empty() ? "none" : known) + ")");
      }
      values[static_cast<std::size_t>(at - names.begin())] = value;
    }
    return load_compiled<SegmentModel>(path, "flow", values);
  };
  return m;
}

template <typename Params, typename Make>
Model builtin_scene(const std::map<std::string, std::string>& params, const std::string& name,
                    Make make) {
  Params base;
  for (const auto& [key, value] : params) set_param(base, key, value);
  Model m{make(base), name, {}};
  m.with_parameters = [base, make](const ParameterValues& changes) {
    Params p = base;
    for (const auto& [key, value] : changes) set_param(p, key, format_number(value));
    return make(p);
  };
  return m;
}

Eigen::VectorXd field_at(const Model& m, ConstVector x, const std::string& sides) {
  if (x.size() != m.states()) {
    throw InvalidArgument("field: x has " + std::to_string(x.size()) + " entries, the model " +
                          std::to_string(m.states()) + " states");
  }
  const Signs b = Signs::parse(sides);
  if (b.size() != m.surfaces()) {
    throw InvalidArgument("field: the sides \"" + sides + "\" name " + std::to_string(b.size()) +
                          " surfaces, the model has " + std::to_string(m.surfaces()));
  }
  Eigen::VectorXd xdot(m.states());
  const Eigen::VectorXd xc = x;
  m.model->field(xc.data(), b, xdot.data());
  return xdot;
}

Eigen::VectorXd surfaces_at(const Model& m, ConstVector x) {
  if (x.size() != m.states()) {
    throw InvalidArgument("surfaces: x has " + std::to_string(x.size()) + " entries, the model " +
                          std::to_string(m.states()) + " states");
  }
  Eigen::VectorXd h(m.surfaces());
  const Eigen::VectorXd xc = x;
  if (m.surfaces() > 0) m.model->surface_values(xc.data(), h.data());
  return h;
}

}  // namespace

void bind_flow(nb::module_& m) {
  nb::class_<Model> model(m, "Model");
  refuse_pickle(model, "a compiled or built-in model",
                "pickle the bflow.Model written in SymPy (it pickles by its expressions), or "
                "call bflow.biped / bflow.pronk again with the same parameters");
  model.def_prop_ro("states", &Model::states)
      .def_prop_ro("surfaces", &Model::surfaces)
      .def_ro("path", &Model::path)
      .def("field", &field_at, "x"_a, "sides"_a)
      .def("surface_values", &surfaces_at, "x"_a)
      .def("normals", [](const Model& mm, ConstVector x) {
        if (x.size() != mm.states()) {
          throw InvalidArgument("normals: x has " + std::to_string(x.size()) +
                                " entries, the model " + std::to_string(mm.states()) + " states");
        }
        return Eigen::MatrixXd(mm.model->surface_normals(x));
      });
  m.def("_load_model", &load_model, "path"_a, "parameters"_a, "names"_a);
  m.def(
      "_biped",
      [](const std::map<std::string, std::string>& params) {
        return builtin_scene<BipedParams>(params, "biped", [](const BipedParams& p) {
          validate_biped_params(p);
          return visit_biped(p, [](const auto& scene) -> std::shared_ptr<const SegmentModel> {
            using Scene = std::decay_t<decltype(scene)>;
            return std::make_shared<const ModelAdapter<Scene>>(scene);
          });
        });
      },
      "params"_a);
  m.def("_biped_initial_state", [] { return Eigen::VectorXd(biped_initial_state()); });
  m.def(
      "_pronk",
      [](const std::map<std::string, std::string>& params) {
        return builtin_scene<PronkParams>(params, "pronk", [](const PronkParams& p) {
          validate_pronk_params(p);
          return std::shared_ptr<const SegmentModel>(
              std::make_shared<const ModelAdapter<PronkScene>>(make_pronk(p)));
        });
      },
      "params"_a);
  m.def("_pronk_initial_state", [] { return Eigen::VectorXd(pronk_initial_state()); });

  nb::class_<FlowOptions>(m, "FlowOptions")
      .def(nb::init<>())
      .def_prop_rw(
          "rtol", [](const FlowOptions& o) { return o.integrator.rtol; },
          [](FlowOptions& o, double v) { o.integrator.rtol = v; })
      .def_prop_rw(
          "atol", [](const FlowOptions& o) { return o.integrator.atol; },
          [](FlowOptions& o, std::optional<double> v) { o.integrator.atol = v; },
          nb::arg("value").none())
      .def_prop_rw(
          "max_step", [](const FlowOptions& o) { return o.integrator.max_step; },
          [](FlowOptions& o, double v) { o.integrator.max_step = v; })
      .def_prop_rw(
          "max_steps", [](const FlowOptions& o) { return o.integrator.max_steps; },
          [](FlowOptions& o, long v) { o.integrator.max_steps = v; })
      .def_prop_rw(
          "backend", [](const FlowOptions& o) { return std::string(to_string(o.backend)); },
          [](FlowOptions& o, const std::string& v) { o.backend = parse_backend(v); })
      .def_prop_rw(
          "grouping", [](const FlowOptions& o) { return std::string(to_string(o.grouping)); },
          [](FlowOptions& o, const std::string& v) { o.grouping = parse_grouping(v); })
      .def_rw("grouping_safety", &FlowOptions::grouping_safety)
      .def_rw("window", &FlowOptions::simultaneity_window)
      .def_rw("near_simultaneity_band", &FlowOptions::near_simultaneity_band)
      .def_rw("grazing_threshold", &FlowOptions::grazing_threshold)
      .def_rw("max_events", &FlowOptions::max_events)
      .def_prop_rw(
          "initial_sides",
          [](const FlowOptions& o) {
            return o.initial_sides ? std::optional<std::string>(o.initial_sides->str())
                                   : std::nullopt;
          },
          [](FlowOptions& o, std::optional<std::string> v) {
            if (v) {
              o.initial_sides = Signs::parse(*v);
            } else {
              o.initial_sides.reset();
            }
          },
          nb::arg("value").none());

  const std::string rerun =
      "it is part of a run's result; pickle the model, x0, t and options and run again, or keep "
      "the numbers you need";
  nb::class_<EventRecord> event(m, "Event",
                                "One event: where, which surfaces, how it was grouped.");
  refuse_pickle(event, "bflow.Event", rerun);
  event.def_ro("t", &EventRecord::t, "the first crossing's located time (where the jump acts)")
      .def_ro("rho", &EventRecord::rho)
      .def_ro("surfaces", &EventRecord::surfaces, "surfaces crossed together, lowest first")
      .def_ro("crossing_times", &EventRecord::crossing_times,
              "per crossed surface, its located crossing time")
      .def_ro("spread", &EventRecord::spread, "max - min of crossing_times")
      .def_ro("window", &EventRecord::window, "the grouping window used at this event")
      .def_ro("gap", &EventRecord::gap, "time to the nearest crossing not grouped with it")
      .def_ro("automatic_window", &EventRecord::automatic_window)
      .def_prop_ro("sides_before", [](const EventRecord& e) { return e.sides_before.str(); })
      .def_prop_ro("sides_after", [](const EventRecord& e) { return e.sides_after.str(); })
      .def_ro("margin_before", &EventRecord::margin_before)
      .def_ro("margin_after", &EventRecord::margin_after)
      .def("__repr__", [](const EventRecord& e) {
        std::string s = "Event(t=" + format_number(e.t) + ", surfaces=[";
        for (std::size_t k = 0; k < e.surfaces.size(); ++k)
          s += (k ? ", " : "") + std::to_string(e.surfaces[k]);
        return s + "], spread=" + format_number(e.spread) + ", window=" + format_number(e.window) +
               ")";
      });

  nb::class_<FlowNotice> notice(m, "Notice",
                                "What the engine decided for the user or could not decide.");
  refuse_pickle(notice, "bflow.Notice", rerun);
  notice.def_prop_ro("kind", [](const FlowNotice& n) { return std::string(to_string(n.kind)); })
      .def_ro("surfaces", &FlowNotice::surfaces)
      .def_ro("times", &FlowNotice::times)
      .def_ro("gap", &FlowNotice::gap)
      .def_ro("band", &FlowNotice::band)
      .def_ro("message", &FlowNotice::message)
      .def("__repr__", [](const FlowNotice& n) { return "Notice(" + n.message + ")"; });

  nb::class_<FlowResult> result(m, "FlowResult");
  refuse_pickle(result, "bflow.FlowResult", rerun);
  result.def_prop_ro("status", [](const FlowResult& r) { return std::string(to_string(r.status)); })
      .def_ro("message", &FlowResult::message)
      .def_ro("t", &FlowResult::t)
      .def_ro("x", &FlowResult::x)
      .def_prop_ro("sides", [](const FlowResult& r) { return r.sides.str(); })
      .def_ro("v", &FlowResult::v, "images of the directions (d x k)")
      .def_ro("events", &FlowResult::events)
      .def_ro("notices", &FlowResult::notices)
      .def_ro("steps", &FlowResult::steps)
      .def_ro("field_evaluations", &FlowResult::field_evaluations)
      .def_prop_ro(
          "backend", [](const FlowResult& r) { return std::string(to_string(r.backend)); },
          "the integrator that ran (for backend \"auto\", the one it chose)")
      .def_prop_ro("ok", &FlowResult::ok);

  nb::class_<FlowPiece>(m, "FlowPiece")
      .def_ro("orders", &FlowPiece::orders)
      .def_ro("matrix", &FlowPiece::matrix);

  nb::class_<FlowDerivative> derivative(m, "FlowDerivative");
  refuse_pickle(derivative, "bflow.FlowDerivative",
                "it holds the run's transition matrices and jump maps; pickle the model, x0, t "
                "and options and call flow_derivative again");
  derivative.def_prop_ro("dim", &FlowDerivative::dim)
      .def_prop_ro("event_count", &FlowDerivative::events)
      .def_prop_ro("event_times", &FlowDerivative::event_times)
      .def_prop_ro("event_surfaces", &FlowDerivative::event_surfaces)
      .def_prop_ro("notices", &FlowDerivative::notices)
      .def_prop_ro("time_derivative", &FlowDerivative::time_derivative)
      .def("_apply_vector",
           [](const FlowDerivative& f, ConstVector dx) { return Eigen::VectorXd(f.apply(dx)); })
      .def(
          "_apply_block",
          [](const FlowDerivative& f, ConstMatrix dx) {
            return Eigen::MatrixXd(f.apply_block(dx));
          },
          nb::call_guard<nb::gil_scoped_release>())
      .def("crossing_orders", &FlowDerivative::crossing_orders, "dx"_a)
      .def("active_jacobian", &FlowDerivative::active_jacobian, "dx"_a)
      .def("pieces", &FlowDerivative::pieces, nb::call_guard<nb::gil_scoped_release>())
      .def("is_linear", &FlowDerivative::is_linear)
      .def("jacobian", &FlowDerivative::jacobian)
      .def("jumps", [](const FlowDerivative& f) { return f.jumps(); })
      .def("transitions", [](const FlowDerivative& f) { return f.transitions(); });

  m.def(
      "_simulate",
      [](const Model& model, ConstVector x0, double t, std::optional<Eigen::MatrixXd> directions,
         const FlowOptions& options) {
        if (directions) return simulate(*model.model, x0, t, *directions, options);
        return simulate(*model.model, x0, t, options);
      },
      "model"_a, "x0"_a, "t"_a, "directions"_a.none(), "options"_a,
      nb::call_guard<nb::gil_scoped_release>());
  m.def(
      "_flow_derivative",
      [](const Model& model, ConstVector x0, double t, const FlowOptions& options) {
        FlowResult trajectory;
        FlowDerivative d = flow_derivative(*model.model, x0, t, options, &trajectory);
        return std::make_pair(std::move(d), std::move(trajectory));
      },
      "model"_a, "x0"_a, "t"_a, "options"_a, nb::call_guard<nb::gil_scoped_release>());
  m.def(
      "_fd_one_sided",
      [](const Model& model, ConstVector x0, double t, ConstVector dx, double alpha,
         const FlowOptions& options) {
        return Eigen::VectorXd(fd::one_sided(*model.model, x0, t, dx, alpha, options));
      },
      "model"_a, "x0"_a, "t"_a, "dx"_a, "alpha"_a, "options"_a,
      nb::call_guard<nb::gil_scoped_release>());
  m.def(
      "_fd_central",
      [](const Model& model, ConstVector x0, double t, ConstVector dx, double alpha,
         const FlowOptions& options) {
        return Eigen::VectorXd(fd::central(*model.model, x0, t, dx, alpha, options));
      },
      "model"_a, "x0"_a, "t"_a, "dx"_a, "alpha"_a, "options"_a,
      nb::call_guard<nb::gil_scoped_release>());
  m.attr("_ceres_include_dir") = BFLOW_CERES_INCLUDE_DIR;
  m.attr("_eigen_include_dir") = BFLOW_EIGEN_INCLUDE_DIR;
}

}  // namespace bflow::python

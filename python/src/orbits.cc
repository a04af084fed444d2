// Periodic orbits through a Poincare section (a coordinate's level in parse_coordinate_section's
// text: "-x4", "x1=0.3"; a hyperplane; or s(x) compiled from SymPy, bflow_section_model_*),
// their stability bracket and verdict, and families over a parameter.
#include <complex>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/stl/complex.h>
#include <nanobind/stl/function.h>
#include <nanobind/stl/shared_ptr.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include "bflow/orbits/orbit_family.h"
#include "bflow/orbits/periodic_orbit.h"
#include "bindings.h"
#include "model_handle.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace bflow::python {

void bind_orbits(nb::module_& m) {
  nb::class_<OrbitOptions>(m, "OrbitOptions")
      .def(nb::init<>())
      .def_rw("flow", &OrbitOptions::flow)
      .def_rw("tolerance", &OrbitOptions::tolerance)
      .def_rw("max_newton_iterations", &OrbitOptions::max_newton_iterations)
      .def_rw("max_backtracks", &OrbitOptions::max_backtracks)
      .def_rw("max_return_time", &OrbitOptions::max_return_time)
      .def_rw("return_search_window", &OrbitOptions::return_search_window)
      .def_rw("min_return_time", &OrbitOptions::min_return_time)
      .def_rw("growth_directions", &OrbitOptions::growth_directions)
      .def_rw("growth_iterations", &OrbitOptions::growth_iterations)
      .def_rw("max_product_length", &OrbitOptions::max_product_length)
      .def_rw("max_products", &OrbitOptions::max_products)
      .def_rw("stability", &OrbitOptions::stability);
  m.def("_default_orbit_flow_options", &default_orbit_flow_options);

  nb::class_<GrowthBracket>(m, "GrowthBracket",
                            "The growth-rate bracket of DP(x*) and how each end was obtained.")
      .def_ro("lower", &GrowthBracket::lower)
      .def_ro("upper", &GrowthBracket::upper)
      .def_ro("pieces", &GrowthBracket::pieces)
      .def_ro("upper_length", &GrowthBracket::upper_length)
      .def_ro("lower_period", &GrowthBracket::lower_period)
      .def_ro("lower_direction", &GrowthBracket::lower_direction)
      .def_ro("realisable_products", &GrowthBracket::realisable_products)
      .def_ro("multipliers", &GrowthBracket::multipliers)
      .def_ro("lower_margin", &GrowthBracket::lower_margin)
      .def_ro("upper_margin", &GrowthBracket::upper_margin);

  nb::class_<OrbitNewtonStep>(m, "OrbitNewtonStep")
      .def_ro("iteration", &OrbitNewtonStep::iteration)
      .def_ro("residual", &OrbitNewtonStep::residual)
      .def_ro("period", &OrbitNewtonStep::period)
      .def_ro("step_length", &OrbitNewtonStep::step_length)
      .def_ro("events", &OrbitNewtonStep::events)
      .def_ro("largest_event", &OrbitNewtonStep::largest_event);

  nb::class_<PeriodicOrbit> orbit(m, "PeriodicOrbit");
  refuse_pickle(orbit, "bflow.PeriodicOrbit",
                "it is a solver's result with its return map; pickle the model, section, guess and "
                "options and call find_orbit again (from orbit.x it converges at once), or keep "
                "the numbers you need");
  orbit.def_ro("converged", &PeriodicOrbit::converged)
      .def_ro("message", &PeriodicOrbit::message)
      .def_ro("x", &PeriodicOrbit::x)
      .def_ro("period", &PeriodicOrbit::period)
      .def_ro("return_map", &PeriodicOrbit::return_map)
      .def_ro("newton_iterations", &PeriodicOrbit::newton_iterations)
      .def_ro("residual", &PeriodicOrbit::residual)
      .def_ro("correction", &PeriodicOrbit::correction)
      .def_ro("growth_rate_lower", &PeriodicOrbit::growth_rate_lower)
      .def_ro("growth_rate_upper", &PeriodicOrbit::growth_rate_upper)
      .def_prop_ro("stability",
                   [](const PeriodicOrbit& o) { return std::string(to_string(o.stability)); })
      .def_ro("bracket", &PeriodicOrbit::bracket)
      .def_ro("tangent_basis", &PeriodicOrbit::tangent_basis)
      .def_ro("events", &PeriodicOrbit::events)
      .def_ro("notices", &PeriodicOrbit::notices)
      .def_ro("steps", &PeriodicOrbit::steps)
      .def_ro("decisions", &PeriodicOrbit::decisions);

  nb::class_<PoincareSection>(m, "_Section", "A Poincare section s(x) = 0, crossed upwards.")
      .def("value", [](const PoincareSection& s, const Eigen::VectorXd& x) { return s.value(x); })
      .def("gradient",
           [](const PoincareSection& s, const Eigen::VectorXd& x) { return s.gradient(x); });
  m.def(
      "_coordinate_section",
      [](const std::string& text, int states) -> std::shared_ptr<PoincareSection> {
        return std::make_shared<SectionAdapter<CoordinateSection>>(
            parse_coordinate_section(text, states));
      },
      "text"_a, "states"_a);
  m.def(
      "_hyperplane_section",
      [](const Eigen::VectorXd& normal, double offset) -> std::shared_ptr<PoincareSection> {
        return std::make_shared<SectionAdapter<HyperplaneSection>>(
            HyperplaneSection{normal, offset});
      },
      "normal"_a, "offset"_a);
  m.def(
      "_load_section",
      [](const std::string& path, const std::vector<double>& parameters) {
        return std::const_pointer_cast<PoincareSection>(
            load_compiled<PoincareSection>(path, "section", parameters));
      },
      "path"_a, "parameters"_a);
  m.def(
      "_find_orbit",
      [](const Model& model, const std::shared_ptr<PoincareSection>& section,
         const Eigen::Ref<const Eigen::VectorXd>& guess, const OrbitOptions& options) {
        return find_periodic_orbit(*model.model, *section, guess, options);
      },
      "model"_a, "section"_a, "guess"_a, "options"_a, nb::call_guard<nb::gil_scoped_release>());

  nb::class_<OrbitFamilyMember>(m, "OrbitFamilyMember")
      .def_ro("value", &OrbitFamilyMember::value)
      .def_ro("orbit", &OrbitFamilyMember::orbit)
      .def_ro("guess", &OrbitFamilyMember::guess)
      .def_ro("predictor", &OrbitFamilyMember::predictor)
      .def_ro("decisions", &OrbitFamilyMember::decisions)
      .def_ro("runs", &OrbitFamilyMember::runs);
  // The solver and the progress report are Python callables: the GIL stays held.
  m.def(
      "_continue_orbits",
      [](const std::vector<double>& values, const Eigen::Ref<const Eigen::VectorXd>& guess,
         const std::function<PeriodicOrbit(double, const Eigen::VectorXd&)>& solve, bool secant,
         const std::function<void(int, const OrbitFamilyMember&)>& progress) {
        OrbitFamilyOptions options;
        options.secant = secant;
        options.progress = progress;
        return continue_orbits(values, guess, solve, options);
      },
      "values"_a, "guess"_a, "solve"_a, "secant"_a, "progress"_a.none());
}

}  // namespace bflow::python

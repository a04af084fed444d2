// FESD simulation of the built-in Filippov examples (IRMA and the four switching cases of [F]
// Example 3, with their exact solutions) and of models compiled from SymPy (bflow_step_model_*,
// model_handle.h).
#include <string>
#include <utility>
#include <vector>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/stl/function.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/shared_ptr.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include "bflow/core/errors.h"
#include "bflow/examples/irma.h"
#include "bflow/examples/switching_cases.h"
#include "bflow/fesd/fesd.h"
#include "bindings.h"
#include "interrupt.h"
#include "model_handle.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace bflow::python {
namespace {

constexpr const char* kExamples = "irma, crossing, sliding-enter, sliding-leave, spontaneous";

// Calls f(model, x0) with the example's model and its initial state.
template <typename F>
auto with_example(const std::string& name, F&& f) {
  if (name == "irma") {
    return f(adapt_step(examples::Irma{}), Eigen::VectorXd(examples::Irma::initial_state()));
  }
  if (name != "crossing" && name != "sliding-enter" && name != "sliding-leave" &&
      name != "spontaneous") {
    throw InvalidArgument("fesd_simulate: unknown example \"" + name + "\"; the examples are " +
                          kExamples);
  }
  const examples::SwitchingCaseSolution exact = examples::exact_switching_case(name);
  if (name == "crossing") return f(adapt_step(examples::CrossingCase{}), exact.x0);
  if (name == "sliding-enter") return f(adapt_step(examples::SlidingEnterCase{}), exact.x0);
  if (name == "sliding-leave") return f(adapt_step(examples::SlidingLeaveCase{}), exact.x0);
  return f(adapt_step(examples::SpontaneousCase{}), exact.x0);
}

}  // namespace

void bind_fesd(nb::module_& m) {
  nb::class_<StepModel>(m, "_StepModel", "A compiled step inclusion (FESD's StepModel).")
      .def_prop_ro("states", &StepModel::states)
      .def_prop_ro("switches", &StepModel::switches)
      .def_prop_ro("modes", &StepModel::modes);
  m.def(
      "_load_step_model",
      [](const std::string& path, const std::vector<double>& parameters) {
        return std::const_pointer_cast<StepModel>(
            load_compiled<StepModel>(path, "step", parameters));
      },
      "path"_a, "parameters"_a);
  m.def(
      "_fesd_model",
      [](const std::shared_ptr<StepModel>& model, double t_end, const Eigen::VectorXd& x0,
         FesdOptions options) {
        options.cancelled = interrupt_check();
        return fesd_simulate(*model, x0, t_end, options);
      },
      "model"_a, "t_end"_a, "x0"_a, "options"_a, nb::call_guard<nb::gil_scoped_release>());

  // The solver options FesdOptions and OcpOptions share (bflow/fesd/solver_options.h).
  nb::class_<SolverOptions>(m, "SolverOptions")
      .def(nb::init<>())
      .def_rw("print_level", &SolverOptions::print_level)
      .def_rw("linear_solver", &SolverOptions::linear_solver)
      .def_rw("linear_solver_library", &SolverOptions::linear_solver_library)
      .def_rw("mumps_amalgamation", &SolverOptions::mumps_amalgamation)
      .def_rw("blas_threads", &SolverOptions::blas_threads)
      .def_rw("keep_freed_memory", &SolverOptions::keep_freed_memory)
      .def_rw("derivative_programs", &SolverOptions::derivative_programs);

  // The relaxation homotopy's schedule FesdOptions and OcpOptions share
  // (bflow/fesd/homotopy_options.h; OcpHomotopyOptions extends it).
  nb::class_<HomotopyOptions>(m, "HomotopyOptions")
      .def(nb::init<>())
      .def_rw("sigma_initial", &HomotopyOptions::sigma_initial)
      .def_rw("sigma_final", &HomotopyOptions::sigma_final)
      .def_rw("sigma_factor", &HomotopyOptions::sigma_factor)
      .def_rw("superlinear", &HomotopyOptions::superlinear)
      .def_rw("nlp_tolerance", &HomotopyOptions::nlp_tolerance)
      .def_rw("max_nlp_iterations", &HomotopyOptions::max_nlp_iterations);

  nb::class_<FesdOptions>(m, "FesdOptions")
      .def(nb::init<>())
      .def_prop_rw(
          "scheme", [](const FesdOptions& o) { return std::string(to_string(o.scheme)); },
          [](FesdOptions& o, const std::string& v) { o.scheme = parse_collocation_scheme(v); })
      .def_rw("stages", &FesdOptions::stages)
      .def_rw("elements", &FesdOptions::elements)
      .def_rw("steps", &FesdOptions::steps)
      .def_rw("standard", &FesdOptions::standard)
      .def_prop_rw(
          "formulation", [](const FesdOptions& o) { return std::string(to_string(o.formulation)); },
          [](FesdOptions& o, const std::string& v) { o.formulation = parse_dcs_formulation(v); })
      .def_rw("lifting_depth", &FesdOptions::lifting_depth)
      .def_rw("exact_hessian", &FesdOptions::exact_hessian)
      .def_rw("newton", &FesdOptions::newton)
      .def_rw("sensitivities", &FesdOptions::sensitivities)
      .def_rw("homotopy", &FesdOptions::homotopy)
      .def_rw("solver", &FesdOptions::solver)
      .def_rw("progress", &FesdOptions::progress);

  nb::class_<FesdStepReport>(m, "FesdStepReport", "One integration step taken by fesd_simulate.")
      .def_ro("index", &FesdStepReport::index)
      .def_ro("planned", &FesdStepReport::planned)
      .def_ro("t", &FesdStepReport::t)
      .def_ro("length", &FesdStepReport::length)
      .def_ro("halvings", &FesdStepReport::halvings)
      .def_ro("newton", &FesdStepReport::newton)
      .def_ro("nlp_iterations", &FesdStepReport::nlp_iterations)
      .def_ro("complementarity", &FesdStepReport::complementarity);

  nb::class_<FesdResult> result(
      m, "FesdResult",
      "A run of fesd_simulate. ok: the run reached T (status \"converged\"); status: "
      "\"converged\", \"step failed\", \"invalid model\" or \"cancelled\"; message: why not "
      "ok, and notes (a step solved only to IPOPT's acceptable level, no sensitivity); x_end, "
      "grid, states, step_sizes, switch_times, active_sets, max_complementarity, sensitivity "
      "(dx(T)/dx0) and the counters halved_steps, newton_steps, acceptable_only_steps, "
      "nlp_iterations.");
  refuse_pickle(result, "bflow.FesdResult",
                "it is a run's result; keep the arrays you need (x_end, grid, states, ...)");
  result.def_prop_ro("status", [](const FesdResult& r) { return std::string(to_string(r.status)); })
      .def_prop_ro("ok", &FesdResult::ok)
      .def_ro("message", &FesdResult::message)
      .def_ro("x_end", &FesdResult::x_end)
      .def_ro("grid", &FesdResult::grid)
      .def_ro("states", &FesdResult::states)
      .def_ro("step_sizes", &FesdResult::step_sizes)
      .def_ro("switch_times", &FesdResult::switch_times)
      .def_ro("active_sets", &FesdResult::active_sets)
      .def_ro("max_complementarity", &FesdResult::max_complementarity)
      .def_ro("ipopt", &FesdResult::ipopt, "the IPOPT the NLPs ran on, e.g. 'IPOPT 3.14.19'")
      .def_ro("linear_solver", &FesdResult::linear_solver,
              "IPOPT's linear solver with its version or library, e.g. 'mumps 5.8.2'")
      .def_ro("blas", &FesdResult::blas,
              "the BLAS under the linear solver and its threads during the NLPs, e.g. "
              "'OpenBLAS 0.3.28, 1 thread (libcasadi-tp-openblas.so.0)'")
      .def_ro("derivatives", &FesdResult::derivatives,
              "how the Jacobian and exact Hessian of the steps IPOPT solved were computed, "
              "summed over the steps: 'programs: 180 traced, none kept on Jets' or 'Jets "
              "(derivative_programs off)'")
      .def_ro("halved_steps", &FesdResult::halved_steps)
      .def_ro("newton_steps", &FesdResult::newton_steps)
      .def_ro("acceptable_only_steps", &FesdResult::acceptable_only_steps)
      .def_ro("acceptable_only", &FesdResult::acceptable_only)
      .def_ro("nlp_iterations", &FesdResult::nlp_iterations)
      .def_ro("sensitivity", &FesdResult::sensitivity, "dx(T)/dx0 (d x d)");

  m.def(
      "_fesd_example",
      [](const std::string& name, double t_end, std::optional<Eigen::VectorXd> x0,
         FesdOptions options) {
        options.cancelled = interrupt_check();
        return with_example(name, [&](const StepModel& model, const Eigen::VectorXd& start) {
          return fesd_simulate(model, x0 ? *x0 : start, t_end, options);
        });
      },
      "example"_a, "t_end"_a, "x0"_a.none(), "options"_a, nb::call_guard<nb::gil_scoped_release>());
  m.def(
      "_fesd_exact",
      [](const std::string& name) {
        if (name == "irma") {
          throw InvalidArgument("fesd_exact: irma has no closed-form solution");
        }
        with_example(name, [](const StepModel&, const Eigen::VectorXd&) { return 0; });
        const examples::SwitchingCaseSolution s = examples::exact_switching_case(name);
        return std::make_pair(std::make_pair(s.x0, s.t_end),
                              std::make_pair(s.switch_times, s.x_end));
      },
      "example"_a);
  m.def("_irma_initial_state", [] { return Eigen::VectorXd(examples::Irma::initial_state()); });
}

}  // namespace bflow::python

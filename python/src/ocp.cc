// Optimal control through FESD for the built-in examples with exact optima (the braking block
// and the turbo car, examples/ocp_examples.h) and for models compiled from SymPy
// (bflow_ocp_model_*, model_handle.h) with the problem's data as an OcpProblem.
#include <string>
#include <utility>
#include <vector>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/stl/function.h>
#include <nanobind/stl/map.h>
#include <nanobind/stl/shared_ptr.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include "bflow/core/errors.h"
#include "bflow/examples/ocp_examples.h"
#include "bflow/ocp/ocp.h"
#include "bindings.h"
#include "interrupt.h"
#include "model_handle.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace bflow::python {

void bind_ocp(nb::module_& m) {
  // The homotopy's options beyond HomotopyOptions (bound in fesd.cc), bflow/ocp/ocp.h.
  nb::class_<OcpHomotopyOptions, HomotopyOptions>(m, "OcpHomotopyOptions")
      .def(nb::init<>())
      .def_prop_rw(
          "relaxation",
          [](const OcpHomotopyOptions& o) {
            return std::string(o.relaxation == OcpRelaxation::kL1Penalty ? "l1"
                               : o.relaxation == OcpRelaxation::kElastic ? "elastic"
                                                                         : "scholtes");
          },
          [](OcpHomotopyOptions& o, const std::string& v) {
            if (v == "scholtes") {
              o.relaxation = OcpRelaxation::kScholtes;
            } else if (v == "l1") {
              o.relaxation = OcpRelaxation::kL1Penalty;
            } else if (v == "elastic") {
              o.relaxation = OcpRelaxation::kElastic;
            } else {
              throw InvalidArgument("relaxation: unknown relaxation \"" + v +
                                    "\"; use scholtes, l1 or elastic");
            }
          })
      .def_rw("complementarity_tolerance", &OcpHomotopyOptions::complementarity_tolerance)
      .def_rw("intermediate_tolerance_factor", &OcpHomotopyOptions::intermediate_tolerance_factor)
      .def_rw("warm_start", &OcpHomotopyOptions::warm_start)
      .def_rw("polish", &OcpHomotopyOptions::polish)
      .def_rw("early_polish_sigma", &OcpHomotopyOptions::early_polish_sigma)
      .def_rw("stop_at_complementarity", &OcpHomotopyOptions::stop_at_complementarity)
      .def_rw("acceptable_tolerance", &OcpHomotopyOptions::acceptable_tolerance)
      .def_rw("monotone_mu_down_to", &OcpHomotopyOptions::monotone_mu_down_to)
      .def_rw("max_total_iterations", &OcpHomotopyOptions::max_total_iterations)
      .def_rw("continue_after_failure", &OcpHomotopyOptions::continue_after_failure);

  nb::class_<OcpOptions>(m, "OcpOptions")
      .def(nb::init<>())
      .def_rw("stages", &OcpOptions::stages)
      .def_rw("elements", &OcpOptions::elements)
      .def_rw("collocation_stages", &OcpOptions::collocation_stages)
      .def_prop_rw(
          "scheme", [](const OcpOptions& o) { return std::string(to_string(o.scheme)); },
          [](OcpOptions& o, const std::string& v) { o.scheme = parse_collocation_scheme(v); })
      .def_prop_rw(
          "collocation_form",
          [](const OcpOptions& o) { return std::string(to_string(o.collocation_form)); },
          [](OcpOptions& o, const std::string& v) {
            o.collocation_form = parse_collocation_form(v);
          })
      .def_prop_rw(
          "formulation", [](const OcpOptions& o) { return std::string(to_string(o.formulation)); },
          [](OcpOptions& o, const std::string& v) { o.formulation = parse_dcs_formulation(v); })
      .def_rw("standard", &OcpOptions::standard)
      .def_rw("exact_hessian", &OcpOptions::exact_hessian)
      .def_rw("lifting_depth", &OcpOptions::lifting_depth)
      .def_rw("homotopy", &OcpOptions::homotopy)
      .def_rw("solver", &OcpOptions::solver)
      .def_prop_rw(
          "cross_complementarity",
          [](const OcpOptions& o) { return std::string(to_string(o.cross_complementarity)); },
          [](OcpOptions& o, const std::string& v) {
            o.cross_complementarity = parse_cross_complementarity(v);
          })
      .def_rw("step_deviation_weight", &OcpOptions::step_deviation_weight)
      .def_rw("equilibration_weight", &OcpOptions::equilibration_weight)
      .def_rw("progress", &OcpOptions::progress);

  nb::class_<OcpHomotopyStep>(m, "OcpHomotopyStep", "One NLP of the homotopy.")
      .def_ro("sigma", &OcpHomotopyStep::sigma)
      .def_ro("objective", &OcpHomotopyStep::objective)
      .def_ro("complementarity", &OcpHomotopyStep::complementarity)
      .def_ro("iterations", &OcpHomotopyStep::iterations)
      .def_ro("cpu_seconds", &OcpHomotopyStep::cpu_seconds)
      .def_ro("ipopt_status", &OcpHomotopyStep::ipopt_status)
      .def_ro("kkt_error", &OcpHomotopyStep::kkt_error)
      .def_ro("polish", &OcpHomotopyStep::polish)
      .def_ro("mu_strategy", &OcpHomotopyStep::mu_strategy)
      .def_ro("mu_init", &OcpHomotopyStep::mu_init)
      .def_ro("product_multipliers", &OcpHomotopyStep::product_multipliers)
      .def_ro("worst_rows", &OcpHomotopyStep::worst_rows);

  nb::class_<OcpResult> result(m, "OcpResult");
  refuse_pickle(result, "bflow.OcpResult",
                "it is a solver's result; keep the arrays you need (u, x_grid, switch_times, ...)");
  result.def_prop_ro("status", [](const OcpResult& r) { return std::string(to_string(r.status)); })
      .def_prop_ro("ok", &OcpResult::ok)
      .def_ro("message", &OcpResult::message)
      .def_ro("notes", &OcpResult::notes)
      .def_ro("objective", &OcpResult::objective)
      .def_ro("T", &OcpResult::T)
      .def_ro("stage_times", &OcpResult::stage_times)
      .def_ro("x_stages", &OcpResult::x_stages)
      .def_ro("u", &OcpResult::u)
      .def_ro("grid", &OcpResult::grid)
      .def_ro("x_grid", &OcpResult::x_grid)
      .def_ro("step_sizes", &OcpResult::step_sizes)
      .def_ro("switch_times", &OcpResult::switch_times)
      .def_ro("active_sets", &OcpResult::active_sets)
      .def_ro("max_complementarity", &OcpResult::max_complementarity)
      .def_ro("ipopt_status", &OcpResult::ipopt_status)
      .def_ro("ipopt", &OcpResult::ipopt, "the IPOPT the NLPs ran on, e.g. 'IPOPT 3.14.19'")
      .def_ro("linear_solver", &OcpResult::linear_solver,
              "IPOPT's linear solver with its version or library, e.g. 'mumps 5.8.2'")
      .def_ro("blas", &OcpResult::blas,
              "the BLAS under the linear solver and its threads during the NLPs, e.g. "
              "'OpenBLAS 0.3.28, 1 thread (libcasadi-tp-openblas.so.0)'")
      .def_ro("derivatives", &OcpResult::derivatives,
              "how the Jacobian and exact Hessian were computed: 'programs: 180 traced, none "
              "kept on Jets' or 'Jets (derivative_programs off)'")
      .def_ro("kkt_error", &OcpResult::kkt_error)
      .def_ro("polished", &OcpResult::polished)
      .def_ro("homotopy", &OcpResult::homotopy)
      .def_ro("ipopt_iterations", &OcpResult::ipopt_iterations)
      .def_ro("cpu_seconds", &OcpResult::cpu_seconds)
      .def_ro("unknowns", &OcpResult::unknowns)
      .def_ro("constraints", &OcpResult::constraints)
      .def_ro("jacobian_nonzeros", &OcpResult::jacobian_nonzeros)
      .def_ro("hessian_nonzeros", &OcpResult::hessian_nonzeros);

  nb::class_<OcpModel>(m, "_OcpModel", "A compiled optimal control model (OcpModel).")
      .def_prop_ro("states", &OcpModel::states)
      .def_prop_ro("controls", &OcpModel::controls)
      .def_prop_ro("switches", &OcpModel::switches)
      .def_prop_ro("path_constraints", &OcpModel::path_constraints)
      .def_prop_ro("terminal_constraints", &OcpModel::terminal_constraints);
  m.def(
      "_load_ocp_model",
      [](const std::string& path, const std::vector<double>& parameters) {
        return std::const_pointer_cast<OcpModel>(load_compiled<OcpModel>(path, "ocp", parameters));
      },
      "path"_a, "parameters"_a);

  nb::class_<OcpProblem>(m, "OcpProblem", "The data of an optimal control problem (ocp.h).")
      .def(nb::init<>())
      .def_rw("x0", &OcpProblem::x0)
      .def_rw("horizon", &OcpProblem::horizon)
      .def_rw("time_optimal", &OcpProblem::time_optimal)
      .def_rw("T_min", &OcpProblem::T_min)
      .def_rw("T_max", &OcpProblem::T_max)
      .def_rw("x_lower", &OcpProblem::x_lower)
      .def_rw("x_upper", &OcpProblem::x_upper)
      .def_rw("u_lower", &OcpProblem::u_lower)
      .def_rw("u_upper", &OcpProblem::u_upper)
      .def_rw("path_lower", &OcpProblem::path_lower)
      .def_rw("path_upper", &OcpProblem::path_upper)
      .def_rw("terminal_lower", &OcpProblem::terminal_lower)
      .def_rw("terminal_upper", &OcpProblem::terminal_upper)
      .def_prop_rw(
          "guess",
          [](const OcpProblem& p) {
            return std::string(p.guess == OcpGuess::kSimulation  ? "simulation"
                               : p.guess == OcpGuess::kReference ? "reference"
                                                                 : "constant");
          },
          [](OcpProblem& p, const std::string& v) {
            if (v == "constant") {
              p.guess = OcpGuess::kConstant;
            } else if (v == "simulation") {
              p.guess = OcpGuess::kSimulation;
            } else {
              throw InvalidArgument("guess: unknown guess \"" + v +
                                    "\"; use constant or simulation");
            }
          })
      .def_rw("guess_x", &OcpProblem::guess_x)
      .def_rw("guess_u", &OcpProblem::guess_u);
  m.def(
      "_ocp_model",
      [](const std::shared_ptr<OcpModel>& model, const OcpProblem& problem, OcpOptions options) {
        options.cancelled = interrupt_check();
        return ocp_solve(*model, problem, options);
      },
      "model"_a, "problem"_a, "options"_a, nb::call_guard<nb::gil_scoped_release>());

  m.def(
      "_ocp_example",
      [](const std::string& name, OcpOptions options) {
        options.cancelled = interrupt_check();
        if (name == "braking-block") {
          return ocp_solve(adapt_ocp(examples::BrakingBlock{}), examples::BrakingBlock::problem(),
                           options);
        }
        if (name == "turbo-car") {
          return ocp_solve(adapt_ocp(examples::TurboCar{}), examples::TurboCar::problem(), options);
        }
        throw InvalidArgument("ocp_solve: unknown example \"" + name +
                              "\"; the examples are braking-block, turbo-car, monoped and hopper");
      },
      "example"_a, "options"_a, nb::call_guard<nb::gil_scoped_release>());
  m.def("_ocp_exact", [](const std::string& name) {
    std::map<std::string, std::vector<double>> exact;
    if (name == "braking-block") {
      using examples::BrakingBlock;
      exact["objective"] = {BrakingBlock::optimal_cost()};
      exact["stop_time"] = {BrakingBlock::stop_time()};
      exact["final_position"] = {BrakingBlock::final_position()};
    } else if (name == "turbo-car") {
      using examples::TurboCar;
      exact["T"] = {TurboCar::kOptimalTime};
      exact["switch_times"] = {TurboCar::kSwitchTimes[0], TurboCar::kSwitchTimes[1]};
      exact["control_switch_times"] = {TurboCar::kControlSwitchTimes[0],
                                       TurboCar::kControlSwitchTimes[1]};
    } else {
      throw InvalidArgument("ocp_exact: unknown example \"" + name +
                            "\"; the examples are braking-block and turbo-car");
    }
    return exact;
  });
}

}  // namespace bflow::python

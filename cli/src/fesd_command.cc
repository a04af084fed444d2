// `bflow fesd`: FESD simulation of a built-in Filippov example (format in docs/cli.md).
#include <algorithm>
#include <cmath>
#include <ctime>
#include <exception>
#include <new>
#include <ostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/filippov.h"
#include "bflow/examples/irma.h"
#include "bflow/examples/switching_cases.h"
#include "bflow/fesd/butcher.h"
#include "bflow/fesd/fesd.h"
#include "bflow/fesd/linear_solver.h"
#include "cli_commands.h"
#include "cli_json.h"
#include "cli_util.h"

namespace bflow::cli {
namespace {

struct Example {
  const char* name;
  double t_end;
  int steps;  // default N_sim
};

constexpr Example kExamples[] = {{"irma", 100.0, 20},
                                 {"crossing", 1.0, 4},
                                 {"sliding-enter", 1.0, 4},
                                 {"sliding-leave", 2.0, 4},
                                 {"spontaneous", 1.0, 4}};

std::string example_list() {
  std::string names;
  for (const Example& e : kExamples) names += (names.empty() ? "" : ", ") + std::string(e.name);
  return names;
}

// Calls f(model, x0) with the example's model and initial state.
template <typename F>
auto with_example(const std::string& name, F&& f) {
  if (name == "irma") {
    return f(adapt_step(examples::Irma{}), Eigen::VectorXd(examples::Irma::initial_state()));
  }
  const examples::SwitchingCaseSolution exact = examples::exact_switching_case(name);
  if (name == "crossing") return f(adapt_step(examples::CrossingCase{}), exact.x0);
  if (name == "sliding-enter") return f(adapt_step(examples::SlidingEnterCase{}), exact.x0);
  if (name == "sliding-leave") return f(adapt_step(examples::SlidingLeaveCase{}), exact.x0);
  return f(adapt_step(examples::SpontaneousCase{}), exact.x0);
}

// Bad input; the message starts with the option. Exit code 2.
class OptionError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

[[noreturn]] void fail(const std::string& option, const std::string& problem) {
  throw OptionError(option + ": " + problem);
}

int switches_of(const std::string& name) { return name == "irma" ? examples::Irma::kSwitches : 1; }

OrderedJson size_json(const DcsSize& s) {
  OrderedJson j;
  j["n_f"] = s.modes;
  j["n_beta"] = s.lifting;
  j["n_alg"] = s.algebraic;
  j["n_comp"] = s.complementarity;
  j["n_eq"] = s.equalities;
  return j;
}

// The JSON and its newline in one write (a failed write is detected where the command ends).
void write_result(std::ostream& out, const OrderedJson& j, bool compact) {
  std::ostringstream buffer;
  write_json(buffer, j, compact);
  buffer << '\n';
  out << buffer.str() << std::flush;
}

// Every range the library would check, checked here first so that the message names the option
// the user typed.
void check_ranges(const FesdCommandOptions& options, DcsFormulation formulation) {
  if (options.stages < 1 || options.stages > kMaxCollocationStages) {
    fail("--stages", "the number of Runge-Kutta stages must be in [1, " +
                         std::to_string(kMaxCollocationStages) + "], got " +
                         std::to_string(options.stages));
  }
  if (options.nfe < 1) {
    fail("--nfe", "the number of finite elements per integration step must be >= 1, got " +
                      std::to_string(options.nfe));
  }
  if (options.nsim && *options.nsim < 1) {
    fail("--nsim",
         "the number of integration steps must be >= 1, got " + std::to_string(*options.nsim));
  }
  if (options.t && !(*options.t > 0.0 && std::isfinite(*options.t))) {
    fail("--T", "the horizon must be finite and > 0, got " + format_number(*options.t));
  }
  if (const std::string why =
          lifting_depth_error(options.lifting, switches_of(options.example), options.example);
      !why.empty()) {
    fail("--lifting", why);
  }
  if (formulation == DcsFormulation::kStewart && options.lifting != 0) {
    fail("--lifting", "a lifting depth (" + std::to_string(options.lifting) +
                          ") applies to --formulation step only, not stewart");
  }
}

}  // namespace

int run_fesd(const FesdCommandOptions& options, std::ostream& out, std::ostream& err) {
  try {
    const Example* example = nullptr;
    for (const Example& e : kExamples) {
      if (options.example == e.name) example = &e;
    }
    if (example == nullptr) {
      report_error(
          err, "--example: unknown example " + quote(options.example) + "; use " + example_list());
      return kExitBadInput;
    }
    DcsFormulation formulation = DcsFormulation::kStep;
    CollocationScheme scheme = CollocationScheme::kRadauIIA;
    try {
      formulation = parse_dcs_formulation(options.formulation);
    } catch (const InvalidArgument&) {
      report_error(err, "--formulation: unknown formulation " + quote(options.formulation) +
                            ": use step or stewart");
      return kExitBadInput;
    }
    try {
      scheme = parse_collocation_scheme(options.scheme);
    } catch (const InvalidArgument&) {
      report_error(err, "--scheme: unknown collocation scheme " + quote(options.scheme) +
                            ": use radau or gauss");
      return kExitBadInput;
    }
    check_ranges(options, formulation);
    const int nsim = options.nsim.value_or(example->steps);
    const double t_end = options.t.value_or(example->t_end);
    FesdOptions o;
    o.scheme = scheme;
    o.stages = options.stages;
    o.elements = options.nfe;
    o.steps = nsim;
    o.standard = options.standard;
    o.formulation = formulation;
    o.lifting_depth = options.lifting;
    o.exact_hessian = options.exact_hessian;
    const std::string solver_problem = apply_solver_options(options.solver, o);
    if (!solver_problem.empty()) throw OptionError(solver_problem);  // before anything runs
    // The library refuses the same sizes (naming N_FE and N_sim); here with the options' names.
    const FesdProblemSize size =
        with_example(options.example, [&](const StepModel& model, const Eigen::VectorXd&) {
          return fesd_problem_size(model, o);
        });
    if (const std::string excess = size.step_excess(); !excess.empty()) {
      fail("--nfe", std::to_string(options.nfe) + " finite elements of " +
                        std::to_string(options.stages) + " stages give " + excess +
                        " (see docs/fesd.md)");
    }
    if (const std::string excess = size.run_excess(); !excess.empty()) {
      fail("--nsim", std::to_string(nsim) + " integration steps of " + std::to_string(options.nfe) +
                         " finite elements give " + excess + " (see docs/fesd.md)");
    }

    OrderedJson j;
    if (options.sizes) {
      // [F] Table 4 for the example's n_c switching functions, every base region a mode.
      const SignMatrix s = SignMatrix::dense(switches_of(options.example));
      j["example"] = options.example;
      j["n_c"] = s.switches();
      j["stewart"] = size_json(dcs_size(s, DcsFormulation::kStewart));
      j["step"] = size_json(dcs_size(s, DcsFormulation::kStep, options.lifting));
      OrderedJson nlp;
      nlp["formulation"] = to_string(formulation);
      nlp["lifting"] = options.lifting;
      nlp["scheme"] = to_string(scheme);
      nlp["stages"] = options.stages;
      nlp["nfe"] = options.nfe;
      nlp["unknowns"] = size.unknowns;
      nlp["constraints"] = size.constraints;
      nlp["jacobian_nonzeros"] = size.jacobian_nonzeros;
      if (options.exact_hessian) nlp["hessian_nonzeros_bound"] = size.hessian_nonzeros;
      j["nlp"] = nlp;
    } else {
      const std::clock_t start = std::clock();
      const FesdResult r =
          with_example(options.example, [&](const StepModel& model, const Eigen::VectorXd& x0) {
            return fesd_simulate(model, x0, t_end, o);
          });
      const double cpu = static_cast<double>(std::clock() - start) / CLOCKS_PER_SEC;
      j["T"] = t_end;
      j["nsim"] = nsim;
      j["x_T"] = vector_json(r.x_end);
      j["switch_times"] = r.switch_times;
      j["steps"] = o.steps;
      j["max_complementarity"] = r.max_complementarity;
      j["cpu_seconds"] = cpu;
      j["formulation"] = to_string(formulation);
      j["ipopt"] = r.ipopt;
      j["linear_solver"] = r.linear_solver;
      j["blas"] = r.blas;
      j["derivatives"] = r.derivatives;
      j["nlp_iterations"] = r.nlp_iterations;
      j["newton_steps"] = r.newton_steps;
      // Steps IPOPT accepted only at its acceptable level with complementarity above
      // sigma_final (the message then names the first).
      j["acceptable_only"] = r.acceptable_only;
      j["acceptable_only_steps"] = r.acceptable_only_steps;
      if (r.sensitivity.size() > 0) j["sensitivity"] = rows_json(r.sensitivity);
      if (!r.ok() || !r.message.empty()) {
        j["status"] = to_string(r.status);
        j["message"] = r.message;
      }
      // The partial record of a failed run: x_T is the state where it stopped.
      if (!r.ok()) j["t_reached"] = r.grid.back();
      if (options.trajectory) {
        OrderedJson t;
        t["t"] = r.grid;
        t["x"] = columns_json(r.states);
        t["h"] = r.step_sizes;
        t["active_sets"] = r.active_sets;
        j["trajectory"] = t;
      }
      write_result(out, j, options.compact);
      if (!r.ok()) {
        report_error(err, with_field("fesd", r.message));
        return kExitFailure;
      }
      if (r.acceptable_only) err << "warning: " << one_line(with_field("fesd", r.message)) << '\n';
      return kExitOk;
    }
    write_result(out, j, options.compact);
    return kExitOk;
  } catch (const OptionError& e) {
    report_error(err, e.what());
    return kExitBadInput;
  } catch (const InvalidArgument& e) {
    // What the library rejects that no option decides (the messages start with "fesd:").
    report_error(err, with_field("fesd", e.what()));
    return kExitBadInput;
  } catch (const std::bad_alloc&) {
    report_error(err, "fesd: out of memory");
    return kExitFailure;
  } catch (const std::exception& e) {
    report_error(err, std::string("fesd: internal: ") + e.what());
    return kExitFailure;
  }
}

}  // namespace bflow::cli

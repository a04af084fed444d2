// `bflow fesd`: FESD simulation of a built-in Filippov example (format in docs/cli.md).
#include <cmath>
#include <ctime>
#include <exception>
#include <ostream>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/filippov.h"
#include "bflow/examples/irma.h"
#include "bflow/examples/switching_cases.h"
#include "bflow/integrators/fesd.h"
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

FesdResult simulate_example(const std::string& name, double t_end, const FesdOptions& o) {
  if (name == "irma") {
    return fesd_simulate(adapt_step(examples::Irma{}), examples::Irma::initial_state(), t_end, o);
  }
  const examples::SwitchingCaseSolution exact = examples::exact_switching_case(name);
  if (name == "crossing")
    return fesd_simulate(adapt_step(examples::CrossingCase{}), exact.x0, t_end, o);
  if (name == "sliding-enter") {
    return fesd_simulate(adapt_step(examples::SlidingEnterCase{}), exact.x0, t_end, o);
  }
  if (name == "sliding-leave") {
    return fesd_simulate(adapt_step(examples::SlidingLeaveCase{}), exact.x0, t_end, o);
  }
  return fesd_simulate(adapt_step(examples::SpontaneousCase{}), exact.x0, t_end, o);
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
    } catch (const InvalidArgument& e) {
      report_error(err, std::string("--formulation: ") + e.what());
      return kExitBadInput;
    }
    try {
      scheme = parse_collocation_scheme(options.scheme);
    } catch (const InvalidArgument& e) {
      report_error(err, std::string("--scheme: ") + e.what());
      return kExitBadInput;
    }
    if (options.sizes) {
      // [F] Table 4 for the example's n_c switching functions, every base region a mode.
      const SignMatrix s = SignMatrix::dense(switches_of(options.example));
      OrderedJson j;
      j["example"] = options.example;
      j["n_c"] = s.switches();
      j["stewart"] = size_json(dcs_size(s, DcsFormulation::kStewart));
      j["step"] = size_json(dcs_size(s, DcsFormulation::kStep, options.lifting));
      write_json(out, j, options.compact);
      out << '\n';
      return kExitOk;
    }
    FesdOptions o;
    o.scheme = scheme;
    o.stages = options.stages;
    o.elements = options.nfe;
    o.steps = options.nsim > 0 ? options.nsim : example->steps;
    o.standard = options.standard;
    o.formulation = formulation;
    o.lifting_depth = options.lifting;
    o.exact_hessian = options.exact_hessian;
    const double t_end = options.t > 0 ? options.t : example->t_end;
    const std::clock_t start = std::clock();
    FesdResult r;
    try {
      r = simulate_example(options.example, t_end, o);
    } catch (const InvalidArgument& e) {
      report_error(err, std::string("fesd: ") + e.what());
      return kExitBadInput;
    }
    const double cpu = static_cast<double>(std::clock() - start) / CLOCKS_PER_SEC;
    OrderedJson j;
    j["x_T"] = vector_json(r.x_end);
    j["switch_times"] = r.switch_times;
    j["steps"] = o.steps;
    j["max_complementarity"] = r.max_complementarity;
    j["cpu_seconds"] = cpu;
    j["formulation"] = to_string(formulation);
    j["nlp_iterations"] = r.nlp_iterations;
    j["newton_steps"] = r.newton_steps;
    // Steps IPOPT accepted only at its acceptable level with complementarity above sigma_final
    // (the message then names the first).
    j["acceptable_only"] = r.acceptable_only;
    j["acceptable_only_steps"] = r.acceptable_only_steps;
    if (r.sensitivity.size() > 0) j["sensitivity"] = rows_json(r.sensitivity);
    if (!r.ok() || !r.message.empty()) {
      j["status"] = to_string(r.status);
      j["message"] = r.message;
    }
    if (options.trajectory) {
      OrderedJson t;
      t["t"] = r.grid;
      t["x"] = columns_json(r.states);
      t["h"] = r.step_sizes;
      t["active_sets"] = r.active_sets;
      j["trajectory"] = t;
    }
    write_json(out, j, options.compact);
    out << '\n';
    if (r.ok() && r.acceptable_only) err << "warning: " << one_line(r.message) << '\n';
    return r.ok() ? kExitOk : kExitFailure;
  } catch (const std::exception& e) {
    report_error(err, std::string("internal: ") + e.what());
    return kExitFailure;
  }
}

}  // namespace bflow::cli

// `bflow flow`: simulates a scene across its switching surfaces and prints the B-derivative of
// its flow on the requested directions (format in docs/cli.md).
//
// Every option is validated before anything is simulated, so that a rejection names the option
// ("--dx[1]: has 3 numbers, expected d = 2"). One run of bflow::flow_derivative() gives the
// whole derivative (transition matrices and jump maps), which is then evaluated on every
// direction; --fd adds finite differences of the simulated flow (bflow::fd::compare), the
// independent check. Nothing is written to `out` unless the whole result is computed, except
// the partial record of a simulation that stops early or overflows (exit code 1).
//
// Overflow. The options are finite, but a finite start can still overflow: a huge velocity
// makes |F| exceed the double range, a huge direction makes its image infinite. The library
// then often reports what follows as bad input: a margin eta . F / (|eta| |F|) that is 0 because
// |F| is infinite reads as grazing, tangents that became infinite end flow_derivative() with an
// InvalidArgument. The command watches the model's evaluations (OverflowWatch) and reports such
// a run as a failed computation, exit code 1, with "status": "overflow".
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <exception>
#include <mutex>
#include <new>
#include <optional>
#include <ostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/biped.h"
#include "bflow/core/errors.h"
#include "bflow/core/flow_derivative.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/signs.h"
#include "bflow/examples/piecewise_constant.h"
#include "bflow/integrators/finite_differences.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "bflow/integrators/overflow_watch.h"
#include "cli_commands.h"
#include "cli_json.h"
#include "cli_util.h"
#include "scene_setup.h"

namespace bflow::cli {
namespace {

// A number of the result that overflowed; the message names it. Exit code 1 with the record
// computed so far.
class OverflowError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// ---------------------------------------------------------------------------------------------
// The run.

void check_finite(const Eigen::Ref<const Eigen::MatrixXd>& values, const std::string& what) {
  if (!values.allFinite()) throw OverflowError(what + " is not finite");
}

OrderedJson events_json(const std::vector<EventRecord>& events) {
  OrderedJson list = OrderedJson::array();
  for (std::size_t i = 0; i < events.size(); ++i) {
    const EventRecord& e = events[i];
    check_finite(e.rho, "events[" + std::to_string(i) + "].rho");
    OrderedJson margins = OrderedJson::array();
    for (std::size_t k = 0; k < e.surfaces.size(); ++k) {
      margins.push_back(
          OrderedJson{{"before", e.margin_before.at(k)}, {"after", e.margin_after.at(k)}});
    }
    OrderedJson item = OrderedJson::object();
    item["t"] = e.t;
    item["surfaces"] = e.surfaces;
    item["crossing_times"] = e.crossing_times;
    item["spread"] = e.spread;
    item["window"] = e.window;
    if (std::isfinite(e.gap)) {
      item["gap"] = e.gap;
    } else {
      item["gap"] = nullptr;
    }
    item["rho"] = vector_json(e.rho);
    item["sides_before"] = e.sides_before.str();
    item["sides_after"] = e.sides_after.str();
    item["margins"] = std::move(margins);
    list.push_back(std::move(item));
  }
  return list;
}

// The crossing order at each event of the tangent that arrives there, in model surface indices.
std::vector<std::vector<int>> crossing_orders(const FlowDerivative& derivative,
                                              const Eigen::VectorXd& dx) {
  std::vector<std::vector<int>> orders;
  for (CrossingOrder& order : derivative.crossing_orders(dx))
    orders.push_back(std::move(order.order));
  return orders;
}

OrderedJson notices_json(const std::vector<FlowNotice>& notices) {
  OrderedJson list = OrderedJson::array();
  for (const FlowNotice& notice : notices) {
    OrderedJson item = OrderedJson::object();
    item["kind"] = to_string(notice.kind);
    item["surfaces"] = notice.surfaces;
    item["times"] = notice.times;
    item["gap"] = notice.gap;
    item["band"] = notice.band;
    item["message"] = notice.message;
    list.push_back(std::move(item));
  }
  return list;
}

struct Evaluation {
  OrderedJson result;
  int code = kExitOk;
  std::string error;  // with code 1
  std::vector<std::string> warnings;
};

// The simulations run on `watched` (which forwards to `model`); `result` gathers the record.
Evaluation evaluate_watched(const SegmentModel& model, const OverflowWatch& watched,
                            const Eigen::VectorXd& x0,
                            const std::vector<Eigen::VectorXd>& directions, const Request& request,
                            OrderedJson& result) {
  result["x0"] = vector_json(x0);
  // A run without tangents first: an early stop is reported with what was reached.
  const FlowResult plain = simulate(watched, x0, request.t, request.flow);
  result["backend"] = to_string(plain.backend);  // what --integrator auto chose, or the one named
  if (!plain.ok()) {
    result["status"] = to_string(plain.status);
    result["message"] = plain.message;
    result["t_reached"] = plain.t;
    result["events"] = events_json(plain.events);
    result["notices"] = notices_json(plain.notices);
    std::vector<std::string> warnings;
    for (const FlowNotice& notice : plain.notices) warnings.push_back(notice.message);
    return {std::move(result), kExitFailure,
            "flow: the simulation stopped at t = " + format_number(plain.t) + " before t = " +
                format_number(request.t) + " (" + to_string(plain.status) + "): " + plain.message,
            std::move(warnings)};
  }
  FlowResult trajectory;
  const FlowDerivative derivative =
      flow_derivative(watched, x0, request.t, request.flow, &trajectory);
  check_finite(trajectory.x, "x_t");
  result["x_t"] = vector_json(trajectory.x);
  result["events"] = events_json(trajectory.events);
  result["notices"] = notices_json(trajectory.notices);
  OrderedJson list = OrderedJson::array();
  for (std::size_t k = 0; k < directions.size(); ++k) {
    const std::string name = "directions[" + std::to_string(k) + "]";
    const Eigen::VectorXd& dx = directions[k];
    Eigen::VectorXd image;
    Eigen::MatrixXd jacobian;
    try {
      image = derivative.apply(dx);
      jacobian = derivative.active_jacobian(dx);
    } catch (const InvalidArgument& e) {
      // dx has d finite entries (checked with the options), so what the derivative refuses
      // now is an image or a crossing time beyond the double range.
      throw OverflowError(name + ": " + e.what());
    }
    check_finite(image, name + ".image");
    check_finite(jacobian, name + ".jacobian");
    OrderedJson item = OrderedJson::object();
    item["dx"] = vector_json(dx);
    item["image"] = vector_json(image);
    item["orders"] = crossing_orders(derivative, dx);
    item["jacobian"] = rows_json(jacobian);
    if (request.fd) {
      const fd::Report report = fd::compare(model, x0, request.t, dx, image, request.flow);
      const fd::ReportRow& best = report.best_one_sided();
      OrderedJson rows = OrderedJson::array();
      for (const fd::ReportRow& row : report.rows) {
        rows.push_back(OrderedJson{{"alpha", row.alpha},
                                   {"one_sided_error", row.one_sided_error},
                                   {"central_error", row.central_error}});
      }
      OrderedJson fd_json = OrderedJson::object();
      fd_json["one_sided"] = vector_json(best.one_sided);
      fd_json["central"] = vector_json(best.central);
      fd_json["alpha"] = best.alpha;
      fd_json["rows"] = std::move(rows);
      item["fd"] = std::move(fd_json);
    }
    list.push_back(std::move(item));
  }
  result["directions"] = std::move(list);
  std::vector<std::string> warnings;
  for (const FlowNotice& notice : trajectory.notices) warnings.push_back(notice.message);
  return {std::move(result), kExitOk, "", std::move(warnings)};
}

// The run, with overflow told apart from bad input: a library rejection that follows an
// overflow, or a result that is not finite, is a failed computation (exit code 1) whose record
// holds what was computed before it, "status": "overflow" and the "message".
Evaluation evaluate(const SegmentModel& model, const Eigen::VectorXd& x0,
                    const std::vector<Eigen::VectorXd>& directions, const Request& request,
                    OrderedJson result) {
  const OverflowWatch watched(model);
  std::string overflow;
  try {
    return evaluate_watched(model, watched, x0, directions, request, result);
  } catch (const OverflowError& e) {
    overflow = e.what();
  } catch (const InvalidArgument& e) {
    overflow = watched.overflow();
    if (overflow.empty()) throw;
    overflow += "; the library then reported: " + std::string(e.what());
  }
  result["status"] = "overflow";
  result["message"] = overflow;
  return {std::move(result), kExitFailure, "flow: the computation overflowed: " + overflow, {}};
}

Evaluation run(const FlowCommandOptions& options) {
  const SceneSetup setup = parse_scene_setup(options);
  const Request& request = setup.request;
  // x0 and the directions, now that d is known; then the run.
  return with_scene(setup, {}, [&](const SegmentModel& model, const Eigen::VectorXd& default_x0) {
    const int d = model.states();
    const Eigen::VectorXd x0 =
        request.x0_text ? parse_vector(*request.x0_text, "--x0", d) : default_x0;
    std::vector<Eigen::VectorXd> directions;
    for (std::size_t k = 0; k < request.dx_texts.size(); ++k) {
      directions.push_back(parse_vector(request.dx_texts[k], "--dx[" + std::to_string(k) + "]", d));
    }
    if (directions.empty()) {
      for (int i = 0; i < d; ++i) directions.push_back(Eigen::VectorXd::Unit(d, i));
    }
    return evaluate(model, x0, directions, request, setup.head);
  });
}

int flow_command(const FlowCommandOptions& options, std::ostream& out, std::ostream& err) {
  try {
    const Evaluation evaluation = run(options);
    std::ostringstream buffer;
    write_json(buffer, evaluation.result, options.compact);
    buffer << '\n';
    out << buffer.str();
    for (const std::string& warning : evaluation.warnings) {
      err << "warning: " << one_line(warning) << '\n';
    }
    if (evaluation.code != kExitOk) report_error(err, evaluation.error);
    return evaluation.code;
  } catch (const InputError& e) {
    report_error(err, e.what());
    return kExitBadInput;
  } catch (const InvalidArgument& e) {
    // Sliding, grazing, an integrator that is not built, x0 on a surface, ...
    report_error(err, std::string("flow: ") + e.what());
    return kExitBadInput;
  } catch (const std::bad_alloc&) {
    report_error(err, "flow: out of memory");
    return kExitFailure;
  } catch (const std::exception& e) {
    report_error(err, std::string("flow: internal: ") + e.what());
    return kExitFailure;
  }
}

}  // namespace

int run_flow(const FlowCommandOptions& options, std::ostream& out, std::ostream& err) {
  return finish_output(out, err, flow_command(options, out, err));
}

}  // namespace bflow::cli

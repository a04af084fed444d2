// Sweeps of the flow's B-derivative over a grid of initial states, on a pool of threads
// (bflow::run_ordered), with a progress line on stderr.
#include <cstdint>
#include <cstdio>
#include <string>
#include <tuple>
#include <vector>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include "bflow/core/errors.h"
#include "bflow/sweep/parallel.h"
#include "bflow/sweep/sweep.h"
#include "bindings.h"
#include "model_handle.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace bflow::python {

void bind_sweep(nb::module_& m) {
  nb::class_<FlowSampleRecord> record(m, "SweepRecord", "One sample of a sweep.");
  refuse_pickle(record, "bflow.SweepRecord", "keep the numbers you need (x_t, images, ...)");
  record.def_ro("index", &FlowSampleRecord::index)
      .def_ro("varied", &FlowSampleRecord::varied)
      .def_ro("status", &FlowSampleRecord::status)
      .def_ro("message", &FlowSampleRecord::message)
      .def_ro("t_reached", &FlowSampleRecord::t_reached)
      .def_ro("x_t", &FlowSampleRecord::x_t)
      .def_ro("events", &FlowSampleRecord::events)
      .def_ro("images", &FlowSampleRecord::images)
      .def_ro("orders", &FlowSampleRecord::orders)
      .def_ro("pieces", &FlowSampleRecord::pieces)
      .def_prop_ro("ok", &FlowSampleRecord::ok)
      .def("structure", &event_structure, "direction"_a = 0,
           "its events and the crossing order the direction takes, e.g. \"0+1 (1>0)\"");

  m.def(
      "_sweep",
      [](const Model& model, const Eigen::Ref<const Eigen::VectorXd>& x0, double t,
         const std::vector<std::tuple<int, std::string, double, double, std::int64_t>>& axes,
         const std::vector<Eigen::VectorXd>& directions, const FlowOptions& flow, int threads,
         bool progress) {
        if (x0.size() != model.states()) {
          throw InvalidArgument("sweep: x0 has " + std::to_string(x0.size()) +
                                " entries, the model " + std::to_string(model.states()) +
                                " states");
        }
        std::vector<SweepAxis> grid_axes;
        bool varies_parameters = false;
        for (const auto& [index, parameter, lo, hi, signed_count] : axes) {
          if (signed_count < 0) {
            throw InvalidArgument(
                "sweep: the axis " +
                (parameter.empty() ? "x[" + std::to_string(index) + "]" : parameter) +
                " has a count of " + std::to_string(signed_count) + "; it needs >= 1");
          }
          const auto count = static_cast<std::uint64_t>(signed_count);
          if (!parameter.empty()) {
            if (!model.with_parameters) {
              throw InvalidArgument("sweep: the axis of \"" + parameter +
                                    "\" varies a "
                                    "parameter, and the model " +
                                    model.path + " has no parameters to vary");
            }
            grid_axes.push_back(SweepAxis::parameter_axis(parameter, lo, hi, count));
            varies_parameters = true;
            continue;
          }
          if (index < 0 || index >= model.states()) {
            throw InvalidArgument("sweep: the axis of x[" + std::to_string(index) +
                                  "] is outside the model's " + std::to_string(model.states()) +
                                  " states");
          }
          grid_axes.push_back(SweepAxis::state_axis(index, lo, hi, count));
        }
        const SweepGrid grid(grid_axes);
        for (const Eigen::VectorXd& dx : directions) {
          if (dx.size() != model.states()) {
            throw InvalidArgument("sweep: a direction has " + std::to_string(dx.size()) +
                                  " entries, the model " + std::to_string(model.states()) +
                                  " states");
          }
        }
        FlowSweepRequest request;
        request.t = t;
        request.directions = directions;
        request.flow = flow;
        std::vector<FlowSampleRecord> records;
        records.reserve(static_cast<std::size_t>(grid.samples()));
        SweepRunOptions run;
        run.threads = threads;
        if (progress) {
          run.progress = [](const SweepProgress& p) {
            const double left = p.seconds_left();
            std::fprintf(
                stderr, "\rsweep: %llu/%llu samples (%.0f %%), %.0f/s, %s   ",
                static_cast<unsigned long long>(p.done), static_cast<unsigned long long>(p.total),
                p.total > 0 ? 100.0 * static_cast<double>(p.done) / static_cast<double>(p.total)
                            : 100.0,
                p.rate(),
                left < 0.0 ? "time left unknown"
                : left == 0.0
                    ? "done"
                    : (std::to_string(static_cast<long>(left + 0.5)) + " s left").c_str());
            std::fflush(stderr);
          };
        }
        const Eigen::VectorXd start = x0;
        // The parameters of sample i, by name (none without parameter axes).
        const auto parameters_of = [&grid](std::uint64_t i) {
          ParameterValues changes;
          const std::vector<double> values = grid.values(i);
          for (std::size_t a = 0; a < grid.axes().size(); ++a) {
            if (grid.axes()[a].kind == SweepAxis::Kind::kParameter) {
              changes.emplace_back(grid.axes()[a].parameter, values[a]);
            }
          }
          return changes;
        };
        // A parameter the model does not have is refused before any sample runs.
        if (varies_parameters) model.with_parameters(parameters_of(0));
        run_ordered<FlowSampleRecord>(
            0, grid.samples(),
            [&](std::uint64_t i) {
              Eigen::VectorXd x = start;
              grid.apply_states(i, x);
              if (!varies_parameters) {
                return evaluate_flow_sample(*model.model, x, request, i, grid.values(i));
              }
              const std::shared_ptr<const SegmentModel> changed =
                  model.with_parameters(parameters_of(i));
              return evaluate_flow_sample(*changed, x, request, i, grid.values(i));
            },
            [&](std::uint64_t i, const std::string& what) {
              return FlowSampleRecord::error(i, grid.values(i), what);
            },
            [&](FlowSampleRecord&& r) { records.push_back(std::move(r)); }, run);
        if (progress) std::fprintf(stderr, "\n");
        return records;
      },
      "model"_a, "x0"_a, "t"_a, "axes"_a, "directions"_a, "flow"_a, "threads"_a, "progress"_a,
      nb::call_guard<nb::gil_scoped_release>());
}

}  // namespace bflow::python

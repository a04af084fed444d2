// Sweeps of the flow's B-derivative over a grid of initial states, on a pool of threads
// (bflow::run_ordered), with a progress line on stderr; Ctrl-C stops them with the finished
// records, and a sweep whose records would not fit in memory is refused before it runs.
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cstddef>
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
#include "interrupt.h"
#include "model_handle.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace bflow::python {
namespace {

// The bytes glibc's malloc takes for n: n + 8 rounded up to 16, at least 32.
double heap_chunk(std::size_t n) {
  return n == 0 ? 0.0 : static_cast<double>(std::max<std::size_t>(32, (n + 8 + 15) / 16 * 16));
}

double string_bytes(const std::string& s) {
  return s.capacity() > 15 ? heap_chunk(s.capacity() + 1) : 0.0;  // 15: libstdc++'s inline size
}

// What one record costs once it is a SweepRecord in the returned list, beyond its heap arrays:
// the nanobind instance that holds the C++ struct (object header and the struct itself), the
// list's pointer, nanobind's table entry for the instance and the moved-from struct left in
// the C++ vector until the call returns (sizeof(FlowSampleRecord) again). Measured with the
// peak RSS of sweeps of 10^5 and 3 10^5 samples of a 2-state model with one event and two
// directions (x86-64, glibc, CPython 3.11): 1234 and 1258 bytes per record (1036 and 1041 held
// after the call), where record_bytes without this constant counts 1120 (720 of heap arrays and
// 2 x 200 of structs); the 138 left are rounded up to 160.
constexpr double kPythonBytesPerRecord = 160.0;

// The bytes a record holds in the list the sweep returns.
double record_bytes(const FlowSampleRecord& r) {
  double b = 2.0 * sizeof(FlowSampleRecord) + kPythonBytesPerRecord;
  b += heap_chunk(r.varied.size() * sizeof(double)) + string_bytes(r.status) +
       string_bytes(r.message) + heap_chunk(static_cast<std::size_t>(r.x_t.size()) * 8);
  b += heap_chunk(r.events.size() * sizeof(EventRecord));
  for (const EventRecord& e : r.events) {
    b += heap_chunk(static_cast<std::size_t>(e.rho.size()) * 8) +
         heap_chunk(e.surfaces.size() * sizeof(int)) + heap_chunk(e.crossing_times.size() * 8) +
         heap_chunk(e.margin_before.size() * 8) + heap_chunk(e.margin_after.size() * 8);
  }
  b += heap_chunk(r.images.size() * sizeof(Eigen::VectorXd));
  for (const Eigen::VectorXd& v : r.images) b += heap_chunk(static_cast<std::size_t>(v.size()) * 8);
  b += heap_chunk(r.orders.size() * sizeof(std::vector<std::vector<int>>));
  for (const auto& direction : r.orders) {
    b += heap_chunk(direction.size() * sizeof(std::vector<int>));
    for (const std::vector<int>& event : direction) b += heap_chunk(event.size() * sizeof(int));
  }
  return b;
}

// The memory a sweep may fill with its records: 3/4 of the machine's physical memory (the rest
// is the interpreter's, the model's and everyone else's), or of the address-space limit when
// that is lower.
double usable_memory_bytes(double* physical) {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
  double limit =
      pages > 0 && page > 0 ? static_cast<double>(pages) * static_cast<double>(page) : 0.0;
  *physical = limit;
  rlimit r{};
  if (getrlimit(RLIMIT_AS, &r) == 0 && r.rlim_cur != RLIM_INFINITY) {
    limit = limit > 0.0 ? std::min(limit, static_cast<double>(r.rlim_cur))
                        : static_cast<double>(r.rlim_cur);
  }
  return 0.75 * limit;
}

std::string bytes_text(double bytes) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.3g", bytes);
  return text;
}

// Refuses a sweep whose records, each as large as `typical`, would not fit (see
// usable_memory_bytes), naming the samples, the bytes needed and the bytes available.
void check_memory(std::uint64_t samples, const FlowSampleRecord& typical, const char* basis) {
  double physical = 0.0;
  const double usable = usable_memory_bytes(&physical);
  if (usable <= 0.0) return;  // the system does not say: nothing to compare with
  const double per_record = record_bytes(typical);
  const double needed = per_record * static_cast<double>(samples);
  if (needed <= usable) return;
  throw InvalidArgument("sweep: " + std::to_string(samples) + " samples would hold about " +
                        bytes_text(needed) + " bytes of records (" + bytes_text(per_record) +
                        " bytes each, " + basis + "), more than the " + bytes_text(usable) +
                        " bytes a sweep may use (3/4 of the " + bytes_text(physical) +
                        " bytes of this machine's memory or of the address-space limit); "
                        "sweep fewer samples, or run the command `bflow sweep`, which streams "
                        "the records to a file");
}

}  // namespace

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
        // Before any sample runs: a record without events (the least any sample holds) times the
        // samples must fit; the first record checks again with its own events.
        {
          FlowSampleRecord least;
          least.varied.assign(grid.axes().size(), 0.0);
          least.x_t = Eigen::VectorXd::Zero(model.states());
          least.images.assign(directions.size(), Eigen::VectorXd::Zero(model.states()));
          least.orders.resize(directions.size());
          check_memory(grid.samples(), least, "counting no event");
        }
        std::vector<FlowSampleRecord> records;
        records.reserve(static_cast<std::size_t>(grid.samples()));
        SweepRunOptions run;
        run.threads = threads;
        run.cancelled = interrupt_check();
        const int pool = static_cast<int>(std::min<std::uint64_t>(
            static_cast<std::uint64_t>(sweep_threads(run)), grid.samples()));
        if (progress) {
          std::fprintf(stderr, "sweep: %llu samples on %d thread%s%s\n",
                       static_cast<unsigned long long>(grid.samples()), pool, pool == 1 ? "" : "s",
                       threads > pool ? " (one per sample)" : "");
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
        const SweepRunResult done = run_ordered<FlowSampleRecord>(
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
            [&](FlowSampleRecord&& r) {
              if (records.empty() && grid.samples() > 1) {
                check_memory(grid.samples(), r, "each assumed to have the first sample's events");
              }
              records.push_back(std::move(r));
            },
            run);
        if (progress) std::fprintf(stderr, "\n");
        return std::make_tuple(std::move(records), done.threads, done.cancelled, grid.samples());
      },
      "model"_a, "x0"_a, "t"_a, "axes"_a, "directions"_a, "flow"_a, "threads"_a, "progress"_a,
      nb::call_guard<nb::gil_scoped_release>());
}

}  // namespace bflow::python

// Sweeps of the B-derivative of a flow over a grid of initial states and parameters: the grid,
// the record of one sample, its evaluation, and the two streamed formats (JSON lines and CSV).
// parallel.h runs the samples on threads; docs/sweep.md shows the command built on both.
//
//   bflow::SweepGrid grid({bflow::SweepAxis::state_axis(0, -1.0, 1.0, 101)});
//   const bflow::FlowSweepRequest request{x0, 1.0, {dx}, {}};
//   bflow::SweepWriter writer(std::cout, bflow::SweepFormat::kJsonLines, grid, d, 1);
//   bflow::run_ordered<bflow::FlowSampleRecord>(
//       0, grid.samples(),
//       [&](std::uint64_t i) {
//         Eigen::VectorXd x = x0;
//         grid.apply_states(i, x);
//         return bflow::evaluate_flow_sample(model, x, request, i, grid.values(i));
//       },
//       [&](std::uint64_t i, const std::string& what) {
//         return bflow::FlowSampleRecord::error(i, grid.values(i), what);
//       },
//       [&](bflow::FlowSampleRecord&& r) { writer.write(r); });
#ifndef BFLOW_SWEEP_SWEEP_H_
#define BFLOW_SWEEP_SWEEP_H_

#include <cstddef>
#include <cstdint>
#include <ostream>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/segment.h"

namespace bflow {

/** One varied coordinate: a state entry or a named parameter, `count` values from lo to hi
    (equally spaced, both ends included; count 1 is lo alone). */
struct SweepAxis {
  enum class Kind { kState, kParameter };
  Kind kind = Kind::kState;
  int state = 0;          ///< with kState: the index into x0
  std::string parameter;  ///< with kParameter: the parameter's name
  double lo = 0.0, hi = 0.0;
  std::uint64_t count = 1;

  static SweepAxis state_axis(int index, double lo, double hi, std::uint64_t count);
  static SweepAxis parameter_axis(std::string name, double lo, double hi, std::uint64_t count);
  /** The k-th value, lo + k (hi - lo) / (count - 1) (lo when count = 1); hi exactly at the
      end. When hi - lo exceeds the double range (ends near +-1.8e308) the value is computed as
      (1 - s) lo + s hi with s = k / (count - 1) instead, which stays finite. */
  double value(std::uint64_t k) const;
  /** "x[1]" or the parameter's name. */
  std::string name() const;
};

/** The samples of a sweep: every combination of the axes' values, in grid order (the first
    axis varies slowest, like nested loops in the order the axes are given). A grid without axes
    has one sample. */
class SweepGrid {
 public:
  /** @throws InvalidArgument for a count of 0, a non-finite end, more than 2^53 samples
      (indices stay exact in a double), or the same state or parameter on two axes (the later
      axis's values would replace the earlier's). */
  explicit SweepGrid(std::vector<SweepAxis> axes);
  const std::vector<SweepAxis>& axes() const { return axes_; }
  std::uint64_t samples() const { return samples_; }
  /** The varied values of sample `index`, in the order of the axes. @pre index < samples() */
  std::vector<double> values(std::uint64_t index) const;
  /** Writes the state axes' values of sample `index` into x. */
  void apply_states(std::uint64_t index, Eigen::Ref<Eigen::VectorXd> x) const;

 private:
  std::vector<SweepAxis> axes_;
  std::uint64_t samples_ = 1;
};

/** What every sample of a flow sweep computes, beside its initial state. */
struct FlowSweepRequest {
  double t = 1.0;                           ///< final time
  std::vector<Eigen::VectorXd> directions;  ///< the B-derivative's images of these (dx)
  FlowOptions flow;
};

/** One sample's outcome. status is "ok"; an integration status that stopped the run early
    (to_string(IntegrationStatus), e.g. "step-size underflow"); "overflow" when a number of the
    result (x_t, an event time, an image) is not finite, the message naming it; "rejected" when
    the library refused the run as bad input for the engine (grazing, sliding, Zeno; the
    message says which); or "error" for any other failure. Only "ok" has x_t, images, orders and
    pieces, and every number of an "ok" record is finite. */
struct FlowSampleRecord {
  std::uint64_t index = 0;
  std::vector<double> varied;
  std::string status = "ok";
  std::string message;
  double t_reached = 0.0;  ///< the time the simulation reached (t when ok)
  Eigen::VectorXd x_t;
  std::vector<EventRecord> events;
  std::vector<Eigen::VectorXd> images;  ///< one per direction
  /** Per direction, per event: the order in which that direction's perturbation crosses the
      event's surfaces (model indices, first crossed first). */
  std::vector<std::vector<std::vector<int>>> orders;
  /** The number of linear pieces of the B-derivative: the product over events of (surfaces
      crossed together)! (a double: exact up to 2^53, +inf beyond the double range). */
  double pieces = 1.0;
  bool ok() const { return status == "ok"; }

  static FlowSampleRecord error(std::uint64_t index, std::vector<double> varied,
                                const std::string& message);
};

/** The flow from x0 to request.t and its B-derivative on the requested directions; a failure
    (see FlowSampleRecord) is recorded, never thrown. Thread-safe for a model whose evaluations
    are (every adapted scene and example is). */
FlowSampleRecord evaluate_flow_sample(const SegmentModel& model,
                                      const Eigen::Ref<const Eigen::VectorXd>& x0,
                                      const FlowSweepRequest& request, std::uint64_t index,
                                      std::vector<double> varied);

/** A record's event structure, the colour of its cell in an atlas of crossing orders: its
    events in time order joined by " | ", each the surfaces crossed together ("0+1"), followed for
    a group by the order that direction `direction` takes ("0+1 (1>0)"); "no event" when there is
    none; the status for a failed sample ("rejected", ...). Samples with the same structure cross
    the same surfaces in the same order, so their B-derivatives along the direction come from the
    same piece. */
std::string event_structure(const FlowSampleRecord& record, std::size_t direction = 0);

enum class SweepFormat { kJsonLines, kCsv };
/** "jsonl" or "csv". @throws InvalidArgument naming the formats for anything else. */
SweepFormat parse_sweep_format(const std::string& text);

/** Writes records, one line each, as they come, after a first line that identifies the sweep.
    The identity line: JSON lines {"sweep": IDENTITY}, CSV "# bflow sweep IDENTITY" followed by
    the column header. IDENTITY is the caller's JSON object (the command puts bflow's version,
    the scene, its parameters, t, x0, the directions and the integrator and grouping options
    there) with "format", "states", "directions" and "axes" ([{"name", "lo", "hi", "count"}])
    added by the writer; it lets find_resume_point() continue only the same sweep.
    JSON lines: {"index", "varied", "status", "message" (failures only), "t_reached", "x_t",
    "events": [{"t", "surfaces"}], "images", "orders", "pieces"}; failed samples have x_t,
    images and orders empty and pieces 0.
    CSV: the header lines, then index, varied values (columns named after the axes), status,
    message, t_reached, x_t[0..d), image<k>[0..d) per direction, events (t:s1+s2;... ), orders
    (per direction: events separated by ';', surfaces by '>' and directions by '|'), pieces;
    failed samples leave the numbers empty; line breaks in a message become spaces, so a record
    is always one line. Numbers are in the shortest form that reads back as the same double
    (format_number). */
class SweepWriter {
 public:
  /** @throws InvalidArgument when `identity` is not the text of a JSON object. */
  SweepWriter(std::ostream& out, SweepFormat format, const SweepGrid& grid, int states,
              int directions, const std::string& identity = "{}");
  /** The identity line (and for CSV the column header); call once before the first record of
      a new output. */
  void header() { out_ << header_line(); }
  /** The identity line, and for CSV the column header, each with its newline. */
  std::string header_line() const;
  /** The identity object as written in the first line (compact JSON). */
  const std::string& identity() const { return identity_; }
  SweepFormat format() const { return format_; }
  const SweepGrid& grid() const { return grid_; }
  /** The record's line (with its newline), for writing later: thread-safe, so that workers can
      format their records and the writing thread only copies bytes. */
  std::string line(const FlowSampleRecord& record) const;
  void write(const FlowSampleRecord& record) { out_ << line(record); }

 private:
  std::ostream& out_;
  SweepFormat format_;
  const SweepGrid& grid_;
  int states_, directions_;
  std::string identity_;
};

/** How much of an earlier output of the same sweep can be kept. */
struct SweepResumePoint {
  std::uint64_t records = 0;  ///< whole records 0 .. records - 1: resume at this index
  std::uint64_t bytes = 0;    ///< the length of the output that holds them (and the CSV header)
};

/** The longest line find_resume_point() reads by default: 64 MiB. */
inline constexpr std::size_t kResumeMaxLineBytes = std::size_t{64} << 20;

/** Reads an output that `writer`'s sweep wrote and stopped (a killed process, a lost node): its
    identity line (and CSV header), byte for byte the writer's header_line(), then records
    0, 1, 2, ..., each a whole line that parses as a record of this format (CSV: as many fields
    as the header) whose index and varied values are those of the grid. The last line may be
    cut (no newline) if it is the start of the next record; it is left out. An empty output, or
    one holding only the start of the identity line, has nothing to keep (bytes = 0).
    Reads at most max_line_bytes + 1 bytes per line, so an endless or binary input ends early.
    @throws InvalidArgument naming the line and the problem for anything else: not a sweep
    output, the output of another sweep (the message names the first identity field that
    differs), another format, a record that is not whole, out of order or beyond the grid, a
    line longer than max_line_bytes. The caller then leaves the output as it was. */
SweepResumePoint find_resume_point(std::istream& in, const SweepWriter& writer,
                                   std::size_t max_line_bytes = kResumeMaxLineBytes);

}  // namespace bflow

#endif  // BFLOW_SWEEP_SWEEP_H_

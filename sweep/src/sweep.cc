#include "bflow/sweep/sweep.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <limits>
#include <sstream>
#include <utility>

#include <nlohmann/json.hpp>

#include "bflow/core/errors.h"
#include "bflow/core/flow_derivative.h"

namespace bflow {
namespace {

constexpr std::uint64_t kMaxSamples = std::uint64_t{1} << 53;

void check_axis(const SweepAxis& axis) {
  if (axis.count == 0) {
    throw InvalidArgument("sweep: the axis " + axis.name() + " has a count of 0; it needs >= 1");
  }
  if (!std::isfinite(axis.lo) || !std::isfinite(axis.hi)) {
    throw InvalidArgument("sweep: the axis " + axis.name() + " has a non-finite end: " +
                          format_number(axis.lo) + " to " + format_number(axis.hi));
  }
  if (axis.kind == SweepAxis::Kind::kState && axis.state < 0) {
    throw InvalidArgument("sweep: a state axis has the negative index " +
                          std::to_string(axis.state));
  }
}

// A CSV field on one line: line breaks become spaces; quoted when it holds a separator or a
// quote.
std::string csv_field(std::string text) {
  for (char& c : text) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  if (text.find_first_of(",\"") == std::string::npos) return text;
  std::string quoted = "\"";
  for (char c : text) {
    if (c == '"') quoted += '"';
    quoted += c;
  }
  return quoted + "\"";
}

[[noreturn]] void not_this_sweep(std::uint64_t line, const std::string& problem) {
  throw InvalidArgument("sweep: the output to resume is not from this sweep: line " +
                        std::to_string(line) + " " + problem);
}

// The index and the varied values at the start of a CSV record.
std::vector<double> csv_leading_numbers(const std::string& line, std::size_t count) {
  std::vector<double> values;
  std::size_t start = 0;
  while (values.size() < count) {
    const std::size_t comma = line.find(',', start);
    const std::string field = line.substr(start, comma - start);
    char* end = nullptr;
    const double v = std::strtod(field.c_str(), &end);
    if (field.empty() || end != field.c_str() + field.size()) return {};
    values.push_back(v);
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return values.size() == count ? values : std::vector<double>{};
}

nlohmann::ordered_json vector_json(const Eigen::Ref<const Eigen::VectorXd>& v) {
  nlohmann::ordered_json list = nlohmann::ordered_json::array();
  for (Eigen::Index k = 0; k < v.size(); ++k) {
    // JSON has no inf or nan: a non-finite entry is written as null.
    if (std::isfinite(v[k])) {
      list.push_back(v[k]);
    } else {
      list.push_back(nullptr);
    }
  }
  return list;
}

}  // namespace

SweepAxis SweepAxis::state_axis(int index, double lo, double hi, std::uint64_t count) {
  SweepAxis axis;
  axis.kind = Kind::kState;
  axis.state = index;
  axis.lo = lo;
  axis.hi = hi;
  axis.count = count;
  return axis;
}

SweepAxis SweepAxis::parameter_axis(std::string name, double lo, double hi, std::uint64_t count) {
  SweepAxis axis;
  axis.kind = Kind::kParameter;
  axis.parameter = std::move(name);
  axis.lo = lo;
  axis.hi = hi;
  axis.count = count;
  return axis;
}

double SweepAxis::value(std::uint64_t k) const {
  if (count <= 1 || k == 0) return lo;
  if (k + 1 == count) return hi;
  return lo + (hi - lo) * static_cast<double>(k) / static_cast<double>(count - 1);
}

std::string SweepAxis::name() const {
  return kind == Kind::kState ? "x[" + std::to_string(state) + "]" : parameter;
}

SweepGrid::SweepGrid(std::vector<SweepAxis> axes) : axes_(std::move(axes)) {
  for (const SweepAxis& axis : axes_) {
    check_axis(axis);
    if (axis.count > kMaxSamples / samples_) {
      throw InvalidArgument("sweep: the grid has more than 2^53 samples (the axis " + axis.name() +
                            " has " + std::to_string(axis.count) + " values)");
    }
    samples_ *= axis.count;
  }
}

std::vector<double> SweepGrid::values(std::uint64_t index) const {
  BFLOW_ASSERT(index < samples_);
  std::vector<double> out(axes_.size());
  for (std::size_t a = axes_.size(); a-- > 0;) {  // the last axis varies fastest
    out[a] = axes_[a].value(index % axes_[a].count);
    index /= axes_[a].count;
  }
  return out;
}

void SweepGrid::apply_states(std::uint64_t index, Eigen::Ref<Eigen::VectorXd> x) const {
  const std::vector<double> v = values(index);
  for (std::size_t a = 0; a < axes_.size(); ++a) {
    if (axes_[a].kind != SweepAxis::Kind::kState) continue;
    if (axes_[a].state >= x.size()) {
      throw InvalidArgument("sweep: the axis " + axes_[a].name() +
                            " is outside the state (d = " + std::to_string(x.size()) + ")");
    }
    x[axes_[a].state] = v[a];
  }
}

FlowSampleRecord FlowSampleRecord::error(std::uint64_t index, std::vector<double> varied,
                                         const std::string& message) {
  FlowSampleRecord r;
  r.index = index;
  r.varied = std::move(varied);
  r.status = "error";
  r.message = message;
  r.pieces = 0.0;
  return r;
}

FlowSampleRecord evaluate_flow_sample(const SegmentModel& model,
                                      const Eigen::Ref<const Eigen::VectorXd>& x0,
                                      const FlowSweepRequest& request, std::uint64_t index,
                                      std::vector<double> varied) {
  FlowSampleRecord r;
  r.index = index;
  r.varied = std::move(varied);
  try {
    FlowResult trajectory;
    const FlowDerivative derivative =
        flow_derivative(model, x0, request.t, request.flow, &trajectory);
    r.t_reached = trajectory.t;
    r.x_t = trajectory.x;
    r.events = std::move(trajectory.events);
    for (const Eigen::VectorXd& dx : request.directions) {
      r.images.push_back(derivative.apply(dx));
      std::vector<std::vector<int>> orders;
      for (CrossingOrder& order : derivative.crossing_orders(dx))
        orders.push_back(std::move(order.order));
      r.orders.push_back(std::move(orders));
    }
    for (const EventRecord& e : r.events) {
      for (int k = 2; k <= e.group_size(); ++k) r.pieces *= k;
    }
    return r;
  } catch (const InvalidArgument& e) {
    r.message = e.what();
  }
  // Not a whole run: was it an integration outcome (the library quotes it in the exception)?
  r.pieces = 0.0;
  try {
    const FlowResult plain = simulate(model, x0, request.t, request.flow);
    r.t_reached = plain.t;
    r.events = plain.events;
    if (!plain.ok()) {
      r.status = to_string(plain.status);
      r.message = plain.message;
      return r;
    }
  } catch (const InvalidArgument& e) {
    r.message = e.what();
  }
  r.status = "rejected";
  return r;
}

std::string event_structure(const FlowSampleRecord& r, std::size_t direction) {
  if (!r.ok()) return r.status;
  if (r.events.empty()) return "no event";
  std::string text;
  for (std::size_t e = 0; e < r.events.size(); ++e) {
    if (e > 0) text += " | ";
    const std::vector<int>& surfaces = r.events[e].surfaces;
    for (std::size_t k = 0; k < surfaces.size(); ++k) {
      if (k > 0) text += '+';
      text += std::to_string(surfaces[k]);
    }
    if (surfaces.size() > 1 && direction < r.orders.size() && e < r.orders[direction].size()) {
      text += " (";
      const std::vector<int>& order = r.orders[direction][e];
      for (std::size_t k = 0; k < order.size(); ++k) {
        if (k > 0) text += '>';
        text += std::to_string(order[k]);
      }
      text += ')';
    }
  }
  return text;
}

SweepFormat parse_sweep_format(const std::string& text) {
  if (text == "jsonl") return SweepFormat::kJsonLines;
  if (text == "csv") return SweepFormat::kCsv;
  throw InvalidArgument("sweep: unknown format \"" + text + "\"; the formats are jsonl and csv");
}

SweepWriter::SweepWriter(std::ostream& out, SweepFormat format, const SweepGrid& grid, int states,
                         int directions)
    : out_(out), format_(format), grid_(grid), states_(states), directions_(directions) {}

std::string SweepWriter::header_line() const {
  if (format_ != SweepFormat::kCsv) return "";
  std::ostringstream line;
  line << "index";
  for (const SweepAxis& axis : grid_.axes()) line << ',' << csv_field(axis.name());
  line << ",status,message,t_reached";
  for (int i = 0; i < states_; ++i) line << ",x_t[" << i << ']';
  for (int k = 0; k < directions_; ++k) {
    for (int i = 0; i < states_; ++i) line << ",image" << k << '[' << i << ']';
  }
  line << ",events,orders,pieces\n";
  return line.str();
}

std::string SweepWriter::line(const FlowSampleRecord& r) const {
  std::ostringstream line;
  if (format_ == SweepFormat::kJsonLines) {
    nlohmann::ordered_json j = nlohmann::ordered_json::object();
    j["index"] = r.index;
    j["varied"] = r.varied;
    j["status"] = r.status;
    if (!r.ok()) j["message"] = r.message;
    j["t_reached"] = r.t_reached;
    j["x_t"] = vector_json(r.x_t);
    nlohmann::ordered_json events = nlohmann::ordered_json::array();
    for (const EventRecord& e : r.events) {
      events.push_back(nlohmann::ordered_json{{"t", e.t}, {"surfaces", e.surfaces}});
    }
    j["events"] = std::move(events);
    nlohmann::ordered_json images = nlohmann::ordered_json::array();
    for (const Eigen::VectorXd& image : r.images) images.push_back(vector_json(image));
    j["images"] = std::move(images);
    j["orders"] = r.orders;
    j["pieces"] = r.pieces;
    line << j.dump() << '\n';
  } else {
    line << r.index;
    for (double v : r.varied) line << ',' << format_number(v);
    line << ',' << r.status << ',' << csv_field(r.message) << ',' << format_number(r.t_reached);
    for (int i = 0; i < states_; ++i) {
      line << ',';
      if (r.ok() && i < r.x_t.size()) line << format_number(r.x_t[i]);
    }
    for (int k = 0; k < directions_; ++k) {
      for (int i = 0; i < states_; ++i) {
        line << ',';
        if (r.ok() && static_cast<std::size_t>(k) < r.images.size() &&
            i < r.images[static_cast<std::size_t>(k)].size()) {
          line << format_number(r.images[static_cast<std::size_t>(k)][i]);
        }
      }
    }
    line << ',';
    for (std::size_t e = 0; e < r.events.size(); ++e) {
      if (e > 0) line << ';';
      line << format_number(r.events[e].t) << ':';
      for (std::size_t s = 0; s < r.events[e].surfaces.size(); ++s) {
        if (s > 0) line << '+';
        line << r.events[e].surfaces[s];
      }
    }
    line << ',';
    for (std::size_t k = 0; k < r.orders.size(); ++k) {
      if (k > 0) line << '|';
      for (std::size_t e = 0; e < r.orders[k].size(); ++e) {
        if (e > 0) line << ';';
        for (std::size_t s = 0; s < r.orders[k][e].size(); ++s) {
          if (s > 0) line << '>';
          line << r.orders[k][e][s];
        }
      }
    }
    line << ',' << format_number(r.pieces) << '\n';
  }
  return line.str();
}

SweepResumePoint find_resume_point(std::istream& in, const SweepWriter& writer) {
  SweepResumePoint point;
  const SweepGrid& grid = writer.grid();
  const std::string header = writer.header_line();
  std::string line;
  std::uint64_t number = 0;  // line number, from 1
  std::uint64_t offset = 0;
  while (std::getline(in, line)) {
    ++number;
    if (in.eof()) break;  // no newline: the line was cut
    const std::uint64_t next_offset = offset + line.size() + 1;
    if (number == 1 && !header.empty()) {
      if (line + "\n" != header) not_this_sweep(number, "is not the CSV header of this sweep");
      offset = point.bytes = next_offset;
      continue;
    }
    const std::uint64_t index = point.records;
    if (index >= grid.samples()) not_this_sweep(number, "is a record beyond the grid's samples");
    std::vector<double> found;
    if (writer.format() == SweepFormat::kJsonLines) {
      const nlohmann::json j = nlohmann::json::parse(line, nullptr, false);
      if (j.is_discarded() || !j.is_object() || !j.contains("index") ||
          !j["index"].is_number_unsigned() || !j.contains("varied") || !j["varied"].is_array()) {
        not_this_sweep(number, "is not a JSON-lines record");
      }
      found.push_back(static_cast<double>(j["index"].get<std::uint64_t>()));
      for (const auto& v : j["varied"]) {
        if (!v.is_number()) not_this_sweep(number, "has a varied value that is not a number");
        found.push_back(v.get<double>());
      }
    } else {
      found = csv_leading_numbers(line, 1 + grid.axes().size());
      if (found.empty()) not_this_sweep(number, "is not a CSV record of this sweep");
    }
    std::vector<double> expected{static_cast<double>(index)};
    for (double v : grid.values(index)) expected.push_back(v);
    if (found != expected) {
      const auto text = [](const std::vector<double>& v) {
        return format_vector(
            Eigen::Map<const Eigen::VectorXd>(v.data(), static_cast<Eigen::Index>(v.size())));
      };
      not_this_sweep(number,
                     "has index and varied values " + text(found) + ", expected " + text(expected));
    }
    ++point.records;
    offset = point.bytes = next_offset;
  }
  return point;
}

}  // namespace bflow

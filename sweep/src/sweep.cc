#include "bflow/sweep/sweep.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <limits>
#include <sstream>
#include <string>
#include <utility>

#include <nlohmann/json.hpp>

#include "bflow/core/errors.h"
#include "bflow/core/flow_derivative.h"
#include "bflow/integrators/overflow_watch.h"

namespace bflow {
namespace {

constexpr std::uint64_t kMaxSamples = std::uint64_t{1} << 53;
constexpr const char* kCsvIdentityPrefix = "# bflow sweep ";

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

enum class LineEnd { kWhole, kCut, kNone, kTooLong };

// The next line of `in` without its newline: whole, cut (the input ends without a newline),
// none (the input has ended) or too long (more than `max` bytes; reading stops there).
LineEnd read_line(std::istream& in, std::string& line, std::size_t max) {
  line.clear();
  std::streambuf* const buffer = in.rdbuf();
  if (buffer == nullptr) return LineEnd::kNone;
  while (true) {
    const int c = buffer->sbumpc();
    if (c == std::char_traits<char>::eof()) return line.empty() ? LineEnd::kNone : LineEnd::kCut;
    if (c == '\n') return LineEnd::kWhole;
    if (line.size() >= max) return LineEnd::kTooLong;
    line.push_back(static_cast<char>(c));
  }
}

// The fields of a CSV line (a quoted field may hold commas and doubled quotes); 0 when a quote
// is left open.
std::size_t csv_field_count(const std::string& line) {
  std::size_t fields = 1;
  bool quoted = false;
  for (std::size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"') {
        if (i + 1 < line.size() && line[i + 1] == '"') {
          ++i;
        } else {
          quoted = false;
        }
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      ++fields;
    }
  }
  return quoted ? 0 : fields;
}

// Whether `line` is a whole JSON-lines record of sample `index`: valid JSON that starts
// {"index":INDEX,"varied":[v...],"status":" with the grid's values, read back exactly.
bool json_record_matches(const std::string& line, std::uint64_t index, const SweepGrid& grid) {
  const std::string start = "{\"index\":" + std::to_string(index) + ",\"varied\":[";
  if (line.compare(0, start.size(), start) != 0) return false;
  const char* at = line.c_str() + start.size();
  const std::vector<double> values = grid.values(index);
  for (std::size_t k = 0; k < values.size(); ++k) {
    if (k > 0 && *at++ != ',') return false;
    char* end = nullptr;
    const double v = std::strtod(at, &end);
    if (end == at || v != values[k]) return false;
    at = end;
  }
  static const std::string status = "],\"status\":\"";
  std::size_t position = static_cast<std::size_t>(at - line.c_str());
  if (line.compare(position, status.size(), status) != 0) return false;
  // The other keys of a record, in their order (a quote inside a string is escaped, so these
  // are keys); then a validating scan of the whole line.
  for (const char* key : {",\"t_reached\":", ",\"x_t\":[", ",\"events\":[", ",\"images\":[",
                          ",\"orders\":[", ",\"pieces\":"}) {
    position = line.find(key, position);
    if (position == std::string::npos) return false;
  }
  return line.back() == '}' && nlohmann::json::accept(line);
}

// A value of a file, quoted for a message: JSON-escaped, invalid UTF-8 replaced, at most about
// `max` bytes.
std::string shown(const std::string& text, std::size_t max = 60) {
  const bool cut = text.size() > max;
  std::string dumped = nlohmann::json(text.substr(0, max))
                           .dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  if (cut) dumped.insert(dumped.size() - 1, "...");
  std::string escaped;  // JSON leaves DEL as it is; a message shows it
  for (char c : dumped) escaped += c == '\x7f' ? std::string("\\u007f") : std::string(1, c);
  return escaped;
}

// Why the first line of an output is not this sweep's identity line: "is not a bflow sweep
// output (...)", "is a CSV output", or "is from another sweep: its "t" is 0.5, this sweep's 1".
std::string identity_difference(const std::string& line, const SweepWriter& writer) {
  const std::string json_prefix = "{\"sweep\":";
  std::string object_text;
  const bool json_line = line.compare(0, json_prefix.size(), json_prefix) == 0;
  const bool csv_line = line.compare(0, std::strlen(kCsvIdentityPrefix), kCsvIdentityPrefix) == 0;
  nlohmann::ordered_json found;
  if (json_line) {
    const nlohmann::ordered_json whole = nlohmann::ordered_json::parse(line, nullptr, false);
    if (!whole.is_discarded() && whole.is_object() && whole.size() == 1 &&
        whole.contains("sweep")) {
      found = whole["sweep"];
    }
  } else if (csv_line) {
    found =
        nlohmann::ordered_json::parse(line.substr(std::strlen(kCsvIdentityPrefix)), nullptr, false);
  }
  if (!found.is_object()) {
    return "is not a bflow sweep output (its first line is " + shown(line) + ")";
  }
  const nlohmann::ordered_json expected = nlohmann::ordered_json::parse(writer.identity());
  const auto value = [](const nlohmann::ordered_json& v) {
    const std::string text = v.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
    return text.size() > 80 ? text.substr(0, 77) + "..." : text;
  };
  for (const auto& [key, want] : expected.items()) {
    if (!found.contains(key)) {
      return "is from another sweep: it has no \"" + key + "\", this sweep's is " + value(want);
    }
    if (found[key] != want) {
      return "is from another sweep: its \"" + key + "\" is " + value(found[key]) +
             ", this sweep's is " + value(want);
    }
  }
  for (const auto& [key, unused] : found.items()) {
    if (!expected.contains(key)) {
      return "is from another sweep: it has " + shown(key) + ", which this sweep has not";
    }
  }
  return "is from another sweep: its first line is not byte for byte this sweep's identity";
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
  const double scaled = (hi - lo) * static_cast<double>(k);
  if (std::isfinite(scaled)) return lo + scaled / static_cast<double>(count - 1);
  // hi - lo (or k times it) is beyond the double range: a convex combination of the ends, each
  // term at most max(|lo|, |hi|) in magnitude, stays finite.
  const double s = static_cast<double>(k) / static_cast<double>(count - 1);
  return (1.0 - s) * lo + s * hi;
}

std::string SweepAxis::name() const {
  return kind == Kind::kState ? "x[" + std::to_string(state) + "]" : parameter;
}

SweepGrid::SweepGrid(std::vector<SweepAxis> axes) : axes_(std::move(axes)) {
  for (std::size_t a = 0; a < axes_.size(); ++a) {
    const SweepAxis& axis = axes_[a];
    check_axis(axis);
    // A coordinate on two axes would take the later axis's value only: the earlier one's
    // values would label samples they did not produce.
    for (std::size_t b = 0; b < a; ++b) {
      if (axes_[b].kind == axis.kind && axes_[b].name() == axis.name()) {
        throw InvalidArgument("sweep: " + axis.name() + " is varied by axes " + std::to_string(b) +
                              " and " + std::to_string(a) + "; vary each once");
      }
    }
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
  // A rejection that follows an overflow in the model's evaluations is an overflow, as in
  // `bflow flow` (overflow_watch.h).
  const OverflowWatch watched(model);
  try {
    FlowResult trajectory;
    const FlowDerivative derivative =
        flow_derivative(watched, x0, request.t, request.flow, &trajectory);
    r.t_reached = trajectory.t;
    r.x_t = trajectory.x;
    r.events = std::move(trajectory.events);
    for (const Eigen::VectorXd& dx : request.directions) {
      std::vector<std::vector<int>> orders;
      try {
        r.images.push_back(derivative.apply(dx));
        for (CrossingOrder& order : derivative.crossing_orders(dx))
          orders.push_back(std::move(order.order));
      } catch (const InvalidArgument& e) {
        // The direction has the state's size and finite entries (the caller checked them), so
        // what apply() or crossing_orders() refuse now is a number beyond the double range.
        r.images.resize(r.orders.size());
        r.images.push_back(Eigen::VectorXd::Constant(dx.size(), INFINITY));
        if (r.message.empty()) r.message = e.what();
      }
      r.orders.push_back(std::move(orders));
    }
    for (const EventRecord& e : r.events) {
      for (int k = 2; k <= e.group_size(); ++k) r.pieces *= k;
    }
    // A finite start can still overflow (a huge direction, a field beyond the double range):
    // such a record is not "ok", and keeps none of the numbers that are not finite.
    std::string overflowed;
    if (!std::isfinite(r.t_reached)) overflowed = "t_reached";
    if (overflowed.empty() && !r.x_t.allFinite()) overflowed = "x_t";
    for (std::size_t e = 0; overflowed.empty() && e < r.events.size(); ++e) {
      if (!std::isfinite(r.events[e].t)) overflowed = "events[" + std::to_string(e) + "].t";
    }
    for (std::size_t k = 0; overflowed.empty() && k < r.images.size(); ++k) {
      if (!r.images[k].allFinite()) overflowed = "images[" + std::to_string(k) + "]";
    }
    if (!overflowed.empty()) {
      r.status = "overflow";
      r.message = "the computation overflowed: " + overflowed + " is not finite" +
                  (r.message.empty() ? "" : " (" + r.message + ")");
      if (!std::isfinite(r.t_reached)) r.t_reached = 0.0;
      r.x_t.resize(0);
      r.images.clear();
      r.orders.clear();
      r.pieces = 0.0;
      bool events_finite = true;
      for (const EventRecord& e : r.events) events_finite = events_finite && std::isfinite(e.t);
      if (!events_finite) r.events.clear();
    }
    return r;
  } catch (const InvalidArgument& e) {
    r.message = e.what();
  }
  // Not a whole run: was it an integration outcome (the library quotes it in the exception)?
  r.pieces = 0.0;
  try {
    const FlowResult plain = simulate(watched, x0, request.t, request.flow);
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
  const std::string overflow = watched.overflow();
  if (!overflow.empty()) {
    r.status = "overflow";
    r.message =
        "the computation overflowed: " + overflow + "; the library then reported: " + r.message;
    return r;
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
                         int directions, const std::string& identity)
    : out_(out), format_(format), grid_(grid), states_(states), directions_(directions) {
  nlohmann::ordered_json object = nlohmann::ordered_json::parse(identity, nullptr, false);
  if (object.is_discarded() || !object.is_object()) {
    throw InvalidArgument("sweep: the identity of a sweep must be a JSON object, got " +
                          identity.substr(0, 80));
  }
  object["format"] = format == SweepFormat::kCsv ? "csv" : "jsonl";
  object["states"] = states;
  object["directions"] = directions;
  nlohmann::ordered_json axes = nlohmann::ordered_json::array();
  for (const SweepAxis& axis : grid.axes()) {
    axes.push_back(nlohmann::ordered_json{
        {"name", axis.name()}, {"lo", axis.lo}, {"hi", axis.hi}, {"count", axis.count}});
  }
  object["axes"] = std::move(axes);
  identity_ = object.dump();  // one line: dump() escapes every control character
}

std::string SweepWriter::header_line() const {
  if (format_ != SweepFormat::kCsv) return "{\"sweep\":" + identity_ + "}\n";
  std::ostringstream line;
  line << kCsvIdentityPrefix << identity_ << '\n';
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

SweepResumePoint find_resume_point(std::istream& in, const SweepWriter& writer,
                                   std::size_t max_line_bytes) {
  SweepResumePoint point;
  const SweepGrid& grid = writer.grid();
  std::vector<std::string> header_lines;
  {
    const std::string header = writer.header_line();
    std::size_t at = 0;
    while (at < header.size()) {
      const std::size_t newline = header.find('\n', at);
      header_lines.push_back(header.substr(at, newline - at));
      at = newline + 1;
    }
  }
  std::string line;
  std::uint64_t number = 0;  // line number, from 1
  std::uint64_t offset = 0;
  for (const std::string& expected : header_lines) {
    ++number;
    const LineEnd end = read_line(in, line, std::max(max_line_bytes, expected.size()));
    if (end == LineEnd::kNone) return point;  // only a start of the header: nothing to keep
    const bool prefix =
        line.size() <= expected.size() && expected.compare(0, line.size(), line) == 0;
    if (end == LineEnd::kCut && prefix) return point;
    if (end == LineEnd::kWhole && line == expected) {
      offset += line.size() + 1;
      continue;
    }
    if (number == 1) {
      throw InvalidArgument("sweep: the output to resume " + identity_difference(line, writer));
    }
    not_this_sweep(number, "is not the CSV column header of this sweep");
  }
  point.bytes = offset;
  const std::size_t columns =
      writer.format() == SweepFormat::kCsv ? csv_field_count(header_lines.back()) : std::size_t{0};
  while (true) {
    ++number;
    const std::uint64_t index = point.records;
    const LineEnd end = read_line(in, line, max_line_bytes);
    if (end == LineEnd::kNone) break;
    if (end == LineEnd::kTooLong) {
      not_this_sweep(number, "is longer than " + std::to_string(max_line_bytes) +
                                 " bytes, more than any record");
    }
    if (index >= grid.samples()) not_this_sweep(number, "is a record beyond the grid's samples");
    if (end == LineEnd::kCut) {
      // The last line, without its newline: the start of record `index`, cut by the stop.
      const std::string start = writer.format() == SweepFormat::kJsonLines
                                    ? "{\"index\":" + std::to_string(index) + ","
                                    : std::to_string(index) + ",";
      const std::size_t n = std::min(line.size(), start.size());
      if (line.compare(0, n, start, 0, n) == 0) break;
      not_this_sweep(
          number, "is an incomplete line that is not the start of record " + std::to_string(index));
    }
    std::vector<double> found;
    if (writer.format() == SweepFormat::kJsonLines && json_record_matches(line, index, grid)) {
      // The usual case, checked without building the document (a resumed output can hold
      // gigabytes).
    } else if (writer.format() == SweepFormat::kJsonLines) {
      const nlohmann::json j = nlohmann::json::parse(line, nullptr, false);
      if (j.is_discarded() || !j.is_object() || !j.contains("index") ||
          !j["index"].is_number_unsigned() || !j.contains("varied") || !j["varied"].is_array() ||
          !j.contains("status") || !j["status"].is_string() || !j.contains("pieces")) {
        not_this_sweep(number, "is not a JSON-lines record");
      }
      found.push_back(static_cast<double>(j["index"].get<std::uint64_t>()));
      for (const auto& v : j["varied"]) {
        if (!v.is_number()) not_this_sweep(number, "has a varied value that is not a number");
        found.push_back(v.get<double>());
      }
    } else {
      if (csv_field_count(line) != columns) {
        not_this_sweep(number, "is not a CSV record of this sweep (not " + std::to_string(columns) +
                                   " fields)");
      }
      found = csv_leading_numbers(line, 1 + grid.axes().size());
      if (found.empty()) not_this_sweep(number, "is not a CSV record of this sweep");
    }
    std::vector<double> expected{static_cast<double>(index)};
    for (double v : grid.values(index)) expected.push_back(v);
    if (writer.format() == SweepFormat::kJsonLines && found == expected) {
      // Its index and values are this record's, but its keys are not a record's.
      not_this_sweep(number, "is not a whole JSON-lines record (a key is missing or misspelt)");
    }
    if (!found.empty() && found != expected) {
      const auto text = [](const std::vector<double>& v) {
        return format_vector(
            Eigen::Map<const Eigen::VectorXd>(v.data(), static_cast<Eigen::Index>(v.size())));
      };
      not_this_sweep(number,
                     "has index and varied values " + text(found) + ", expected " + text(expected));
    }
    ++point.records;
    offset += line.size() + 1;
    point.bytes = offset;
  }
  return point;
}

}  // namespace bflow

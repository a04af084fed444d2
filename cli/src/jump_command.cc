// `bflow jump`: the JumpMap of the core, JSON in, JSON out (format in docs/cli.md).
//
// The input is validated field by field before the core sees it, so that every rejection names
// the field ("tangents[2]: has 3 numbers, expected d = 2"); what only the core can judge (rank,
// transversality, sign words) is passed through with its own message, which already names the
// field. Nothing is written to `out` unless the whole result is computed and finite.
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <istream>
#include <iterator>
#include <map>
#include <memory>
#include <new>
#include <optional>
#include <ostream>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bflow/core/errors.h"
#include "bflow/core/field_limits.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/signs.h"
#include "bflow/core/triangulation.h"
#include "cli_commands.h"
#include "cli_json.h"
#include "cli_util.h"

namespace bflow::cli {
namespace {

using Json = nlohmann::json;

// Bad input; the message starts with the field. Exit code 2.
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A result that cannot be printed honestly (overflow to a non-finite number). Exit code 1.
class OutputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The barycentric image is printed only when its own error estimate is below this fraction of
// |B(dx)|.
constexpr double kBarycentricTolerance = 1e-8;

[[noreturn]] void fail(const std::string& field, const std::string& problem) {
  throw InputError(field + ": " + problem);
}

const std::vector<std::string>& known_keys() {
  static const std::vector<std::string> keys = {"normals", "field_limits", "tangents", "pieces",
                                                "triangulation"};
  return keys;
}

// Levenshtein distance, for "did you mean" on a mistyped key.
std::size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t above = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = above;
    }
  }
  return row[b.size()];
}

// "string \"abc\"", "number", "array of 3", ... for "expected X, got Y".
std::string describe(const Json& v) {
  switch (v.type()) {
    case Json::value_t::string:
      return "string " + quote(v.get_ref<const std::string&>(), 20);
    case Json::value_t::boolean:
      return std::string("boolean ") + (v.get<bool>() ? "true" : "false");
    case Json::value_t::array:
      return "an array of " + std::to_string(v.size());
    case Json::value_t::object:
      return "an object";
    case Json::value_t::null:
      return "null";
    default:
      return "a number";
  }
}

// ---------------------------------------------------------------------------------------------
// Parsing: nlohmann's DOM builder, plus a check that no object repeats a key (the DOM would
// keep the last one silently).

class DuplicateCheckingParser {
 public:
  explicit DuplicateCheckingParser(Json& root) : dom_(root) {}

  bool null() { return element() && dom_.null(); }
  bool boolean(bool v) { return element() && dom_.boolean(v); }
  bool number_integer(Json::number_integer_t v) { return element() && dom_.number_integer(v); }
  bool number_unsigned(Json::number_unsigned_t v) { return element() && dom_.number_unsigned(v); }
  bool number_float(Json::number_float_t v, const Json::string_t& s) {
    return element() && dom_.number_float(v, s);
  }
  bool string(Json::string_t& v) { return element() && dom_.string(v); }
  bool binary(Json::binary_t& v) { return element() && dom_.binary(v); }
  bool start_object(std::size_t size) {
    element();
    frames_.push_back(Frame{true, {}, {}, 0});
    return dom_.start_object(size);
  }
  bool key(Json::string_t& k) {
    Frame& frame = frames_.back();
    if (!frame.keys.insert(k).second) {
      throw InputError(path() + ": key " + quote(k) + " appears twice");
    }
    frame.key = k;
    return dom_.key(k);
  }
  bool end_object() {
    frames_.pop_back();
    return dom_.end_object();
  }
  bool start_array(std::size_t size) {
    element();
    frames_.push_back(Frame{false, {}, {}, 0});
    return dom_.start_array(size);
  }
  bool end_array() {
    frames_.pop_back();
    return dom_.end_array();
  }
  // A template, so that the exception reaches the caller with its own type.
  template <typename Exception>
  bool parse_error(std::size_t position, const std::string& token, const Exception& e) {
    return dom_.parse_error(position, token, e);
  }

 private:
  struct Frame {
    bool object;
    std::set<std::string> keys;
    std::string key;    // last key read (objects)
    std::size_t count;  // elements started (arrays)
  };

  // Counts one more element of the enclosing array.
  bool element() {
    if (!frames_.empty() && !frames_.back().object) ++frames_.back().count;
    return true;
  }

  // A key as it appears in a path: as is when it is short and plain ("field_limits", "+-"),
  // else quoted at a bounded length.
  static std::string path_key(const std::string& key) {
    const bool plain = !key.empty() && key.size() <= 40 &&
                       key.find_first_not_of(
                           "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
                           "0123456789_+-") == std::string::npos;
    return plain ? key : quote(key, 40);
  }

  // The innermost container's place in the document: "input", "field_limits", "tangents[2]".
  std::string path() const {
    std::string text;
    for (std::size_t i = 0; i + 1 < frames_.size(); ++i) {
      const Frame& f = frames_[i];
      if (f.object) {
        text += (text.empty() ? "" : ".") + path_key(f.key);
      } else {
        text += "[" + std::to_string(f.count - 1) + "]";
      }
    }
    return text.empty() ? "input" : text;
  }

  nlohmann::detail::json_sax_dom_parser<Json> dom_;
  std::vector<Frame> frames_;
};

// nlohmann's message with the input it quotes ("last read: '...'", which holds as much of the
// input as the failing token, a whole string up to its bad byte; "number overflow parsing
// '...'") cut to a short printable prefix.
std::string bounded_parse_message(const std::string& message) {
  for (const std::string marker : {"last read: '", "number overflow parsing '"}) {
    const auto start = message.find(marker);
    if (start == std::string::npos) continue;
    const auto first = start + marker.size();
    auto last = message.find("'; expected ", first);
    if (last == std::string::npos) last = message.size() - (message.back() == '\'' ? 1 : 0);
    if (last < first) return message;
    return message.substr(0, first) + escaped(message.substr(first, last - first), 40, false) +
           message.substr(last);
  }
  return message;
}

// "line L, column C" of byte `offset` (both from 1, columns in bytes, as nlohmann counts).
std::string position_of(const std::string& text, std::size_t offset) {
  std::size_t line = 1, line_start = 0;
  for (std::size_t i = 0; i < offset && i < text.size(); ++i) {
    if (text[i] == '\n') {
      ++line;
      line_start = i + 1;
    }
  }
  return "line " + std::to_string(line) + ", column " + std::to_string(offset - line_start + 1);
}

Json parse_document(const std::string& text) {
  Json root;
  DuplicateCheckingParser parser(root);
  try {
    Json::sax_parse(text, &parser);
  } catch (const Json::exception& e) {
    // Syntax errors and number overflow ("1e999"). Drop nlohmann's tag,
    // "[json.exception.parse_error.101] "; keep the position and the reason.
    std::string message = e.what();
    const auto tag_end = message.find("] ");
    if (message.rfind("[json.exception.", 0) == 0 && tag_end != std::string::npos) {
      message.erase(0, tag_end + 2);
    }
    throw InputError("input: not valid JSON: " + bounded_parse_message(message));
  }
  // nlohmann reads a NUL byte as the end of the input: a document followed by one parses, and
  // whatever comes after it would be ignored. A NUL cannot be inside the document (not even in
  // a string, where control characters must be escaped), so any NUL is a trailing byte.
  if (const auto nul = text.find('\0'); nul != std::string::npos) {
    throw InputError("input: not valid JSON: a NUL byte follows the document at " +
                     position_of(text, nul) + " (" + std::to_string(text.size() - nul) +
                     " trailing bytes); only whitespace may follow the document");
  }
  return root;
}

// ---------------------------------------------------------------------------------------------
// Field readers. `field` is the name used in messages.

double read_number(const Json& v, const std::string& field) {
  if (!v.is_number()) fail(field, "expected a number, got " + describe(v));
  const double x = v.get<double>();
  if (!std::isfinite(x)) fail(field, "number is out of the range of a double");
  return x;
}

// An array of exactly `dim` numbers.
Eigen::VectorXd read_vector(const Json& v, const std::string& field, Eigen::Index dim) {
  if (!v.is_array()) {
    fail(field, "expected an array of d = " + std::to_string(dim) + " numbers, got " + describe(v));
  }
  if (static_cast<Eigen::Index>(v.size()) != dim) {
    fail(field,
         "has " + std::to_string(v.size()) + " numbers, expected d = " + std::to_string(dim));
  }
  Eigen::VectorXd out(dim);
  for (Eigen::Index i = 0; i < dim; ++i) {
    out[i] = read_number(v[static_cast<std::size_t>(i)], field + "[" + std::to_string(i) + "]");
  }
  return out;
}

Eigen::MatrixXd read_normals(const Json& v) {
  if (!v.is_array()) {
    fail("normals", "expected an array of rows eta_j (one per surface), got " + describe(v));
  }
  if (v.empty()) fail("normals", "has no rows; expected at least one surface");
  for (std::size_t j = 0; j < v.size(); ++j) {
    if (!v[j].is_array()) {
      fail("normals",
           "row " + std::to_string(j) + " is not an array of numbers (got " + describe(v[j]) + ")");
    }
  }
  const std::size_t d = v[0].size();
  if (d == 0) fail("normals", "row 0 is empty; expected d >= 1 numbers");
  for (std::size_t j = 1; j < v.size(); ++j) {
    if (v[j].size() != d) {
      fail("normals", "row " + std::to_string(j) + " has " + std::to_string(v[j].size()) +
                          " numbers, expected " + std::to_string(d));
    }
  }
  const std::size_t n = v.size();
  if (n > d) {
    // Checked here so that the limits are not first reported as incomplete.
    fail("normals", "n = " + std::to_string(n) + " surfaces in d = " + std::to_string(d) +
                        " dimensions; at most d surfaces can meet transversally");
  }
  Eigen::MatrixXd eta(n, d);
  for (std::size_t j = 0; j < n; ++j) {
    for (std::size_t i = 0; i < d; ++i) {
      eta(static_cast<Eigen::Index>(j), static_cast<Eigen::Index>(i)) =
          read_number(v[j][i], "normals[" + std::to_string(j) + "][" + std::to_string(i) + "]");
    }
  }
  return eta;
}

// A sign word of n characters '-' and '+', checked here rather than by the core so that the
// message counts characters (code points: "−" is one, not its three bytes) and quotes the one
// that is wrong.
void check_sign_word(const std::string& word, int n) {
  std::size_t characters = 0;
  std::string wrong;
  std::size_t wrong_position = 0;
  for (std::size_t i = 0; i < word.size(); ++characters) {
    std::size_t length = 1;
    if (word[i] != '-' && word[i] != '+') {
      const std::string character = quote_character(word, i, length);
      if (wrong.empty()) {
        wrong = character;
        wrong_position = characters;
      }
    }
    i += length;
  }
  if (characters != static_cast<std::size_t>(n)) {
    fail("field_limits", "word " + quote(word, 40) + " has " + std::to_string(characters) +
                             " characters, expected " + std::to_string(n) + " (one per surface)");
  }
  if (!wrong.empty()) {
    fail("field_limits", "sign word " + quote(word, 40) + " has " + wrong + " at position " +
                             std::to_string(wrong_position) + "; only '-' and '+' are allowed");
  }
}

Eigen::MatrixXd read_field_limits(const Json& v, int n, int d) {
  if (!v.is_object()) {
    fail(
        "field_limits",
        "expected an object mapping each sign word to d numbers, e.g. {\"--\": [1, 1], ...}, got " +
            describe(v));
  }
  std::map<std::string, Eigen::VectorXd> words;
  for (const auto& item : v.items()) {
    check_sign_word(item.key(), n);
    words.emplace(item.key(),
                  read_vector(item.value(), "field_limits[" + quote(item.key()) + "]", d));
  }
  try {
    return limits_table_from_words(n, d, words);
  } catch (const InvalidArgument& e) {
    throw InputError(with_field("field_limits", e.what()));
  }
}

std::vector<Eigen::VectorXd> read_tangents(const Json& v, int d) {
  if (!v.is_array()) {
    fail("tangents", "expected an array of tangent vectors of d = " + std::to_string(d) +
                         " numbers, got " + describe(v));
  }
  std::vector<Eigen::VectorXd> tangents;
  tangents.reserve(v.size());
  for (std::size_t k = 0; k < v.size(); ++k) {
    tangents.push_back(read_vector(v[k], "tangents[" + std::to_string(k) + "]", d));
  }
  return tangents;
}

bool read_flag(const Json& document, const std::string& key) {
  const auto it = document.find(key);
  if (it == document.end()) return false;
  if (!it->is_boolean()) fail(key, "expected true or false, got " + describe(*it));
  return it->get<bool>();
}

const Json& required(const Json& document, const std::string& key) {
  const auto it = document.find(key);
  if (it == document.end()) fail(key, "required field is missing");
  return *it;
}

void check_keys(const Json& document) {
  if (!document.is_object()) {
    fail("input",
         "expected a JSON object with keys \"normals\", \"field_limits\", \"tangents\", got " +
             describe(document));
  }
  const auto& keys = known_keys();
  for (const auto& item : document.items()) {
    if (std::find(keys.begin(), keys.end(), item.key()) != keys.end()) continue;
    std::string hint;
    for (const auto& k : keys) {
      if (edit_distance(item.key(), k) <= 2) hint = " (did you mean \"" + k + "\"?)";
    }
    fail("input", "unknown key " + quote(item.key()) + hint +
                      "; the keys are normals, field_limits, tangents, pieces, triangulation");
  }
}

// ---------------------------------------------------------------------------------------------
// Output.

void check_finite(const Eigen::Ref<const Eigen::MatrixXd>& values, const std::string& field,
                  const std::string& what) {
  if (!values.allFinite()) {
    throw OutputError(field + ": " + what +
                      " is not finite (overflow in the computation; rescale the normals, limits or "
                      "tangents)");
  }
}

// Words in binary order (column b.bits() of the core's tables): "--", "+-", "-+", "++".
OrderedJson words_json(const Eigen::MatrixXd& columns, int n) {
  OrderedJson out = OrderedJson::object();
  for (Eigen::Index w = 0; w < columns.cols(); ++w) {
    out[Signs(n, static_cast<std::uint64_t>(w)).str()] = vector_json(columns.col(w));
  }
  return out;
}

// ---------------------------------------------------------------------------------------------

// Bytes of JSON text per number, an upper estimate: the shortest round-trip form of a double
// has at most 24 characters, plus ", " or an indentation.
constexpr double kBytesPerNumber = 26.0;

double factorial(int n) {
  double value = 1.0;
  for (int k = 2; k <= n; ++k) value *= k;
  return value;
}

// An upper estimate of the output's size, from the sizes alone (before anything is computed).
double estimate_output_bytes(int n, int d, std::size_t tangents, bool pieces, bool triangulation) {
  const double count = factorial(n);
  double numbers = static_cast<double>(tangents) * (2.0 * d + 2.0 * n + double(d) * d);
  double lines = static_cast<double>(tangents) * (d + 8.0);
  if (pieces) {
    numbers += count * (n + double(d) * d);
    lines += count * (d + 6.0);
  }
  if (triangulation) {
    numbers += std::ldexp(2.0 * d, n) + double(d) * (d - n + 1) + count * (n + (n + 1.0) * n);
    lines += std::ldexp(2.0, n) + d + count * 6.0;
  }
  return 256.0 + numbers * kBytesPerNumber + lines * 16.0;
}

std::string format_bytes(double bytes) {
  char text[64];
  if (bytes >= 1024.0 * 1024.0 * 1024.0) {
    std::snprintf(text, sizeof text, "%.3g GiB", bytes / (1024.0 * 1024.0 * 1024.0));
  } else {
    std::snprintf(text, sizeof text, "%.3g MiB", bytes / (1024.0 * 1024.0));
  }
  return text;
}

// The computed result: everything but the pieces as JSON, and the map to stream the pieces from.
struct Evaluation {
  OrderedJson head = OrderedJson::object();  // "n", "d", "results"
  OrderedJson tail = OrderedJson::object();  // "triangulation", if asked
  std::unique_ptr<JumpMap> jump;
  bool pieces = false;
  double estimated_bytes = 0.0;
};

// A computed quantity the double range cannot hold (the core says "beyond the double range").
[[noreturn]] void computation_failed(const std::string& field, const InvalidArgument& e) {
  throw OutputError(with_field(field, e.what()));
}

Evaluation evaluate(const Json& document, const JumpOptions& options) {
  check_keys(document);
  const Json& normals_json = required(document, "normals");
  const Json& limits_json = required(document, "field_limits");
  const Json& tangents_json = required(document, "tangents");

  const Eigen::MatrixXd eta = read_normals(normals_json);
  const int n = static_cast<int>(eta.rows());
  const int d = static_cast<int>(eta.cols());
  const Eigen::MatrixXd limits = read_field_limits(limits_json, n, d);
  const std::vector<Eigen::VectorXd> tangents = read_tangents(tangents_json, d);
  const bool want_pieces = read_flag(document, "pieces");
  const bool want_triangulation = read_flag(document, "triangulation");
  if (want_pieces && n > JumpMap::kMaxEnumeratedSurfaces) {
    fail("pieces", "n = " + std::to_string(n) +
                       " surfaces give n! pieces; \"pieces\" is limited "
                       "to n <= " +
                       std::to_string(JumpMap::kMaxEnumeratedSurfaces));
  }
  if (want_triangulation && n > JumpMap::kMaxEnumeratedSurfaces) {
    fail("triangulation", "n = " + std::to_string(n) +
                              " surfaces give n! simplices; "
                              "\"triangulation\" is limited to n <= " +
                              std::to_string(JumpMap::kMaxEnumeratedSurfaces));
  }
  Evaluation result;
  result.pieces = want_pieces;
  result.estimated_bytes =
      estimate_output_bytes(n, d, tangents.size(), want_pieces, want_triangulation);
  if (result.estimated_bytes > static_cast<double>(options.max_output_bytes)) {
    fail(want_pieces          ? "pieces"
         : want_triangulation ? "triangulation"
                              : "tangents",
         "the output would be about " + format_bytes(result.estimated_bytes) +
             " (n = " + std::to_string(n) + ", d = " + std::to_string(d) +
             ", n! = " + format_number(factorial(n)) + "), above the limit of " +
             format_bytes(static_cast<double>(options.max_output_bytes)) +
             "; raise it with --max-output-bytes or ask for less");
  }

  try {
    result.jump = std::make_unique<JumpMap>(eta, limits);
  } catch (const InvalidArgument& e) {
    // The core names "normals" or "field_limits" itself.
    const std::string message = e.what();
    throw InputError(message.rfind("normals:", 0) == 0 ? message
                                                       : with_field("field_limits", message));
  }
  const JumpMap& jump = *result.jump;

  std::unique_ptr<Triangulation> triangulation;
  if (want_triangulation) {
    try {
      triangulation = std::make_unique<Triangulation>(jump.triangulation());
    } catch (const InvalidArgument& e) {
      computation_failed("triangulation", e);
    }
  }

  result.head["n"] = n;
  result.head["d"] = d;
  OrderedJson results = OrderedJson::array();
  for (std::size_t k = 0; k < tangents.size(); ++k) {
    const std::string name = "results[" + std::to_string(k) + "]";
    const Eigen::VectorXd& dx = tangents[k];
    Eigen::VectorXd image;
    CrossingOrder order;
    Eigen::MatrixXd jacobian;
    try {
      image = jump.apply(dx);
      order = jump.order(dx);
      jacobian = jump.active_jacobian(dx);
    } catch (const InvalidArgument& e) {
      computation_failed("tangents[" + std::to_string(k) + "]", e);
    }
    const Eigen::Map<const Eigen::VectorXd> times(order.times.data(),
                                                  static_cast<Eigen::Index>(order.times.size()));
    check_finite(image, name, "image");
    check_finite(times, name, "crossing_times");
    check_finite(jacobian, name, "jacobian");
    OrderedJson item = OrderedJson::object();
    item["image"] = vector_json(image);
    item["order"] = order.order;
    item["crossing_times"] = vector_json(times);
    item["jacobian"] = rows_json(jacobian);
    if (triangulation) {
      BarycentricEvaluation barycentric;
      try {
        barycentric = triangulation->apply_barycentric(dx);
      } catch (const InvalidArgument& e) {
        computation_failed("tangents[" + std::to_string(k) + "]: barycentric_image", e);
      }
      // The triangulation's own estimate of its rounding error: when its terms cancel (a dx of
      // 1e307 mapped to 1) the barycentric image says nothing, and printing it would mislead.
      if (!(barycentric.error_estimate <=
            kBarycentricTolerance * image.lpNorm<Eigen::Infinity>())) {
        throw OutputError(
            "tangents[" + std::to_string(k) +
            "]: barycentric_image: the triangulation cannot evaluate this tangent in double "
            "precision (its error estimate " +
            format_number(barycentric.error_estimate) +
            " against |B(dx)| = " + format_number(image.lpNorm<Eigen::Infinity>()) +
            ": its terms cancel); drop \"triangulation\" or rescale the data");
      }
      check_finite(barycentric.image, name, "barycentric_image");
      item["barycentric_image"] = vector_json(barycentric.image);
    }
    results.push_back(std::move(item));
  }
  result.head["results"] = std::move(results);

  if (want_pieces) {
    // Every piece is computed once before anything is written, so that a piece beyond the
    // double range is refused with nothing on stdout; then streamed again while writing.
    try {
      jump.for_each_piece([](const std::vector<int>&, const Eigen::Ref<const Eigen::MatrixXd>&) {});
    } catch (const InvalidArgument& e) {
      computation_failed("pieces", e);
    }
  }

  if (triangulation) {
    check_finite(triangulation->zeta(), "triangulation", "zeta");
    check_finite(triangulation->zeta_image(), "triangulation", "zeta_image");
    check_finite(triangulation->lineality_basis(), "triangulation", "lineality_basis");
    OrderedJson simplices = OrderedJson::array();
    for (const Simplex& simplex : triangulation->simplices()) {
      OrderedJson words = OrderedJson::array();
      for (const Signs& b : simplex.words) words.push_back(b.str());
      OrderedJson item = OrderedJson::object();
      item["order"] = simplex.order;
      item["words"] = std::move(words);
      simplices.push_back(std::move(item));
    }
    OrderedJson t = OrderedJson::object();
    if (triangulation->scale_exponent() != 0) t["scale_exponent"] = triangulation->scale_exponent();
    t["zeta"] = words_json(triangulation->zeta(), n);
    t["zeta_image"] = words_json(triangulation->zeta_image(), n);
    t["lineality_basis"] = columns_json(triangulation->lineality_basis());
    t["simplices"] = std::move(simplices);
    result.tail["triangulation"] = std::move(t);
  }
  return result;
}

// Thrown out of the pieces' loop once `out` has failed (a closed pipe, a full disk): the pieces
// left would go nowhere.
struct WriteFailed {};

// Writes the top-level object key by key, the pieces one at a time in between: the same text
// as formatting the whole document at once, without ever holding the n! pieces.
// @throws WriteFailed when `out` fails while the pieces are written.
void write_evaluation(std::ostream& out, const Evaluation& e, bool compact) {
  bool first = true;
  const auto key = [&](const char* name) {
    out << (first ? "" : (compact ? "," : ",\n")) << (compact ? "" : "  ") << '"' << name << '"'
        << (compact ? ":" : ": ");
    first = false;
  };
  out << (compact ? "{" : "{\n");
  for (auto it = e.head.begin(); it != e.head.end(); ++it) {
    key(it.key().c_str());
    write_json(out, it.value(), compact, 1);
  }
  if (e.pieces) {
    key("pieces");
    out << (compact ? "[" : "[\n");
    bool first_piece = true;
    e.jump->for_each_piece(
        [&](const std::vector<int>& sigma, const Eigen::Ref<const Eigen::MatrixXd>& matrix) {
          if (!out) throw WriteFailed{};
          OrderedJson item = OrderedJson::object();
          item["order"] = sigma;
          item["matrix"] = rows_json(matrix);
          out << (first_piece ? "" : (compact ? "," : ",\n")) << (compact ? "" : "    ");
          write_json(out, item, compact, 2);
          first_piece = false;
        });
    out << (compact ? "]" : "\n  ]");
  }
  for (auto it = e.tail.begin(); it != e.tail.end(); ++it) {
    key(it.key().c_str());
    write_json(out, it.value(), compact, 1);
  }
  out << (compact ? "}" : "\n}") << '\n';
}

// Outputs up to this size are formatted in memory first, so that a failure leaves stdout empty;
// larger ones (only n! pieces get there) are written as they are formatted.
constexpr double kBufferedOutputBytes = 16.0 * 1024 * 1024;

int run_jump_text(const std::string& text, std::ostream& out, std::ostream& err,
                  const JumpOptions& options) {
  try {
    const Evaluation evaluation = evaluate(parse_document(text), options);
    if (evaluation.estimated_bytes <= kBufferedOutputBytes) {
      std::ostringstream buffer;
      write_evaluation(buffer, evaluation, options.compact);
      out << buffer.str();
    } else {
      try {
        write_evaluation(out, evaluation, options.compact);
      } catch (const WriteFailed&) {
        // Reported below, as every failed write is.
      }
    }
    // A failed write: "stdout: write failed (<reason>)", exit code 1.
    return finish_output(out, err, kExitOk);
  } catch (const InputError& e) {
    report_error(err, e.what());
    return kExitBadInput;
  } catch (const OutputError& e) {
    report_error(err, e.what());
    return kExitFailure;
  } catch (const InvalidArgument& e) {
    report_error(err, with_field("input", e.what()));
    return kExitBadInput;
  } catch (const std::bad_alloc&) {
    report_error(err, "input: out of memory (the input or the requested output is too large)");
    return kExitFailure;
  } catch (const std::exception& e) {
    report_error(err, std::string("internal: ") + e.what());
    return kExitFailure;
  }
}

// Reads at most `limit` bytes; false (with a message) when there are more or reading fails.
// The refusal of an input longer than --max-input-bytes; `what` names the input.
void report_too_long(std::ostream& err, const std::string& what, long long limit) {
  report_error(err, "input: " + what + " is longer than " + std::to_string(limit) +
                        " bytes (--max-input-bytes " + std::to_string(limit) +
                        "); raise the limit for a larger document");
}

bool read_capped(std::istream& in, long long limit, const std::string& what, std::string& text,
                 std::ostream& err) {
  char buffer[1 << 16];
  while (in) {
    in.read(buffer, sizeof buffer);
    const std::streamsize got = in.gcount();
    if (got <= 0) break;
    text.append(buffer, static_cast<std::size_t>(got));
    if (static_cast<long long>(text.size()) > limit) {
      report_too_long(err, what, limit);
      return false;
    }
  }
  if (in.bad()) {
    report_error(err, "input: cannot read " + what);
    return false;
  }
  return true;
}

}  // namespace

int run_jump(std::istream& in, std::ostream& out, std::ostream& err, const JumpOptions& options) {
  std::string text;
  try {
    if (!read_capped(in, options.max_input_bytes, "the standard input", text, err)) {
      return kExitBadInput;
    }
  } catch (const std::exception& e) {
    report_error(err, std::string("input: cannot read: ") + e.what());
    return kExitBadInput;
  }
  return run_jump_text(text, out, err, options);
}

int run_jump_file(const std::string& path, std::istream& stdin_stream, std::ostream& out,
                  std::ostream& err, const JumpOptions& options) {
  for (const auto& [value, option] : {std::pair{options.max_input_bytes, "--max-input-bytes"},
                                      std::pair{options.max_output_bytes, "--max-output-bytes"}}) {
    if (value < 1) {
      report_error(err, std::string(option) + ": must be >= 1, got " + std::to_string(value));
      return kExitBadInput;
    }
  }
  if (path == "-") return run_jump(stdin_stream, out, err, options);
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(path.c_str(), "rb"), std::fclose);
  if (!file) {
    report_error(err, "input: cannot open " + quote(path, 200) + ": " + std::strerror(errno));
    return kExitBadInput;
  }
  std::string text;
  char buffer[1 << 16];
  std::size_t got = 0;
  while ((got = std::fread(buffer, 1, sizeof buffer, file.get())) > 0) {
    text.append(buffer, got);
    if (static_cast<long long>(text.size()) > options.max_input_bytes) {
      report_too_long(err, quote(path, 200), options.max_input_bytes);
      return kExitBadInput;
    }
  }
  if (std::ferror(file.get())) {
    report_error(err, "input: cannot read " + quote(path, 200) + ": " + std::strerror(errno));
    return kExitBadInput;
  }
  return run_jump_text(text, out, err, options);
}

}  // namespace bflow::cli

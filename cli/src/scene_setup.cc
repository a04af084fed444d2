#include "scene_setup.h"

#include <cerrno>
#include <cfloat>
#include <cmath>
#include <cstdlib>
#include <string>
#include <type_traits>

#include "bflow/core/errors.h"
#include "cli_util.h"

namespace bflow::cli {

[[noreturn]] void fail(const std::string& option, const std::string& problem) {
  throw InputError(option + ": " + problem);
}

std::string trimmed(const std::string& text) {
  const auto first = text.find_first_not_of(" \t");
  if (first == std::string::npos) return "";
  const auto last = text.find_last_not_of(" \t");
  return text.substr(first, last - first + 1);
}

void refuse_empty(const std::string& value, const std::string& option) {
  if (value.empty()) fail(option, "the value is empty");
}

namespace {

// Whether the significand of a number's text (before its exponent) has a nonzero digit: the
// text then names a nonzero number, whatever strtod made of it.
bool names_nonzero(const std::string& text) {
  std::size_t i = text.find_first_not_of("+-");
  if (i == std::string::npos) return false;
  const bool hex = text.compare(i, 2, "0x") == 0 || text.compare(i, 2, "0X") == 0;
  if (hex) i += 2;
  const std::string digits = hex ? "123456789abcdefABCDEF" : "123456789";
  const char exponent = hex ? 'p' : 'e';
  for (; i < text.size(); ++i) {
    const char c = text[i];
    if (c == exponent || c == exponent - 'a' + 'A') break;
    if (digits.find(c) != std::string::npos) return true;
  }
  return false;
}

// What is wrong with `text` (already trimmed, not empty) as a double: "is not a number", "is out
// of the range of a double", "underflows: ..."; "" when it is one, then in `value`. inf and nan
// are numbers here.
std::string number_problem(const std::string& text, double& value) {
  char* end = nullptr;
  errno = 0;
  value = std::strtod(text.c_str(), &end);
  const bool range_error = errno == ERANGE;
  if (text.empty() || end != text.c_str() + text.size()) return "is not a number";
  if (range_error && std::fabs(value) > 1.0) return "is out of the range of a double";
  // Underflow: a nonzero number read as 0 or as a subnormal (which keeps fewer than 53 bits).
  const bool subnormal = value != 0.0 && std::fabs(value) < DBL_MIN;
  if (subnormal || (value == 0.0 && (range_error || names_nonzero(text)))) {
    return "underflows: a nonzero number must be at least " + format_number(DBL_MIN) +
           " (the smallest normal double) in magnitude";
  }
  return "";
}

}  // namespace

double read_double(const std::string& raw, const std::string& option) {
  const std::string text = trimmed(raw);
  if (text.empty()) fail(option, "expected a number, got an empty string");
  double value = 0.0;
  if (const std::string problem = number_problem(text, value); !problem.empty()) {
    fail(option, quote(text) + " " + problem);
  }
  return value;
}

// A whole string read by strtod, finite.
double parse_number(const std::string& raw, const std::string& option) {
  const double value = read_double(raw, option);
  if (!std::isfinite(value)) fail(option, quote(trimmed(raw)) + " is not a finite number");
  return value;
}

long long parse_integer(const std::string& raw, const std::string& option, long long min,
                        long long max) {
  refuse_empty(raw, option);
  const std::string text = trimmed(raw);
  const std::size_t digits = text.find_first_not_of("+-") == 1 ? 1 : 0;
  if (text.size() <= digits || text.find_first_not_of("0123456789", digits) != std::string::npos) {
    fail(option, quote(raw) + " is not an integer");
  }
  errno = 0;
  const long long value = std::strtoll(text.c_str(), nullptr, 10);
  if ((errno == ERANGE && value > 0) || value > max) {
    fail(option, quote(raw) + " is too large (at most " + std::to_string(max) + ")");
  }
  if ((errno == ERANGE && value < 0) || value < min) {
    fail(option, quote(raw) + " is too small (at least " + std::to_string(min) + ")");
  }
  return value;
}

// A whole string of decimal digits, at most `max`.
std::uint64_t parse_unsigned(const std::string& raw, const std::string& option, std::uint64_t max) {
  const std::string text = trimmed(raw);
  if (text.empty() || text.find_first_not_of("0123456789") != std::string::npos) {
    fail(option, quote(raw) + " is not a non-negative integer");
  }
  errno = 0;
  const unsigned long long value = std::strtoull(text.c_str(), nullptr, 10);
  if (errno == ERANGE || value > max) {
    fail(option, quote(raw) + " is too large (at most " + std::to_string(max) + ")");
  }
  return value;
}

// "a,b,c" with exactly `dim` numbers.
Eigen::VectorXd parse_vector(const std::string& text, const std::string& option, int dim) {
  std::vector<std::string> items;
  std::size_t start = 0;
  while (true) {
    const std::size_t comma = text.find(',', start);
    items.push_back(text.substr(start, comma == std::string::npos ? comma : comma - start));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  if (static_cast<int>(items.size()) != dim) {
    fail(option, "has " + std::to_string(items.size()) + " number" +
                     (items.size() == 1 ? "" : "s") + ", expected d = " + std::to_string(dim) +
                     " (comma-separated)");
  }
  Eigen::VectorXd v(dim);
  for (int i = 0; i < dim; ++i) {
    v[i] = parse_number(items[static_cast<std::size_t>(i)], option + "[" + std::to_string(i) + "]");
  }
  return v;
}

// Messages in the style of bflow::set_param: `pwconst parameter "d" must be ...`.
PwconstParams pwconst_params(const Params& params) {
  PwconstParams p;
  for (const auto& [key, raw] : params) {
    const std::string name = "pwconst parameter " + quote(key);
    const std::string value = trimmed(raw);
    const bool digits =
        !value.empty() && value.find_first_not_of("0123456789") == std::string::npos;
    if (key == "d") {
      errno = 0;
      const unsigned long long d = digits ? std::strtoull(value.c_str(), nullptr, 10) : 0;
      if (d < 1 || d > 16 || errno == ERANGE) {
        fail("--param", name + " must be an integer in [1, 16], got " + quote(raw));
      }
      p.d = static_cast<int>(d);
    } else if (key == "delta") {
      double delta = 0.0;
      if (const std::string problem = number_problem(value, delta); !problem.empty()) {
        fail("--param", name + " = " + quote(raw) + " " + problem);
      }
      if (!(std::fabs(delta) < 1.0)) {
        fail("--param", name +
                            " must be in (-1, 1) (every component of Delta(b) = -delta b must "
                            "exceed -1), got " +
                            quote(raw));
      }
      p.delta = delta;
    } else if (key == "seed") {
      errno = 0;
      const unsigned long long seed = digits ? std::strtoull(value.c_str(), nullptr, 10) : 0;
      if (!digits || errno == ERANGE) {
        fail("--param", name + " must be an integer in [0, 2^64), got " + quote(raw));
      }
      p.seed = seed;
    } else {
      fail("--param", "unknown pwconst parameter " + quote(key) + " (known: d, delta, seed)");
    }
  }
  if (p.delta && p.seed) {
    fail("--param", "give delta (the linear case) or seed (a random Delta), not both");
  }
  return p;
}

examples::PiecewiseConstantField make_pwconst(const PwconstParams& p) {
  if (p.seed) return examples::PiecewiseConstantField::random(p.d, *p.seed);
  return examples::PiecewiseConstantField::linear(p.d, p.delta.value_or(kDefaultDelta));
}

namespace {

// The loop of biped_params and pronk_params: every key known and every value a whole number
// (biped's variant a name), with messages in the style of bflow::set_param that quote the key and
// the value at a bounded length; set_param itself sets the value and judges its range.
template <typename SceneParams>
SceneParams scene_params(const Params& params, const char* scene, const std::string& known) {
  SceneParams p;
  for (const auto& [key, raw] : params) {
    const bool name_valued = std::is_same_v<SceneParams, BipedParams> && key == "variant";
    if (!name_valued && (key.empty() || key.find_first_of(", ") != std::string::npos ||
                         (", " + known + ",").find(", " + key + ",") == std::string::npos)) {
      fail("--param", std::string("unknown ") + scene + " parameter " + quote(key) +
                          " (known: " + known + ")");
    }
    const std::string value = name_valued ? raw : trimmed(raw);
    double number = 0.0;
    if (const std::string problem = number_problem(value, number);
        !name_valued && !problem.empty()) {
      fail("--param",
           std::string(scene) + " parameter " + quote(key) + " = " + quote(raw) + " " + problem);
    }
    try {
      set_param(p, key, value);
    } catch (const InvalidArgument& e) {
      std::string message = e.what();
      const std::string prefix = "set_param: ";
      if (message.rfind(prefix, 0) == 0) message.erase(0, prefix.size());
      fail("--param", message);
    }
  }
  return p;
}

}  // namespace

BipedParams biped_params(const Params& params) {
  return scene_params<BipedParams>(params, "biped", kBipedParamKeys);
}

PronkParams pronk_params(const Params& params) {
  return scene_params<PronkParams>(params, "pronk", kPronkParamKeys);
}

SceneSetup parse_scene_setup(const FlowCommandOptions& options) {
  // Scene and parameters.
  if (options.scene.empty()) fail("--scene", "required; the scenes are pwconst, biped and pronk");
  if (options.scene != "pwconst" && options.scene != "biped" && options.scene != "pronk") {
    fail("--scene",
         "unknown scene " + quote(options.scene) + "; the scenes are pwconst, biped and pronk");
  }
  // An option given with an empty value ("--t ''") is refused, not taken as its default.
  for (const std::string& text : options.params) refuse_empty(text, "--param");
  for (const auto& [value, option] :
       {std::pair{&options.t, "--t"}, std::pair{&options.x0, "--x0"},
        std::pair{&options.rtol, "--rtol"}, std::pair{&options.atol, "--atol"},
        std::pair{&options.grouping, "--grouping"}, std::pair{&options.window, "--window"},
        std::pair{&options.max_steps, "--max-steps"}}) {
    if (*value) refuse_empty(**value, option);
  }
  for (const std::string& text : options.dx) refuse_empty(text, "--dx");
  refuse_empty(options.integrator, "--integrator");
  std::vector<std::pair<std::string, std::string>> params;
  for (const std::string& text : options.params) {
    const auto equals = text.find('=');
    if (equals == std::string::npos || equals == 0) {
      fail("--param", quote(text) + " is not key=value");
    }
    const std::string key = text.substr(0, equals);
    for (const auto& earlier : params) {
      if (earlier.first == key) fail("--param", quote(key) + " is given twice");
    }
    params.emplace_back(key, text.substr(equals + 1));
  }
  const bool biped = options.scene == "biped";
  const bool pronk = options.scene == "pronk";
  std::optional<PwconstParams> pwconst;
  BipedParams biped_p;
  PronkParams pronk_p;
  if (biped) {
    biped_p = biped_params(params);
  } else if (pronk) {
    pronk_p = pronk_params(params);
  } else {
    pwconst = pwconst_params(params);
  }

  // Time and integrator.
  Request request;
  request.t = biped || pronk ? 0.6 : 1.0;
  if (options.t) {
    request.t = parse_number(*options.t, "--t");
    if (!(request.t >= 0.0)) fail("--t", "must be >= 0, got " + format_number(request.t));
  }
  if (options.rtol) {
    request.flow.integrator.rtol = parse_number(*options.rtol, "--rtol");
    const double rtol = request.flow.integrator.rtol;
    if (!(rtol >= IntegratorOptions::kMinRtol) || !std::isfinite(rtol)) {
      fail("--rtol", "must be >= " + format_number(IntegratorOptions::kMinRtol) +
                         " (below that no step can meet it in double precision), got " +
                         format_number(rtol));
    }
  }
  if (options.atol) {
    const double atol = parse_number(*options.atol, "--atol");
    if (!(atol >= IntegratorOptions::kMinAtol)) {
      fail("--atol", "must be >= " + format_number(IntegratorOptions::kMinAtol) +
                         " (below that the field's rounding alone makes the steps tiny), got " +
                         format_number(atol));
    }
    request.flow.integrator.atol = atol;
  }
  try {
    request.flow.backend = parse_backend(options.integrator);
  } catch (const InvalidArgument&) {
    fail("--integrator",
         "integrator " + quote(options.integrator) +
             " is unknown; choose auto, dopri5, dop853, cvodes-bdf or cvodes-adams");
  }
  if (options.grouping) {
    try {
      request.flow.grouping = parse_grouping(*options.grouping);
    } catch (const InvalidArgument&) {
      fail("--grouping",
           "grouping " + quote(*options.grouping) + " is unknown; choose auto, window or none");
    }
  }
  if (options.window) {
    if (request.flow.grouping != Grouping::kFixedWindow) {
      fail("--window", "needs --grouping window");
    }
    const double window = parse_number(*options.window, "--window");
    if (!(window >= 0.0) || !std::isfinite(window)) {
      fail("--window", "must be finite and >= 0, got " + format_number(window));
    }
    request.flow.simultaneity_window = window;
  } else if (request.flow.grouping == Grouping::kFixedWindow) {
    fail("--grouping", "window needs --window T");
  }
  if (options.max_steps) {
    const std::uint64_t steps = parse_unsigned(*options.max_steps, "--max-steps", 1000000000);
    if (steps < 1) fail("--max-steps", "must be >= 1, got 0");
    request.flow.integrator.max_steps = static_cast<long>(steps);
  }
  request.x0_text = options.x0;
  request.dx_texts = options.dx;
  request.fd = options.fd;

  OrderedJson head = OrderedJson::object();
  head["scene"] = options.scene;
  OrderedJson params_json = OrderedJson::object();
  if (biped) {
    params_json["variant"] = biped_variant_name(biped_p.variant);
    params_json["m"] = biped_p.m;
    params_json["J"] = biped_p.J;
    params_json["g"] = biped_p.g;
    params_json["leg_length"] = biped_p.leg_length;
    params_json["psi"] = biped_p.psi;
    params_json["kappa"] = biped_p.kappa;
    params_json["beta"] = biped_p.beta;
    if (biped_p.thrust > 0.0) {
      params_json["thrust"] = biped_p.thrust;
      params_json["thrust_speed"] = biped_p.thrust_speed;
    }
  } else if (pronk) {
    params_json["m"] = pronk_p.m;
    params_json["J"] = pronk_p.J;
    params_json["g"] = pronk_p.g;
    params_json["hip"] = pronk_p.hip;
    params_json["leg_length"] = pronk_p.leg_length;
    params_json["kappa"] = pronk_p.kappa;
    params_json["beta"] = pronk_p.beta;
    params_json["thrust"] = pronk_p.thrust;
    params_json["thrust_speed"] = pronk_p.thrust_speed;
    params_json["tether"] = pronk_p.tether;
    params_json["tether_damping"] = pronk_p.tether_damping;
  } else {
    params_json["d"] = pwconst->d;
    if (pwconst->seed) {
      params_json["seed"] = *pwconst->seed;
    } else {
      params_json["delta"] = pwconst->delta.value_or(kDefaultDelta);
    }
  }
  head["params"] = std::move(params_json);
  head["integrator"] = to_string(request.flow.backend);
  head["rtol"] = request.flow.integrator.rtol;
  head["atol"] = request.flow.integrator.absolute_tolerance();
  head["grouping"] = to_string(request.flow.grouping);
  if (request.flow.grouping == Grouping::kFixedWindow) {
    head["window"] = request.flow.simultaneity_window;
  }
  head["t"] = request.t;

  SceneSetup setup;
  setup.scene = options.scene;
  setup.biped = biped;
  setup.pronk = pronk;
  setup.params = std::move(params);
  setup.request = std::move(request);
  setup.head = std::move(head);
  return setup;
}

}  // namespace bflow::cli

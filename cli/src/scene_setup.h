// The scene options shared by `bflow flow` and `bflow sweep`: the scene and its parameters, the
// final time, the integrator and the grouping policy, validated into a SceneSetup; and the
// scene's model built from it (with_scene). A rejection is an InputError whose message starts
// with the option ("--param: pwconst parameter \"d\" must be ..."). The readers of numbers
// (read_double, parse_number, parse_integer) serve the numeric options of every command.
#ifndef BFLOW_CLI_SRC_SCENE_SETUP_H_
#define BFLOW_CLI_SRC_SCENE_SETUP_H_

#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/biped.h"
#include "bflow/core/pronk.h"
#include "bflow/examples/piecewise_constant.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "cli_commands.h"
#include "cli_json.h"

namespace bflow::cli {

// Bad input; the message starts with the option. Exit code 2.
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

[[noreturn]] void fail(const std::string& option, const std::string& problem);
std::string trimmed(const std::string& text);
// Refuses an option given with an empty value ("--t ''"): "<option>: the value is empty".
void refuse_empty(const std::string& value, const std::string& option);
// A whole string read by strtod (spaces around it allowed), within the range of a double: text
// that overflows, or that names a nonzero number but underflows to 0 or to a subnormal, is
// refused. inf and nan pass, for the caller's range check to name.
double read_double(const std::string& raw, const std::string& option);
// As read_double, and finite.
double parse_number(const std::string& raw, const std::string& option);
// A whole string of decimal digits, at most `max`.
std::uint64_t parse_unsigned(const std::string& raw, const std::string& option, std::uint64_t max);
// A whole string of decimal digits with an optional sign, in [min, max]; not empty.
long long parse_integer(const std::string& raw, const std::string& option, long long min,
                        long long max);
// "a,b,c" with exactly `dim` numbers.
Eigen::VectorXd parse_vector(const std::string& text, const std::string& option, int dim);

struct PwconstParams {
  int d = 2;
  std::optional<double> delta;
  std::optional<std::uint64_t> seed;
};
constexpr double kDefaultDelta = 0.25;

using Params = std::vector<std::pair<std::string, std::string>>;
PwconstParams pwconst_params(const Params& params);
examples::PiecewiseConstantField make_pwconst(const PwconstParams& p);
BipedParams biped_params(const Params& params);
PronkParams pronk_params(const Params& params);

struct Request {
  double t = 0.0;
  std::optional<std::string> x0_text;
  std::vector<std::string> dx_texts;
  FlowOptions flow;
  bool fd = false;
};

/** What the scene options of `bflow flow` (and `bflow sweep`) ask for, validated. */
struct SceneSetup {
  std::string scene;  ///< "pwconst", "biped" or "pronk"
  bool biped = false;
  bool pronk = false;
  Params params;  ///< the --param pairs, in order, each key once
  Request request;
  /** The record's head: scene, params (all of them, defaults included), integrator, rtol,
      atol, grouping, window (with --grouping window) and t. */
  OrderedJson head;
};

/** @throws InputError naming the option. */
SceneSetup parse_scene_setup(const FlowCommandOptions& options);

/** f(model, default_x0) on the scene of `setup` with `overrides` (key=value) replacing or adding
    to its parameters; default_x0 is rho- = -F_--(0)/2 for pwconst (it reaches the origin at
    t = 1/2, [B] Sec. 3.1), biped_initial_state() for the biped and pronk_initial_state() for
    the pronk.
    @throws InputError for a parameter the scene refuses. */
template <typename F>
auto with_scene(const SceneSetup& setup, const Params& overrides, F&& f) {
  Params params = setup.params;
  for (const auto& [key, value] : overrides) {
    bool replaced = false;
    for (auto& entry : params) {
      if (entry.first == key) {
        entry.second = value;
        replaced = true;
      }
    }
    if (!replaced) params.emplace_back(key, value);
  }
  if (setup.pronk) {
    const auto model = adapt(make_pronk(pronk_params(params)));
    return f(static_cast<const SegmentModel&>(model), Eigen::VectorXd(pronk_initial_state()));
  }
  if (setup.biped) {
    return visit_biped(biped_params(params), [&f](const auto& scene) {
      const auto model = adapt(scene);
      return f(static_cast<const SegmentModel&>(model), Eigen::VectorXd(biped_initial_state()));
    });
  }
  const examples::PiecewiseConstantField field = make_pwconst(pwconst_params(params));
  const auto model = adapt(field);
  return f(static_cast<const SegmentModel&>(model), Eigen::VectorXd(-0.5 * field.limits().col(0)));
}

}  // namespace bflow::cli

#endif  // BFLOW_CLI_SRC_SCENE_SETUP_H_

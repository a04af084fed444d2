// What the tests of `bflow orbit` share: the command run in process, the JSON read back into
// Eigen and into a scene's parameters, and one period of a plain simulation to check a fixed
// point independently of the orbit code.
#ifndef BFLOW_TESTS_CLI_ORBIT_JSON_H_
#define BFLOW_TESTS_CLI_ORBIT_JSON_H_

#include <cstdlib>
#include <filesystem>
#include <ostream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>
#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bflow/core/model.h"
#include "bflow/integrators/hybrid_flow.h"
#include "cli_commands.h"
#include "support/run_command.h"

namespace bflow::testing {

inline Outcome run_orbit_command(const cli::OrbitCommandOptions& options) {
  return capture(
      [&](std::ostream& out, std::ostream& err) { return cli::run_orbit(options, out, err); });
}

inline Eigen::VectorXd vector_of(const nlohmann::json& v) {
  Eigen::VectorXd out(static_cast<Eigen::Index>(v.size()));
  for (std::size_t i = 0; i < v.size(); ++i) out[static_cast<Eigen::Index>(i)] = v[i].get<double>();
  return out;
}

/** A matrix from a JSON list of rows. */
inline Eigen::MatrixXd rows_of(const nlohmann::json& rows) {
  Eigen::MatrixXd out(static_cast<Eigen::Index>(rows.size()),
                      static_cast<Eigen::Index>(rows[0].size()));
  for (std::size_t r = 0; r < rows.size(); ++r) {
    out.row(static_cast<Eigen::Index>(r)) = vector_of(rows[r]).transpose();
  }
  return out;
}

/** A matrix from a JSON list of columns. */
inline Eigen::MatrixXd columns_of(const nlohmann::json& columns) {
  return rows_of(columns).transpose();
}

/** A scene's parameters from the JSON's "params", through the scene's own set_param (each
    number printed with 17 digits reads back exactly; strings such as the biped's variant are
    passed as they are). */
template <typename Params>
Params params_from_json(const nlohmann::json& params) {
  Params p;
  for (auto it = params.begin(); it != params.end(); ++it) {
    const std::string key = it.key();
    const nlohmann::json& value = it.value();
    if (value.is_string()) {
      set_param(p, key, value.get<std::string>());
    } else {
      std::ostringstream text;
      text.precision(17);
      text << value.get<double>();
      set_param(p, key, text.str());
    }
  }
  return p;
}

/** |phi_T(x) - x|_inf by a plain simulation at tight tolerances, and the vertical speed a little
    before T (the apex section -x4 is crossed from ydot > 0 to ydot < 0). */
struct PeriodReturn {
  double error = 0.0;
  double ydot_before = 0.0;
};

inline PeriodReturn one_period(const SegmentModel& model, const Eigen::VectorXd& x, double period) {
  FlowOptions flow;
  flow.integrator.rtol = 1e-12;
  flow.integrator.atol = 1e-14;
  const FlowResult end = simulate(model, x, period, flow);
  const FlowResult before = simulate(model, x, 0.99 * period, flow);
  EXPECT_TRUE(end.ok()) << end.message;
  EXPECT_TRUE(before.ok()) << before.message;
  return PeriodReturn{(end.x - x).lpNorm<Eigen::Infinity>(), before.x[4]};
}

inline bool gnuplot_on_path() {
  const char* path = std::getenv("PATH");
  std::istringstream dirs(path == nullptr ? "" : path);
  for (std::string dir; std::getline(dirs, dir, ':');) {
    if (!dir.empty() && std::filesystem::exists(std::filesystem::path(dir) / "gnuplot")) {
      return true;
    }
  }
  return false;
}

}  // namespace bflow::testing

#endif  // BFLOW_TESTS_CLI_ORBIT_JSON_H_

// The monoped's OCP (examples/include/bflow/examples/monoped_ocp.h, nosnoc's setup at N = 30)
// under one change of its start, homotopy or linear algebra at a time, within a budget of IPOPT
// iterations: the experiments of docs/ocp.md ("Routes towards the monoped's gait with MUMPS").
// Prints one progress line per NLP on stderr and one JSON object on stdout.
//
//   monoped_routes [--N 30] [--formulation step|stewart] [--budget 2500]
//                  [--relaxation scholtes|l1|elastic] [--sigma0 X] [--polish-from X]
//                  [--guess constant|gait] [--sides-guess] [--start FILE.json]
//                  [--ipopt-num=mumps_pivtol=1e-4 ...]
//   monoped_routes --simulate FILE.json [--hop-gain 1] [--lbfgs] [--formulation stewart]
//
// --polish-from X turns the polish on (the setup has it off) from the first NLP at sigma <= X
// (OcpHomotopyOptions::early_polish_sigma); its iterations count against the budget too.
// --guess gait starts from a kinematic two-hop gait (GaitGuess below) in place of x0 everywhere;
// --sides-guess sets the algebraic variables at the sides of the guessed states instead of the
// setup's neutral ones.
// --start FILE.json continues from an earlier run's output (its element-boundary states and its
// controls, resampled to this N): continuation in N (solve coarse, start the fine grid from it)
// or in sigma from a solution of another formulation; the algebraic variables follow the sides.
// --simulate FILE.json only simulates HopController (below) by FESD, stage by stage, printing
// each stage's start, and writes the trajectory as a --start file.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bflow/examples/monoped.h"
#include "bflow/examples/monoped_ocp.h"
#include "bflow/ocp/ocp.h"
#include "ipopt_flags.h"

namespace {

// A kinematic two-hop gait from x0 to the target: three stances with the foot fixed on the
// ground at x = 0, 1.5 and 3 (the body moves 0.1 past the foot, crouching to 0.33 and back to
// 0.38 with the knee bent so that the foot stays put), and two ballistic flights of 0.5 s
// between them (g = 9.81, the leg angles interpolated). It satisfies the contact geometry (the
// foot on the ground in stance, above it in flight) but not the dynamics: a start whose flight
// phases and contact sides are those of a hopping gait.
struct GaitGuess {
  double t_takeoff[2] = {0.4, 1.6}, t_landing[2] = {0.9, 2.1};
  double foot[3] = {0.0, 1.5, 3.0};
  double reach = 0.1, z_end = 0.38, z_mid = 0.33, g = 9.81, horizon = 3.0;

  // The base during stance i at normalised time s in [0, 1].
  void stance(int i, double s, double& x, double& z) const {
    const double xa = i == 0 ? foot[0] : foot[i] - reach;
    const double xb = i == 2 ? foot[2] : foot[i] + reach;
    const double smooth = s * s * (3.0 - 2.0 * s);
    x = xa + (xb - xa) * (i == 1 ? s : smooth);
    const double e = 2.0 * s - 1.0;
    const bool standing_end = (i == 0 && s < 0.5) || (i == 2 && s > 0.5);
    z = z_mid + ((standing_end ? 0.4 : z_end) - z_mid) * e * e;
  }
  // Hip and knee angles that put the foot (links of 0.2) at x_foot on the ground.
  static void legs(double x, double z, double x_foot, double& hip, double& knee) {
    const double dx = x_foot - x;
    const double length = std::min(std::sqrt(dx * dx + z * z), 0.4 - 1e-9);
    const double beta = std::acos(length / 0.4);
    hip = std::atan2(dx, z) + beta;
    knee = -2.0 * beta;
  }
  Eigen::Vector4d q(double t) const {
    double x = 0.0, z = 0.0, hip = 0.0, knee = 0.0;
    for (int i = 0; i < 3; ++i) {
      const double ta = i == 0 ? 0.0 : t_landing[i - 1];
      const double tb = i == 2 ? horizon : t_takeoff[i];
      if (t >= ta && t <= tb) {
        stance(i, (t - ta) / (tb - ta), x, z);
        legs(x, z, foot[i], hip, knee);
        return {x, z, hip, knee};
      }
    }
    const int i = t < t_landing[0] ? 0 : 1;
    double xa, za, xb, zb, hip_a, knee_a, hip_b, knee_b;
    stance(i, 1.0, xa, za);
    legs(xa, za, foot[i], hip_a, knee_a);
    stance(i + 1, 0.0, xb, zb);
    legs(xb, zb, foot[i + 1], hip_b, knee_b);
    const double flight = t_landing[i] - t_takeoff[i], tau = t - t_takeoff[i];
    const double vz0 = (zb - za) / flight + g * flight / 2.0;
    return {xa + (xb - xa) * tau / flight, za + vz0 * tau - g * tau * tau / 2.0,
            hip_a + (hip_b - hip_a) * tau / flight, knee_a + (knee_b - knee_a) * tau / flight};
  }
  // (q, v, clock) at t, v by central differences.
  Eigen::VectorXd state(double t) const {
    Eigen::VectorXd s = Eigen::VectorXd::Zero(9);
    s.head(4) = q(t);
    const double h = 1e-5, ta = std::max(0.0, t - h), tb = std::min(horizon, t + h);
    s.segment(4, 4) = (q(tb) - q(ta)) / (tb - ta);
    s[8] = t;
    return s;
  }
};

// An earlier run's trajectory: x linear between its element boundaries (in numerical time),
// and its controls piecewise constant over its stages.
struct StartFrom {
  std::vector<double> grid;
  Eigen::MatrixXd x, u;

  explicit StartFrom(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw std::runtime_error("--start: cannot read " + path);
    const nlohmann::json j = nlohmann::json::parse(in);
    grid = j.at("grid").get<std::vector<double>>();
    const auto xs = j.at("x_grid").get<std::vector<std::vector<double>>>();
    const auto us = j.at("u").get<std::vector<std::vector<double>>>();
    if (xs.size() != grid.size() || us.empty())
      throw std::runtime_error("--start: " + path + " has no trajectory of matching size");
    x.resize(static_cast<Eigen::Index>(xs[0].size()), static_cast<Eigen::Index>(xs.size()));
    for (std::size_t c = 0; c < xs.size(); ++c)
      x.col(static_cast<Eigen::Index>(c)) =
          Eigen::Map<const Eigen::VectorXd>(xs[c].data(), static_cast<Eigen::Index>(xs[c].size()));
    u.resize(static_cast<Eigen::Index>(us[0].size()), static_cast<Eigen::Index>(us.size()));
    for (std::size_t c = 0; c < us.size(); ++c)
      u.col(static_cast<Eigen::Index>(c)) =
          Eigen::Map<const Eigen::VectorXd>(us[c].data(), static_cast<Eigen::Index>(us[c].size()));
  }
  Eigen::VectorXd state(double t) const {
    const auto it = std::upper_bound(grid.begin(), grid.end(), t);
    if (it == grid.begin()) return x.col(0);
    if (it == grid.end()) return x.col(x.cols() - 1);
    const auto b = static_cast<Eigen::Index>(it - grid.begin());
    const double w = (t - grid[static_cast<std::size_t>(b - 1)]) /
                     (grid[static_cast<std::size_t>(b)] - grid[static_cast<std::size_t>(b - 1)]);
    return (1.0 - w) * x.col(b - 1) + w * x.col(b);
  }
  Eigen::MatrixXd controls(int stages) const {
    Eigen::MatrixXd out(u.rows(), stages);
    for (int k = 0; k < stages; ++k) {
      const double middle = (k + 0.5) / stages;
      out.col(k) =
          u.col(std::min<Eigen::Index>(static_cast<Eigen::Index>(middle * u.cols()), u.cols() - 1));
    }
    return out;
  }
};

// A hopping controller sampled at the start of each stage: constant torques by inverse dynamics
// that take the hip and knee angles to GaitGuess's angles at the stage's end (the joints'
// accelerations a = 2 (q_ref - q - v dt) / dt^2; in flight with the base free, in stance with
// the foot held on the ground by the contact force), clamped to |u| <= 100, and the speed of
// time that brings the clock to the stage's end time (time-freezing's clock runs slower in
// contact).
struct HopController {
  int stages = 30;
  double horizon = 3.0, gain = 1.0;
  Eigen::VectorXd operator()(int k, const Eigen::VectorXd& x) const {
    const bflow::examples::Monoped robot;
    const double length = horizon / stages, t_next = (k + 1) * length;
    const double s = std::clamp((t_next - x[8]) / length, 0.99, 5.0), dt = s * length;
    const Eigen::VectorXd ref = GaitGuess{}.state(std::min(t_next, horizon));
    const Eigen::Vector4d q = x.head(4), v = x.segment(4, 4);
    Eigen::Matrix4d M;
    Eigen::Matrix<double, 4, 4, Eigen::RowMajor> Mr;
    robot.mass(q.data(), Mr.data());
    M = Mr;
    Eigen::Vector4d f;
    robot.forces(q.data(), v.data(), static_cast<const double*>(nullptr), f.data());
    Eigen::Vector2d a;
    for (int j = 0; j < 2; ++j)
      a[j] = gain * 2.0 * (ref[2 + j] - q[2 + j] - v[2 + j] * dt) / (dt * dt);
    Eigen::Vector2d base, tau;
    if (robot.gap(x.data()) > 2e-3) {
      base = M.topLeftCorner<2, 2>().ldlt().solve(f.head(2) - M.topRightCorner<2, 2>() * a);
      tau = M.bottomLeftCorner<2, 2>() * base + M.bottomRightCorner<2, 2>() * a - f.tail(2);
    } else {
      double p[2], bias[2];
      Eigen::Matrix<double, 2, 4, Eigen::RowMajor> J;
      robot.point(q.data(), v.data(), robot.l_thigh, robot.l_shank, p, J.data(), bias);
      base = -J.rightCols<2>() * a - Eigen::Vector2d(bias[0], bias[1]);
      const Eigen::Vector2d lambda =
          M.topLeftCorner<2, 2>() * base + M.topRightCorner<2, 2>() * a - f.head(2);
      tau = M.bottomLeftCorner<2, 2>() * base + M.bottomRightCorner<2, 2>() * a - f.tail(2) -
            J.rightCols<2>().transpose() * lambda;
    }
    Eigen::VectorXd u(3);
    u << std::clamp(tau[0], -100.0, 100.0), std::clamp(tau[1], -100.0, 100.0), s;
    return u;
  }
};

}  // namespace

int main(int argc, char** argv) {
  const bflow_bench::IpoptFlags ipopt = bflow_bench::take_ipopt_flags(argc, argv);
  CLI::App app("The monoped's OCP with one route changed, within an iteration budget (JSON)");
  int stages = 30, budget = 2500;
  std::string formulation = "step", relaxation = "scholtes", guess = "constant";
  double sigma0 = 0.0, polish_from = -1.0;
  bool sides = false;
  std::string start;
  app.add_option("--N", stages, "control stages")->check(CLI::PositiveNumber);
  app.add_option("--formulation", formulation, "step or stewart");
  app.add_option("--budget", budget, "IPOPT iterations of the whole run (0: none)");
  app.add_option("--relaxation", relaxation, "scholtes, l1 or elastic");
  app.add_option("--sigma0", sigma0, "initial sigma (default the setup's 1)");
  app.add_option("--polish-from", polish_from,
                 "polish from the first NLP at sigma <= X (default: no polish, as the setup)");
  app.add_option("--guess", guess, "constant (the setup's) or gait (GaitGuess)");
  app.add_flag("--sides-guess", sides, "algebraic variables at the sides of the guessed states");
  app.add_option("--start", start, "an earlier run's JSON output to start from (any N)")
      ->check(CLI::ExistingFile);
  std::string simulate;
  app.add_option("--simulate", simulate,
                 "only simulate the hopping controller (HopController) by FESD and write its "
                 "trajectory to FILE (a --start file)");
  double hop_gain = 1.0;
  bool lbfgs = false;
  app.add_option(
      "--hop-gain", hop_gain,
      "--simulate: the controller's joint accelerations times this (0: hold the joints)");
  app.add_flag("--lbfgs", lbfgs, "--simulate: IPOPT's limited-memory Hessian");
  CLI11_PARSE(app, argc, argv);

  const bflow::examples::MonopedTask task;
  const bflow::DcsFormulation form = bflow::parse_dcs_formulation(formulation);
  bflow::OcpOptions o = task.options(stages, form);
  bflow::OcpProblem p = task.problem(stages);
  o.homotopy.max_total_iterations = budget;
  o.homotopy.relaxation = relaxation == "elastic" ? bflow::OcpRelaxation::kElastic
                          : relaxation == "l1"    ? bflow::OcpRelaxation::kL1Penalty
                                                  : bflow::OcpRelaxation::kScholtes;
  if (sigma0 > 0.0) o.homotopy.sigma_initial = sigma0;
  if (polish_from >= 0.0) {
    o.homotopy.polish = true;
    o.homotopy.early_polish_sigma = polish_from;
  }
  if (guess == "gait") {
    p.guess = bflow::OcpGuess::kReference;
    p.guess_trajectory = [](double t) { return GaitGuess{}.state(t); };
  }
  if (!start.empty()) {
    const StartFrom from(start);
    p.guess = bflow::OcpGuess::kReference;
    p.guess_trajectory = [from](double t) { return from.state(t); };
    p.guess_u = from.controls(stages);
    guess = "start " + start;
    sides = true;
  }
  if (sides) o.algebraic_guess = bflow::AlgebraicGuess::kSides;
  ipopt.apply_to(o);
  o.progress = [](const bflow::OcpHomotopyStep& s) {
    std::fprintf(stderr,
                 "  sigma %.3g%s: %d iterations, cost %.4g, complementarity %.2g, sum mu %.3g, "
                 "largest mu %.3g, %.1f s, %s\n",
                 s.sigma, s.polish ? " (polish)" : "", s.iterations, s.objective, s.complementarity,
                 s.product_multipliers, s.largest_product_multiplier, s.cpu_seconds,
                 s.ipopt_status.c_str());
    if (!s.worst_rows.empty()) std::fprintf(stderr, "    worst rows: %s\n", s.worst_rows.c_str());
  };
  if (!simulate.empty()) {
    HopController hop{stages};
    hop.gain = hop_gain;
    const auto started = std::chrono::steady_clock::now();
    const auto policy = [&](int k, const Eigen::VectorXd& x) {
      const Eigen::VectorXd u = hop(k, x);
      const bflow::examples::Monoped robot;
      std::fprintf(
          stderr,
          "stage %d at %.0f s: q = (%.3f, %.3f, %.3f, %.3f), gap %.4f, clock %.3f, "
          "u = (%.2f, %.2f, %.3f)\n",
          k, std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count(),
          x[0], x[1], x[2], x[3], robot.gap(x.data()), x[8], u[0], u[1], u[2]);
      return u;
    };
    bflow::FesdOptions sim;
    sim.formulation = form;
    sim.elements = o.elements;
    sim.stages = o.collocation_stages;
    sim.steps = 1;
    sim.lifting_depth = o.lifting_depth;
    sim.exact_hessian = !lbfgs;
    sim.homotopy.max_nlp_iterations = 3000;
    sim.homotopy.nlp_tolerance = 1e-10;
    Eigen::MatrixXd controls;
    const bflow::FesdResult r = bflow::examples::with_monoped(
        task, form, stages, [&](const auto& model, const bflow::OcpProblem&) {
          return bflow::simulate_policy(model, p.x0, p.horizon, stages, policy, sim, p.u_lower,
                                        p.u_upper, &controls);
        });
    nlohmann::ordered_json j;
    j["status"] = bflow::to_string(r.status);
    j["message"] = r.message;
    j["hops"] = bflow::examples::MonopedTask::hops(r.states);
    j["grid"] = r.grid;
    for (Eigen::Index c = 0; c < r.states.cols(); ++c) {
      const Eigen::VectorXd col = r.states.col(c);
      j["x_grid"].push_back(std::vector<double>(col.data(), col.data() + col.size()));
    }
    for (Eigen::Index c = 0; c < controls.cols(); ++c) {
      const Eigen::VectorXd col = controls.col(c);
      j["u"].push_back(std::vector<double>(col.data(), col.data() + col.size()));
    }
    std::ofstream(simulate) << j.dump(1) << "\n";
    std::fprintf(stderr, "%s, %d hops, written to %s\n", bflow::to_string(r.status),
                 j["hops"].get<int>(), simulate.c_str());
    return r.ok() ? 0 : 1;
  }
  const bflow::OcpResult r = bflow::examples::with_monoped(
      task, form, stages,
      [&](const auto& model, const bflow::OcpProblem&) { return bflow::ocp_solve(model, p, o); });

  const bflow::examples::Monoped robot;
  double lowest = 0.0;
  for (Eigen::Index c = 0; c < r.x_grid.cols(); ++c)
    lowest = std::min(lowest, robot.gap(r.x_grid.col(c).data()));
  const Eigen::VectorXd end = r.x_stages.col(r.x_stages.cols() - 1);
  nlohmann::ordered_json j;
  j["N"] = stages;
  j["formulation"] = formulation;
  j["relaxation"] = relaxation;
  j["guess"] = guess + (sides ? " (sides)" : " (neutral)");
  j["sigma0"] = o.homotopy.sigma_initial;
  j["polish_from"] = polish_from;
  j["budget"] = budget;
  j["status"] = bflow::to_string(r.status);
  j["message"] = r.message;
  j["notes"] = r.notes;
  j["ipopt_iterations"] = r.ipopt_iterations;
  j["cpu_seconds"] = r.cpu_seconds;
  j["objective"] = r.objective;
  j["complementarity"] = r.max_complementarity;
  j["polished"] = r.polished;
  j["hops"] = bflow::examples::MonopedTask::hops(r.x_grid);
  j["q_error"] = bflow::examples::MonopedTask::target_error(end);
  j["v_end_max"] = end.segment(4, 4).cwiseAbs().maxCoeff();
  j["clock_end"] = end[8];
  j["deepest_foot"] = lowest;
  j["grid"] = r.grid;
  for (Eigen::Index c = 0; c < r.x_grid.cols(); ++c) {
    const Eigen::VectorXd col = r.x_grid.col(c);
    j["x_grid"].push_back(std::vector<double>(col.data(), col.data() + col.size()));
  }
  for (Eigen::Index c = 0; c < r.u.cols(); ++c) {
    const Eigen::VectorXd col = r.u.col(c);
    j["u"].push_back(std::vector<double>(col.data(), col.data() + col.size()));
  }
  for (const bflow::OcpHomotopyStep& s : r.homotopy) {
    j["homotopy"].push_back({{"sigma", s.sigma},
                             {"polish", s.polish},
                             {"iterations", s.iterations},
                             {"objective", s.objective},
                             {"complementarity", s.complementarity},
                             {"product_multipliers", s.product_multipliers},
                             {"largest_product_multiplier", s.largest_product_multiplier},
                             {"cpu_seconds", s.cpu_seconds},
                             {"status", s.ipopt_status},
                             {"worst_rows", s.worst_rows}});
  }
  std::cout << j.dump(1) << "\n";
  return 0;
}

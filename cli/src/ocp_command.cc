// `bflow ocp`: optimal control of a built-in nonsmooth example through FESD (format in
// docs/cli.md), with the errors of the run against the example's exact optimum.
#include <algorithm>
#include <array>
#include <cmath>
#include <exception>
#include <filesystem>
#include <functional>
#include <iterator>
#include <new>
#include <optional>
#include <ostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/filippov.h"
#include "bflow/examples/hopper.h"
#include "bflow/examples/monoped.h"
#include "bflow/examples/monoped_ocp.h"
#include "bflow/examples/ocp_examples.h"
#include "bflow/fesd/butcher.h"
#include "bflow/fesd/fesd.h"
#include "bflow/fesd/linear_solver.h"
#include "bflow/ocp/ocp.h"
#include "cli_commands.h"
#include "cli_json.h"
#include "cli_util.h"
#include "demo_util.h"

namespace bflow::cli {
namespace {

namespace fs = std::filesystem;

constexpr const char* kExamples[] = {"turbo-car", "braking-block", "monoped", "hopper"};

// The smallest --tol: IPOPT's tolerance on the scaled optimality error of the last NLP. Measured
// at the defaults (N = 10): the braking block meets 1e-14 (the last NLP in 254 iterations) but
// not 1e-15 (acceptable level only, after 1782); the turbo car meets 1e-13 only at its
// acceptable level before the polish, and neither 1e-14 nor 1e-15 (IPOPT's iteration limit,
// 45 s). Below 1e-14 no solve of these problems meets it in double precision; 1e-300 used to
// run to the iteration limits.
constexpr double kMinNlpTolerance = 1e-14;

// How far above J* a solved braking block may end, in units of (T/N)^2: piecewise-constant
// controls on N stages put the discretised optimum 0.126 (T/N)^2 above J* (measured for N = 2
// .. 40 at the defaults, and with --standard, another scheme, formulation or relaxation), up to
// 0.42 (T/N)^2 with one element per stage (N = 3), where the stop inside a stage cannot be
// placed; implicit Euler (--stages 1) ends below J*. A run 58 % above J* (any --sigma0 below
// 1e-12 at N = 10: J = 3.0345) is another stationary point, not the discretisation.
constexpr double kBrakingBlockSlack = 1.0;

// Bad input; the message starts with the option. Exit code 2.
class OptionError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

[[noreturn]] void fail(const std::string& option, const std::string& problem) {
  throw OptionError(option + ": " + problem);
}

// Calls f(model, problem) with the example's model and data (the monoped's model depends on the
// formulation: three regions for the step formulation, the eight base sets for Stewart's).
template <typename F>
auto with_example(const std::string& name, const examples::MonopedTask& monoped,
                  DcsFormulation formulation, int stages, F&& f) {
  if (name == "turbo-car") {
    return f(adapt_ocp(examples::TurboCar{}), examples::TurboCar::problem());
  }
  if (name == "monoped") return examples::with_monoped(monoped, formulation, stages, f);
  if (name == "hopper") {
    const OcpProblem problem = examples::HopperTask(stages).problem();
    if (formulation == DcsFormulation::kStewart) {
      return f(adapt_ocp(examples::hopper_model<TimeFreezingRegions::kBaseSets>()), problem);
    }
    return f(adapt_ocp(examples::hopper_model<TimeFreezingRegions::kUnions>()), problem);
  }
  return f(adapt_ocp(examples::BrakingBlock{}), examples::BrakingBlock::problem());
}

// The number of control stages: --N, or the example's default.
int stages_of(const OcpCommandOptions& options) {
  if (options.example == "hopper") return options.n.value_or(examples::HopperTask{}.stages);
  return options.n.value_or(options.example == "monoped" ? 30 : 10);
}

OcpRelaxation parse_relaxation(const std::string& text) {
  if (text == "scholtes") return OcpRelaxation::kScholtes;
  if (text == "l1") return OcpRelaxation::kL1Penalty;
  if (text == "elastic") return OcpRelaxation::kElastic;
  fail("--relaxation", "unknown relaxation " + quote(text) + "; use scholtes, l1 or elastic");
}

void check_positive(const std::optional<double>& value, const std::string& option,
                    const std::string& what) {
  if (value && !(*value > 0.0 && std::isfinite(*value))) {
    fail(option, what + " must be finite and > 0, got " + format_number(*value));
  }
}

// Every range the library would check, checked here first so that the message names the option
// the user typed.
void check_ranges(const OcpCommandOptions& options, const OcpOptions& defaults) {
  if (stages_of(options) < 1) {
    fail("--N",
         "the number of control stages must be >= 1, got " + std::to_string(stages_of(options)));
  }
  if (options.nfe < 1) {
    fail("--nfe", "the number of finite elements per control stage must be >= 1, got " +
                      std::to_string(options.nfe));
  }
  if (options.stages < 1 || options.stages > kMaxCollocationStages) {
    fail("--stages", "the number of Runge-Kutta stages must be in [1, " +
                         std::to_string(kMaxCollocationStages) + "], got " +
                         std::to_string(options.stages));
  }
  check_positive(options.sigma0, "--sigma0", "the initial relaxation parameter");
  check_positive(options.sigma_final, "--sigma-final", "the final relaxation parameter");
  check_positive(options.tol, "--tol", "the NLP tolerance");
  if (options.early_polish_sigma &&
      !(*options.early_polish_sigma >= 0.0 && std::isfinite(*options.early_polish_sigma))) {
    fail("--early-polish-sigma",
         "the sigma from which the polish is tried must be finite and "
         ">= 0 (0: only the final polish), got " +
             format_number(*options.early_polish_sigma));
  }
  if (options.monotone_mu_down_to && !(*options.monotone_mu_down_to >= 0.0)) {
    fail("--monotone-mu-down-to",
         "the sigma down to which warm starts run the monotone mu strategy must be >= 0 (inf: "
         "the adaptive strategy throughout), got " +
             format_number(*options.monotone_mu_down_to));
  }
  if (options.tol && *options.tol < kMinNlpTolerance) {
    fail("--tol", "must be >= " + format_number(kMinNlpTolerance) +
                      " (below that IPOPT cannot meet it in double precision), got " +
                      format_number(*options.tol));
  }
  const double sigma0 = options.sigma0.value_or(defaults.homotopy.sigma_initial);
  const double sigma_final = options.sigma_final.value_or(defaults.homotopy.sigma_final);
  if (sigma_final > sigma0) {
    if (!options.sigma_final) {
      fail("--sigma0", format_number(sigma0) + " is below the final " + format_number(sigma_final) +
                           " (the default of --sigma-final)");
    }
    const std::string sigma0_text =
        format_number(sigma0) + (options.sigma0 ? "" : " (the default of --sigma0)");
    fail("--sigma-final", format_number(sigma_final) + " is above the initial " + sigma0_text);
  }
  if (options.max_iterations && *options.max_iterations < 0) {
    fail("--max-iterations", "the iteration budget must be >= 0 (0: no limit), got " +
                                 std::to_string(*options.max_iterations));
  }
  if (options.plot && options.plot->empty()) fail("--plot", "the directory name is empty");
}

// The library's size of the NLP against IPOPT's indices and the memory limit, refused as --N
// before anything is built.
void check_size(const OcpModel& model, const OcpCommandOptions& options, const OcpOptions& o) {
  if (const std::string excess = ocp_problem_size(model, o).excess(); !excess.empty()) {
    fail("--N", std::to_string(stages_of(options)) + " control stages of " +
                    std::to_string(options.nfe) + " finite elements give " + excess);
  }
}

// The JSON and its newline in one write (a failed write is detected where the command ends).
void write_result(std::ostream& out, const OrderedJson& j, bool compact) {
  std::ostringstream buffer;
  write_json(buffer, j, compact);
  buffer << '\n';
  out << buffer.str() << std::flush;
}

// |a - b|, or null when the run has no value to compare.
OrderedJson error_json(const double* value, double exact) {
  if (value == nullptr) return nullptr;
  return std::abs(*value - exact);
}

// The example's known optimum and this run's distance to it.
OrderedJson exact_json(const std::string& example, const OcpResult& r) {
  OrderedJson j;
  if (example == "turbo-car") {
    using examples::TurboCar;
    const std::vector<double> switches(std::begin(TurboCar::kSwitchTimes),
                                       std::end(TurboCar::kSwitchTimes));
    j["T"] = TurboCar::kOptimalTime;
    j["switch_times"] = switches;
    j["T_error"] = std::abs(r.T - TurboCar::kOptimalTime);
    j["objective_error"] = std::abs(r.objective - TurboCar::kOptimalTime);
    // Only a run that found as many switches as the optimum has is compared, in order.
    if (r.switch_times.size() == switches.size()) {
      double worst = 0.0;
      for (std::size_t k = 0; k < switches.size(); ++k) {
        worst = std::max(worst, std::abs(r.switch_times[k] - switches[k]));
      }
      j["switch_times_error"] = worst;
    } else {
      j["switch_times_error"] = nullptr;
    }
  } else if (example == "hopper") {
    using examples::HopperTask;
    const Eigen::VectorXd target = HopperTask::target();
    j["q_target"] = std::vector<double>(target.data(), target.data() + 4);
    j["t_physical_end"] = HopperTask::kHorizon;
    if (r.x_stages.cols() > 0) {
      const Eigen::VectorXd end = r.x_stages.col(r.x_stages.cols() - 1);
      j["q_error"] = HopperTask::target_error(end);
      j["t_physical_end_error"] = std::abs(end[8] - HopperTask::kHorizon);
    } else {
      j["q_error"] = nullptr;
      j["t_physical_end_error"] = nullptr;
    }
  } else if (example == "monoped") {
    using examples::MonopedTask;
    const Eigen::Vector4d target = MonopedTask::target();
    j["q_target"] = std::vector<double>(target.data(), target.data() + 4);
    j["t_physical_end"] = MonopedTask::kHorizon;
    if (r.x_stages.cols() > 0) {
      const Eigen::VectorXd end = r.x_stages.col(r.x_stages.cols() - 1);
      j["q_error"] = MonopedTask::target_error(end);
      j["t_physical_end_error"] = std::abs(end[8] - MonopedTask::kHorizon);
    } else {
      j["q_error"] = nullptr;
      j["t_physical_end_error"] = nullptr;
    }
  } else {
    using examples::BrakingBlock;
    j["objective"] = BrakingBlock::optimal_cost();
    j["stop_time"] = BrakingBlock::stop_time();
    j["final_position"] = BrakingBlock::final_position();
    j["objective_error"] = std::abs(r.objective - BrakingBlock::optimal_cost());
    // The block comes to rest where v = c reaches 0: the run's first switch.
    j["stop_time_error"] = error_json(r.switch_times.empty() ? nullptr : &r.switch_times.front(),
                                      BrakingBlock::stop_time());
    const double* final_position =
        r.x_stages.cols() > 0 ? &r.x_stages(0, r.x_stages.cols() - 1) : nullptr;
    j["final_position_error"] = error_json(final_position, BrakingBlock::final_position());
  }
  return j;
}

// A solved run that ends far from the example's known optimum stopped at another stationary
// point of the MPCC: a notice (in the JSON's notes and on stderr), not an error (the NLP was
// solved), with the remedy measured in docs/ocp.md. "" when there is nothing to say.
//
// The turbo car's optimum is a solution of the discretised problem when its control switches
// (8/3 and 32/3 of 40/3) are stage boundaries, i.e. N a multiple of 5, and the horizon is free
// (not with standard time-stepping, whose grid cannot place the switch of v at 10): T must
// then be 40/3. The braking block's controls are constant on stages, which puts the
// discretised optimum above J* by about 0.126 (T/N)^2 (kBrakingBlockSlack).
std::string spurious_notice(const OcpCommandOptions& options, const OcpResult& r) {
  if (!r.ok()) return "";
  const int n = stages_of(options);
  const auto remedy = [](const char* sigma0) {
    return std::string(
               ": the homotopy ended at another stationary point of the complementarity problem "
               "(docs/ocp.md, Known limits); a larger --sigma0 (") +
           sigma0 + ") or another N may reach the optimum";
  };
  if (options.example == "turbo-car") {
    using examples::TurboCar;
    if (options.standard || n % 5 != 0) return "";
    const double error = std::abs(r.T - TurboCar::kOptimalTime);
    if (error <= 1e-6) return "";
    return "ocp: T = " + format_number(r.T) + " is " + format_number(error) +
           " above the optimum 40/3, which N = " + std::to_string(n) + " stages represent exactly" +
           remedy("e.g. 1000");
  }
  if (options.example == "braking-block") {
    using examples::BrakingBlock;
    const double h = BrakingBlock::problem().horizon / n;
    const double slack = kBrakingBlockSlack * h * h;
    const double excess = r.objective - BrakingBlock::optimal_cost();
    if (!(excess > slack)) return "";
    return "ocp: the cost " + format_number(r.objective) + " is " + format_number(excess) +
           " above the optimum 2 sqrt5 + asinh 2 - 4 = " +
           format_number(BrakingBlock::optimal_cost()) + ", more than the " + format_number(slack) +
           " = (T/N)^2 that controls constant on N = " + std::to_string(n) + " stages explain" +
           remedy("e.g. the default, 100");
  }
  return "";
}

OrderedJson homotopy_json(const std::vector<OcpHomotopyStep>& steps) {
  OrderedJson list = OrderedJson::array();
  for (const OcpHomotopyStep& s : steps) {
    OrderedJson j;
    j["sigma"] = s.sigma;
    j["objective"] = s.objective;
    j["complementarity"] = s.complementarity;
    j["product_multipliers"] = s.product_multipliers;
    j["largest_product_multiplier"] = s.largest_product_multiplier;
    j["iterations"] = s.iterations;
    j["cpu_seconds"] = s.cpu_seconds;
    j["status"] = s.ipopt_status;
    j["kkt_error"] = std::isfinite(s.kkt_error) ? OrderedJson(s.kkt_error) : OrderedJson(nullptr);
    j["polish"] = s.polish;
    j["mu_strategy"] = s.mu_strategy;
    j["mu_init"] = s.mu_init;
    if (!s.worst_rows.empty()) j["worst_rows"] = s.worst_rows;
    list.push_back(j);
  }
  return list;
}

// One line per NLP of the homotopy on `err`, while the solve runs.
std::string progress_line(const OcpHomotopyStep& s) {
  std::string line = s.polish ? "ocp: polish       " : formatted("ocp: sigma %.1e", s.sigma);
  line += formatted("  objective %.6g  complementarity %.1e  iterations %d  %.2f s", s.objective,
                    s.complementarity, s.iterations, s.cpu_seconds);
  if (s.ipopt_status != "Solve_Succeeded") line += "  " + s.ipopt_status;
  return line;
}

// Data and scripts of the three plots, then gnuplot on each. @throws DemoError.
void write_plots(const fs::path& dir, const OcpModel& model, const OcpResult& r) {
  const int d = model.states(), nu = model.controls(), nc = model.switches();
  std::ostringstream grid;
  grid << "# t x_0 .. x_" << d - 1 << " c_0 .. c_" << nc - 1
       << " at every element boundary (bflow ocp)\n";
  std::vector<double> c(static_cast<std::size_t>(nc));
  for (std::size_t k = 0; k < r.grid.size(); ++k) {
    const Eigen::VectorXd x = r.x_grid.col(static_cast<Eigen::Index>(k));
    model.switching(x.data(), c.data());
    grid << format_number(r.grid[k]);
    for (int i = 0; i < d; ++i) grid << ' ' << format_number(x[i]);
    for (int i = 0; i < nc; ++i) grid << ' ' << format_number(c[static_cast<std::size_t>(i)]);
    grid << '\n';
  }
  write_file(dir / "ocp_grid.dat", grid.str(), "ocp");

  // Each stage's control twice, at its start and its end: steps when drawn with lines.
  std::ostringstream controls;
  controls << "# t u_0 .. u_" << nu - 1 << " (piecewise constant, each stage at both ends)\n";
  for (Eigen::Index k = 0; k < r.u.cols(); ++k) {
    for (double t : {r.stage_times[static_cast<std::size_t>(k)],
                     r.stage_times[static_cast<std::size_t>(k) + 1]}) {
      controls << format_number(t);
      for (int i = 0; i < nu; ++i) controls << ' ' << format_number(r.u(i, k));
      controls << '\n';
    }
  }
  write_file(dir / "ocp_controls.dat", controls.str(), "ocp");

  std::ostringstream switches;
  switches << "# switch times\n";
  for (double t : r.switch_times) switches << format_number(t) << '\n';
  write_file(dir / "ocp_switch_times.dat", switches.str(), "ocp");

  const auto script = [&](const std::string& name, const std::string& title,
                          const std::string& ylabel, const std::string& plot) {
    std::ostringstream gp;
    gp << "# Written by `bflow ocp`; run in this directory: gnuplot " << name << ".gp\n"
       << "set encoding utf8\n"
          "set terminal pngcairo size 900,600 enhanced font 'Sans,12'\n"
       << "set output (exists('bflow_output') ? bflow_output : '" << name << ".png')\n"
       << "set title \"" << title << "\"\n"
       << "set xlabel 't'\nset ylabel '" << ylabel << "'\n"
       << "set grid lc rgb '#dddddd'\nset key outside right top\n"
       << "set offsets 0, 0, graph 0.05, graph 0.05\n"
       << plot;
    write_file(dir / (name + ".gp"), gp.str(), "ocp");
    run_gnuplot(dir, name + ".gp", name + ".png", "ocp", "leave out --plot");
  };
  std::string states = "plot ";
  for (int i = 0; i < d; ++i) {
    states += formatted("'ocp_grid.dat' using 1:%d with linespoints pt 7 ps 0.5 title 'x_%d'%s",
                        i + 2, i, i + 1 < d ? ", \\\n  " : "\n");
  }
  script("ocp_states", "States at the element boundaries", "x", states);
  std::string inputs = "plot ";
  for (int i = 0; i < nu; ++i) {
    inputs += formatted("'ocp_controls.dat' using 1:%d with lines lw 2 title 'u_%d'%s", i + 2, i,
                        i + 1 < nu ? ", \\\n  " : "\n");
  }
  script("ocp_controls", "Controls, constant on each stage", "u", inputs);
  // The switch times as vertical lines through the plotted range of c.
  std::string switching = "set xzeroaxis lt 1 lc rgb '#888888'\n";
  for (double t : r.switch_times) {
    switching += "set arrow from " + format_number(t) + ", graph 0 to " + format_number(t) +
                 ", graph 1 nohead dt 2 lc rgb '#B22222'\n";
  }
  switching += "plot ";
  for (int i = 0; i < nc; ++i) {
    switching +=
        formatted("'ocp_grid.dat' using 1:%d with linespoints pt 7 ps 0.5 title 'c_%d(x)', \\\n  ",
                  d + 2 + i, i);
  }
  switching += "NaN with lines dt 2 lc rgb '#B22222' title 'switch times'\n";
  script("ocp_switching", "Switching functions; dashed: the switch times", "c(x)", switching);
}

// How a time-freezing robot (x = (q, v, clock), four positions) is drawn: its name (the files'
// prefix), the points of its outline at q, the frame's ranges and the titles of its positions,
// velocities and first two controls (then the slack, if any, and the speed of time, last).
struct RobotPicture {
  std::string name, outline, xrange, yrange;
  double horizon = 0.0, frame_step = 0.25;
  std::function<std::vector<std::array<double, 2>>(const Eigen::Vector4d&)> points;
  std::array<std::string, 8> states;
  std::array<std::string, 2> controls;
  std::string torque_label;
};

RobotPicture robot_picture(const std::string& example) {
  RobotPicture p;
  if (example == "monoped") {
    p.name = "monoped";
    p.outline = "body, thigh, shank";
    p.horizon = examples::MonopedTask::kHorizon;
    p.xrange = "[-0.35:3.45]";
    p.yrange = "[-0.05:0.85]";
    p.points = [](const Eigen::Vector4d& q) {
      const examples::Monoped robot;
      double knee[2], foot[2];
      robot.knee(q.data(), knee);
      robot.foot(q.data(), foot);
      // head (5 cm above the base), base (the hip), knee and foot
      return std::vector<std::array<double, 2>>{
          {q[0], q[1] + 0.05}, {q[0], q[1]}, {knee[0], knee[1]}, {foot[0], foot[1]}};
    };
    p.states = {
        "q_x [m]",   "q_z [m]",   "{/Symbol f}_{hip} [rad]",   "{/Symbol f}_{knee} [rad]",
        "v_x [m/s]", "v_z [m/s]", "{/Symbol w}_{hip} [rad/s]", "{/Symbol w}_{knee} [rad/s]"};
    p.controls = {"u_{hip}", "u_{knee}"};
    p.torque_label = "torque [N m]";
    return p;
  }
  p.name = "hopper";
  p.outline = "body and leg";
  p.horizon = examples::HopperTask::kHorizon;
  p.xrange = "[-0.2:5.4]";
  p.yrange = "[-0.05:1.55]";
  p.points = [](const Eigen::Vector4d& q) {
    const double foot_x = examples::Hopper{}.tangential_position(q.data());
    const double foot_z = examples::Hopper{}.gap(q.data());
    return std::vector<std::array<double, 2>>{{q[0], q[1]}, {foot_x, foot_z}};
  };
  p.states = {"x [m]",     "y [m]",     "{/Symbol q} [rad]",   "l [m]",
              "v_x [m/s]", "v_y [m/s]", "{/Symbol w} [rad/s]", "dl/dt [m/s]"};
  p.controls = {"torque [N m]", "leg force [N]"};
  p.torque_label = "torque, force";
  return p;
}

// A time-freezing robot's pictures against physical time (the clock, x_8): the robot drawn every
// 0.25 s over the ground, its positions and velocities, and its first two controls and speed of
// time. Files NAME_frames, NAME_states (.dat, .gp, .png) and NAME_controls (.gp, .png).
// @throws DemoError.
void write_robot_plots(const fs::path& dir, const RobotPicture& pic, const OcpResult& r) {
  const Eigen::MatrixXd& x = r.x_grid;
  const std::string& name = pic.name;
  std::ostringstream frames;
  frames << "# x z t: the points of the " << name << " (" << pic.outline
         << "), one block per frame (bflow ocp)\n";
  const int count = static_cast<int>(std::lround(pic.horizon / pic.frame_step)) + 1;
  Eigen::Index j = 0;
  for (int f = 0; f < count && x.cols() > 0; ++f) {
    const double t = pic.horizon * f / (count - 1);
    while (j + 1 < x.cols() && x(8, j) < t - 1e-9) ++j;
    for (const auto& point : pic.points(x.col(j).head(4))) {
      frames << format_number(point[0]) << ' ' << format_number(point[1]) << ' ' << format_number(t)
             << '\n';
    }
    frames << "\n\n";
  }
  write_file(dir / (name + "_frames.dat"), frames.str(), "ocp");

  std::ostringstream states;
  states << "# t, then the positions and velocities, t the clock (physical time), at every element "
            "boundary\n";
  for (Eigen::Index k = 0; k < x.cols(); ++k) {
    states << format_number(x(8, k));
    for (int i = 0; i < 8; ++i) states << ' ' << format_number(x(i, k));
    states << '\n';
  }
  write_file(dir / (name + "_states.dat"), states.str(), "ocp");

  const auto script = [&](const std::string& plot, const std::string& body) {
    const std::string file = name + "_" + plot;
    const std::string text = "# Written by `bflow ocp`; run in this directory: gnuplot " + file +
                             ".gp\nset encoding utf8\n" +
                             "set output (exists('bflow_output') ? bflow_output : '" + file +
                             ".png')\n" + body;
    write_file(dir / (file + ".gp"), text, "ocp");
    run_gnuplot(dir, file + ".gp", file + ".png", "ocp", "leave out --plot");
  };
  const auto step = format_number(pic.frame_step);
  script("frames",
         "set terminal pngcairo size 1400,420 enhanced font 'Sans,12'\n"
         "set title 'The " +
             name + " every " + step + " s (" + pic.outline +
             "); colour: physical time'\n"
             "set size ratio -1\nset xlabel 'x [m]'\nset ylabel 'z [m]'\n"
             "set xrange " +
             pic.xrange + "\nset yrange " + pic.yrange +
             "\n"
             "set cblabel 't [s]'\nset palette rgbformulae 33,13,10\n"
             "set grid lc rgb '#dddddd'\n"
             "plot 0 with lines lc rgb '#555555' lw 2 title 'ground', \\\n"
             "  '" +
             name +
             "_frames.dat' using 1:2:3 with linespoints lw 2 pt 7 ps 0.6 "
             "lc palette notitle\n");
  std::string body =
      "set terminal pngcairo size 1000,800 enhanced font 'Sans,12'\n"
      "set multiplot layout 2,1 title 'The " +
      name +
      " against physical time'\n"
      "set grid lc rgb '#dddddd'\nset key outside right top\nset xlabel 't [s]'\n";
  for (int half = 0; half < 2; ++half) {
    body += std::string("set ylabel '") + (half == 0 ? "position" : "velocity") + "'\nplot ";
    for (int i = 0; i < 4; ++i) {
      body += (i == 0 ? "'" + name + "_states.dat'" : std::string("  ''")) +
              " using 1:" + std::to_string(2 + 4 * half + i) + " with lines lw 2 title '" +
              pic.states[static_cast<std::size_t>(4 * half + i)] + "'" + (i < 3 ? ", \\\n" : "\n");
    }
  }
  script("states", body + "unset multiplot\n");
  // ocp_controls.dat: t, then the controls; the speed of time is the last.
  const int speed_column = 1 + static_cast<int>(r.u.rows());
  script("controls",
         "set terminal pngcairo size 1000,500 enhanced font 'Sans,12'\n"
         "set title 'Controls and speed of time, constant on each stage'\n"
         "set grid lc rgb '#dddddd'\nset key outside right top\nset xlabel 't [s]'\n"
         "set ylabel '" +
             pic.torque_label +
             "'\nset y2label 'speed of time s'\n"
             "set ytics nomirror\nset y2tics\n"
             "plot 'ocp_controls.dat' using 1:2 with lines lw 2 title '" +
             pic.controls[0] + "', \\\n  '' using 1:3 with lines lw 2 title '" + pic.controls[1] +
             "', \\\n  '' using 1:" + std::to_string(speed_column) +
             " axes x1y2 with lines lw 2 dt 2 title 's'\n");
}

}  // namespace

int run_ocp(const OcpCommandOptions& options, std::ostream& out, std::ostream& err) {
  try {
    bool known = false;
    std::string names;
    for (const char* e : kExamples) {
      known = known || options.example == e;
      names += (names.empty() ? "" : ", ") + std::string(e);
    }
    if (options.example.empty()) {
      report_error(err, "--example: is required; use " + names);
      return kExitBadInput;
    }
    if (!known) {
      report_error(err, "--example: unknown example " + quote(options.example) + "; use " + names);
      return kExitBadInput;
    }
    DcsFormulation formulation;
    try {
      formulation = parse_dcs_formulation(
          options.formulation.value_or(options.example == "hopper" ? "stewart" : "step"));
    } catch (const InvalidArgument&) {
      report_error(err, "--formulation: unknown formulation " + quote(*options.formulation) +
                            ": use step or stewart");
      return kExitBadInput;
    }
    examples::MonopedTask monoped;
    if (options.setup) {
      if (options.example != "monoped") {
        fail("--setup", "only the monoped has setups, not " + quote(options.example));
      }
      try {
        monoped.setup = examples::parse_monoped_setup(*options.setup);
      } catch (const InvalidArgument&) {
        fail("--setup", "unknown setup " + quote(*options.setup) + "; use nosnoc or strict");
      }
    }
    const int hopper_jumps = examples::HopperTask::kJumps;
    if (options.example == "hopper" &&
        (stages_of(options) < hopper_jumps || stages_of(options) % hopper_jumps != 0)) {
      fail("--N", "the hopper's number of control stages must be a positive multiple of " +
                      std::to_string(hopper_jumps) + " (its reference samples each of the " +
                      std::to_string(hopper_jumps) + " jumps at N / " +
                      std::to_string(hopper_jumps) + " stages), got " +
                      std::to_string(stages_of(options)));
    }
    // The monoped starts from its setup's options (MonopedTask::options), nosnoc's by default;
    // the hopper from nosnoc's settings of its example (HopperTask::options).
    OcpOptions o =
        options.example == "monoped" ? monoped.options(std::max(stages_of(options), 1), formulation)
        : options.example == "hopper" ? examples::HopperTask(stages_of(options)).options()
                                      : OcpOptions{};
    o.formulation = formulation;
    try {
      o.scheme = parse_collocation_scheme(options.scheme);
    } catch (const InvalidArgument&) {
      report_error(err, "--scheme: unknown collocation scheme " + quote(options.scheme) +
                            ": use radau or gauss");
      return kExitBadInput;
    }
    try {
      o.collocation_form = parse_collocation_form(options.collocation_form);
    } catch (const InvalidArgument&) {
      report_error(err, "--collocation-form: unknown collocation form " +
                            quote(options.collocation_form) + ": use integral or derivative");
      return kExitBadInput;
    }
    o.homotopy.relaxation = parse_relaxation(options.relaxation);
    if (options.cross) {
      try {
        o.cross_complementarity = parse_cross_complementarity(*options.cross);
      } catch (const InvalidArgument&) {  // the text quoted as every user text on stderr
        fail("--cross", "unknown cross complementarity " + quote(*options.cross) +
                            "; use element-sums, point-pairs or point-sums");
      }
    }
    check_ranges(options, o);
    const std::string solver_problem = apply_solver_options(options.solver, o);
    if (!solver_problem.empty()) throw OptionError(solver_problem);  // before anything runs
    o.stages = stages_of(options);
    o.elements = options.nfe;
    o.collocation_stages = options.stages;
    o.standard = options.standard;
    if (o.standard) {
      // The example's settings for FESD's free element lengths and cross complementarity, which
      // standard time-stepping has no use for (its lengths are fixed, its products point by
      // point): left out, the same solve. A --cross given with --standard is refused by
      // ocp_solve.
      if (!options.cross) o.cross_complementarity = CrossComplementarity::kElementSums;
      o.step_deviation_weight = 0.0;
      o.equilibration_weight = 0.0;
    }
    if (options.sigma0) o.homotopy.sigma_initial = *options.sigma0;
    if (options.sigma_final) o.homotopy.sigma_final = *options.sigma_final;
    if (options.tol) o.homotopy.nlp_tolerance = *options.tol;
    if (options.early_polish_sigma) {
      if (!o.homotopy.polish && *options.early_polish_sigma > 0.0) {
        fail("--early-polish-sigma", "the " + options.example +
                                         " does not polish (its homotopy ends at its last NLP), "
                                         "so there is no early polish to try from sigma " +
                                         format_number(*options.early_polish_sigma));
      }
      o.homotopy.early_polish_sigma = *options.early_polish_sigma;
    }
    if (options.monotone_mu_down_to) {
      o.homotopy.monotone_mu_down_to = *options.monotone_mu_down_to;
    }
    if (options.max_iterations) o.homotopy.max_total_iterations = *options.max_iterations;
    if (options.lifting) {
      if (*options.lifting != 0 && formulation != DcsFormulation::kStep) {
        fail("--lifting", "a lifting depth (" + std::to_string(*options.lifting) +
                              ") applies to the step formulation only, not " +
                              to_string(formulation));
      }
      o.lifting_depth = *options.lifting;
    }
    if (!options.quiet) {
      o.progress = [&err](const OcpHomotopyStep& s) {
        err << progress_line(s) << '\n' << std::flush;
      };
    }
    with_example(options.example, monoped, o.formulation, o.stages,
                 [&](const OcpModel& model, const OcpProblem&) {
                   // The bound of `bflow fesd`, from the model's n_c.
                   if (const std::string why =
                           lifting_depth_error(o.lifting_depth, model.switches(), options.example);
                       !why.empty()) {
                     fail("--lifting", why);
                   }
                   check_size(model, options, o);
                   return 0;
                 });
    // A directory that cannot take the plots, or holds something other than a file where a
    // plot's file goes, is refused before the solve.
    if (options.plot) {
      prepare_output_directory(*options.plot, "ocp");
      std::vector<std::string> files = {"ocp_grid.dat", "ocp_controls.dat", "ocp_switch_times.dat"};
      for (const char* plot : {"ocp_states", "ocp_controls", "ocp_switching"}) {
        files.insert(files.end(), {std::string(plot) + ".gp", std::string(plot) + ".png"});
      }
      if (options.example == "monoped" || options.example == "hopper") {
        const std::string name = options.example;
        files.insert(files.end(), {name + "_frames.dat", name + "_states.dat"});
        for (const char* plot : {"_frames", "_states", "_controls"}) {
          files.insert(files.end(), {name + plot + ".gp", name + plot + ".png"});
        }
      }
      for (const std::string& file : files) {
        check_replaceable_file(std::filesystem::path(*options.plot) / file, "ocp");
      }
    }

    return with_example(
        options.example, monoped, o.formulation, o.stages,
        [&](const OcpModel& model, const OcpProblem& problem) {
          const OcpResult r = ocp_solve(model, problem, o);
          const std::string notice = spurious_notice(options, r);
          std::vector<std::string> notes = r.notes;
          if (!notice.empty()) notes.push_back(notice);
          OrderedJson j;
          j["example"] = options.example;
          j["N"] = o.stages;
          j["nfe"] = options.nfe;
          j["status"] = to_string(r.status);
          j["message"] = r.message;
          if (options.example == "monoped") j["setup"] = to_string(monoped.setup);
          j["cross_complementarity"] = o.standard ? "standard" : to_string(o.cross_complementarity);
          j["ipopt"] = r.ipopt;
          j["linear_solver"] = r.linear_solver;
          j["blas"] = r.blas;
          j["derivatives"] = r.derivatives;
          j["ipopt_status"] = r.ipopt_status;
          j["kkt_error"] = std::isfinite(r.kkt_error) ? OrderedJson(r.kkt_error) : nullptr;
          j["notes"] = notes;
          j["objective"] = r.objective;
          j["T"] = r.T;
          j["t"] = r.stage_times;
          j["x"] = columns_json(r.x_stages);
          j["u"] = columns_json(r.u);
          j["switch_times"] = r.switch_times;
          j["max_complementarity"] = r.max_complementarity;
          j["polished"] = r.polished;
          j["homotopy"] = homotopy_json(r.homotopy);
          j["ipopt_iterations"] = r.ipopt_iterations;
          j["cpu_seconds"] = r.cpu_seconds;
          j["cpu_per_iteration"] = r.cpu_per_iteration;
          if (options.example == "monoped" || options.example == "hopper") {
            const bool monoped_run = options.example == "monoped";
            j["hops"] = r.x_grid.cols() == 0 ? 0
                        : monoped_run        ? examples::MonopedTask::hops(r.x_grid)
                                             : examples::HopperTask::hops(r.x_grid);
            j["t_physical_end"] =
                r.x_stages.cols() > 0 ? OrderedJson(r.x_stages(8, r.x_stages.cols() - 1)) : nullptr;
          }
          j["exact"] = exact_json(options.example, r);
          if (options.trajectory) {
            j["grid"] = r.grid;
            j["x_grid"] = columns_json(r.x_grid);
            j["step_sizes"] = r.step_sizes;
            j["active_sets"] = r.active_sets;
          }
          write_result(out, j, options.compact);
          // The plots are drawn for any result (a failed run is worth seeing); one error line in
          // all cases, the solver's first.
          std::string plot_error;
          if (options.plot) {
            try {
              write_plots(*options.plot, model, r);
              if (options.example == "monoped" || options.example == "hopper") {
                write_robot_plots(*options.plot, robot_picture(options.example), r);
              }
            } catch (const DemoError& e) {
              plot_error = e.what();
            }
          }
          if (!notice.empty()) err << "warning: " << one_line(notice) << '\n' << std::flush;
          if (!r.ok()) {
            report_error(err, "ocp: " + std::string(to_string(r.status)) + ": " + r.message);
            return kExitFailure;
          }
          if (!plot_error.empty()) {
            report_error(err, plot_error);
            return kExitFailure;
          }
          return kExitOk;
        });
  } catch (const OptionError& e) {
    report_error(err, e.what());
    return kExitBadInput;
  } catch (const DemoError& e) {
    report_error(err, e.what());  // the --plot directory
    return kExitFailure;
  } catch (const InvalidArgument& e) {
    // What the library rejects that no option decides (the messages start with "ocp:").
    report_error(err, with_field("ocp", e.what()));
    return kExitBadInput;
  } catch (const std::bad_alloc&) {
    report_error(err, "ocp: out of memory");
    return kExitFailure;
  } catch (const std::exception& e) {
    report_error(err, std::string("ocp: internal: ") + e.what());
    return kExitFailure;
  }
}

}  // namespace bflow::cli

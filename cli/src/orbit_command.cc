// `bflow orbit`: the periodic orbit of a scene through a Poincare section
// (bflow::find_periodic_orbit), the pieces of its return map on the section, the growth-rate
// bracket and the verdict; with --vary-param a family of orbits by natural-parameter continuation
// (format in docs/cli.md).
//
// Every option is validated before the first simulation, every value of the varied parameter and
// the paths of --output and --plot against each other included, so that bad input is exit code 2
// with nothing written or created. An orbit that Newton's method does not find is a result, not
// an exception (PeriodicOrbit::converged): the JSON is printed, stderr ends with one "error:
// orbit: ..." line and the exit code is 1, as for an optimal control problem that is not solved.
// A family goes on past an orbit that is not found, from the last orbit that was.
#include <algorithm>
#include <cfloat>
#include <chrono>
#include <cmath>
#include <complex>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <new>
#include <optional>
#include <ostream>
#include <sstream>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/flow_derivative.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/orbits/orbit_family.h"
#include "bflow/orbits/periodic_orbit.h"
#include "cli_commands.h"
#include "cli_json.h"
#include "cli_util.h"
#include "demo_util.h"
#include "scene_setup.h"

namespace bflow::cli {
namespace {

namespace fs = std::filesystem;

// The biped's parameters for an orbit where --param does not set them: the mode-damping biped on
// stiff legs with the legs' thrust (LegThrust), which hops periodically, both feet landing and
// lifting off together (tests/orbits/biped_orbit_test.cc).
const std::pair<const char*, const char*> kBipedOrbitParams[] = {{"variant", "mode-damping"},
                                                                 {"kappa", "1000"},
                                                                 {"beta", "4"},
                                                                 {"thrust", "10"},
                                                                 {"thrust_speed", "0.1"}};
// The apex of a hop (vertical speed from + to -), and for pwconst a plane its flow crosses once
// and never again: it has no periodic orbit.
constexpr const char* kBipedSection = "-x4";
constexpr const char* kPwconstSection = "x0=1";
// The pronk's own defaults are its stable hop (core/pronk.h): no parameter is overridden. Its
// section is the apex too, and its guess pronk_initial_state(), at rest at height 1, just above
// the apex 0.977 (tests/orbits/pronk_orbit_test.cc).
constexpr const char* kPronkSection = "-x4";
// Families of more orbits than this are refused: each orbit takes a Newton run.
constexpr std::uint64_t kMaxFamily = 100000;
// Pieces of the return map printed; above, "pieces" is null and "piece_count" says how many.
constexpr double kMaxPrintedPieces = 1000.0;
// Steps of the simulation that samples one period for orbit.png.
constexpr int kPlotSamples = 600;

// The orbit's inputs, validated.
struct Plan {
  SceneSetup setup;
  int d = 0;
  CoordinateSection section;
  Eigen::VectorXd x0;
  // The library's defaults with --tol, --max-iterations, --rtol and --atol applied; no progress.
  OrbitOptions options;
};

struct VaryAxis {
  std::string key;
  double lo = 0.0, hi = 0.0;
  int count = 2;
  // LO, HI and count - 2 values evenly between; when HI - LO is beyond the double range
  // (-1e308:1e308), a weighted mean of the ends, which stays within it.
  double value(int k) const {
    if (k == count - 1) return hi;
    const double s = static_cast<double>(k) / static_cast<double>(count - 1);
    const double width = hi - lo;
    if (std::isfinite(width)) return lo + width * s;
    return lo * (1.0 - s) + hi * s;
  }
};

// The key as part of an option's name in a message: at most 60 characters, escaped.
std::string key_text(const VaryAxis& axis) { return escaped(axis.key, 60, false); }

// "key=lo:hi:count" with count >= 2. @throws InputError naming --vary-param.
VaryAxis parse_vary(const std::string& text) {
  const std::string option = "--vary-param";
  refuse_empty(text, option);
  const auto equals = text.find('=');
  if (equals == std::string::npos || equals == 0) {
    fail(option, quote(text) + " is not KEY=LO:HI:COUNT");
  }
  const std::string range = text.substr(equals + 1);
  const auto first = range.find(':');
  const auto second = first == std::string::npos ? first : range.find(':', first + 1);
  if (second == std::string::npos || range.find(':', second + 1) != std::string::npos) {
    fail(option,
         quote(text) + " is not KEY=LO:HI:COUNT (three fields after '=', separated by ':')");
  }
  VaryAxis axis;
  axis.key = trimmed(text.substr(0, equals));
  const std::string name = option + " " + key_text(axis);
  axis.lo = parse_number(range.substr(0, first), name + " LO");
  axis.hi = parse_number(range.substr(first + 1, second - first - 1), name + " HI");
  const std::uint64_t count = parse_unsigned(range.substr(second + 1), name + " COUNT", kMaxFamily);
  if (count < 2) {
    fail(option, quote(text) + ": COUNT must be >= 2 (a family of orbits from LO to HI), got " +
                     std::to_string(count));
  }
  axis.count = static_cast<int>(count);
  // Every value of the family, not only the ends: an interior one can underflow (-1e-307:
  // 1.01e-307:5 has 5e-310 in the middle), which the scene would refuse only when its orbit is
  // due. The ends were read as normal numbers.
  for (int k = 1; k + 1 < axis.count; ++k) {
    const double value = axis.value(k);
    const std::string which = quote(text) + ": value " + std::to_string(k + 1) + " of " +
                              std::to_string(axis.count) + ", " + key_text(axis) + " = " +
                              format_number(value);
    if (!std::isfinite(value)) fail(option, which + ", is beyond the range of a double");
    if (value != 0.0 && std::fabs(value) < DBL_MIN) {
      fail(option, which + ", underflows: a nonzero number must be at least " +
                       format_number(DBL_MIN) +
                       " (the smallest normal double) in magnitude; move LO or HI away from 0 "
                       "or change COUNT");
    }
  }
  return axis;
}

// The key of "key=value", or the whole text when it has no '='.
std::string key_of(const std::string& param) { return param.substr(0, param.find('=')); }

// @throws InputError naming the option.
Plan make_plan(const OrbitCommandOptions& options, std::optional<VaryAxis>& vary) {
  Plan plan;
  FlowCommandOptions scene;
  scene.scene = options.scene;
  if (options.scene == "biped") {
    // (A structured binding cannot be captured by a lambda in C++17: clang refuses it.)
    for (const auto& default_param : kBipedOrbitParams) {
      const std::string key = default_param.first;
      const bool given = std::any_of(options.params.begin(), options.params.end(),
                                     [&](const std::string& p) { return key_of(p) == key; });
      if (!given) scene.params.push_back(key + "=" + default_param.second);
    }
  }
  scene.params.insert(scene.params.end(), options.params.begin(), options.params.end());
  scene.rtol = options.rtol;
  scene.atol = options.atol;
  plan.setup = parse_scene_setup(scene);
  // The orbit's flow options, with the tolerances given (--rtol alone: atol = rtol / 100, as
  // for flow).
  const IntegratorOptions& given = plan.setup.request.flow.integrator;
  IntegratorOptions& integrator = plan.options.flow.integrator;
  if (options.rtol) {
    integrator.rtol = given.rtol;
    integrator.atol = given.atol;
  } else if (options.atol) {
    integrator.atol = given.atol;
  }

  const std::pair<int, Eigen::VectorXd> start =
      with_scene(plan.setup, {}, [](const SegmentModel& model, const Eigen::VectorXd& x) {
        return std::make_pair(model.states(), x);
      });
  plan.d = start.first;
  const bool biped = plan.setup.biped;
  const char* default_section =
      biped ? kBipedSection : (plan.setup.pronk ? kPronkSection : kPwconstSection);
  const std::string section_text = options.section ? *options.section : default_section;
  if (options.section) refuse_empty(*options.section, "--section");
  try {
    plan.section = parse_coordinate_section(section_text, plan.d);
  } catch (const InvalidArgument& e) {
    fail("--section", e.what());
  }
  if (options.x0) {
    refuse_empty(*options.x0, "--x0");
    plan.x0 = parse_vector(*options.x0, "--x0", plan.d);
  } else if (biped) {
    plan.x0 = Eigen::VectorXd::Zero(plan.d);
    plan.x0[1] = 0.8;  // at rest at the apex of the default hop
  } else {
    plan.x0 = start.second;
  }
  if (options.tol) {
    refuse_empty(*options.tol, "--tol");
    const double tol = read_double(*options.tol, "--tol");
    if (!(tol > 0.0 && std::isfinite(tol))) {
      fail("--tol", "Newton's tolerance must be finite and > 0, got " + format_number(tol));
    }
    plan.options.tolerance = tol;
  }
  if (options.max_iterations) {
    plan.options.max_newton_iterations =
        static_cast<int>(parse_integer(*options.max_iterations, "--max-iterations", 0, 1000000));
  }

  if (options.vary_param) {
    VaryAxis axis = parse_vary(*options.vary_param);
    for (const std::string& p : options.params) {
      if (key_of(p) == axis.key) {
        fail("--vary-param", key_text(axis) + " is also fixed by --param " + quote(p) +
                                 "; give it either fixed or varied");
      }
    }
    // The scenes' real parameters are valid on intervals: the ends and the second value
    // checked are valid, so is every value (an integer parameter fails at the second).
    for (const int k : {0, 1, axis.count - 1}) {
      int states = 0;
      try {
        states = with_scene(
            plan.setup, {{axis.key, format_number(axis.value(k))}},
            [](const SegmentModel& model, const Eigen::VectorXd&) { return model.states(); });
      } catch (const InputError& e) {
        const std::string prefix = "--param: ";
        std::string message = e.what();
        if (message.rfind(prefix, 0) == 0) message.erase(0, prefix.size());
        fail("--vary-param", quote(*options.vary_param) + ": " + message);
      } catch (const InvalidArgument& e) {
        fail("--vary-param", quote(*options.vary_param) + ": " + e.what());
      }
      if (states != plan.d) {
        fail("--vary-param",
             key_text(axis) + " changes the dimension of the state (d = " + std::to_string(plan.d) +
                 " to " + std::to_string(states) + "); it cannot vary along a family");
      }
    }
    vary = axis;
  }
  return plan;
}

// ---------------------------------------------------------------------------------------------
// JSON.

// The number of linear pieces: the product over events of (surfaces crossed together)!.
double piece_count(const FlowDerivative& map) {
  double count = 1.0;
  for (const std::vector<int>& surfaces : map.event_surfaces()) {
    for (std::size_t k = 2; k <= surfaces.size(); ++k) count *= static_cast<double>(k);
  }
  return count;
}

OrderedJson return_map_json(const PeriodicOrbit& orbit) {
  const FlowDerivative& map = orbit.return_map;
  const Eigen::MatrixXd& basis = orbit.tangent_basis;
  OrderedJson j = OrderedJson::object();
  j["is_linear"] = map.is_linear();
  j["tangent_basis"] = columns_json(basis);
  const double count = piece_count(map);
  j["piece_count"] = count;
  if (count > kMaxPrintedPieces) {
    j["pieces"] = nullptr;
    return j;
  }
  OrderedJson pieces = OrderedJson::array();
  for (const FlowPiece& piece : map.pieces()) {
    OrderedJson p = OrderedJson::object();
    p["orders"] = piece.orders;
    p["matrix"] = rows_json(basis.transpose() * piece.matrix * basis);
    pieces.push_back(std::move(p));
  }
  j["pieces"] = std::move(pieces);
  return j;
}

OrderedJson events_json(const std::vector<EventRecord>& events) {
  OrderedJson list = OrderedJson::array();
  for (const EventRecord& e : events) {
    OrderedJson item = OrderedJson::object();
    item["t"] = e.t;
    item["surfaces"] = e.surfaces;
    item["group_size"] = e.group_size();
    list.push_back(std::move(item));
  }
  return list;
}

OrderedJson number_or_null(bool known, double value) {
  return known ? OrderedJson(value) : OrderedJson(nullptr);
}

// The orbit's keys, added to `j`.
void add_orbit(OrderedJson& j, const PeriodicOrbit& orbit) {
  // With no step the guess had no return map: no period, no residual.
  const bool returned = !orbit.steps.empty();
  j["converged"] = orbit.converged;
  j["message"] = orbit.message;
  j["x"] = vector_json(orbit.x);
  j["period"] = number_or_null(returned, orbit.period);
  j["newton_iterations"] = orbit.newton_iterations;
  j["residual"] = number_or_null(returned, orbit.residual);
  j["correction"] = number_or_null(returned, orbit.correction);
  OrderedJson steps = OrderedJson::array();
  for (const OrbitNewtonStep& s : orbit.steps) {
    steps.push_back(OrderedJson{{"iteration", s.iteration},
                                {"residual", s.residual},
                                {"period", s.period},
                                {"step_length", s.step_length}});
  }
  j["newton_steps"] = std::move(steps);
  j["events"] = events_json(orbit.events);
  const bool found = orbit.converged;
  j["return_map"] = found ? return_map_json(orbit) : OrderedJson(nullptr);
  j["growth_rate_lower"] = number_or_null(found, orbit.growth_rate_lower);
  j["growth_rate_upper"] = number_or_null(found, orbit.growth_rate_upper);
  j["stability"] = found ? OrderedJson(to_string(orbit.stability)) : OrderedJson(nullptr);
  if (found) {
    j["bracket"] = OrderedJson{{"pieces", orbit.bracket.pieces},
                               {"upper_length", orbit.bracket.upper_length},
                               {"lower_period", orbit.bracket.lower_period}};
  } else {
    j["bracket"] = nullptr;
  }
  if (found && orbit.return_map.is_linear()) {
    OrderedJson multipliers = OrderedJson::array();
    for (const std::complex<double>& m : orbit.bracket.multipliers) {
      multipliers.push_back(OrderedJson{{"real", m.real()}, {"imag", m.imag()}});
    }
    j["multipliers"] = std::move(multipliers);
  } else {
    j["multipliers"] = nullptr;
  }
  OrderedJson notices = OrderedJson::array();
  for (const FlowNotice& notice : orbit.notices) notices.push_back(notice.message);
  j["notices"] = std::move(notices);
  j["decisions"] = orbit.decisions;
}

struct Member {
  double value = 0.0;
  PeriodicOrbit orbit;
  std::string predictor;  // where its Newton run started (OrbitFamilyMember::predictor)
  int runs = 0;
  std::vector<std::string> decisions;  // the family's, then the orbit's
};

OrderedJson member_json(const Member& m) {
  const PeriodicOrbit& o = m.orbit;
  const bool returned = !o.steps.empty();
  OrderedJson j = OrderedJson::object();
  j["value"] = m.value;
  j["predictor"] = m.predictor;
  j["runs"] = m.runs;
  j["converged"] = o.converged;
  j["message"] = o.message;
  j["x"] = vector_json(o.x);
  j["period"] = number_or_null(returned, o.period);
  j["newton_iterations"] = o.newton_iterations;
  j["residual"] = number_or_null(returned, o.residual);
  j["correction"] = number_or_null(returned, o.correction);
  j["growth_rate_lower"] = number_or_null(o.converged, o.growth_rate_lower);
  j["growth_rate_upper"] = number_or_null(o.converged, o.growth_rate_upper);
  j["stability"] = o.converged ? OrderedJson(to_string(o.stability)) : OrderedJson(nullptr);
  j["decisions"] = m.decisions;
  return j;
}

// ---------------------------------------------------------------------------------------------
// Progress lines.

std::string newton_line(const OrbitNewtonStep& s) {
  std::string line = formatted("orbit: newton %2d  residual %.3e  period %.10g  events %d",
                               s.iteration, s.residual, s.period, s.events);
  if (s.largest_event > 1) line += formatted(" (up to %d surfaces at once)", s.largest_event);
  if (s.iteration > 0) line += formatted("  step %g", s.step_length);
  return line;
}

std::string member_line(const VaryAxis& axis, int k, const PeriodicOrbit& o, double seconds) {
  std::string line =
      formatted("orbit: %s = %.10g (%d/%d)  ", axis.key.c_str(), axis.value(k), k + 1, axis.count);
  if (o.converged) {
    line += formatted("period %.10g  growth rate in [%.6g, %.6g]  %s  newton %d", o.period,
                      o.growth_rate_lower, o.growth_rate_upper, to_string(o.stability),
                      o.newton_iterations);
  } else {
    line += "not found: " + one_line(o.message);
  }
  return line + formatted("  %.2f s", seconds);
}

// ---------------------------------------------------------------------------------------------
// Plots.

// A gnuplot string in single quotes (noenhanced: '_' stays itself).
std::string gnuplot_text(const std::string& text) {
  std::string quoted;
  for (char c : text) quoted += c == '\'' ? std::string("''") : std::string(1, c);
  return "'" + quoted + "'";
}

std::vector<std::string> state_names(const Plan& plan) {
  if (plan.setup.biped || plan.setup.pronk) return {"x", "y", "theta", "xdot", "ydot", "thetadot"};
  std::vector<std::string> names;
  for (int i = 0; i < plan.d; ++i) names.push_back("x_" + std::to_string(i));
  return names;
}

// One period of the orbit at kPlotSamples + 1 equal times (rows: t, x), by simulations chained
// from where the last ended, on its sides. @throws DemoError when a simulation stops.
Eigen::MatrixXd sample_period(const SegmentModel& model, const PeriodicOrbit& orbit,
                              const FlowOptions& flow) {
  const int d = model.states();
  Eigen::MatrixXd rows(kPlotSamples + 1, d + 1);
  Eigen::VectorXd x = orbit.x;
  FlowOptions options = flow;
  const double h = orbit.period / kPlotSamples;
  rows(0, 0) = 0.0;
  rows.row(0).tail(d) = x.transpose();
  for (int k = 1; k <= kPlotSamples; ++k) {
    const FlowResult r = simulate(model, x, h, options);
    if (!r.ok()) {
      throw DemoError("orbit: simulating the orbit for --plot stopped at t = " +
                      format_number((k - 1) * h + r.t) + ": " + r.message);
    }
    x = r.x;
    options.initial_sides = r.sides;
    rows(k, 0) = k == kPlotSamples ? orbit.period : k * h;
    rows.row(k).tail(d) = x.transpose();
  }
  return rows;
}

std::string csv_number(double value) { return std::isfinite(value) ? format_number(value) : "NaN"; }

// orbit.csv, orbit.gp and orbit.png: every state against time over one period (the events dashed)
// and the phase plot of the two components that vary most. @throws DemoError.
void plot_orbit(const fs::path& dir, const Plan& plan, const PeriodicOrbit& orbit,
                const Eigen::MatrixXd& rows) {
  const std::vector<std::string> names = state_names(plan);
  const int d = plan.d;
  std::ostringstream csv;
  csv << 't';
  for (const std::string& name : names) csv << ',' << name;
  csv << '\n';
  for (Eigen::Index k = 0; k < rows.rows(); ++k) {
    for (Eigen::Index i = 0; i < rows.cols(); ++i) {
      csv << (i > 0 ? "," : "") << csv_number(rows(k, i));
    }
    csv << '\n';
  }
  write_file(dir / "orbit.csv", csv.str(), "orbit");

  // The two components with the largest range, in index order.
  std::vector<int> order(static_cast<std::size_t>(d));
  for (int i = 0; i < d; ++i) order[static_cast<std::size_t>(i)] = i;
  const auto range = [&](int i) { return rows.col(i + 1).maxCoeff() - rows.col(i + 1).minCoeff(); };
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return range(a) > range(b); });
  const int first = std::min(order[0], d > 1 ? order[1] : order[0]);
  const int second = std::max(order[0], d > 1 ? order[1] : order[0]);

  std::ostringstream gp;
  gp << "# Written by `bflow orbit`; run in this directory: gnuplot orbit.gp\n"
     << "set terminal pngcairo size 1000,900 noenhanced font 'Sans,11'\n"
     << gnuplot_output("orbit.png") << "set datafile separator ','\n"
     << "set multiplot layout 2,1 title "
     << gnuplot_text(plan.setup.scene + ": periodic orbit through " + to_string(plan.section) +
                     ", period " + formatted("%.6g", orbit.period) + ", " +
                     to_string(orbit.stability) + " (growth rate in [" +
                     formatted("%.6g", orbit.growth_rate_lower) + ", " +
                     formatted("%.6g", orbit.growth_rate_upper) + "])")
     << "\nset grid lc rgb '#dddddd'\nset key outside right top\n"
     << "set rmargin at screen 0.8\n"  // both panels equally wide, whatever their keys
     << "set xlabel 't'\nset ylabel 'state'\n";
  for (const EventRecord& e : orbit.events) {
    gp << "set arrow from " << format_number(e.t) << ", graph 0 to " << format_number(e.t)
       << ", graph 1 nohead dt 2 lc rgb '#B22222'\n";
  }
  gp << "plot ";
  for (int i = 0; i < d; ++i) {
    gp << "'orbit.csv' skip 1 using 1:" << i + 2 << " with lines lw 2 title "
       << gnuplot_text(names[static_cast<std::size_t>(i)]) << ", \\\n  ";
  }
  gp << "NaN with lines dt 2 lc rgb '#B22222' title 'events'\n"
     << "unset arrow\n"
     << "set xlabel " << gnuplot_text(names[static_cast<std::size_t>(first)]) << "\n"
     << "set ylabel " << gnuplot_text(names[static_cast<std::size_t>(second)]) << "\n"
     << "plot 'orbit.csv' skip 1 using " << first + 2 << ':' << second + 2
     << " with lines lw 2 title 'one period', \\\n"
     << "  'orbit.csv' skip 1 every ::0::0 using " << first + 2 << ':' << second + 2
     << " with points pt 7 ps 1.5 lc rgb 'black' title 'fixed point on the section'\n"
     << "unset multiplot\n";
  write_file(dir / "orbit.gp", gp.str(), "orbit");
  run_gnuplot(dir, "orbit.gp", "orbit.png", "orbit", "leave out --plot");
}

// family.csv, growth_rate.gp and growth_rate.png: the bracket along the family, and a line at 1.
// @throws DemoError.
void plot_family(const fs::path& dir, const Plan& plan, const VaryAxis& axis,
                 const std::vector<Member>& family) {
  const std::vector<std::string> names = state_names(plan);
  std::ostringstream csv;
  csv << axis.key << ",converged,period,growth_rate_lower,growth_rate_upper,stability,"
      << "newton_iterations";
  for (const std::string& name : names) csv << ',' << name;
  csv << '\n';
  for (const Member& m : family) {
    const PeriodicOrbit& o = m.orbit;
    const double nan = std::nan("");
    csv << csv_number(m.value) << ',' << (o.converged ? 1 : 0) << ','
        << csv_number(o.converged ? o.period : nan) << ','
        << csv_number(o.converged ? o.growth_rate_lower : nan) << ','
        << csv_number(o.converged ? o.growth_rate_upper : nan) << ','
        << (o.converged ? to_string(o.stability) : "not-found") << ',' << o.newton_iterations;
    for (Eigen::Index i = 0; i < o.x.size(); ++i) csv << ',' << csv_number(o.x[i]);
    csv << '\n';
  }
  write_file(dir / "family.csv", csv.str(), "orbit");
  std::ostringstream gp;
  gp << "# Written by `bflow orbit`; run in this directory: gnuplot growth_rate.gp\n"
     << "set terminal pngcairo size 900,600 noenhanced font 'Sans,11'\n"
     << gnuplot_output("growth_rate.png") << "set datafile separator ','\n"
     << "set title "
     << gnuplot_text(plan.setup.scene + ": growth rate of the return map along the family")
     << "\nset xlabel " << gnuplot_text(axis.key) << "\n"
     << "set ylabel 'growth rate per period'\n"
     << "set grid lc rgb '#dddddd'\nset key inside left top box opaque\n"
     << "set yrange [0:*]\n"  // the line at 1 in view
     << "plot 'family.csv' skip 1 using 1:4 with linespoints lw 2 pt 7 title 'lower bound', \\\n"
     << "  'family.csv' skip 1 using 1:5 with linespoints lw 2 pt 6 dt 3 title 'upper bound', \\\n"
     << "  1 with lines dt 2 lc rgb 'black' title 'rate 1: stable below, unstable above'\n";
  write_file(dir / "growth_rate.gp", gp.str(), "orbit");
  run_gnuplot(dir, "growth_rate.gp", "growth_rate.png", "orbit", "leave out --plot");
}

// ---------------------------------------------------------------------------------------------
// The command.

// Refuses an --output that --plot also needs: the plot's directory, a directory above it, or
// one of the files drawn there. Before anything is created or computed. @throws InputError.
void refuse_clashing_paths(const std::string& output, const std::string& plot,
                           const std::vector<std::string>& files) {
  // Without a trailing separator ("out/" is "out").
  const auto normal = [](const std::string& path) {
    const fs::path p = resolved(path);
    return p.has_filename() || !p.has_relative_path() ? p : p.parent_path();
  };
  const fs::path file = normal(output);
  const fs::path dir = normal(plot);
  if (file == dir || same_file(output, plot)) {
    fail("--output", quote(output, 200) + " is also the --plot directory " + quote(plot, 200) +
                         "; name another file");
  }
  // A directory above the plot's: component by component, so that /a/b is not above /a/bc.
  if (std::mismatch(file.begin(), file.end(), dir.begin(), dir.end()).first == file.end()) {
    fail("--output", quote(output, 200) + " is a directory above the --plot directory " +
                         quote(plot, 200) + "; name another file");
  }
  for (const std::string& name : files) {
    if (same_file(fs::path(plot) / name, output)) {
      fail("--output",
           quote(output, 200) + " is also the plot's " + name + " (--plot); name another file");
    }
  }
}

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

int orbit_command(const OrbitCommandOptions& options, std::ostream& out, std::ostream& err) {
  std::optional<VaryAxis> vary;
  Plan plan = make_plan(options, vary);
  // Every file the command writes is checked before anything is computed, and before anything
  // is created: the names first, then the file system.
  std::vector<std::string> files = {"orbit.csv", "orbit.gp", "orbit.png"};
  if (vary) files.insert(files.end(), {"family.csv", "growth_rate.gp", "growth_rate.png"});
  if (options.output) refuse_empty(*options.output, "--output");
  if (options.plot) refuse_empty(*options.plot, "--plot");
  if (options.output && options.plot) refuse_clashing_paths(*options.output, *options.plot, files);
  // A directory that is missing or refuses files is found now, not after the orbits are
  // computed.
  if (options.output) check_writable_file(*options.output, "orbit");
  if (options.plot) {
    prepare_output_directory(*options.plot, "orbit");
    for (const std::string& file : files) {
      check_replaceable_file(fs::path(*options.plot) / file, "orbit");
    }
  }

  OrbitOptions o = plan.options;
  if (!options.quiet) {
    o.progress = [&err](const OrbitNewtonStep& s) { err << newton_line(s) << '\n' << std::flush; };
  }
  Eigen::MatrixXd samples;
  std::string plot_error;
  const PeriodicOrbit orbit =
      with_scene(plan.setup, {}, [&](const SegmentModel& model, const Eigen::VectorXd&) {
        PeriodicOrbit found = find_periodic_orbit(model, plan.section, plan.x0, o);
        if (options.plot && found.converged) {
          try {
            samples = sample_period(model, found, o.flow);
          } catch (const DemoError& e) {
            plot_error = e.what();
          }
        }
        return found;
      });

  std::vector<Member> family;
  if (vary) {
    OrbitOptions member_options = plan.options;
    std::vector<double> values;
    for (int k = 0; k < vary->count; ++k) values.push_back(vary->value(k));
    auto start = std::chrono::steady_clock::now();
    OrbitFamilyOptions family_options;
    family_options.progress = [&](int k, const OrbitFamilyMember& member) {
      if (!options.quiet) {
        err << member_line(*vary, k, member.orbit, seconds_since(start)) << '\n' << std::flush;
      }
      start = std::chrono::steady_clock::now();
    };
    const std::vector<OrbitFamilyMember> members = continue_orbits(
        values, plan.x0,
        [&](double value, const Eigen::VectorXd& guess) {
          try {
            return with_scene(plan.setup, {{vary->key, format_number(value)}},
                              [&](const SegmentModel& model, const Eigen::VectorXd&) {
                                return find_periodic_orbit(model, plan.section, guess,
                                                           member_options);
                              });
          } catch (const InputError& e) {
            // Every value was checked in make_plan; should the scene still refuse one, the
            // family's JSON is kept and the orbit recorded as not found.
            throw InvalidArgument(e.what());
          }
        },
        family_options);
    for (const OrbitFamilyMember& member : members) {
      std::vector<std::string> decisions = member.decisions;
      decisions.insert(decisions.end(), member.orbit.decisions.begin(),
                       member.orbit.decisions.end());
      family.push_back(
          Member{member.value, member.orbit, member.predictor, member.runs, std::move(decisions)});
    }
  }

  OrderedJson j = OrderedJson::object();
  j["scene"] = plan.setup.scene;
  j["params"] = plan.setup.head["params"];
  j["section"] = to_string(plan.section);
  j["rtol"] = o.flow.integrator.rtol;
  j["atol"] = o.flow.integrator.absolute_tolerance();
  j["tolerance"] = o.tolerance;
  j["max_iterations"] = o.max_newton_iterations;
  j["x0"] = vector_json(plan.x0);
  add_orbit(j, orbit);
  if (vary) {
    j["vary_param"] =
        OrderedJson{{"key", vary->key}, {"lo", vary->lo}, {"hi", vary->hi}, {"count", vary->count}};
    OrderedJson list = OrderedJson::array();
    for (const Member& m : family) list.push_back(member_json(m));
    j["family"] = std::move(list);
  }
  std::ostringstream text;
  write_json(text, j, options.compact);
  text << '\n';
  if (options.output) {
    write_file(*options.output, text.str(), "orbit");
  } else {
    out << text.str() << std::flush;
  }
  for (const FlowNotice& notice : orbit.notices) {
    err << "warning: " << one_line(notice.message) << '\n';
  }

  if (options.plot && plot_error.empty()) {
    try {
      if (orbit.converged) plot_orbit(*options.plot, plan, orbit, samples);
      const bool any = std::any_of(family.begin(), family.end(),
                                   [](const Member& m) { return m.orbit.converged; });
      if (vary && any) plot_family(*options.plot, plan, *vary, family);
    } catch (const DemoError& e) {
      plot_error = e.what();
    }
  }

  if (!orbit.converged) {
    report_error(err, "orbit: no periodic orbit found: " + orbit.message);
    return kExitFailure;
  }
  std::vector<std::string> missed;
  for (const Member& m : family) {
    if (!m.orbit.converged) missed.push_back(format_number(m.value));
  }
  if (!missed.empty()) {
    std::string values;
    for (std::size_t k = 0; k < missed.size() && k < 5; ++k) {
      values += (k > 0 ? ", " : "") + missed[k];
    }
    if (missed.size() > 5) values += ", ...";
    const Member& first_missed = *std::find_if(family.begin(), family.end(),
                                               [](const Member& m) { return !m.orbit.converged; });
    report_error(err, "orbit: " + std::to_string(missed.size()) + " of " +
                          std::to_string(family.size()) + " orbits of the family not found (" +
                          vary->key + " = " + values +
                          "); the first: " + first_missed.orbit.message);
    return kExitFailure;
  }
  if (!plot_error.empty()) {
    report_error(err, plot_error);
    return kExitFailure;
  }
  return kExitOk;
}

}  // namespace

int run_orbit(const OrbitCommandOptions& options, std::ostream& out, std::ostream& err) {
  int code = kExitOk;
  try {
    code = orbit_command(options, out, err);
  } catch (const InputError& e) {
    report_error(err, e.what());
    code = kExitBadInput;
  } catch (const DemoError& e) {  // the --plot directory or the --output file
    report_error(err, e.what());
    code = kExitFailure;
  } catch (const InvalidArgument& e) {
    // What the library rejects that no option decides (a scene it cannot build, ...).
    report_error(err, with_field("orbit", e.what()));
    code = kExitBadInput;
  } catch (const std::bad_alloc&) {
    report_error(err, "orbit: out of memory");
    code = kExitFailure;
  } catch (const std::exception& e) {
    report_error(err, std::string("orbit: internal: ") + e.what());
    code = kExitFailure;
  }
  return finish_output(out, err, code);
}

}  // namespace bflow::cli

// What accuracy costs in time: the flow's B-derivative by bflow (AD: variational equations by
// Jets between events, jump maps at events) against finite differences of the simulation and
// against "naive AD", for three problems with an exact or an independent reference.
//
//   pwconst  the piecewise-constant field of [B] Section 3.1 (examples::PiecewiseConstantField::
//            planar_demo(), d = 2) from rho- = -F_--(0)/2 for t = 1. Both coordinate planes are
//            crossed at once at t = 1/2 and the field is constant in between, so the reference
//            is exact: D phi = B, the JumpMap of the limits with eta = I ([B] (3.2) in general
//            form), checked against one-sided differences of the exact flow and against the
//            independent reference below (both printed). Two pieces.
//   biped    the mode-damping biped of [B] Section 3.2.4 (bflow/core/biped.h, defaults) from
//            (0, 1, 0, 0, 0, 0) for t = 0.6: both feet touch at t = 0.3968 (one event of two
//            surfaces, two pieces).
//   three    examples::ThreeSurfaces (examples/three_surfaces.h), d = 5, from nominal_start()
//            for t = 1.5: three curved surfaces crossed at once at t = 1 with a different
//            nonlinear field in each of the 8 regions (one event of three surfaces, six pieces).
//
// The reference of biped and three is independent of bflow's engine: examples::ReferenceFlow
// (examples/reference_flow.h: long double, fixed-step sixth-order Runge-Kutta, crossings
// located by bisection), one-sided differences D(a) = (phi(x0 + a dx) - phi(x0)) / a
// extrapolated twice, (8 D(a/4) - 6 D(a/2) + D(a)) / 3 at a = 5e-5 (error O(a^3) plus
// rounding), on each direction, which lies inside one piece (the crossing order its perturbed
// runs realise is printed). Its own accuracy is printed: the change when its step or a is
// halved (~1e-14 relative). For three the reference starts from phi_{-1}(rho) in long double, on
// the nonsmooth trajectory; the engine starts from that point rounded to double.
//
// The derivative is piecewise linear, so it is compared on k = d fixed directions dx_k chosen
// in both pieces (the printout names each direction's crossing order). The error of a method
// is max_k |D dx_k - D_ref dx_k| / |D_ref dx_k|. Methods:
//
//   ad          flow_derivative() and FlowDerivative::apply_block() on the k directions, for
//               dopri5, cvodes-bdf and cvodes-adams at rtol 1e-4 ... 1e-12 (atol 1e-3 rtol),
//               with the default error control (the tangents in the norm); "ad-dopri5-state-only"
//               with the state alone in dopri5's error norm. A backend whose make_integrator()
//               throws is skipped with a note.
//   naive-ad    the tangents carried through the simulation with no jump: the product
//               Phi_m ... Phi_1 Phi_0 of FlowDerivative::transitions(), what differentiating
//               through the integrator's switching logic gives when the event time is not
//               differentiated. Its error plateaus at the size of the jump's effect.
//   fd-one-sided (phi(x0 + a dx_k) - phi(x0)) / a: k + 1 simulations (dopri5).
//   fd-central   (phi(x0 + a dx_k) - phi(x0 - a dx_k)) / (2a), and phi(x0) for the state:
//               2k + 1 simulations. At a kink it converges to (D(dx) - D(-dx))/2, not D(dx).
//
// Differences are swept two ways: a = sqrt(rtol) (one-sided) and a = rtol^(1/3) (central) for
// every rtol of the AD sweep (series "...-matched"), and a = 1e-2 ... 1e-10 at rtol 1e-10 and
// 1e-12 (series "...-sweep"). They run ungrouped (Grouping::kNone), so a perturbed run
// resolves crossings however close: grouped, the driver would flip the later surfaces early
// (by up to the window), an error of O(window) in the state that is O(window / a) in a
// difference quotient.
//
// CPU time is the median over 9 repetitions of the process CPU time
// (clock_gettime(CLOCK_PROCESS_CPUTIME_ID)) per derivative, each repetition repeating the
// computation for at least 20 ms; the repetitions run in rounds over all points, so each
// point's samples are spread over the whole run. With k = d directions one-sided differences cost d
// + 1 simulations and central 2d + 1, as for the full Jacobian.
//
// Output: docs/accuracy_<problem>.csv and, through gnuplot (pngcairo), docs/accuracy_<problem>.png
// (left: error against CPU time; right: the differences' error against a). A table and the
// key ratios go to stdout. Run: scripts/accuracy (docs/accuracy.md explains the numbers).
//
//   accuracy_harness [--out DIR] [--no-plot] [--quick]
//
// --quick: 2 repetitions of at least 1 ms (a smoke run; the times are then rough).
#include <time.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/biped.h"
#include "bflow/core/flow_derivative.h"
#include "bflow/core/jump_map.h"
#include "bflow/examples/piecewise_constant.h"
#include "bflow/examples/reference_flow.h"
#include "bflow/examples/three_surfaces.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"

namespace {

using bflow::Backend;
using bflow::FlowOptions;
using bflow::FlowResult;
using bflow::SegmentModel;
using LVector = Eigen::Matrix<long double, Eigen::Dynamic, 1>;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Errors are drawn no lower than this (an exact result would be log(0)).
constexpr double kPlotFloor = 1e-17;

struct Settings {
  std::string out_dir = ".";
  bool plot = true;
  int repetitions = 9;
  double min_batch_seconds = 2e-2;
};

double cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

// Keeps a result alive so the timed work cannot be optimised away.
volatile double g_sink = 0.0;

// CPU time of one call of `work`, from calling it until min_batch_seconds have passed.
double batch_cpu_time(const Settings& settings, const std::function<double()>& work) {
  const double start = cpu_seconds();
  double elapsed = 0.0;
  long calls = 0;
  do {
    g_sink = g_sink + work();
    ++calls;
    elapsed = cpu_seconds() - start;
  } while (elapsed < settings.min_batch_seconds);
  return elapsed / static_cast<double>(calls);
}

double median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  return values[values.size() / 2];
}

struct Problem {
  std::string name;
  std::string title;
  const SegmentModel* model = nullptr;
  Eigen::VectorXd x0;
  double t = 0.0;
  Eigen::MatrixXd directions;  // d x k
  Eigen::MatrixXd reference;   // d x k, D_ref dx_k
  std::vector<std::string> direction_notes;
};

double relative_error(const Eigen::MatrixXd& images, const Eigen::MatrixXd& reference) {
  double worst = 0.0;
  for (Eigen::Index k = 0; k < reference.cols(); ++k) {
    worst = std::max(worst, (images.col(k) - reference.col(k)).norm() / reference.col(k).norm());
  }
  return worst;
}

std::string order_text(const std::vector<int>& order) {
  std::string text;
  for (std::size_t i = 0; i < order.size(); ++i) {
    text += (i ? " then " : "") + std::to_string(order[i]);
  }
  return "surface " + text;
}

struct Point {
  std::string series;  // e.g. "ad-dopri5", "fd-one-sided-sweep-rtol1e-12"
  std::string method;  // ad, naive-ad, fd-one-sided, fd-central
  Backend backend = Backend::kDopri5;
  double rtol = kNaN;
  double atol = kNaN;
  double alpha = kNaN;
  double error = kNaN;
  double cpu = kNaN;  // median CPU seconds per derivative
  int simulations = 0;
  long steps = 0;
  std::function<double()> work;  // the timed computation
};

FlowOptions options_for(Backend backend, double rtol) {
  FlowOptions options;
  options.backend = backend;
  options.integrator.rtol = rtol;
  options.integrator.atol = 1e-3 * rtol;
  return options;
}

Eigen::MatrixXd product_of_transitions(const bflow::FlowDerivative& derivative) {
  Eigen::MatrixXd product = Eigen::MatrixXd::Identity(derivative.dim(), derivative.dim());
  for (const Eigen::MatrixXd& phi : derivative.transitions()) product = phi * product;
  return product;
}

// AD and naive AD at one tolerance, with the default error control (the tangents in the norm);
// with state_only: AD only, the state alone in the error norm. @throws when the backend is not
// built.
std::vector<Point> ad_points(const Problem& p, Backend backend, double rtol, bool state_only) {
  FlowOptions options = options_for(backend, rtol);
  options.integrator.tangents_in_error_norm = !state_only;
  FlowResult trajectory;
  const bflow::FlowDerivative derivative =
      bflow::flow_derivative(*p.model, p.x0, p.t, options, &trajectory);
  Point ad;
  ad.series = std::string("ad-") + bflow::to_string(backend) + (state_only ? "-state-only" : "");
  ad.method = "ad";
  ad.backend = backend;
  ad.rtol = rtol;
  ad.atol = options.integrator.absolute_tolerance();
  ad.simulations = 1;
  ad.steps = trajectory.steps;
  ad.error = relative_error(derivative.apply_block(p.directions), p.reference);
  ad.work = [&p, options] {
    const bflow::FlowDerivative d = bflow::flow_derivative(*p.model, p.x0, p.t, options);
    return d.apply_block(p.directions)(0, 0);
  };
  if (state_only) return {ad};
  Point naive = ad;
  naive.series = std::string("naive-ad-") + bflow::to_string(backend);
  naive.method = "naive-ad";
  naive.error = relative_error(product_of_transitions(derivative) * p.directions, p.reference);
  naive.work = [&p, options] {
    const bflow::FlowDerivative d = bflow::flow_derivative(*p.model, p.x0, p.t, options);
    return (product_of_transitions(d) * p.directions)(0, 0);
  };
  return {ad, naive};
}

Eigen::VectorXd end_state(const Problem& p, const Eigen::VectorXd& x0, const FlowOptions& options,
                          long* steps = nullptr) {
  const FlowResult r = bflow::simulate(*p.model, x0, p.t, options);
  if (!r.ok()) {
    throw bflow::InvalidArgument(std::string("simulation ended with ") +
                                 bflow::to_string(r.status) + ": " + r.message);
  }
  if (steps != nullptr) *steps = r.steps;
  return r.x;
}

// Differences on the problem's k directions, plus the nominal run: k + 1 or 2k + 1 simulations.
Eigen::MatrixXd differences(const Problem& p, double alpha, bool central,
                            const FlowOptions& options, long* steps = nullptr) {
  const Eigen::VectorXd nominal = end_state(p, p.x0, options, steps);
  Eigen::MatrixXd images(p.x0.size(), p.directions.cols());
  for (Eigen::Index k = 0; k < p.directions.cols(); ++k) {
    const Eigen::VectorXd plus = end_state(p, p.x0 + alpha * p.directions.col(k), options);
    if (central) {
      const Eigen::VectorXd minus = end_state(p, p.x0 - alpha * p.directions.col(k), options);
      images.col(k) = (plus - minus) / (2 * alpha);
    } else {
      images.col(k) = (plus - nominal) / alpha;
    }
  }
  return images;
}

Point fd_point(const Problem& p, const std::string& series, double rtol, double alpha,
               bool central) {
  FlowOptions options = options_for(Backend::kDopri5, rtol);
  options.grouping = bflow::Grouping::kNone;
  Point point;
  point.series = series;
  point.method = central ? "fd-central" : "fd-one-sided";
  point.rtol = rtol;
  point.atol = options.integrator.absolute_tolerance();
  point.alpha = alpha;
  const int k = static_cast<int>(p.directions.cols());
  point.simulations = central ? 2 * k + 1 : k + 1;
  point.error = relative_error(differences(p, alpha, central, options, &point.steps), p.reference);
  point.work = [&p, alpha, central, options] {
    return differences(p, alpha, central, options)(0, 0);
  };
  return point;
}

std::string format(const char* spec, double value) {
  const int size = std::snprintf(nullptr, 0, spec, value);
  std::string text(static_cast<std::size_t>(std::max(size, 0)) + 1, '\0');
  std::snprintf(text.data(), text.size(), spec, value);
  text.pop_back();
  return text;
}

void print_point(const Point& point) {
  std::printf("  %-32s %8s %8s %10s %12s %5d %6ld\n", point.series.c_str(),
              std::isnan(point.rtol) ? "" : format("%.0e", point.rtol).c_str(),
              std::isnan(point.alpha) ? "" : format("%.0e", point.alpha).c_str(),
              format("%.2e", point.error).c_str(), format("%.1f", point.cpu * 1e6).c_str(),
              point.simulations, point.steps);
  std::fflush(stdout);
}

std::vector<double> decades(int first, int last) {
  std::vector<double> values;
  for (int e = first; e <= last; ++e) values.push_back(std::pow(10.0, -e));
  return values;
}

// Runs every method on p. Failures of single points are reported and skipped.
std::vector<Point> sweep(const Problem& p, const Settings& settings) {
  std::vector<Point> points;
  auto run = [&](const std::string& what, const std::function<std::vector<Point>()>& f) {
    try {
      for (const Point& point : f()) points.push_back(point);
      return true;
    } catch (const std::exception& e) {
      std::printf("  %-32s skipped: %s\n", what.c_str(), e.what());
      return false;
    }
  };
  for (Backend backend : {Backend::kDopri5, Backend::kCvodesBdf, Backend::kCvodesAdams}) {
    try {
      bflow::make_integrator(backend);
    } catch (const std::exception& e) {
      std::printf("  %-32s skipped: %s\n", (std::string("ad-") + bflow::to_string(backend)).c_str(),
                  e.what());
      continue;
    }
    for (double rtol : decades(4, 12)) {
      run(std::string("ad-") + bflow::to_string(backend) + " rtol " + format("%.0e", rtol),
          [&] { return ad_points(p, backend, rtol, false); });
    }
  }
  for (double rtol : decades(4, 12)) {
    run("ad-dopri5-state-only rtol " + format("%.0e", rtol),
        [&] { return ad_points(p, Backend::kDopri5, rtol, true); });
  }
  for (double rtol : decades(4, 12)) {
    run("fd-one-sided-matched", [&] {
      return std::vector<Point>{fd_point(p, "fd-one-sided-matched", rtol, std::sqrt(rtol), false)};
    });
    run("fd-central-matched", [&] {
      return std::vector<Point>{fd_point(p, "fd-central-matched", rtol, std::cbrt(rtol), true)};
    });
  }
  for (double rtol : {1e-10, 1e-12}) {
    const std::string suffix = "-sweep-rtol" + format("%.0e", rtol);
    for (double alpha : decades(2, 10)) {
      run("fd-one-sided" + suffix, [&] {
        return std::vector<Point>{fd_point(p, "fd-one-sided" + suffix, rtol, alpha, false)};
      });
      run("fd-central" + suffix, [&] {
        return std::vector<Point>{fd_point(p, "fd-central" + suffix, rtol, alpha, true)};
      });
    }
  }
  // Timing in rounds: every point is timed once per round, so the repetitions of a point are
  // spread over the whole run and a burst of load elsewhere on the machine touches one of them
  // rather than all.
  std::vector<std::vector<double>> samples(points.size());
  for (int round = 0; round < settings.repetitions; ++round) {
    for (std::size_t i = 0; i < points.size(); ++i) {
      samples[i].push_back(batch_cpu_time(settings, points[i].work));
    }
  }
  std::printf("\n  %-32s %8s %8s %10s %12s %5s %6s\n", "series", "rtol", "alpha", "error", "CPU us",
              "sims", "steps");
  for (std::size_t i = 0; i < points.size(); ++i) {
    points[i].cpu = median(samples[i]);
    print_point(points[i]);
  }
  return points;
}

void write_csv(const std::string& path, const std::vector<Point>& points) {
  std::ofstream out(path);
  out << "series,method,backend,rtol,atol,alpha,error,cpu_seconds,simulations,steps\n";
  auto number = [](double v) { return std::isnan(v) ? std::string() : format("%.6e", v); };
  for (const Point& point : points) {
    const bool has_backend = point.method == "ad" || point.method == "naive-ad";
    out << point.series << ',' << point.method << ','
        << (has_backend ? bflow::to_string(point.backend) : "dopri5") << ',' << number(point.rtol)
        << ',' << number(point.atol) << ',' << number(point.alpha) << ',' << number(point.error)
        << ',' << number(point.cpu) << ',' << point.simulations << ',' << point.steps << '\n';
  }
  if (!out) throw bflow::InvalidArgument("cannot write " + path);
}

std::vector<Point> select(const std::vector<Point>& points, const std::string& series) {
  std::vector<Point> selected;
  for (const Point& point : points) {
    if (point.series == series) selected.push_back(point);
  }
  return selected;
}

const Point* find(const std::vector<Point>& points, const std::string& series, double rtol) {
  for (const Point& point : points) {
    if (point.series == series && std::abs(point.rtol / rtol - 1) < 1e-9) return &point;
  }
  return nullptr;
}

const Point* best(const std::vector<Point>& points, const std::string& series) {
  const Point* found = nullptr;
  for (const Point& point : points) {
    if (point.series == series && (found == nullptr || point.error < found->error)) {
      found = &point;
    }
  }
  return found;
}

// ---------------------------------------------------------------------------------------------
// Plot

struct Series {
  std::string key;
  std::string title;
  std::string style;
};

// One gnuplot datablock per series: cpu error rtol alpha.
std::string datablock(const std::string& name, const std::vector<Point>& points) {
  std::string text = "$" + name + " << EOD\n";
  for (const Point& point : points) {
    text += format("%.6e", point.cpu) + " " + format("%.6e", std::max(point.error, kPlotFloor)) +
            " " + format("%.3e", point.rtol) + " " +
            (std::isnan(point.alpha) ? std::string("NaN") : format("%.3e", point.alpha)) + "\n";
  }
  return text + "EOD\n";
}

std::string block_name(const std::string& series) {
  std::string name;
  for (char c : series) name += (std::isalnum(static_cast<unsigned char>(c)) ? c : '_');
  return name;
}

// Plots `series` from datablocks: column `x` against the error, one "linespoints" each.
std::string plot_command(const std::vector<Series>& series, const std::vector<Point>& points,
                         int x) {
  std::string command;
  for (const Series& s : series) {
    if (select(points, s.key).empty()) continue;
    command += std::string(command.empty() ? "plot " : ", ") + "$" + block_name(s.key) + " using " +
               std::to_string(x) + ":2 with linespoints " + s.style + " title '" + s.title + "'";
  }
  return command;
}

// The rtol exponent next to each point of an AD series, when its errors differ at all.
std::string rtol_labels(const std::vector<Point>& points, const std::string& series,
                        const std::string& colour, const char* offset) {
  const std::vector<Point> selected = select(points, series);
  double lo = 1.0, hi = 0.0;
  for (const Point& point : selected) {
    lo = std::min(lo, std::max(point.error, kPlotFloor));
    hi = std::max(hi, std::max(point.error, kPlotFloor));
  }
  if (selected.empty() || hi < 100 * lo) return "";
  return ", $" + block_name(series) +
         " using 1:2:(sprintf('%d', int(floor(-log10($3) + 0.5)))) with labels offset char " +
         offset + " font 'DejaVu Sans,9' tc rgb '" + colour + "' notitle";
}

void plot(const Problem& p, const std::vector<Point>& points, const Settings& settings) {
  const std::vector<Series> left = {
      {"ad-dopri5", "AD, dopri5", "lc rgb '#1f77b4' pt 7 ps 1.1 lw 2"},
      {"ad-dopri5-state-only", "AD, dopri5, state-only error norm",
       "lc rgb '#9467bd' pt 13 ps 1.3 lw 2"},
      {"ad-cvodes-bdf", "AD, CVODES BDF", "lc rgb '#2ca02c' pt 5 ps 1.0 lw 2"},
      {"ad-cvodes-adams", "AD, CVODES Adams", "lc rgb '#17becf' pt 9 ps 1.2 lw 2"},
      {"naive-ad-dopri5", "naive AD (no jump), dopri5", "lc rgb '#7f7f7f' pt 6 ps 1.0 lw 2 dt 2"},
      {"fd-one-sided-matched", "one-sided FD, α = rtol^{1/2}", "lc rgb '#d62728' pt 4 ps 1.0 lw 2"},
      {"fd-central-matched", "central FD, α = rtol^{1/3}", "lc rgb '#ff7f0e' pt 8 ps 1.1 lw 2"},
  };
  const std::vector<Series> right = {
      {"fd-one-sided-sweep-rtol1e-10", "one-sided FD, rtol 1e-10", "lc rgb '#d62728' pt 4 lw 2"},
      {"fd-one-sided-sweep-rtol1e-12", "one-sided FD, rtol 1e-12",
       "lc rgb '#d62728' pt 5 lw 2 dt 3"},
      {"fd-central-sweep-rtol1e-10", "central FD, rtol 1e-10", "lc rgb '#ff7f0e' pt 8 lw 2"},
      {"fd-central-sweep-rtol1e-12", "central FD, rtol 1e-12", "lc rgb '#ff7f0e' pt 9 lw 2 dt 3"},
  };
  double smallest = 1.0;
  for (const Point& point : points)
    smallest = std::min(smallest, std::max(point.error, kPlotFloor));
  std::string script;
  for (const auto* group : {&left, &right}) {
    for (const Series& s : *group) script += datablock(block_name(s.key), select(points, s.key));
  }
  const std::string png = settings.out_dir + "/accuracy_" + p.name + ".png";
  script += "set terminal pngcairo size 1600,820 enhanced font 'DejaVu Sans,12'\n";
  script += "set output '" + png + "'\n";
  script += "set multiplot layout 1,2 title '" + p.title + "' font 'DejaVu Sans,14'\n";
  script += "set logscale xy\nset format x '10^{%L}'\nset format y '10^{%L}'\n";
  script += "set grid xtics ytics lc rgb '#dddddd'\n";
  // Both keys below, in a margin of the same height, so the two panels line up.
  script +=
      "set key below vertical Left reverse maxrows 5 width -1 font 'DejaVu Sans,11' spacing 1.05\n";
  script += "set bmargin 11\nset tmargin 3\n";
  script += format("set yrange [%g:10]\n", smallest / 5);
  script += "set ylabel 'max_k |D dx_k − D_{ref} dx_k| / |D_{ref} dx_k|'\n";
  script += "set title 'Work–precision (numbers: AD at rtol 10^{−n}, atol 10^{−3} rtol)'\n";
  script += "set xlabel 'CPU time per derivative (s), median'\n";
  if (smallest <= kPlotFloor) {
    script += format("set label 1 'exact (error 0) drawn at %.0e' at graph 0.02, graph 0.12 ",
                     kPlotFloor) +
              "font 'DejaVu Sans,10'\n";
  }
  script += plot_command(left, points, 1) +
            rtol_labels(points, "ad-dopri5", "#1f77b4", "-1.2,0.7") +
            rtol_labels(points, "ad-dopri5-state-only", "#9467bd", "1.0,-0.7") + "\n";
  script += "unset label 1\n";
  script += "set title 'Finite differences: error against the step α'\n";
  script += "set xlabel 'α'\n";
  std::string command = plot_command(right, points, 4);
  const std::pair<const char*, const char*> lines[] = {{"ad-dopri5", "#1f77b4"},
                                                       {"ad-dopri5-state-only", "#9467bd"}};
  for (const auto& [series, colour] : lines) {
    for (double rtol : {1e-10, 1e-12}) {
      const Point* ad = find(points, series, rtol);
      if (ad == nullptr) continue;
      command += format(", %.6e", std::max(ad->error, kPlotFloor)) + " with lines lc rgb '" +
                 colour + "' lw 2 dt " + (rtol > 1e-11 ? "1" : "3") + " title '" +
                 (std::string(series) == "ad-dopri5" ? "AD dopri5" : "AD dopri5, state-only norm") +
                 ", rtol " + format("%.0e", rtol) + "'";
    }
  }
  const Point* naive = find(points, "naive-ad-dopri5", 1e-12);
  if (naive != nullptr) {
    command += format(", %.6e", std::max(naive->error, kPlotFloor)) +
               " with lines lc rgb '#7f7f7f' lw 2 dt 2 title 'naive AD, rtol 1e-12'";
  }
  script += command + "\nunset multiplot\n";

  FILE* gnuplot = popen("gnuplot", "w");
  if (gnuplot == nullptr) {
    std::printf("  no plot: cannot start gnuplot\n");
    return;
  }
  std::fputs(script.c_str(), gnuplot);
  const int status = pclose(gnuplot);
  if (status != 0) {
    std::printf("  gnuplot failed (status %d); script:\n%s\n", status, script.c_str());
  } else {
    std::printf("  wrote %s\n", png.c_str());
  }
}

// ---------------------------------------------------------------------------------------------
// Problems

// Twice Richardson-extrapolated one-sided differences of the independent reference flow on
// each direction (from x0, in long double), and the crossing order the perturbed runs realised.
// Prints how much halving the reference's step or alpha changes it: its own accuracy. At
// a = 5e-5 the O(a^3) truncation (~1e-14 on the biped) and the rounding (~1e-19 / a, amplified
// ~15x by the extrapolation) are about equal.
template <typename Model>
Eigen::MatrixXd independent_reference(const Model& model, const LVector& x0, double t,
                                      const Eigen::MatrixXd& directions,
                                      std::vector<std::vector<int>>* orders) {
  constexpr long double kAlpha = 5e-5L;
  const bflow::examples::ReferenceFlow<Model> ref(model);
  const bflow::examples::ReferenceFlow<Model> fine(model, ref.max_step() / 2);
  Eigen::MatrixXd images(directions.rows(), directions.cols());
  double step_change = 0.0, alpha_change = 0.0;
  for (Eigen::Index k = 0; k < directions.cols(); ++k) {
    const LVector dx = directions.col(k).cast<long double>();
    const auto r = ref.richardson2(x0, dx, t, kAlpha);
    const LVector r_step = fine.richardson2(x0, dx, t, kAlpha).value;
    const LVector r_alpha = ref.richardson2(x0, dx, t, kAlpha / 2).value;
    const long double scale = r.value.norm();
    step_change = std::max(step_change, static_cast<double>((r_step - r.value).norm() / scale));
    alpha_change = std::max(alpha_change, static_cast<double>((r_alpha - r.value).norm() / scale));
    images.col(k) = r.value.template cast<double>();
    std::vector<int> order;
    for (const auto& crossing : r.crossings) order.push_back(crossing.surface);
    orders->push_back(order);
  }
  std::printf(
      "  reference: ReferenceFlow (long double, RK6 step %.2g), (8 D(a/4) - 6 D(a/2) + D(a)) / 3 "
      "at a = 5e-5; halving its step changes it by %.1e, halving a by %.1e\n",
      static_cast<double>(ref.max_step()), step_change, alpha_change);
  return images;
}

Problem pwconst_problem(const bflow::examples::PiecewiseConstantField& field,
                        const SegmentModel& model) {
  Problem p;
  p.name = "pwconst";
  p.title = "Piecewise-constant field ([B] §3.1, planar demo Δ), d = 2, t = 1";
  p.model = &model;
  p.x0 = -0.5 * field.limits().col(0);
  p.t = 1.0;
  p.directions.resize(2, 2);
  p.directions.col(0) << 1.0, 0.2;
  p.directions.col(1) << -0.3, 1.0;
  for (Eigen::Index k = 0; k < 2; ++k) p.directions.col(k).normalize();
  const bflow::JumpMap jump(Eigen::MatrixXd::Identity(2, 2), field.limits());
  p.reference = jump.apply_block(p.directions);
  for (Eigen::Index k = 0; k < 2; ++k) {
    p.direction_notes.push_back(order_text(jump.order(p.directions.col(k)).order) + " first");
  }
  // Independent checks: one-sided differences of the exact (straight-line) flow, and the
  // independent reference flow.
  double worst = 0.0;
  const double alpha = 1e-6;
  for (Eigen::Index k = 0; k < 2; ++k) {
    const Eigen::VectorXd fd =
        (field.flow(p.x0 + alpha * p.directions.col(k), p.t) - field.flow(p.x0, p.t)) / alpha;
    worst = std::max(worst, (fd - p.reference.col(k)).norm() / p.reference.col(k).norm());
  }
  std::printf(
      "pwconst: reference B (exact); one-sided differences of the exact flow at "
      "alpha = 1e-6 agree to %.1e\n",
      worst);
  std::vector<std::vector<int>> orders;
  const Eigen::MatrixXd independent =
      independent_reference(field, p.x0.cast<long double>(), p.t, p.directions, &orders);
  std::printf("  B against the independent reference: %.1e\n",
              relative_error(independent, p.reference));
  return p;
}

// Independent reference of a problem, with the crossing orders as direction notes, and how far
// the engine's own tightest derivative (the previous reference) and one-sided differences of
// the engine at rtol 1e-13 are from it.
template <typename Model>
void set_independent_reference(Problem& p, const Model& model, const LVector& x0,
                               const char* (*note)(int first)) {
  std::vector<std::vector<int>> orders;
  p.reference = independent_reference(model, x0, p.t, p.directions, &orders);
  for (const std::vector<int>& order : orders) {
    p.direction_notes.push_back(order_text(order) + (order.empty() ? "" : note(order[0])));
  }
  const std::pair<double, bool> checks[] = {{1e-13, true}, {1e-13, false}};
  for (const auto& [rtol, tangent_norm] : checks) {
    FlowOptions other = options_for(Backend::kDopri5, rtol);
    other.integrator.atol = 1e-2 * rtol;
    other.integrator.tangents_in_error_norm = tangent_norm;
    FlowResult run;
    const bflow::FlowDerivative check = bflow::flow_derivative(*p.model, p.x0, p.t, other, &run);
    std::printf("  engine (dopri5 rtol %.0e atol %.0e, %s, %ld steps, %zu event(s)", rtol,
                other.integrator.absolute_tolerance(),
                tangent_norm ? "tangents in the norm" : "state-only norm", run.steps,
                run.events.size());
    for (const bflow::EventRecord& event : run.events) {
      std::printf(", t = %.6f (%d surfaces)", event.t, event.group_size());
    }
    std::printf(") against the reference: %.1e\n",
                relative_error(check.apply_block(p.directions), p.reference));
  }
  FlowOptions fd_options = options_for(Backend::kDopri5, 1e-13);
  fd_options.integrator.atol = 1e-15;
  fd_options.grouping = bflow::Grouping::kNone;
  const Eigen::VectorXd nominal = bflow::simulate(*p.model, p.x0, p.t, fd_options).x;
  for (Eigen::Index k = 0; k < p.directions.cols(); ++k) {
    const double alpha = 1e-7;
    const FlowResult moved =
        bflow::simulate(*p.model, p.x0 + alpha * p.directions.col(k), p.t, fd_options);
    const Eigen::VectorXd fd = (moved.x - nominal) / alpha;
    std::printf(
        "  dx_%ld: engine one-sided FD (alpha 1e-7, rtol 1e-13) against the reference: %.1e "
        "(%zu events)\n",
        static_cast<long>(k), (fd - p.reference.col(k)).norm() / p.reference.col(k).norm(),
        moved.events.size());
  }
}

const char* foot_note(int first) {
  return first == 0 ? " (foot 0 touches first)" : " (foot 1 touches first)";
}

const char* no_note(int) { return ""; }

Problem biped_problem(const bflow::BipedModeDampingScene& scene, const SegmentModel& model) {
  Problem p;
  p.name = "biped";
  p.title = "Mode-damping biped ([B] §3.2.4), d = 6, t = 0.6: both feet touch at t = 0.397";
  p.model = &model;
  p.x0 = bflow::biped_initial_state();
  p.t = 0.6;
  p.directions.resize(6, 6);
  p.directions.col(0) << 1, 0, 0, 0, 0, 0;
  p.directions.col(1) << -1, 0, 0, 0, 0, 0;
  p.directions.col(2) << 0, 0, 1, 0, 0, 0;
  p.directions.col(3) << 0, 0.5, -1, 0, 0, 0;
  p.directions.col(4) << 0.3, -0.5, 0.2, 1.0, -0.4, 0.6;
  p.directions.col(5) << -0.2, 0.4, 0.1, -0.7, 0.5, -1.0;
  for (Eigen::Index k = 0; k < 6; ++k) p.directions.col(k).normalize();
  // x0 is exact in double and the trajectory is symmetric in any precision (x = theta = 0
  // stay 0), so both feet touch at the same instant in the reference too.
  std::printf("biped: independent reference\n");
  set_independent_reference(p, scene, p.x0.cast<long double>(), foot_note);
  return p;
}

Problem three_surfaces_problem(const SegmentModel& model) {
  using bflow::examples::ThreeSurfaces;
  Problem p;
  p.name = "three";
  p.title =
      "Three curved surfaces crossed at once (examples::ThreeSurfaces), d = 5, t = 1.5: all "
      "at t = 1";
  p.model = &model;
  // The start on the nonsmooth trajectory in long double (the reference's), and rounded to
  // double (the engine's).
  const bflow::examples::ReferenceFlow<ThreeSurfaces> ref(ThreeSurfaces{});
  const Eigen::Matrix<long double, 5, 1> rho = ThreeSurfaces::crossing_point().cast<long double>();
  const LVector start = ref.backward(rho, ThreeSurfaces::kCrossingTime, bflow::Signs(3));
  p.x0 = start.cast<double>();
  p.t = ThreeSurfaces::kFinalTime;
  // k = d = 5 directions in five of the six crossing orders: tangents at rho pulled back to
  // the start by central differences of the reference's backward flow (smooth: sides fixed).
  const std::array<std::array<int, 3>, 5> orders = {
      {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 1, 0}}};
  p.directions.resize(5, 5);
  for (int k = 0; k < 5; ++k) {
    const LVector tangent = ThreeSurfaces::tangent_in_order(orders[k]).cast<long double>();
    const long double e = 1e-6L;
    const LVector plus =
        ref.backward(rho + e * tangent, ThreeSurfaces::kCrossingTime, bflow::Signs(3));
    const LVector minus =
        ref.backward(rho - e * tangent, ThreeSurfaces::kCrossingTime, bflow::Signs(3));
    p.directions.col(k) = ((plus - minus) / (2 * e)).cast<double>();
    p.directions.col(k).normalize();
  }
  std::printf("three: independent reference\n");
  set_independent_reference(p, ThreeSurfaces{}, start, no_note);
  return p;
}

void print_directions(const Problem& p) {
  for (Eigen::Index k = 0; k < p.directions.cols(); ++k) {
    std::printf("  dx_%ld = (", static_cast<long>(k));
    for (Eigen::Index i = 0; i < p.directions.rows(); ++i) {
      std::printf("%s%.3f", i ? ", " : "", p.directions(i, k));
    }
    std::printf("): %s, |D_ref dx| = %.3f\n",
                p.direction_notes[static_cast<std::size_t>(k)].c_str(), p.reference.col(k).norm());
  }
}

void summarize(const Problem& p, const std::vector<Point>& points) {
  std::printf("\n%s: best error per series (and its CPU time)\n", p.name.c_str());
  std::vector<std::string> seen;
  for (const Point& point : points) {
    if (std::find(seen.begin(), seen.end(), point.series) != seen.end()) continue;
    seen.push_back(point.series);
    const Point* b = best(points, point.series);
    std::printf("  %-32s %.2e at rtol %.0e%s, %.1f us\n", b->series.c_str(), b->error, b->rtol,
                std::isnan(b->alpha) ? "" : format(", alpha %.0e", b->alpha).c_str(), b->cpu * 1e6);
  }
  const Point* one_sided = best(points, "fd-one-sided-sweep-rtol1e-10");
  const Point* central = find(points, "fd-central-matched", 1e-10);
  for (const char* series : {"ad-dopri5", "ad-dopri5-state-only"}) {
    const Point* ad = find(points, series, 1e-10);
    if (ad == nullptr) continue;
    if (one_sided != nullptr) {
      std::printf("  rtol 1e-10, %s: error %.2e; best one-sided FD %.2e (alpha %.0e): ", series,
                  ad->error, one_sided->error, one_sided->alpha);
      if (ad->error > 0) {
        std::printf("AD %.1e x more accurate\n", one_sided->error / ad->error);
      } else {
        std::printf("AD exact\n");
      }
    }
    if (central != nullptr) {
      std::printf(
          "  rtol 1e-10, %s: %.1f us; central FD (%d simulations) %.1f us: AD %.2f x "
          "faster\n",
          series, ad->cpu * 1e6, central->simulations, central->cpu * 1e6, central->cpu / ad->cpu);
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  Settings settings;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--out" && i + 1 < argc) {
      settings.out_dir = argv[++i];
    } else if (arg == "--no-plot") {
      settings.plot = false;
    } else if (arg == "--quick") {
      settings.repetitions = 2;
      settings.min_batch_seconds = 1e-3;
    } else {
      std::fprintf(stderr, "usage: accuracy_harness [--out DIR] [--no-plot] [--quick]\n");
      return 2;
    }
  }
  try {
    const auto field = bflow::examples::PiecewiseConstantField::planar_demo();
    const auto pwconst_model = bflow::adapt(field);
    const auto biped_scene = bflow::make_biped_mode_damping(bflow::BipedParams{});
    const auto biped_model = bflow::adapt(biped_scene);
    const auto three_model = bflow::adapt(bflow::examples::ThreeSurfaces{});
    auto run = [&](const std::string& name, const std::function<Problem()>& make) {
      std::printf("\n== %s\n", name.c_str());
      const Problem p = make();
      std::printf("%s\n", p.title.c_str());
      print_directions(p);
      const std::vector<Point> points = sweep(p, settings);
      const std::string csv = settings.out_dir + "/accuracy_" + p.name + ".csv";
      write_csv(csv, points);
      std::printf("  wrote %s\n", csv.c_str());
      summarize(p, points);
      if (settings.plot) plot(p, points, settings);
    };
    run("pwconst", [&] { return pwconst_problem(field, pwconst_model); });
    run("biped", [&] { return biped_problem(biped_scene, biped_model); });
    run("three", [&] { return three_surfaces_problem(three_model); });
  } catch (const std::exception& e) {
    std::fprintf(stderr, "accuracy_harness: %s\n", e.what());
    return 1;
  }
  return 0;
}

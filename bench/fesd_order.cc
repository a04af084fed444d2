// The integration-order experiment of [F] Figure 6 on IRMA: the first 100 minutes, N_FE = 3,
// N_sim integration steps, FESD with Radau IIA and Gauss-Legendre of 1 to 4 stages and standard
// time-stepping (Radau IIA, 2 stages, fixed grid), error max_i |x_i(100) - exact| against the
// closed form of examples/irma.h, and the CPU time of each run. Writes docs/fesd_order.csv and,
// through gnuplot (pngcairo), docs/fesd_order.png (error against h) and
// docs/fesd_work_precision.png (error against CPU time), and prints the fitted slopes: least
// squares of log error on log h over the runs above 1e-13 (round-off is about 1e-15) whose every
// step was solved by Newton's method (no IPOPT homotopy, no halved step: those runs carry the
// homotopy's tolerances and a different grid), and over the three finest of them (the
// asymptotic order), with the N_sim range each fit used.
//
//   fesd_order [--out DIR] [--no-plot] [--quick] [--stages S] [--steps N1,N2,...]
//     --quick: N_sim 4, 8, 16 only; --stages: the Radau IIA and Gauss-Legendre series of S
//     stages only (no standard time-stepping); --steps: these N_sim instead.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <string>
#include <vector>

#include "bflow/examples/irma.h"
#include "bflow/fesd/fesd.h"

namespace {

struct Series {
  std::string name;
  bflow::CollocationScheme scheme;
  int stages;
  bool standard;
  int order;  // expected: 2s - 1, 2s, or 1 for standard time-stepping
};

struct Point {
  int steps;
  double h;
  double error;
  double cpu;
  int halved;
  int homotopy;  // integration steps solved by the IPOPT homotopy
};

// Errors below this are round-off (the solutions are exact FESD solutions to machine precision).
constexpr double kFloor = 1e-13;

// The runs a slope is fitted over: above the floor, every step by Newton.
std::vector<Point> fitted(const std::vector<Point>& all) {
  std::vector<Point> points;
  for (const Point& p : all) {
    if (p.error > kFloor && p.halved == 0 && p.homotopy == 0) points.push_back(p);
  }
  return points;
}

// Least-squares slope over the fitted runs; the `last` finest of them if last > 0.
double slope(const std::vector<Point>& all, int last = 0) {
  std::vector<Point> points = fitted(all);
  if (last > 0 && static_cast<int>(points.size()) > last) {
    points.erase(points.begin(), points.end() - last);
  }
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int n = 0;
  for (const Point& p : points) {
    const double x = std::log(p.h), y = std::log(p.error);
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
    ++n;
  }
  if (n < 2) return NAN;
  return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

}  // namespace

int main(int argc, char** argv) {
  std::string out_dir = "docs";
  bool plot = true, quick = false;
  int only_stages = 0;
  std::vector<int> custom_steps;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--out" && i + 1 < argc) {
      out_dir = argv[++i];
    } else if (arg == "--no-plot") {
      plot = false;
    } else if (arg == "--quick") {
      quick = true;
    } else if (arg == "--stages" && i + 1 < argc) {
      only_stages = std::atoi(argv[++i]);
    } else if (arg == "--steps" && i + 1 < argc) {
      const std::string list = argv[++i];
      for (std::size_t at = 0; at < list.size();) {
        std::size_t comma = list.find(',', at);
        if (comma == std::string::npos) comma = list.size();
        custom_steps.push_back(std::atoi(list.substr(at, comma - at).c_str()));
        at = comma + 1;
      }
    } else {
      std::fprintf(stderr,
                   "usage: fesd_order [--out DIR] [--no-plot] [--quick] [--stages S] "
                   "[--steps N1,N2,...]\n");
      return 2;
    }
  }
  const bflow::examples::Irma irma;
  const double t_end = 100.0;
  const auto exact =
      bflow::examples::exact_irma(irma, bflow::examples::Irma::initial_state(), t_end);
  const auto model = bflow::adapt_step(irma);
  std::vector<Series> series;
  for (int s = 1; s <= 4; ++s) {
    if (only_stages > 0 && s != only_stages) continue;
    series.push_back(
        {"radau" + std::to_string(s), bflow::CollocationScheme::kRadauIIA, s, false, 2 * s - 1});
  }
  for (int s = 1; s <= 4; ++s) {
    if (only_stages > 0 && s != only_stages) continue;
    series.push_back(
        {"gauss" + std::to_string(s), bflow::CollocationScheme::kGaussLegendre, s, false, 2 * s});
  }
  if (only_stages == 0) {
    series.push_back({"standard-radau2", bflow::CollocationScheme::kRadauIIA, 2, true, 1});
  }
  const std::vector<int> steps =
      !custom_steps.empty() ? custom_steps
      : quick               ? std::vector<int>{4, 8, 16}
              : std::vector<int>{1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 200, 300};

  const std::string csv_path = out_dir + "/fesd_order.csv";
  FILE* csv = std::fopen(csv_path.c_str(), "w");
  if (csv == nullptr) {
    std::fprintf(stderr, "fesd_order: cannot write %s\n", csv_path.c_str());
    return 1;
  }
  std::fprintf(csv, "series,stages,n_sim,h,error,cpu_seconds,halved_steps,homotopy_steps\n");
  std::vector<std::vector<Point>> results;
  for (const Series& s : series) {
    std::vector<Point> points;
    for (int n : steps) {
      bflow::FesdOptions o;
      o.scheme = s.scheme;
      o.stages = s.stages;
      o.standard = s.standard;
      o.elements = 3;
      o.steps = n;
      o.sensitivities = false;
      const std::clock_t start = std::clock();  // process CPU time
      const bflow::FesdResult r =
          bflow::fesd_simulate(model, bflow::examples::Irma::initial_state(), t_end, o);
      const double cpu = static_cast<double>(std::clock() - start) / CLOCKS_PER_SEC;
      const double h = t_end / (n * o.elements);
      if (!r.ok()) {
        std::printf("%-16s N_sim %3d: %s\n", s.name.c_str(), n, r.message.c_str());
        continue;
      }
      const double error = (r.x_end - exact.x).cwiseAbs().maxCoeff();
      const int homotopy = static_cast<int>(r.nlp_iterations.size()) - r.newton_steps;
      points.push_back({n, h, error, cpu, r.halved_steps, homotopy});
      std::fprintf(csv, "%s,%d,%d,%.6g,%.6e,%.4f,%d,%d\n", s.name.c_str(), s.stages, n, h, error,
                   cpu, r.halved_steps, homotopy);
      std::printf("%-16s N_sim %3d  h %.4g  error %.3e  %.2f s%s%s\n", s.name.c_str(), n, h, error,
                  cpu, homotopy ? " (homotopy)" : "", r.halved_steps ? " (steps halved)" : "");
      std::fflush(stdout);
    }
    results.push_back(points);
  }
  std::fclose(csv);
  std::printf(
      "\nwrote %s\n\n| series | expected order | fitted slope | N_sim fitted | three finest | "
      "CPU s, all runs |\n| --- | ---: | ---: | --- | ---: | ---: |\n",
      csv_path.c_str());
  for (std::size_t k = 0; k < series.size(); ++k) {
    double cpu = 0;
    for (const Point& p : results[k]) cpu += p.cpu;
    const std::vector<Point> used = fitted(results[k]);
    const std::string range = used.empty() ? "none"
                                           : std::to_string(used.front().steps) + "-" +
                                                 std::to_string(used.back().steps) + " (" +
                                                 std::to_string(used.size()) + " runs)";
    std::printf("| %s | %d | %.2f | %s | %.2f | %.1f |\n", series[k].name.c_str(), series[k].order,
                slope(results[k]), range.c_str(), slope(results[k], 3), cpu);
  }
  if (!plot) return 0;
  std::string script;
  for (int figure = 0; figure < 2; ++figure) {
    const bool work = figure == 1;
    script += "set terminal pngcairo size 900,650 font ',11' noenhanced\nset output '" + out_dir +
              (work ? "/fesd_work_precision.png'\n" : "/fesd_order.png'\n") +
              "set logscale xy\nset format y '1e%L'\nset format x '" + (work ? "1e%L" : "%g") +
              "'\nset grid\nset key outside right\n"
              "set ylabel 'max |x(100) - x_exact(100)|'\n";
    script += work ? "set xlabel 'CPU time [s]'\n"
                     "set title 'FESD on IRMA: accuracy against CPU time (N_sim 1 to 300)'\nplot "
                   : "set xlabel 'h = T / (N_sim N_FE) [min]'\n"
                     "set title 'FESD on IRMA: error against step size'\nplot ";
    for (std::size_t k = 0; k < series.size(); ++k) {
      // Work-precision: points only (the runs' costs are not ordered by N_sim).
      script += std::string(k ? ", " : "") + "'-' using 1:2 with " +
                (work ? "points ps 1.3" : "linespoints lw 2") + " title '" + series[k].name + "'";
    }
    script += "\n";
    for (const auto& points : results) {
      for (const Point& p : points) {
        char line[64];
        std::snprintf(line, sizeof line, "%.6e %.6e\n", work ? p.cpu : p.h,
                      std::max(p.error, 1e-16));
        script += line;
      }
      script += "e\n";
    }
  }
  FILE* gnuplot = popen("gnuplot", "w");
  if (gnuplot == nullptr) {
    std::printf("no plot: cannot start gnuplot\n");
    return 0;
  }
  std::fputs(script.c_str(), gnuplot);
  const int status = pclose(gnuplot);
  std::printf(status == 0 ? "wrote %s/fesd_order.png and fesd_work_precision.png\n"
                          : "gnuplot failed for %s\n",
              out_dir.c_str());
  return 0;
}

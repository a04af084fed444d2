// The integration-order experiment of [F] Figure 6 on IRMA: the first 100 minutes, N_FE = 3,
// N_sim integration steps, FESD with Radau IIA and Gauss-Legendre of 1 to 4 stages and standard
// time-stepping (Radau IIA, 2 stages, fixed grid), error max_i |x_i(100) - exact| against the
// closed form of examples/irma.h. Writes docs/fesd_order.csv and, through gnuplot (pngcairo),
// docs/fesd_order.png, and prints the fitted slopes (least squares of log error on log h over
// the points above the 1e-10 floor).
//
//   fesd_order [--out DIR] [--no-plot] [--quick]      (--quick: N_sim 4, 8, 16 only)
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "bflow/examples/irma.h"
#include "bflow/integrators/fesd.h"

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
};

double slope(const std::vector<Point>& points) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int n = 0;
  for (const Point& p : points) {
    if (!(p.error > 1e-10)) continue;
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
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--out" && i + 1 < argc) {
      out_dir = argv[++i];
    } else if (arg == "--no-plot") {
      plot = false;
    } else if (arg == "--quick") {
      quick = true;
    } else {
      std::fprintf(stderr, "usage: fesd_order [--out DIR] [--no-plot] [--quick]\n");
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
    series.push_back(
        {"radau" + std::to_string(s), bflow::CollocationScheme::kRadauIIA, s, false, 2 * s - 1});
  }
  for (int s = 1; s <= 4; ++s) {
    series.push_back(
        {"gauss" + std::to_string(s), bflow::CollocationScheme::kGaussLegendre, s, false, 2 * s});
  }
  series.push_back({"standard-radau2", bflow::CollocationScheme::kRadauIIA, 2, true, 1});
  const std::vector<int> steps =
      quick ? std::vector<int>{4, 8, 16} : std::vector<int>{4, 8, 16, 32, 64};

  const std::string csv_path = out_dir + "/fesd_order.csv";
  FILE* csv = std::fopen(csv_path.c_str(), "w");
  if (csv == nullptr) {
    std::fprintf(stderr, "fesd_order: cannot write %s\n", csv_path.c_str());
    return 1;
  }
  std::fprintf(csv, "series,stages,n_sim,h,error,cpu_seconds,halved_steps\n");
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
      const auto start = std::chrono::steady_clock::now();
      const bflow::FesdResult r =
          bflow::fesd_simulate(model, bflow::examples::Irma::initial_state(), t_end, o);
      const double cpu =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      const double h = t_end / (n * o.elements);
      if (!r.ok()) {
        std::printf("%-16s N_sim %3d: %s\n", s.name.c_str(), n, r.message.c_str());
        continue;
      }
      const double error = (r.x_end - exact.x).cwiseAbs().maxCoeff();
      points.push_back({n, h, error, cpu, r.halved_steps});
      std::fprintf(csv, "%s,%d,%d,%.6g,%.6e,%.4f,%d\n", s.name.c_str(), s.stages, n, h, error, cpu,
                   r.halved_steps);
      std::printf("%-16s N_sim %3d  h %.4g  error %.3e  %.2f s%s\n", s.name.c_str(), n, h, error,
                  cpu, r.halved_steps ? " (steps halved)" : "");
      std::fflush(stdout);
    }
    results.push_back(points);
  }
  std::fclose(csv);
  std::printf("\nwrote %s\n\n| series | expected order | fitted slope |\n| --- | ---: | ---: |\n",
              csv_path.c_str());
  for (std::size_t k = 0; k < series.size(); ++k) {
    std::printf("| %s | %d | %.2f |\n", series[k].name.c_str(), series[k].order, slope(results[k]));
  }
  if (!plot) return 0;
  std::string script = "set terminal pngcairo size 900,650 font ',11' noenhanced\nset output '" +
                       out_dir +
                       "/fesd_order.png'\nset logscale xy\nset format y '1e%L'\nset grid\n"
                       "set key outside right\nset xlabel 'h = T / (N_sim N_FE) [min]'\n"
                       "set ylabel 'max |x(100) - x_exact(100)|'\n"
                       "set title 'FESD on IRMA: error against step size'\nplot ";
  for (std::size_t k = 0; k < series.size(); ++k) {
    script += std::string(k ? ", " : "") + "'-' using 1:2 with linespoints lw 2 title '" +
              series[k].name + "'";
  }
  script += "\n";
  for (const auto& points : results) {
    for (const Point& p : points) {
      char line[64];
      std::snprintf(line, sizeof line, "%.6e %.6e\n", p.h, std::max(p.error, 1e-16));
      script += line;
    }
    script += "e\n";
  }
  FILE* gnuplot = popen("gnuplot", "w");
  if (gnuplot == nullptr) {
    std::printf("no plot: cannot start gnuplot\n");
    return 0;
  }
  std::fputs(script.c_str(), gnuplot);
  const int status = pclose(gnuplot);
  std::printf(status == 0 ? "wrote %s/fesd_order.png\n" : "gnuplot failed for %s\n",
              out_dir.c_str());
  return 0;
}

// `bflow demo`: dispatch on --scene, and the pwconst scene: the B-derivative of the
// piecewise-constant field of [B] Section 3.1 at rho = 0 in d = 2, non-linear case (Figure 3.1,
// right): a table of B on unit vectors, the two pieces, self-checks against independent
// computations, and a plot of the unit circle and its image, a piecewise ellipse. The biped
// scene is in demo_biped.cc.
//
// Every number printed comes from the library (JumpMap, Triangulation) or from the exact flow
// of the field (straight lines between crossings), which checks B by one-sided differences.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <ostream>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/signs.h"
#include "bflow/core/triangulation.h"
#include "bflow/examples/piecewise_constant.h"
#include "cli_commands.h"
#include "cli_util.h"
#include "demo_util.h"

namespace bflow::cli {
namespace {

namespace fs = std::filesystem;

constexpr double kPi = 3.14159265358979323846;
constexpr int kCirclePoints = 720;
// |B(dx) - M_sigma dx|, B(F--) vs F++, the pieces on their common ray: both sides are products
// of at most two rank-1 updates of entries O(1) applied to |dx| = O(1), so a few eps.
constexpr double kRoundingTolerance = 1e-13;
// Barycentric evaluation solves 2 x 2 systems whose conditioning is O(10) here.
constexpr double kBarycentricTolerance = 1e-12;
// One-sided differences of a piecewise-affine flow are exact up to rounding in x, which is
// divided by alpha: eps * |x| / alpha ~ 1e-10.
constexpr double kDifferenceStep = 1e-6;
constexpr double kDifferenceTolerance = 1e-8;

std::string times_text(const std::vector<double>& times) {
  return vector_text(
      Eigen::Map<const Eigen::VectorXd>(times.data(), static_cast<Eigen::Index>(times.size())));
}

int piece_index(const Pieces& pieces, const std::vector<int>& order) {
  for (std::size_t k = 0; k < pieces.size(); ++k) {
    if (pieces[k].order == order) return static_cast<int>(k);
  }
  throw DemoError("demo: internal: order " + order_text(order) + " is not among the pieces");
}

std::string gnuplot_script(const Pieces& pieces, double range) {
  const std::string m0 = "M_{" + order_text(pieces[0].order) + "}";
  const std::string m1 = "M_{" + order_text(pieces[1].order) + "}";
  std::ostringstream gp;
  gp << "# The unit circle and its image under B, the B-derivative of the flow of the\n"
        "# piecewise-constant field of [B] Section 3.1 at rho = 0 (Figure 3.1, right).\n"
        "# Written by `bflow demo`; run in this directory: gnuplot demo_circle.gp\n"
        "set encoding utf8\n"
        "set terminal pngcairo size 800,800 enhanced font 'Sans,12'\n"
        "set output (exists('bflow_output') ? bflow_output : 'demo_circle.png')\n"
        "set title \"B-derivative of the piecewise-constant field ([B] Sec. 3.1) at ρ = 0\\n"
        "the unit circle and its image under B, a piecewise ellipse\"\n"
        "set size ratio -1\n"
     << formatted("set xrange [%.3f:%.3f]\nset yrange [%.3f:%.3f]\n", -range, range, -range, range)
     << "set xlabel 'δx_0'\n"
        "set ylabel 'δx_1'\n"
        "set grid lc rgb '#dddddd'\n"
        "set xzeroaxis lt 1 lc rgb '#aaaaaa'\n"
        "set yzeroaxis lt 1 lc rgb '#aaaaaa'\n"
        "set key outside bottom center horizontal maxcols 2 samplen 2 spacing 1.1\n"
        "data = 'demo_circle.dat'\n"
        "plot \\\n"
     << "  data index 1 using 2:3 with filledcurves xy=0,0 fs transparent solid 0.18 noborder"
        " fc rgb '"
     << gnuplot_color(0) << "' title 'cone where " << m0 << " acts', \\\n"
     << "  data index 2 using 2:3 with filledcurves xy=0,0 fs transparent solid 0.18 noborder"
        " fc rgb '"
     << gnuplot_color(1) << "' title 'cone where " << m1 << " acts', \\\n"
     << "  data index 1 using 4:5 with filledcurves xy=0,0 fs transparent solid 0.55 noborder"
        " fc rgb '"
     << gnuplot_color(0) << "' title 'image under " << m0 << "', \\\n"
     << "  data index 2 using 4:5 with filledcurves xy=0,0 fs transparent solid 0.55 noborder"
        " fc rgb '"
     << gnuplot_color(1) << "' title 'image under " << m1 << "', \\\n"
     << "  data index 0 using 2:3 with lines lw 2 lc rgb 'black' title 'unit circle', \\\n"
        "  data index 0 using 4:5 with lines lw 2.5 lc rgb '#B22222' title 'B(unit circle)', \\\n"
     << formatted(
            "  data index 3 using (0):(0):(%.3f*$2):(%.3f*$3) with vectors nohead dt 2 lw 2"
            " lc rgb '#444444' title 'cone boundaries ±F_{--}', \\\n",
            range * 1.5, range * 1.5)
     << "  data index 3 using 4:5 with points pt 7 ps 1.5 lc rgb '#B22222'"
        " title 'their images under B'\n";
  return gp.str();
}

}  // namespace

int demo_pwconst(const DemoOptions& options, std::ostream& out, std::ostream& /*err*/) {
  const auto model = examples::PiecewiseConstantField::planar_demo();
  const int d = model.states();
  const Eigen::MatrixXd eta = Eigen::MatrixXd::Identity(d, d);
  const JumpMap jump(eta, model.limits());
  const Triangulation triangulation = jump.triangulation();
  const Pieces pieces = jump.pieces();
  const Signs minus = Signs::all_minus(d);
  const Signs plus = Signs::all_plus(d);
  const Eigen::VectorXd f_minus = jump.limit(minus);
  const Eigen::VectorXd f_plus = jump.limit(plus);

  out << "bflow demo: the B-derivative of the flow of the piecewise-constant field of [B]\n"
         "Section 3.1 at the point rho = 0 where both switching surfaces meet (Figure 3.1, right)\n"
         "\n"
         "  xdot = F(x) = 1 + Delta(sign(x)),  h(x) = x,  d = n = 2,  eta = I\n"
         "  B maps a tangent dx before the event to B(dx) after it ([B] Algorithm 2.1).\n"
         "\n"
         "  word b   Delta(b)                Gamma(b) = F_b(0)\n";
  for (std::uint64_t w = 0; w < (std::uint64_t{1} << d); ++w) {
    const Signs b(d, w);
    out << "  " << b.str() << "       "
        << vector_text(model.delta().col(static_cast<Eigen::Index>(w))) << "  "
        << vector_text(jump.limit(b)) << '\n';
  }

  // The table: unit vectors every 45 degrees, then F_--.
  struct Row {
    std::string label;
    Eigen::VectorXd dx;
  };
  std::vector<Row> rows;
  for (int degrees = 0; degrees < 360; degrees += 45) {
    const double angle = degrees * kPi / 180.0;
    rows.push_back({std::to_string(degrees), Eigen::Vector2d(std::cos(angle), std::sin(angle))});
  }
  rows.push_back({"F_--", f_minus});

  out << "\nB on unit vectors and on F_--. order: the surfaces in crossing order sigma (from 0);\n"
         "crossing times: when each is crossed, time 0 being dx itself on the F_-- line\n"
         "([B] (6.8)-(6.9)); last column: Algorithm 2.1 against the piece M_sigma.\n\n";
  out << "  angle  dx                      B(dx)                   order  crossing times"
         "          |B(dx) - M_sigma dx|\n";
  double max_piece_error = 0.0;
  for (const Row& row : rows) {
    const Eigen::VectorXd image = jump.apply(row.dx);
    const CrossingOrder order = jump.order(row.dx);
    const double piece_error = (image - jump.active_jacobian(row.dx) * row.dx).norm();
    max_piece_error = std::max(max_piece_error, piece_error);
    out << formatted("  %-5s  ", row.label.c_str()) << vector_text(row.dx) << "  "
        << vector_text(image) << "  " << order_text(order.order) << "  " << times_text(order.times)
        << formatted("  %.1e\n", piece_error);
  }

  out << "\nThe n! = " << pieces.size()
      << " pieces M_sigma ([B] (6.4): saltation matrices, first crossing right-most):\n\n";
  for (const Piece& piece : pieces) {
    const std::string name = "M_" + order_text(piece.order) + " = ";
    for (Eigen::Index r = 0; r < piece.matrix.rows(); ++r) {
      out << "  " << (r == 0 ? name : std::string(name.size(), ' ')) << "[";
      for (Eigen::Index c = 0; c < piece.matrix.cols(); ++c) {
        out << formatted(" %9.6f", piece.matrix(r, c));
      }
      out << " ]";
      if (r == 0) out << "   active where surface " << piece.order[0] << " is crossed first";
      out << '\n';
    }
  }
  const Eigen::Vector2d boundary = f_minus.normalized();
  out << "\n  The two cones meet on the line spanned by F_-- = " << vector_text(f_minus)
      << ";\n  B is continuous there but not linear: |M_(0,1) - M_(1,0)| = "
      << formatted("%.6f", (pieces[0].matrix - pieces[1].matrix).norm()) << ".\n";

  // The circle, for the checks and the plot.
  std::vector<Sample> circle;
  double max_barycentric_error = 0.0;
  double max_radius = 1.0;
  for (int k = 0; k < kCirclePoints; ++k) {
    const double degrees = 360.0 * k / kCirclePoints;
    const Eigen::Vector2d dx(std::cos(degrees * kPi / 180.0), std::sin(degrees * kPi / 180.0));
    const Eigen::Vector2d image = jump.apply(dx);
    max_barycentric_error =
        std::max(max_barycentric_error, (triangulation.apply_barycentric(dx).image - image).norm());
    max_radius = std::max(max_radius, image.norm());
    circle.push_back({degrees, dx, image, piece_index(pieces, jump.order(dx).order)});
  }

  // One-sided differences of the exact flow from rho- = -F_--/2 over unit time ([B] Sec. 3.1).
  const Eigen::VectorXd rho_minus = -0.5 * f_minus;
  const Eigen::VectorXd rho_plus = model.flow(rho_minus, 1.0);
  double max_difference_error = 0.0;
  for (const Row& row : rows) {
    const Eigen::VectorXd moved = model.flow(rho_minus + kDifferenceStep * row.dx, 1.0);
    const Eigen::VectorXd difference = (moved - rho_plus) / kDifferenceStep;
    max_difference_error = std::max(max_difference_error, (difference - jump.apply(row.dx)).norm());
  }

  const std::vector<Check> checks = {
      {"max |B(dx) - M_sigma dx| on the rows above (Algorithm 2.1 against the piece)",
       max_piece_error, kRoundingTolerance},
      {"|B(F_--) - F_++| (ker eta = {0}, so L = span F_--, where B is linear)",
       (jump.apply(f_minus) - f_plus).norm(), kRoundingTolerance},
      {"|M_(0,1) p - M_(1,0) p|, p = F_--/|F_--| (the pieces agree on their boundary)",
       (pieces[0].matrix * boundary - pieces[1].matrix * boundary).norm(), kRoundingTolerance},
      {"max |B(dx) by the triangulation ([B] (6.5)) - B(dx)|, 720 points of the circle",
       max_barycentric_error, kBarycentricTolerance},
      {"|phi(1, rho-) - F_++/2|, the exact flow from rho- = -F_--/2 reaches rho+",
       (rho_plus - 0.5 * f_plus).norm(), kRoundingTolerance},
      {"max |(phi(1, rho- + a dx) - rho+)/a - B(dx)|, a = 1e-6, rows above (exact flow)",
       max_difference_error, kDifferenceTolerance},
  };
  const bool all_passed = print_checks(out, checks);

  // Files.
  const fs::path dir(options.output_dir);  // made and probed by run_demo()

  // The arcs of the two pieces, bounded exactly by the rays +-p where the order changes (for
  // n = d = 2 the cones are the half-planes on either side of the line spanned by F_--).
  std::vector<Sample> boundary_samples;
  for (double sign : {1.0, -1.0}) {
    const Eigen::Vector2d p = sign * boundary;
    double degrees = std::atan2(p[1], p[0]) * 180.0 / kPi;
    if (degrees < 0) degrees += 360.0;
    boundary_samples.push_back({degrees, p, jump.apply(p), -1});
  }
  // arcs[k]: the arc where piece k is active, from boundary ray to boundary ray.
  std::vector<std::vector<Sample>> arcs(pieces.size());
  for (int a = 0; a < 2; ++a) {
    const Sample& start = boundary_samples[static_cast<std::size_t>(a)];
    const Sample& end = boundary_samples[static_cast<std::size_t>(1 - a)];
    const auto offset = [&start](const Sample& s) {
      return std::fmod(s.angle_deg - start.angle_deg + 720.0, 360.0);
    };
    std::vector<Sample> arc = {start};
    for (const Sample& s : circle) {
      if (offset(s) > 1e-9 && offset(s) < 180.0 - 1e-9) arc.push_back(s);
    }
    std::sort(arc.begin() + 1, arc.end(),
              [&offset](const Sample& x, const Sample& y) { return offset(x) < offset(y); });
    arc.push_back(end);
    // The piece is read off the middle of the arc, a quarter turn from the start.
    const Eigen::Vector2d middle(-start.dx[1], start.dx[0]);
    const int piece = piece_index(pieces, jump.order(middle).order);
    for (Sample& s : arc) s.piece = piece;
    arcs[static_cast<std::size_t>(piece)] = std::move(arc);
  }
  if (arcs[0].empty() || arcs[1].empty()) {
    throw DemoError("demo: internal: both arcs fall in one piece");
  }

  std::ostringstream dat;
  dat << "# The unit circle and its image under B, the B-derivative of the flow of the\n"
         "# piecewise-constant field of [B] Section 3.1 at rho = 0 (d = n = 2, eta = I).\n"
         "# Written by `bflow demo`; drawn by demo_circle.gp.\n"
         "# Columns: angle_deg dx_0 dx_1 B(dx)_0 B(dx)_1 piece\n";
  for (std::size_t k = 0; k < pieces.size(); ++k) {
    dat << "#   piece " << k << ": sigma = " << order_text(pieces[k].order) << '\n';
  }
  dat << "# index 0: " << kCirclePoints
      << " points of the unit circle, every 0.5 degrees, and the first again\n";
  write_samples(dat, circle);
  write_samples(dat, {circle.front()});
  for (std::size_t k = 0; k < arcs.size(); ++k) {
    dat << "\n\n# index " << k + 1 << ": the arc where piece " << k << " = "
        << order_text(pieces[k].order) << " is active, from boundary ray to boundary ray\n";
    write_samples(dat, arcs[k]);
  }
  dat << "\n\n# index 3: the boundary rays of the cones, +-F_--/|F_--|, and their images\n";
  write_samples(dat, boundary_samples);

  const fs::path dat_path = dir / "demo_circle.dat";
  const fs::path gp_path = dir / "demo_circle.gp";
  const fs::path png_path = dir / "demo_circle.png";
  write_file(dat_path, dat.str());
  write_file(gp_path, gnuplot_script(pieces, std::ceil(max_radius * 12.0) / 10.0));
  out << "\nWrote " << dat_path.string() << " (the unit circle at " << kCirclePoints
      << " points and its image under B)\n"
      << "Wrote " << gp_path.string() << '\n';
  if (options.no_plot) {
    out << "Skipped the plot (--no-plot); to draw " << png_path.string() << ": cd " << dir.string()
        << " && gnuplot demo_circle.gp\n";
  } else {
    out << "Running gnuplot demo_circle.gp in " << dir.string() << '\n' << std::flush;
    run_gnuplot(dir, "demo_circle.gp", "demo_circle.png");
    out << png_path.string() << '\n';
  }
  return all_passed ? kExitOk : kExitFailure;
}

int run_demo(const DemoOptions& options, std::ostream& out, std::ostream& err) {
  if (options.scene != "biped" && options.scene != "pwconst") {
    report_error(err, "--scene: unknown demo scene " + quote(options.scene) +
                          "; the demo scenes are biped and pwconst");
    return kExitBadInput;
  }
  if (options.output_dir.empty()) {
    report_error(err, "--output: the directory name is empty");
    return kExitBadInput;
  }
  int code = kExitFailure;
  try {
    // Before anything is computed or printed: a directory that cannot be written is refused.
    prepare_output_directory(options.output_dir);
    code =
        options.scene == "biped" ? demo_biped(options, out, err) : demo_pwconst(options, out, err);
  } catch (const DemoError& e) {
    out << std::flush;
    report_error(err, e.what());
  } catch (const std::exception& e) {
    out << std::flush;
    report_error(err, std::string("demo: internal: ") + e.what());
  }
  return finish_output(out, err, code);
}

}  // namespace bflow::cli

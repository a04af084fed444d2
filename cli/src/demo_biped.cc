// `bflow demo` (--scene biped, the default): the B-derivative of the flow of the vertical-plane
// biped of [B] Section 3.2.4 with mode-dependent damping (Figure 3.2, right). Falling from rest,
// both feet touch the ground at the same instant: one event with two surfaces, whose jump map
// has two pieces, M_(0,1) (foot 0 lands first) and M_(1,0). The demo prints the event, the
// pieces, a table of B = D phi_0.6(x0; .) against finite differences of the simulated flow, and
// plots the image of a circle of (theta, y) perturbations, projected on (theta, y): a piecewise
// ellipse.
//
// Every number printed comes from the library (simulate, flow_derivative, fd::one_sided,
// fd::central, biped_touchdown); the checks compare independent computations.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <ostream>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/biped.h"
#include "bflow/core/errors.h"
#include "bflow/core/flow_derivative.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/signs.h"
#include "bflow/integrators/finite_differences.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "cli_commands.h"
#include "cli_util.h"
#include "demo_util.h"

namespace bflow::cli {
namespace {

namespace fs = std::filesystem;

constexpr double kPi = 3.14159265358979323846;
constexpr double kFinalTime = 0.6;
constexpr int kCirclePoints = 360;
// State indices.
constexpr int kX = 0;
constexpr int kY = 1;
constexpr int kTheta = 2;
constexpr int kXdot = 3;
constexpr int kYdot = 4;
constexpr int kThetadot = 5;
constexpr const char* kStateNames[6] = {"x", "y", "theta", "xdot", "ydot", "thetadot"};
// The plane of the circle of perturbations and of the plot: theta (odd under the biped's
// mirror symmetry x -> -x, theta -> -theta: it decides which foot lands first) and y (even).
// The kink shows only in even components of the image (the pieces differ in the ydot row of
// the jump), so a plane of two odd coordinates such as (theta, thetadot) would show a plain
// ellipse: B restricted to it and projected on it is linear.
constexpr int kPlane[2] = {kTheta, kY};

// Tight tolerances, so that integration error divided by alpha stays below the truncation
// error of the differences at kDifferenceStep.
constexpr double kRtol = 1e-10;
constexpr double kAtol = 1e-12;
// One-sided differences have a truncation error alpha |D^2 phi| |dx|^2 / 2 ~ 1e-7 here (the
// second derivative is O(1) on both sides of the touchdown; measured 7e-9 to 9.4e-8 relative
// on the table). Much smaller steps lose to rounding and the integration error divided by alpha.
constexpr double kDifferenceStep = 1e-7;
constexpr double kDifferenceTolerance = 1e-6;
// The touchdown is located on dopri5's dense output of a free fall (a quadratic in t, which
// the fifth-order method integrates exactly): rounding only.
constexpr double kTouchdownTolerance = 1e-12;
// B_sigma = Phi_1 M_sigma Phi_0 compared with Algorithm 2.1 and with each other on the cone
// boundary: products of 6 x 6 matrices with entries O(1)-O(10), a few hundred eps relative.
constexpr double kRoundingTolerance = 1e-12;
// The pieces of the mode-damping jump differ by O(beta) in a velocity row; the conservative
// and dissipative pieces are equal up to rounding ([B] Sections 3.2.2-3.2.3).
constexpr double kKinkLowerBound = 1e-2;

struct Direction {
  std::string label;
  Eigen::VectorXd dx;
};

Eigen::VectorXd unit(int i) { return Eigen::VectorXd::Unit(6, i); }

std::vector<Direction> table_directions() {
  return {
      {"e_x", unit(kX)},
      {"-e_x", -unit(kX)},
      {"e_theta", unit(kTheta)},
      {"-e_theta", -unit(kTheta)},
      {"e_xdot", unit(kXdot)},
      {"-e_xdot", -unit(kXdot)},
      {"e_thetadot", unit(kThetadot)},
      {"-e_thetadot", -unit(kThetadot)},
      {"e_y", unit(kY)},
      {"e_ydot", unit(kYdot)},
      {"e_theta+e_thetadot", unit(kTheta) + unit(kThetadot)},
      {"e_theta-e_thetadot", unit(kTheta) - unit(kThetadot)},
      {"e_x+e_y-e_theta", unit(kX) + unit(kY) - unit(kTheta)},
      {"-e_xdot+e_thetadot", unit(kThetadot) - unit(kXdot)},
  };
}

// Which foot the tangent arriving at the touchdown, Phi_0 dx, crosses first.
struct AtTouchdown {
  int piece;  // 0: foot 0 lands first (order (0,1)), 1: foot 1 first
  bool tie;   // both feet at the same perturbed time: dx is on the cone boundary
  std::vector<int> order;
};

AtTouchdown at_touchdown(const FlowDerivative& derivative, const Eigen::VectorXd& dx) {
  const JumpMap& jump = derivative.jumps()[0];
  const CrossingOrder order = jump.order(derivative.transitions()[0] * dx);
  const double scale = std::max(std::fabs(order.times[0]), std::fabs(order.times[1]));
  const bool tie = std::fabs(order.times[1] - order.times[0]) <= 1e-12 * scale;
  return {order.order[0] == 0 ? 0 : 1, tie, order.order};
}

std::string matrix_text(const std::string& name, const Eigen::MatrixXd& m,
                        const std::string& note) {
  std::string text;
  for (Eigen::Index r = 0; r < m.rows(); ++r) {
    text += "  " + (r == 0 ? name : std::string(name.size(), ' ')) + "[";
    for (Eigen::Index c = 0; c < m.cols(); ++c) {
      const double shown = std::fabs(m(r, c)) < 5e-7 ? 0.0 : m(r, c);
      text += formatted(" %9.5f", shown);
    }
    text += " ]";
    if (r == 0) text += "   " + note;
    text += '\n';
  }
  return text;
}

std::string short_vector_text(const Eigen::VectorXd& v) {
  std::string text = "(";
  for (Eigen::Index i = 0; i < v.size(); ++i) {
    const double shown = std::fabs(v[i]) < 5e-7 ? 0.0 : v[i];
    text += formatted("%8.4f", shown) + (i + 1 < v.size() ? "," : ")");
  }
  return text;
}

std::string gnuplot_script(double range) {
  const std::string b0 = "Φ_1 M_{(0,1)} Φ_0";
  const std::string b1 = "Φ_1 M_{(1,0)} Φ_0";
  std::ostringstream gp;
  gp << "# A circle of (theta, y) perturbations of the biped's initial state and its image under\n"
        "# B = D phi_0.6(x0; .), projected on (theta, y): [B] Figure 3.2, right.\n"
        "# Written by `bflow demo`; run in this directory: gnuplot demo_biped.gp\n"
        "set encoding utf8\n"
        "set terminal pngcairo size 800,800 enhanced font 'Sans,12'\n"
        "set output (exists('bflow_output') ? bflow_output : 'demo_biped.png')\n"
        "set title \"Biped with mode-dependent damping ([B] Sec. 3.2.4, Fig. 3.2): B-derivative "
        "of φ_{0.6}\\n"
        "the circle δx = cos a e_θ + sin a e_y at t = 0 and its image at t = 0.6 projected on "
        "(θ, y)\"\n"
        "set size ratio -1\n"
     << formatted("set xrange [%.3f:%.3f]\nset yrange [%.3f:%.3f]\n", -range, range, -range, range)
     << "set xlabel 'δθ'\n"
        "set ylabel 'δy'\n"
        "set grid lc rgb '#dddddd'\n"
        "set xzeroaxis lt 1 lc rgb '#aaaaaa'\n"
        "set yzeroaxis lt 1 lc rgb '#aaaaaa'\n"
        "set key outside bottom center horizontal maxcols 2 samplen 2 spacing 1.1\n"
        "data = 'demo_biped.dat'\n"
        "plot \\\n"
     << "  data index 1 using 2:3 with filledcurves xy=0,0 fs transparent solid 0.18 noborder"
        " fc rgb '"
     << gnuplot_color(0) << "' title 'cone where foot 0 lands first', \\\n"
     << "  data index 2 using 2:3 with filledcurves xy=0,0 fs transparent solid 0.18 noborder"
        " fc rgb '"
     << gnuplot_color(1) << "' title 'cone where foot 1 lands first', \\\n"
     << "  data index 1 using 4:5 with filledcurves xy=0,0 fs transparent solid 0.55 noborder"
        " fc rgb '"
     << gnuplot_color(0) << "' title 'image under " << b0 << "', \\\n"
     << "  data index 2 using 4:5 with filledcurves xy=0,0 fs transparent solid 0.55 noborder"
        " fc rgb '"
     << gnuplot_color(1) << "' title 'image under " << b1 << "', \\\n"
     << "  data index 0 using 2:3 with lines lw 2 lc rgb 'black' title 'δx, unit circle at t = 0', "
        "\\\n"
        "  data index 0 using 4:5 with lines lw 2.5 lc rgb '#B22222' title 'B(δx) at t = 0.6, a "
        "piecewise ellipse', \\\n"
     << formatted(
            "  data index 3 using (0):(0):(%.3f*$2):(%.3f*$3) with vectors nohead dt 2 lw 2"
            " lc rgb '#444444' title 'cone boundary ±e_y (feet land together)', \\\n",
            range * 1.5, range * 1.5)
     << "  data index 3 using 4:5 with points pt 7 ps 1.5 lc rgb '#B22222'"
        " title 'its image under B'\n";
  return gp.str();
}

double relative(const Eigen::VectorXd& error, const Eigen::VectorXd& reference) {
  return error.norm() / std::max(1.0, reference.norm());
}

}  // namespace

int demo_biped(const DemoOptions& options, std::ostream& out, std::ostream& /*err*/) {
  const BipedParams params;  // the defaults, mode-damping
  const auto model = adapt(make_biped_mode_damping(params));
  const Eigen::VectorXd x0 = biped_initial_state();
  FlowOptions flow;
  flow.integrator.rtol = kRtol;
  flow.integrator.atol = kAtol;

  out << "bflow demo: the B-derivative of the flow of the vertical-plane biped of [B] Section\n"
         "3.2.4 (Figure 3.2, right) with mode-dependent damping: each foot's damper is beta/2\n"
         "while it is the only foot down and beta with both down, so the order in which the\n"
         "feet land matters and the flow has a kink.\n"
         "\n"
         "  x = (x, y, theta, xdot, ydot, thetadot); legs at +-psi from the body's vertical;\n"
         "  ground y = -x^2; surface j = penetration of foot j (side + = foot j down)\n"
      << formatted("  m = %g, J = %g, g = %g, l = %g, psi = %.6f (pi/4), kappa = %g, beta = %g\n",
                   params.m, params.J, params.g, params.leg_length, params.psi, params.kappa,
                   params.beta)
      << "  phi_t from x0 = " << short_vector_text(x0) << " to t = " << kFinalTime << '\n'
      << "  " << to_string(choose_backend(flow.backend, kRtol, model.states(), model.surfaces()))
      << " (the automatic choice), rtol 1e-10, atol 1e-12; the B-derivative from one run of\n"
         "  flow_derivative()\n";

  FlowResult trajectory;
  const FlowDerivative derivative = flow_derivative(model, x0, kFinalTime, flow, &trajectory);
  if (trajectory.events.size() != 1 || trajectory.events[0].group_size() != 2) {
    std::string found;
    for (const EventRecord& e : trajectory.events) {
      found +=
          " t = " + format_number(e.t) + " with " + std::to_string(e.group_size()) + " surface(s);";
    }
    throw DemoError("demo: expected one touchdown event with both feet (2 surfaces), found " +
                    std::to_string(trajectory.events.size()) + " event(s):" + found);
  }
  const EventRecord& event = trajectory.events[0];
  const BipedTouchdown touchdown = biped_touchdown(params);
  const JumpMap& jump = derivative.jumps()[0];
  out << "\nTouchdown: one event, both feet at the same instant (" << event.group_size()
      << " surfaces)\n"
      << formatted("  t = %.12f   (closed form sqrt(2 (1 - y_td) / g) = %.12f)\n", event.t,
                   touchdown.time)
      << "  surfaces " << order_text(event.surfaces) << ", sides " << event.sides_before.str()
      << " -> " << event.sides_after.str() << '\n'
      << "  rho = " << short_vector_text(event.rho) << '\n'
      << formatted(
             "  eta_j . F / (|eta_j| |F|): before %.4f, %.4f; after %.4f, %.4f (transversal)\n",
             event.margin_before[0], event.margin_before[1], event.margin_after[0],
             event.margin_after[1])
      << "  x(" << kFinalTime << ") = " << short_vector_text(trajectory.x) << '\n';

  // The two pieces of the jump at the touchdown.
  const Eigen::MatrixXd m01 = jump.saltation({0, 1});
  const Eigen::MatrixXd m10 = jump.saltation({1, 0});
  std::vector<std::string> differing;
  for (Eigen::Index r = 0; r < m01.rows(); ++r) {
    if ((m01.row(r) - m10.row(r)).norm() > kRoundingTolerance * m01.norm()) {
      differing.push_back(kStateNames[r]);
    }
  }
  std::string rows_text;
  for (const std::string& name : differing) rows_text += (rows_text.empty() ? "" : ", ") + name;
  out << "\nThe two pieces of the touchdown jump ([B] (6.4), saltation matrices, first crossing\n"
         "right-most); they differ only in the "
      << (differing.size() == 1 ? rows_text + " row" : "rows " + rows_text) << ":\n\n"
      << matrix_text("M_(0,1) = ", m01, "foot 0 lands first")
      << matrix_text("M_(1,0) = ", m10, "foot 1 lands first")
      << formatted("\n  |M_(0,1) - M_(1,0)| = %.6f (Frobenius): B is continuous but not linear.\n",
                   (m01 - m10).norm());

  // The same jump for the other variants: their flows are C^1 ([B] Sections 3.2.2-3.2.3).
  double smooth_difference = 0.0;
  for (const BipedVariant variant : {BipedVariant::kConservative, BipedVariant::kDissipative}) {
    BipedParams other = params;
    other.variant = variant;
    const FlowDerivative d = flow_derivative(adapt(make_biped(other)), x0, kFinalTime, flow);
    if (d.events() != 1 || d.jumps()[0].surfaces() != 2) {
      throw DemoError(std::string("demo: the ") + biped_variant_name(variant) +
                      " biped does not touch down with both feet at one event");
    }
    const Eigen::MatrixXd a = d.jumps()[0].saltation({0, 1});
    const Eigen::MatrixXd b = d.jumps()[0].saltation({1, 0});
    const double difference = (a - b).norm() / a.norm();
    smooth_difference = std::max(smooth_difference, difference);
    out << formatted("  %-12s: |M_(0,1) - M_(1,0)| / |M_(0,1)| = %.1e (one piece: C^1 flow)\n",
                     biped_variant_name(variant), difference);
  }

  // The table.
  const std::vector<Direction> directions = table_directions();
  out << "\nB = D phi_" << kFinalTime
      << "(x0; dx) on directions dx, against finite differences of the simulated flow\n"
      << "(alpha = 1e-7). first: the foot that lands first on the perturbed trajectory\n"
      << "('=' both together: dx is on the boundary of the cones, where the pieces agree);\n"
         "one-sided: |(phi(x0 + a dx) - phi(x0))/a - B(dx)| / max(1, |B(dx)|), the ground truth\n"
         "of a B-derivative; central: the same for (phi(x0 + a dx) - phi(x0 - a dx))/(2a), which\n"
         "averages both pieces and is wrong wherever B is not linear along dx.\n\n"
      << "  dx                  first  B(dx) = (x, y, theta, xdot, ydot, thetadot) at t = 0.6"
         "       one-sided  central\n";
  double max_difference_error = 0.0;
  double max_piece_error = 0.0;
  bool seen[2] = {false, false};
  for (const Direction& row : directions) {
    const Eigen::VectorXd image = derivative.apply(row.dx);
    const AtTouchdown at = at_touchdown(derivative, row.dx);
    if (!at.tie) seen[at.piece] = true;
    max_piece_error = std::max(
        max_piece_error, relative(derivative.active_jacobian(row.dx) * row.dx - image, image));
    const Eigen::VectorXd one_sided =
        fd::one_sided(model, x0, kFinalTime, row.dx, kDifferenceStep, flow);
    const Eigen::VectorXd central =
        fd::central(model, x0, kFinalTime, row.dx, kDifferenceStep, flow);
    const double one_sided_error = relative(one_sided - image, image);
    max_difference_error = std::max(max_difference_error, one_sided_error);
    const std::string first = at.tie ? "=" : "foot " + std::to_string(at.order[0]);
    out << formatted("  %-18s  %-6s ", row.label.c_str(), first.c_str()) << short_vector_text(image)
        << formatted("  %.1e   %.1e\n", one_sided_error, relative(central - image, image));
  }
  if (!seen[0] || !seen[1]) {
    throw DemoError("demo: internal: the table does not visit both pieces");
  }

  // The circle of (theta, y) perturbations.
  const Eigen::MatrixXd b01 = derivative.transitions()[1] * m01 * derivative.transitions()[0];
  const Eigen::MatrixXd b10 = derivative.transitions()[1] * m10 * derivative.transitions()[0];
  const Eigen::MatrixXd piece_matrix[2] = {b01, b10};
  const auto embed = [](const Eigen::Vector2d& p) {
    Eigen::VectorXd dx = Eigen::VectorXd::Zero(6);
    dx[kPlane[0]] = p[0];
    dx[kPlane[1]] = p[1];
    return dx;
  };
  const auto project = [](const Eigen::VectorXd& v) {
    return Eigen::Vector2d(v[kPlane[0]], v[kPlane[1]]);
  };
  std::vector<Sample> circle;
  int count[2] = {0, 0};
  int ties = 0;
  double max_radius = 1.0;
  for (int k = 0; k < kCirclePoints; ++k) {
    const double degrees = 360.0 * k / kCirclePoints;
    const Eigen::Vector2d p(std::cos(degrees * kPi / 180.0), std::sin(degrees * kPi / 180.0));
    const Eigen::VectorXd dx = embed(p);
    const Eigen::VectorXd image = derivative.apply(dx);
    const AtTouchdown at = at_touchdown(derivative, dx);
    if (at.tie) {
      ++ties;
    } else {
      ++count[at.piece];
    }
    max_piece_error =
        std::max(max_piece_error, relative(piece_matrix[at.piece] * dx - image, image));
    max_radius = std::max(max_radius, project(image).norm());
    circle.push_back({degrees, p, project(image), at.piece});
  }

  // The cone boundary: the feet land together where the first-crossing times
  // -eta_j . v / (eta_j . F_--) of the arriving tangent v = Phi_0 dx are equal ([B] (6.8)),
  // i.e. on the hyperplane w . dx = 0. Its line in the plane, and a generic point of it.
  const Signs minus = Signs::all_minus(2);
  const Eigen::VectorXd f_minus = jump.limit(minus);
  const Eigen::MatrixXd& eta = jump.normals();
  const Eigen::VectorXd w =
      derivative.transitions()[0].transpose() * (eta.row(0).transpose() / eta.row(0).dot(f_minus) -
                                                 eta.row(1).transpose() / eta.row(1).dot(f_minus));
  const Eigen::Vector2d normal(w[kPlane[0]], w[kPlane[1]]);
  const Eigen::Vector2d boundary = Eigen::Vector2d(-normal[1], normal[0]).normalized();
  Eigen::VectorXd generic(6);
  generic << 1.0, -2.0, 3.0, -4.0, 5.0, -6.0;
  generic -= (w.dot(generic) / w.squaredNorm()) * w;
  double boundary_error = 0.0;
  for (const Eigen::VectorXd& p : {embed(boundary), generic}) {
    boundary_error = std::max(boundary_error, relative(b01 * p - b10 * p, derivative.apply(p)));
  }
  // Why the plot is not in the (theta, thetadot) plane: both pieces, restricted to it and
  // projected on it, agree (the mirror symmetry; see kPlane).
  double odd_plane_difference = 0.0;
  Eigen::MatrixXd odd_rows(2, 6);
  odd_rows.setZero();
  odd_rows(0, kTheta) = 1.0;
  odd_rows(1, kThetadot) = 1.0;
  for (int k = 0; k < kCirclePoints; ++k) {
    const double angle = 2.0 * kPi * k / kCirclePoints;
    const Eigen::VectorXd dx = std::cos(angle) * unit(kTheta) + std::sin(angle) * unit(kThetadot);
    odd_plane_difference =
        std::max(odd_plane_difference, (odd_rows * (b01 - b10) * dx).norm() /
                                           std::max(1.0, (odd_rows * b01 * dx).norm()));
  }
  out << "\nA circle of perturbations dx = cos a e_theta + sin a e_y (" << kCirclePoints
      << " points, every degree): foot 0\nlands first on " << count[0] << " of them, foot 1 on "
      << count[1] << ", both together on " << ties << ". The cones meet on the line through\n"
      << "dx = " << vector_text(boundary)
      << " in (theta, y): a level start lands both feet together, whatever\n"
         "the height. There, and on the whole hyperplane where the feet land together, the pieces\n"
         "B_(0,1) = Phi_1 M_(0,1) Phi_0 and B_(1,0) = Phi_1 M_(1,0) Phi_0 of B agree (Phi_0, "
         "Phi_1:\n"
         "the smooth transitions before and after the touchdown).\n"
         "The plot is in (theta, y) because the kink is in coordinates that are even under the\n"
         "mirror symmetry x -> -x, theta -> -theta (the pieces differ in the ydot row only): on "
         "the\n"
         "(theta, thetadot) plane, projected on it, they differ by at most "
      << formatted("%.1e", odd_plane_difference)
      << " (relative),\nso the image of a circle there is a plain ellipse.\n";

  const std::vector<Check> checks = {
      {"|t_event - closed form|, both feet touch together from rest",
       std::fabs(event.t - touchdown.time), kTouchdownTolerance},
      {"max |B(dx) - B_sigma dx| / |B(dx)|, table and circle (Algorithm 2.1 against the piece)",
       max_piece_error, kRoundingTolerance},
      {"max |B_(0,1) p - B_(1,0) p| / |B(p)|, p on the cone boundary (in the plane, generic)",
       boundary_error, kRoundingTolerance},
      {"max one-sided |FD - B(dx)| / max(1, |B(dx)|), alpha = 1e-7, the table",
       max_difference_error, kDifferenceTolerance},
      {"|M_(0,1) - M_(1,0)|, mode-damping: a true kink", (m01 - m10).norm(), kKinkLowerBound, true},
      {"max |M_(0,1) - M_(1,0)| / |M|, conservative and dissipative: C^1 flows", smooth_difference,
       kRoundingTolerance},
  };
  const bool all_passed = print_checks(out, checks);

  // Files: the circle, the arcs of each piece bounded by the exact boundary rays, the rays.
  const fs::path dir(options.output_dir);  // made and probed by run_demo()
  std::vector<Sample> boundary_samples;
  for (double sign : {1.0, -1.0}) {
    const Eigen::Vector2d p = sign * boundary;
    double degrees = std::atan2(p[1], p[0]) * 180.0 / kPi;
    if (degrees < 0) degrees += 360.0;
    boundary_samples.push_back({degrees, p, project(derivative.apply(embed(p))), -1});
  }
  std::vector<std::vector<Sample>> arcs(2);
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
    const int piece =
        at_touchdown(derivative, embed(Eigen::Vector2d(-start.dx[1], start.dx[0]))).piece;
    for (Sample& s : arc) s.piece = piece;
    arcs[static_cast<std::size_t>(piece)] = std::move(arc);
  }
  if (arcs[0].empty() || arcs[1].empty()) {
    throw DemoError("demo: internal: both arcs fall in one piece");
  }

  std::ostringstream dat;
  dat << "# A circle of perturbations dx = cos a e_theta + sin a e_thetadot of the biped's "
         "initial\n"
         "# state (0,1,0,0,0,0) and its image under B = D phi_0.6(x0; .), projected on\n"
         "# (theta, thetadot). Mode-damping biped of [B] Section 3.2.4. Written by `bflow demo`;\n"
         "# drawn by demo_biped.gp.\n"
         "# Columns: a_deg dtheta dthetadot B(dx)_theta B(dx)_thetadot piece\n"
         "#   piece 0: foot 0 lands first, B = Phi_1 M_(0,1) Phi_0\n"
         "#   piece 1: foot 1 lands first, B = Phi_1 M_(1,0) Phi_0\n"
      << "# index 0: " << kCirclePoints
      << " points of the circle, every degree, and the first again\n";
  write_samples(dat, circle);
  write_samples(dat, {circle.front()});
  for (std::size_t k = 0; k < arcs.size(); ++k) {
    dat << "\n\n# index " << k + 1 << ": the arc where piece " << k
        << " is active, from boundary ray to boundary ray\n";
    write_samples(dat, arcs[k]);
  }
  dat << "\n\n# index 3: the boundary rays of the cones and their images\n";
  write_samples(dat, boundary_samples);

  const fs::path dat_path = dir / "demo_biped.dat";
  const fs::path gp_path = dir / "demo_biped.gp";
  const fs::path png_path = dir / "demo_biped.png";
  write_file(dat_path, dat.str());
  write_file(gp_path, gnuplot_script(std::ceil(max_radius * 12.0) / 10.0));
  out << "\nWrote " << dat_path.string() << " (the circle at " << kCirclePoints
      << " points and its image under B)\n"
      << "Wrote " << gp_path.string() << '\n';
  if (options.no_plot) {
    out << "Skipped the plot (--no-plot); to draw " << png_path.string() << ": cd " << dir.string()
        << " && gnuplot demo_biped.gp\n";
  } else {
    out << "Running gnuplot demo_biped.gp in " << dir.string() << '\n' << std::flush;
    run_gnuplot(dir, "demo_biped.gp", "demo_biped.png");
    out << png_path.string() << '\n';
  }
  return all_passed ? kExitOk : kExitFailure;
}

}  // namespace bflow::cli

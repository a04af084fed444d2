#include "bflow/orbits/periodic_orbit.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <complex>
#include <cstdlib>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Dense>

#include "bflow/core/errors.h"
#include "bflow/orbits/internal/growth_cones.h"

namespace bflow {
namespace {

using Eigen::MatrixXcd;
using Eigen::MatrixXd;
using Eigen::VectorXd;

double inf_norm(const VectorXd& v) { return v.size() == 0 ? 0.0 : v.cwiseAbs().maxCoeff(); }

// Quoted input in messages: at most 60 characters of it.
std::string shortened(const std::string& text) {
  return text.size() <= 60
             ? text
             : text.substr(0, 60) + "... (" + std::to_string(text.size()) + " characters)";
}

// The model with the section appended as surface n: the field ignores the section's side, so
// the section's crossings are events at which nothing jumps. Used only to locate the return.
class SectionModel final : public SegmentModel {
 public:
  SectionModel(const SegmentModel& base, const PoincareSection& section)
      : base_(base), section_(section), n_(base.surfaces()) {}
  int states() const override { return base_.states(); }
  int surfaces() const override { return n_ + 1; }
  void field(const double* x, Signs b, double* xdot) const override {
    base_.field(x, strip(b), xdot);
  }
  void field(const Jet1* x, Signs b, Jet1* xdot) const override { base_.field(x, strip(b), xdot); }
  void field(const Jet2* x, Signs b, Jet2* xdot) const override { base_.field(x, strip(b), xdot); }
  void field(const Jet4* x, Signs b, Jet4* xdot) const override { base_.field(x, strip(b), xdot); }
  void field(const Jet6* x, Signs b, Jet6* xdot) const override { base_.field(x, strip(b), xdot); }
  void field(const JetChunk* x, Signs b, JetChunk* xdot) const override {
    base_.field(x, strip(b), xdot);
  }
  void field(const Jet12* x, Signs b, Jet12* xdot) const override {
    base_.field(x, strip(b), xdot);
  }
  void field(const Jet16* x, Signs b, Jet16* xdot) const override {
    base_.field(x, strip(b), xdot);
  }
  void field_tangents(const Eigen::Ref<const VectorXd>& x, Signs b,
                      const Eigen::Ref<const MatrixXd>& v, Eigen::Ref<VectorXd> f,
                      Eigen::Ref<MatrixXd> fv) const override {
    base_.field_tangents(x, strip(b), v, f, fv);
  }
  void surface_values(const double* x, double* h) const override {
    if (n_ > 0) base_.surface_values(x, h);
    h[n_] = section_.value(Eigen::Map<const VectorXd>(x, states()));
  }
  MatrixXd surface_normals(const Eigen::Ref<const VectorXd>& x) const override {
    MatrixXd normals(n_ + 1, states());
    if (n_ > 0) normals.topRows(n_) = base_.surface_normals(x);
    normals.row(n_) = section_.gradient(x).transpose();
    return normals;
  }

 private:
  Signs strip(Signs b) const {
    return Signs(n_, b.bits() & ((n_ >= 64) ? ~std::uint64_t{0} : ((std::uint64_t{1} << n_) - 1)));
  }
  const SegmentModel& base_;
  const PoincareSection& section_;
  int n_;
};

void check_options(const OrbitOptions& o) {
  auto bad = [](const std::string& what) { throw InvalidArgument("OrbitOptions: " + what); };
  if (!(o.tolerance > 0.0 && std::isfinite(o.tolerance)))
    bad("tolerance must be finite and > 0, got " + format_number(o.tolerance));
  if (o.max_newton_iterations < 0)
    bad("max_newton_iterations must be >= 0, got " + std::to_string(o.max_newton_iterations));
  if (o.max_backtracks < 0)
    bad("max_backtracks must be >= 0, got " + std::to_string(o.max_backtracks));
  if (!(o.max_return_time > 0.0 && std::isfinite(o.max_return_time)))
    bad("max_return_time must be finite and > 0, got " + format_number(o.max_return_time));
  if (!(o.return_search_window > 0.0 && std::isfinite(o.return_search_window)))
    bad("return_search_window must be finite and > 0, got " +
        format_number(o.return_search_window));
  if (!(o.return_search_window * static_cast<double>(OrbitOptions::kMaxReturnWindows) >=
        o.max_return_time))
    bad("return_search_window = " + format_number(o.return_search_window) +
        " would take more than " + std::to_string(OrbitOptions::kMaxReturnWindows) +
        " windows to cover max_return_time = " + format_number(o.max_return_time) +
        "; give a window of at least " +
        format_number(o.max_return_time / static_cast<double>(OrbitOptions::kMaxReturnWindows)));
  if (o.max_backtracks > OrbitOptions::kMaxBacktracks)
    bad("max_backtracks must be <= " + std::to_string(OrbitOptions::kMaxBacktracks) +
        " (a step halved that often is below the round-off of any point), got " +
        std::to_string(o.max_backtracks));
  if (!(o.min_return_time >= 0.0 && o.min_return_time < o.max_return_time))
    bad("min_return_time must be in [0, max_return_time), got " + format_number(o.min_return_time));
  internal::check_growth_options(o);
}

// The section checked against the model once: its own check, then its value and gradient at x
// (finite, d numbers).
void check_section(const char* who, const PoincareSection& section, int d, const VectorXd& x) {
  try {
    section.check(d);
  } catch (const InvalidArgument& e) {
    throw InvalidArgument(std::string(who) + ": " + e.what());
  }
  const VectorXd g = section.gradient(x);
  if (g.size() != d) {
    throw InvalidArgument(std::string(who) + ": the section's gradient has " +
                          std::to_string(g.size()) + " entries, the model " + std::to_string(d) +
                          " states");
  }
  const double s = section.value(x);
  if (!std::isfinite(s) || !g.allFinite()) {
    throw InvalidArgument(std::string(who) + ": the section is not finite at the point (s = " +
                          format_number(s) + ", |Ds| = " + format_number(g.norm()) + ")");
  }
}

// Ds(x), checked: d finite numbers, not all zero.
VectorXd section_gradient(const PoincareSection& section, const VectorXd& x) {
  VectorXd g = section.gradient(x);
  if (g.size() != x.size() || !g.allFinite() || !(g.cwiseAbs().maxCoeff() > 0.0)) {
    throw InvalidArgument(
        "the section's gradient at the point is " +
        (g.size() != x.size()
             ? std::to_string(g.size()) + " numbers for " + std::to_string(x.size()) + " states"
             : "zero or not finite (|Ds| = " + format_number(g.norm()) + ")"));
  }
  return g;
}

void check_point(const char* who, const SegmentModel& model, const Eigen::Ref<const VectorXd>& x) {
  if (x.size() != model.states()) {
    throw InvalidArgument(std::string(who) + ": the point has " + std::to_string(x.size()) +
                          " entries, the model " + std::to_string(model.states()) + " states");
  }
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    if (!std::isfinite(x[i])) {
      throw InvalidArgument(std::string(who) + ": entry " + std::to_string(i) +
                            " of the point is " + format_number(x[i]));
    }
  }
}

// OrbitOptions::flow, checked up front as the simulations would check it: a value they refuse
// would otherwise surface only as a return map that fails, and Newton's run would end with
// converged = false instead of the InvalidArgument the options deserve.
void check_flow_options(const char* who, const SegmentModel& model, const FlowOptions& flow) {
  const auto bad = [&](const std::string& what) {
    throw InvalidArgument(std::string(who) + ": OrbitOptions::flow: " + what);
  };
  const IntegratorOptions& i = flow.integrator;
  if (!(i.rtol >= IntegratorOptions::kMinRtol && std::isfinite(i.rtol))) {
    bad("integrator.rtol must be finite and >= " + format_number(IntegratorOptions::kMinRtol) +
        ", got " + format_number(i.rtol));
  }
  if (!(i.absolute_tolerance() >= IntegratorOptions::kMinAtol &&
        std::isfinite(i.absolute_tolerance()))) {
    bad("integrator.atol must be finite and >= " + format_number(IntegratorOptions::kMinAtol) +
        ", got " + format_number(i.absolute_tolerance()));
  }
  if (!(i.initial_step >= 0.0 && std::isfinite(i.initial_step)) ||
      !(i.min_step >= 0.0 && std::isfinite(i.min_step)) || !(i.max_step > 0.0)) {
    bad("integrator.initial_step and min_step must be finite and >= 0 and max_step > 0, got " +
        format_number(i.initial_step) + ", " + format_number(i.min_step) + ", " +
        format_number(i.max_step));
  }
  if (i.max_steps < 1) bad("integrator.max_steps must be >= 1, got " + std::to_string(i.max_steps));
  if (flow.backend != Backend::kDopri5 && flow.backend != Backend::kDop853 &&
      flow.backend != Backend::kCvodesBdf && flow.backend != Backend::kCvodesAdams &&
      flow.backend != Backend::kAutomatic) {
    bad("backend " + std::to_string(static_cast<int>(flow.backend)) + " is not a Backend");
  }
  if (flow.grouping != Grouping::kAutomatic && flow.grouping != Grouping::kFixedWindow &&
      flow.grouping != Grouping::kNone) {
    bad("grouping " + std::to_string(static_cast<int>(flow.grouping)) + " is not a Grouping");
  }
  if (!(flow.grouping_safety > 0.0 && std::isfinite(flow.grouping_safety)) ||
      !(flow.simultaneity_window >= 0.0 && std::isfinite(flow.simultaneity_window)) ||
      !(flow.near_simultaneity_band >= 1.0 && std::isfinite(flow.near_simultaneity_band))) {
    bad("need a finite grouping_safety > 0, simultaneity_window >= 0 and near_simultaneity_band "
        ">= 1, got " +
        format_number(flow.grouping_safety) + ", " + format_number(flow.simultaneity_window) +
        ", " + format_number(flow.near_simultaneity_band));
  }
  if (!(flow.grazing_threshold >= 0.0 && flow.grazing_threshold < 1.0)) {
    bad("grazing_threshold must be in [0, 1), got " + format_number(flow.grazing_threshold));
  }
  // The section's crossing is an event of the search: with no event allowed there is no return.
  if (flow.max_events < 1) bad("max_events must be >= 1, got " + std::to_string(flow.max_events));
  if (flow.initial_sides && flow.initial_sides->size() != model.surfaces()) {
    bad("initial_sides \"" + shortened(flow.initial_sides->str()) + "\" names " +
        std::to_string(flow.initial_sides->size()) + " surfaces, the model has " +
        std::to_string(model.surfaces()));
  }
}

// The sides of the model's surfaces at x: the given ones or the signs of h(x).
Signs sides_at(const SegmentModel& model, const VectorXd& x, const FlowOptions& flow) {
  const int n = model.surfaces();
  if (flow.initial_sides) return *flow.initial_sides;
  VectorXd h(n);
  if (n > 0) model.surface_values(x.data(), h.data());
  std::uint64_t bits = 0;
  for (int j = 0; j < n; ++j) {
    if (!(h[j] != 0.0) || !std::isfinite(h[j])) {
      throw InvalidArgument("return_map: surface " + std::to_string(j) +
                            " has h = " + format_number(h[j]) +
                            " at the point, so its side is undecided; set "
                            "OrbitOptions::flow.initial_sides");
    }
    if (h[j] > 0.0) bits |= std::uint64_t{1} << j;
  }
  return Signs(n, bits);
}

// x moved onto the section along Ds (a few Newton steps on s).
// Returns false when 30 steps do not bring |s| / |Ds| below 1e-14 (1 + |x|).
bool project(const PoincareSection& section, VectorXd& x) {
  for (int k = 0; k < 30; ++k) {
    const double s = section.value(x);
    VectorXd g;
    try {
      g = section_gradient(section, x);
    } catch (const InvalidArgument& e) {
      throw InvalidArgument(std::string("projecting onto the section: ") + e.what());
    }
    const double scale = g.cwiseAbs().maxCoeff();
    const VectorXd unit = g / scale;  // no overflow in |Ds|^2
    const double gg = unit.squaredNorm();
    if (!std::isfinite(s)) return false;
    if (std::abs(s / scale) <= 1e-14 * (1.0 + inf_norm(x)) * std::sqrt(gg)) return true;
    x -= (s / scale / gg) * unit;
    if (!x.allFinite()) return false;
  }
  return false;
}

VectorXd projected(const PoincareSection& section, VectorXd x, const char* what) {
  if (!project(section, x)) {
    throw InvalidArgument(std::string(what) +
                          ": 30 Newton steps along Ds did not bring it onto the section (|s| = " +
                          format_number(std::abs(section.value(x))) + " at the last)");
  }
  return x;
}

// The number of pieces of map: the product over events of (surfaces crossed together)!, as a
// double (no overflow).
double piece_count(const FlowDerivative& map) {
  double count = 1.0;
  for (const std::vector<int>& surfaces : map.event_surfaces()) {
    for (std::size_t k = 2; k <= surfaces.size(); ++k) count *= static_cast<double>(k);
  }
  return count;
}

// |B^T DP(B c) - c - rhs|_2.
double equation_residual(const FlowDerivative& map, const MatrixXd& basis, const VectorXd& c,
                         const VectorXd& rhs) {
  return (basis.transpose() * map.apply(basis * c) - c - rhs).stableNorm();
}

// d^2/dt^2 s(phi_t(x)) at t = 0, the derivative of Ds . F along F by a central difference:
// where the flow is tangent to the section, its sign says to which side the flow leaves it.
double section_acceleration(const SegmentModel& model, const PoincareSection& section,
                            const VectorXd& x, Signs sides, const VectorXd& f) {
  const double speed = inf_norm(f);
  if (!(speed > 0.0)) return 0.0;
  const double h = 1e-6 * (1.0 + inf_norm(x)) / speed;
  const auto rate = [&](const VectorXd& y) {
    VectorXd fy(y.size());
    model.field(y.data(), sides, fy.data());
    return section.gradient(y).dot(fy);
  };
  const double acceleration = (rate(x + h * f) - rate(x - h * f)) / (2.0 * h);
  return std::isfinite(acceleration) ? acceleration : 0.0;
}

}  // namespace

void CoordinateSection::check(int states) const {
  if (index < 0 || index >= states) {
    throw InvalidArgument("CoordinateSection: index " + std::to_string(index) +
                          " is not a state of the model (0 ... " + std::to_string(states - 1) +
                          ")");
  }
  if (!std::isfinite(value) || !(sign == 1.0 || sign == -1.0)) {
    throw InvalidArgument("CoordinateSection: value must be finite and sign +1 or -1, got value " +
                          format_number(value) + ", sign " + format_number(sign));
  }
}

void HyperplaneSection::check(int states) const {
  if (normal.size() != states) {
    throw InvalidArgument("HyperplaneSection: the normal has " + std::to_string(normal.size()) +
                          " entries, the model " + std::to_string(states) + " states");
  }
  for (Eigen::Index i = 0; i < normal.size(); ++i) {
    if (!std::isfinite(normal[i])) {
      throw InvalidArgument("HyperplaneSection: normal[" + std::to_string(i) + "] is " +
                            format_number(normal[i]) + "; it must be finite");
    }
  }
  if (!std::isfinite(offset)) {
    throw InvalidArgument("HyperplaneSection: the offset is " + format_number(offset) +
                          "; it must be finite");
  }
  if (normal.cwiseAbs().maxCoeff() == 0.0) {
    throw InvalidArgument("HyperplaneSection: the normal is zero: no hyperplane");
  }
}

CoordinateSection parse_coordinate_section(const std::string& text, int states) {
  auto fail = [&](const std::string& why) {
    throw InvalidArgument("section \"" + shortened(text) + "\": " + why +
                          " (write x4, -x4, x1=0.3 or -x1=0.3: s = +-(x_i - value), crossed from "
                          "s < 0 to s > 0)");
  };
  CoordinateSection section;
  std::size_t at = 0;
  if (at < text.size() && (text[at] == '-' || text[at] == '+')) {
    section.sign = text[at] == '-' ? -1.0 : 1.0;
    ++at;
  }
  if (at >= text.size() || text[at] != 'x') fail("expected x followed by a state index");
  ++at;
  const std::size_t digits = at;
  while (at < text.size() && text[at] >= '0' && text[at] <= '9') ++at;
  if (at == digits || at - digits > 6) fail("expected a state index after x");
  section.index = std::stoi(text.substr(digits, at - digits));
  if (section.index >= states) {
    fail("state index " + std::to_string(section.index) + " is not below the " +
         std::to_string(states) + " states");
  }
  if (at < text.size()) {
    if (text[at] != '=') fail("expected = after the index");
    const std::string number = text.substr(at + 1);
    char* end = nullptr;
    errno = 0;
    const double value = std::strtod(number.c_str(), &end);
    if (number.empty() || end != number.c_str() + number.size() || !std::isfinite(value)) {
      fail("\"" + shortened(number) + "\" is not a finite number");
    }
    if (errno == ERANGE || (value != 0.0 && std::abs(value) < std::numeric_limits<double>::min())) {
      fail("\"" + shortened(number) + "\" underflows (its magnitude is below " +
           format_number(std::numeric_limits<double>::min()) + ")");
    }
    section.value = value;
  }
  return section;
}

std::string to_string(const CoordinateSection& section) {
  std::string text = section.sign < 0.0 ? "-x" : "x";
  text += std::to_string(section.index);
  if (section.value != 0.0) text += "=" + format_number(section.value);
  return text;
}

const char* to_string(OrbitStability stability) {
  switch (stability) {
    case OrbitStability::kStable:
      return "stable";
    case OrbitStability::kUnstable:
      return "unstable";
    case OrbitStability::kUndecided:
      return "undecided";
  }
  return "undecided";
}

FlowOptions default_orbit_flow_options() {
  FlowOptions options;
  options.integrator.rtol = 1e-10;
  options.integrator.atol = 1e-12;
  // The return map's derivative is what the verdict reads: its error is held to the tolerance
  // too (every flow's default, stated here because the verdict depends on it). On a symmetric
  // orbit (the biped's and the pronk's hops) the state's own error estimate does not see the
  // tangents that break the symmetry; with the state alone the pronk's bracket is off by 1e-3
  // (upper 0.745588 against 0.744672).
  options.integrator.tangents_in_error_norm = true;
  // dopri5 named, not the flow's automatic choice (dop853 at this tolerance): on the pronk's
  // orbit dop853 holds the return map's tether block to 1.0e-9 of its closed form and the
  // bracket's top to 9.4e-4 of the rate, dopri5 to 4e-11 and 1.7e-5 (tests/orbits).
  options.backend = Backend::kDopri5;
  return options;
}

MatrixXd orthogonal_complement(const Eigen::Ref<const VectorXd>& g) {
  const int d = static_cast<int>(g.size());
  const double scale = d == 0 ? 0.0 : g.cwiseAbs().maxCoeff();
  if (!(scale > 0.0) || !g.allFinite()) {
    throw InvalidArgument(
        "orthogonal_complement: the vector must be finite and nonzero, its largest entry is " +
        format_number(scale) + (g.allFinite() ? "" : " (an entry is not finite)"));
  }
  // Scaled to a largest entry of 1: |g|^2 neither overflows nor underflows.
  Eigen::HouseholderQR<MatrixXd> qr(VectorXd(g / scale));
  const MatrixXd q = qr.householderQ() * MatrixXd::Identity(d, d);
  return q.rightCols(d - 1);
}

NewtonEquationSolution solve_newton_equation(const FlowDerivative& map,
                                             const Eigen::Ref<const MatrixXd>& basis_in,
                                             const Eigen::Ref<const VectorXd>& rhs_in,
                                             long max_pieces) {
  const MatrixXd basis = basis_in;
  const VectorXd rhs = rhs_in;
  const int m = static_cast<int>(basis.cols());
  if (basis.rows() != map.dim() || rhs.size() != m) {
    throw InvalidArgument("solve_newton_equation: the basis is " + std::to_string(basis.rows()) +
                          " x " + std::to_string(m) + " and the right-hand side has " +
                          std::to_string(rhs.size()) + " entries for a map of dimension " +
                          std::to_string(map.dim()) + " (expected " + std::to_string(map.dim()) +
                          " x m and m)");
  }
  if (!basis.allFinite() || !rhs.allFinite()) {
    throw InvalidArgument("solve_newton_equation: the basis or the right-hand side is not finite");
  }
  if (!(max_pieces >= 1 && static_cast<unsigned long>(max_pieces) <= FlowDerivative::kMaxPieces)) {
    throw InvalidArgument("solve_newton_equation: max_pieces must be in [1, " +
                          std::to_string(FlowDerivative::kMaxPieces) +
                          "] (FlowDerivative::kMaxPieces), got " + std::to_string(max_pieces));
  }
  NewtonEquationSolution out;
  const MatrixXd identity = MatrixXd::Identity(m, m);
  // stableNorm: |rhs| and |c| overflow only beyond the double range, not when their squares do.
  const double scale = 1.0 + rhs.stableNorm();
  if (!std::isfinite(scale)) {
    throw InvalidArgument("solve_newton_equation: |rhs| overflows (its largest entry is " +
                          format_number(rhs.cwiseAbs().maxCoeff()) + ")");
  }
  // A solution of the equation on the map itself, to round-off of the pieces' size; a residual
  // or a c whose size overflows proves nothing.
  auto solves = [&](const VectorXd& c, double residual) {
    const double bound = 1e-9 * (scale + c.stableNorm());
    return std::isfinite(residual) && std::isfinite(bound) && residual <= bound;
  };
  const MatrixXd at_rhs = basis.transpose() * map.active_jacobian(basis * rhs) * basis;
  auto same_piece = [](const MatrixXd& a, const MatrixXd& b) {
    return (a - b).norm() <= FlowDerivative::kLinearTolerance * (1.0 + b.norm());
  };
  if (m == 0) {
    out.c = VectorXd::Zero(0);
    out.solutions.push_back(out.c);
    out.pieces_checked = 1;
    return out;
  }
  VectorXd best;
  double best_residual = std::numeric_limits<double>::infinity();
  if (piece_count(map) <= static_cast<double>(max_pieces)) {
    std::vector<MatrixXd> seen;
    for (const FlowPiece& piece : map.pieces()) {
      const MatrixXd a = basis.transpose() * piece.matrix * basis;
      if (std::any_of(seen.begin(), seen.end(),
                      [&](const MatrixXd& b) { return same_piece(a, b); }))
        continue;
      seen.push_back(a);
      const Eigen::CompleteOrthogonalDecomposition<MatrixXd> cod(a - identity);
      if (cod.rank() < m) ++out.singular_pieces;
      const VectorXd c = cod.solve(rhs);
      if (!c.allFinite()) continue;
      const double residual = equation_residual(map, basis, c, rhs);
      if (residual < best_residual) {
        best_residual = residual;
        best = c;
      }
      if (!solves(c, residual)) continue;
      const bool known = std::any_of(
          out.solutions.begin(), out.solutions.end(),
          [&](const VectorXd& other) { return (other - c).norm() <= 1e-8 * (1.0 + c.norm()); });
      if (!known) out.solutions.push_back(c);
    }
    out.pieces_checked = static_cast<int>(seen.size());
  } else {
    // Too many pieces to enumerate: iterate on the active piece from the right-hand side.
    out.exhaustive = false;
    VectorXd probe = rhs;
    for (int round = 1; round <= 50; ++round) {
      out.rounds = round;
      const MatrixXd a = basis.transpose() * map.active_jacobian(basis * probe) * basis - identity;
      const VectorXd c = a.completeOrthogonalDecomposition().solve(rhs);
      if (!c.allFinite()) break;
      const double residual = equation_residual(map, basis, c, rhs);
      if (residual < best_residual) {
        best_residual = residual;
        best = c;
      }
      if (solves(c, residual)) {
        out.solutions.push_back(c);
        break;
      }
      if (!(c.norm() > 0.0)) break;
      probe = c;
    }
    out.pieces_checked = out.rounds;
  }
  std::sort(out.solutions.begin(), out.solutions.end(),
            [](const VectorXd& a, const VectorXd& b) { return a.norm() < b.norm(); });
  out.c = out.solutions.empty() ? (best.size() == m ? best : VectorXd(VectorXd::Zero(m)))
                                : out.solutions.front();
  out.residual = equation_residual(map, basis, out.c, rhs);
  if (out.c.norm() > 0.0) {
    out.piece_changed =
        !same_piece(basis.transpose() * map.active_jacobian(basis * out.c) * basis, at_rhs);
  }
  return out;
}

ReturnMap return_map(const SegmentModel& model, const PoincareSection& section,
                     const Eigen::Ref<const VectorXd>& x_in, const OrbitOptions& options) {
  check_options(options);
  check_point("return_map", model, x_in);
  check_flow_options("return_map", model, options.flow);
  const VectorXd x = x_in;
  const int n = model.surfaces();
  const int d = model.states();
  check_section("return_map", section, d, x);
  const Signs sides = sides_at(model, x, options.flow);
  if (sides.size() != n) {
    throw InvalidArgument("return_map: initial_sides has " + std::to_string(sides.size()) +
                          " surfaces, the model " + std::to_string(n));
  }
  // Crossings of the section before the flow has moved x by more than 100 times the integration
  // tolerance are round-off (x on the section, s(x) = -1e-17): they do not count. A point the
  // flow cannot move that far within max_return_time is (nearly) an equilibrium: no period.
  VectorXd f0(d);
  model.field(x.data(), sides, f0.data());
  if (!f0.allFinite()) {
    throw InvalidArgument("return_map: the field is not finite at the point (|F| = " +
                          format_number(f0.norm()) + ")");
  }
  const IntegratorOptions& integ = options.flow.integrator;
  const double floor = 100.0 * (integ.absolute_tolerance() + integ.rtol * inf_norm(x));
  const double speed = inf_norm(f0);
  if (!(speed * options.max_return_time > floor)) {
    throw InvalidArgument(
        "return_map: the point is (nearly) an equilibrium: |F(x)| = " + format_number(speed) +
        " moves it by at most " + format_number(speed * options.max_return_time) + " within " +
        format_number(options.max_return_time) +
        ", not more than 100 times the integration tolerance " + format_number(floor / 100.0));
  }
  const double earliest = std::max(options.min_return_time, floor / speed);
  // Locate the return on the model with the section as an extra surface, window by window. The
  // section's side at x: its sign, and on the section (to the projection's round-off) the side
  // the flow heads to, to first order or, where the flow is tangent to the section (a body at
  // rest on a section through its height), to second. The driver takes a surface found on the
  // other side of its side bit for one being crossed: a wrong side at a tangent start would
  // lump the section into the first event of the model (a touchdown whose normals the
  // section's then makes dependent) instead of being crossed where the flow meets it.
  const SectionModel augmented(model, section);
  FlowOptions search = options.flow;
  const double s0 = section.value(x);
  const VectorXd g0 = section.gradient(x);
  const double rate0 = g0.dot(f0);
  bool above = s0 > 0.0;
  if (std::abs(s0) <= 1e-14 * (1.0 + inf_norm(x)) * g0.norm()) {
    above = std::abs(rate0) > 1e-12 * g0.norm() * f0.norm()
                ? rate0 > 0.0
                : section_acceleration(model, section, x, sides, f0) > 0.0;
  }
  std::uint64_t bits = sides.bits();
  if (above) bits |= std::uint64_t{1} << n;
  Signs aug_sides(n + 1, bits);
  VectorXd y = x;
  double elapsed = 0.0;
  double tau = -1.0;
  long steps_left = integ.max_steps;
  ReturnMap out;
  for (long window_index = 0; tau < 0.0; ++window_index) {
    if (elapsed >= options.max_return_time || window_index >= OrbitOptions::kMaxReturnWindows) {
      throw InvalidArgument("return_map: no crossing of the section from s < 0 to s > 0 within " +
                            format_number(options.max_return_time) +
                            " after leaving the point (OrbitOptions::max_return_time)");
    }
    const double window = std::min(options.return_search_window, options.max_return_time - elapsed);
    search.initial_sides = aug_sides;
    search.integrator.max_steps = steps_left;
    FlowResult run;
    try {
      run = simulate(augmented, y, window, search);
    } catch (const InvalidArgument& e) {
      // An event the search cannot resolve as grouped (the section crossed where the model's
      // surfaces are, normals dependent there): the search needs only the crossing times, so it
      // resolves every crossing on its own; the return map's derivative does not use it.
      if (search.grouping == Grouping::kNone) {
        throw InvalidArgument("return_map: searching for the return at t = " +
                              format_number(elapsed) + ": " + e.what());
      }
      search.grouping = Grouping::kNone;
      out.decisions.push_back(
          "the search for the return resolved each crossing on its own from t = " +
          format_number(elapsed) +
          ", because an event grouped with the section failed: " + e.what());
      --window_index;
      continue;
    }
    steps_left -= run.steps;
    if (!run.ok()) {
      const bool budget = run.status == IntegrationStatus::kTooManySteps;
      throw InvalidArgument("return_map: the simulation stopped at t = " +
                            format_number(elapsed + run.t) + ": " + run.message +
                            (budget ? " (the search for the return has a budget of " +
                                          std::to_string(integ.max_steps) +
                                          " steps in all: IntegratorOptions::max_steps)"
                                    : std::string()));
    }
    for (const EventRecord& event : run.events) {
      const bool section_up =
          std::find(event.surfaces.begin(), event.surfaces.end(), n) != event.surfaces.end() &&
          event.sides_after.plus(n) && !event.sides_before.plus(n);
      const double t = elapsed + event.t;
      if (section_up && t > earliest) {
        tau = t;
        break;
      }
    }
    y = run.x;
    aug_sides = run.sides;
    elapsed += window;
  }
  // The flow's B-derivative up to tau on the model itself, then the projection onto the section.
  FlowOptions flow = options.flow;
  flow.initial_sides = sides;
  FlowResult trajectory;
  FlowDerivative derivative = flow_derivative(model, x, tau, flow, &trajectory);
  VectorXd f(d);
  model.field(trajectory.x.data(), trajectory.sides, f.data());
  const VectorXd g = section_gradient(section, trajectory.x);
  const double rate = g.dot(f);
  if (!(std::abs(rate) > 1e-12 * g.norm() * f.norm()) || !std::isfinite(rate)) {
    throw InvalidArgument("return_map: the trajectory grazes the section at t = " +
                          format_number(tau) + " (Ds . F = " + format_number(rate) + ")");
  }
  const double shift = -section.value(trajectory.x) / rate;
  out.x = x;
  out.image = trajectory.x + shift * f;
  out.time = tau + shift;
  derivative.append_transition(MatrixXd::Identity(d, d) - f * g.transpose() / rate);
  out.derivative = std::move(derivative);
  out.events = std::move(trajectory.events);
  out.notices = std::move(trajectory.notices);
  return out;
}

namespace {

// A converged point whose trajectory moves by at most kRestMotionPerTolerance x min(tolerance,
// kRestCheckTolerance) x (1 + |x|_inf) over the period is an equilibrium (find_periodic_orbit).
constexpr double kRestMotionPerTolerance = 1000.0;
constexpr double kRestCheckTolerance = 1e-8;
// A Newton correction of at least this fraction of the orbit's excursion, at a point whose
// residual meets the tolerance, marks a vanishing orbit (find_periodic_orbit).
constexpr double kVanishingFraction = 0.1;
// ... where the orbit moves along the correction at least this many residuals.
constexpr double kVanishingMotion = 100.0;

// The largest distance |phi_t(x) - x|_inf over one period, and the largest |u . (phi_t(x) - x)|
// (the orbit's extent along u; 0 when u is empty): at the events and at 32 equal times.
struct Excursion {
  double reach = 0.0;
  double along = 0.0;
};

Excursion excursion(const SegmentModel& model, const VectorXd& x, const ReturnMap& map,
                    const FlowOptions& flow, const VectorXd& u = VectorXd()) {
  Excursion out;
  auto visit = [&](const VectorXd& y) {
    out.reach = std::max(out.reach, inf_norm(y - x));
    if (u.size() == x.size()) out.along = std::max(out.along, std::abs(u.dot(y - x)));
  };
  for (const EventRecord& e : map.events) visit(e.rho);
  FlowOptions options = flow;
  VectorXd y = x;
  const int samples = 32;
  for (int k = 0; k < samples; ++k) {
    const FlowResult r = simulate(model, y, map.time / samples, options);
    if (!r.ok()) break;
    y = r.x;
    options.initial_sides = r.sides;
    visit(y);
  }
  return out;
}

// Why x is a point of a vanishing orbit rather than near a fixed point (empty when it is not):
// Newton's correction dx is at least kVanishingFraction of the orbit's extent along dx while
// the trajectory moves along dx at least kVanishingMotion times the residual. At a fixed point
// with multiplier mu, |dx| is about |P(x) - x| / |1 - mu|: both hold only where |1 - mu| <=
// 1 / (kVanishingMotion kVanishingFraction) = 0.1 and the orbit's extent along dx is at most 10
// corrections, i.e. where the orbit is not resolved at all. The extent along dx is at least the
// residual's component along it; on a direction the orbit is flat in (a coordinate that settles
// to a constant) it is no more, so such a direction is not taken for a vanishing orbit.
std::string vanishing_orbit(int iteration, double residual, double correction, double period,
                            const Excursion& e) {
  if (!(correction > 0.0) || !(correction >= kVanishingFraction * e.along) ||
      !(e.along >= kVanishingMotion * residual)) {
    return {};
  }
  return "the iteration approaches a vanishing orbit, not a fixed point: at iteration " +
         std::to_string(iteration) + " |P(x) - x| = " + format_number(residual) +
         " is small but Newton's correction |dx| = " + format_number(correction) + " is " +
         format_number(correction / e.along) + " of the orbit's extent along it, " +
         format_number(e.along) + " (period " + format_number(period) +
         "): the linearised map puts the fixed point a good part of the orbit's size away, as " +
         "where orbits shrink to a point (period and amplitude to 0)";
}

std::string cut(const std::string& text, std::size_t limit = 400) {
  return text.size() <= limit ? text : text.substr(0, limit) + "...";
}

}  // namespace

PeriodicOrbit find_periodic_orbit(const SegmentModel& model, const PoincareSection& section,
                                  const Eigen::Ref<const VectorXd>& x_guess,
                                  const OrbitOptions& options) {
  check_options(options);
  check_point("find_periodic_orbit", model, x_guess);
  check_flow_options("find_periodic_orbit", model, options.flow);
  check_section("find_periodic_orbit", section, model.states(), x_guess);
  PeriodicOrbit orbit;
  VectorXd x = projected(section, x_guess, "find_periodic_orbit: the guess");
  ReturnMap current;
  try {
    current = return_map(model, section, x, options);
  } catch (const InvalidArgument& e) {
    orbit.x = x;
    orbit.message = std::string("the guess has no return map: ") + e.what();
    return orbit;
  }
  // A guess the flow does not carry across the section from s < 0 to s > 0 (it crosses the other
  // way, or touches it) is no point of an orbit through the section: its return P(x) is.
  {
    const Signs sides = sides_at(model, x, options.flow);
    VectorXd f(model.states());
    model.field(x.data(), sides, f.data());
    const VectorXd g = section_gradient(section, x);
    const double rate = g.dot(f);
    if (!(rate > 1e-12 * g.norm() * f.norm())) {
      orbit.decisions.push_back(
          "the guess does not cross the section from s < 0 to s > 0 (Ds . F = " +
          format_number(rate) +
          "): the search started from its return P(guess), at t = " + format_number(current.time));
      for (const std::string& d : current.decisions) orbit.decisions.push_back(d);
      x = current.image;
      try {
        current = return_map(model, section, x, options);
      } catch (const InvalidArgument& e) {
        orbit.x = x;
        orbit.message = std::string("the guess's return P(guess) has no return map: ") + e.what();
        return orbit;
      }
    }
  }
  for (const std::string& d : current.decisions) orbit.decisions.push_back(d);
  double step_length = 0.0;
  // Newton's tolerance: the caller's, tightened to kRestCheckTolerance where the equilibrium
  // check needs it (`refining`).
  double tolerance = options.tolerance;
  bool refining = false;
  bool vanishing = false;
  NewtonEquationSolution last_solve;
  bool solved_once = false;
  for (int iteration = 0;; ++iteration) {
    const VectorXd r = current.image - x;
    const double residual = inf_norm(r);
    OrbitNewtonStep step;
    step.iteration = iteration;
    step.residual = residual;
    step.period = current.time;
    step.step_length = step_length;
    step.events = static_cast<int>(current.events.size());
    for (const EventRecord& e : current.events) {
      step.largest_event = std::max(step.largest_event, e.group_size());
    }
    if (solved_once) {
      step.solutions = static_cast<int>(last_solve.solutions.size());
      step.pieces_checked = last_solve.pieces_checked;
      step.piece_changed = last_solve.piece_changed;
    }
    orbit.steps.push_back(step);
    if (options.progress) options.progress(step);
    orbit.newton_iterations = iteration;
    const double scale = 1.0 + inf_norm(x);
    const bool small_residual = residual <= tolerance * scale;
    // The Newton correction at x: the step to the fixed point of the linearised map. It is the
    // second half of the convergence test, and the step taken when the test fails.
    const MatrixXd basis = orthogonal_complement(section_gradient(section, x));
    last_solve = solve_newton_equation(current.derivative, basis, -(basis.transpose() * r));
    solved_once = true;
    const double correction = inf_norm(basis * last_solve.c);
    orbit.correction = correction;
    if (small_residual && !(correction <= tolerance * scale)) {
      // A small residual alone proves nothing where the orbits themselves are small (near a
      // point of a switching surface where both fields cross it, every small loop returns
      // close to its start): a correction comparable to the orbit's own excursion says the
      // fixed point of the linearised map lies as far as the whole orbit, and the iterates
      // approach a vanishing orbit.
      const VectorXd dx = basis * last_solve.c;
      const std::string why =
          vanishing_orbit(iteration, residual, correction, current.time,
                          excursion(model, x, current, options.flow, VectorXd(dx / dx.norm())));
      if (!why.empty()) {
        orbit.message = why;
        vanishing = true;
        break;
      }
      // Not converged: Newton goes on from here (the criterion, not a choice made for the
      // caller).
    }
    if (small_residual && correction <= tolerance * scale && tolerance > kRestCheckTolerance) {
      // At a loose tolerance a point near a rest point the iterates slide to meets it as well as
      // a point of a genuine orbit: where the trajectory stays within 1000 tolerances of x,
      // Newton goes on to kRestCheckTolerance, where the two part (the first stops moving, the
      // second keeps its motion).
      const double reach = excursion(model, x, current, options.flow).reach;
      if (!(reach > kRestMotionPerTolerance * tolerance * scale)) {
        orbit.decisions.push_back(
            "iteration " + std::to_string(iteration) + ": the trajectory stays within " +
            format_number(reach) + " of x, not more than 1000 times Newton's tolerance: " +
            "Newton went on to |P(x) - x| <= 1e-8 (1 + |x|) to tell an orbit from a rest point");
        tolerance = kRestCheckTolerance;
        refining = true;
      } else {
        orbit.converged = true;
        break;
      }
    }
    if (residual <= tolerance * scale && correction <= tolerance * scale) {
      orbit.converged = true;
      break;
    }
    if (iteration >= options.max_newton_iterations) {
      orbit.message = "Newton's method did not converge in " + std::to_string(iteration) +
                      " iterations (OrbitOptions::max_newton_iterations): |P(x) - x| = " +
                      format_number(residual) +
                      " and the correction |dx| = " + format_number(correction) +
                      ", the tolerance " + format_number(tolerance * scale);
      break;
    }
    if (last_solve.solutions.empty()) {
      orbit.decisions.push_back(
          "iteration " + std::to_string(iteration) +
          ": the Newton equation DP(x; d) - d = -(P(x) - x) has no solution" +
          (last_solve.exhaustive
               ? " on any of the " + std::to_string(last_solve.pieces_checked) + " pieces"
               : " found in " + std::to_string(last_solve.rounds) +
                     " rounds on the active piece (too many pieces to check)") +
          "; the step of least residual (" + format_number(last_solve.residual) + ") was tried");
    } else if (last_solve.solutions.size() > 1) {
      orbit.decisions.push_back(
          "iteration " + std::to_string(iteration) + ": the Newton equation has " +
          std::to_string(last_solve.solutions.size()) +
          " solutions; the shortest step was taken (|d| = " + format_number(last_solve.c.norm()) +
          ")");
    }
    const VectorXd c = last_solve.c;
    double alpha = 1.0;
    bool accepted = false;
    std::string last_error;
    std::string stop;
    for (int backtrack = 0; backtrack <= options.max_backtracks; ++backtrack, alpha *= 0.5) {
      VectorXd trial = x + alpha * (basis * c);
      if (!project(section, trial)) {
        last_error = "the step could not be projected back onto the section";
        continue;
      }
      if (trial == x) {
        stop = "the step shrank below the round-off of x after " + std::to_string(backtrack) +
               " halvings";
        break;
      }
      try {
        ReturnMap next = return_map(model, section, trial, options);
        if (inf_norm(next.image - trial) < residual) {
          x = trial;
          current = std::move(next);
          accepted = true;
          break;
        }
      } catch (const InvalidArgument& e) {
        last_error = cut(e.what());
      }
    }
    step_length = alpha;
    if (!last_error.empty()) {
      orbit.decisions.push_back("iteration " + std::to_string(iteration) + ": " +
                                (accepted ? "the Newton step was cut to " + format_number(alpha)
                                          : std::string("no step was taken")) +
                                " because the return map failed at a longer step: " + last_error);
    }
    if (!accepted) {
      orbit.message =
          "Newton's line search found no decrease of |P(x) - x| = " + format_number(residual) +
          " at iteration " + std::to_string(iteration) +
          (stop.empty() ? " in " + std::to_string(options.max_backtracks) +
                              " halvings (OrbitOptions::max_backtracks)"
                        : " (" + stop + ")") +
          (last_error.empty() ? "" : " (last failure: " + last_error + ")");
      break;
    }
  }
  orbit.x = x;
  orbit.period = current.time;
  orbit.residual = inf_norm(current.image - x);
  orbit.events = current.events;
  orbit.notices = current.notices;
  orbit.tangent_basis = orthogonal_complement(section_gradient(section, x));
  orbit.return_map = std::move(current.derivative);
  if (refining && !orbit.converged && !vanishing) {
    // The point met the caller's tolerance (the line search only ever lowers the residual);
    // only the refinement for the equilibrium check did not finish.
    orbit.decisions.push_back("refining for the equilibrium check stopped: " + orbit.message);
    orbit.message.clear();
    orbit.converged = true;
  }
  if (orbit.converged) {
    // Near a rest point that the flow spirals into with multiplier mu per turn, P(x) - x is about
    // (mu - 1)(x - x_rest): Newton's iterates may slide to rest while the residual shrinks, and
    // stop where the trajectory stays within about 2 / |1 - mu| residuals of x. A trajectory that
    // stays within 1000 times Newton's tolerance (at most kRestCheckTolerance, to which a looser
    // run was refined above) of x is therefore an equilibrium.
    const VectorXd dx = orbit.tangent_basis * last_solve.c;
    const Excursion moved = excursion(model, x, current, options.flow,
                                      dx.norm() > 0.0 ? VectorXd(dx / dx.norm()) : VectorXd());
    const double reach = moved.reach;
    const double resolution = kRestMotionPerTolerance *
                              std::min(options.tolerance, kRestCheckTolerance) *
                              (1.0 + inf_norm(x));
    if (!(reach > resolution)) {
      orbit.converged = false;
      orbit.message =
          "the iteration ended at an equilibrium, not a periodic orbit: over the return time " +
          format_number(current.time) + " the trajectory stays within " + format_number(reach) +
          " of x, not more than 1000 x min(Newton's tolerance, 1e-8) x (1 + |x|) = " +
          format_number(resolution);
    } else {
      const std::string why = vanishing_orbit(orbit.newton_iterations, orbit.residual,
                                              orbit.correction, current.time, moved);
      if (!why.empty()) {
        orbit.converged = false;
        orbit.message = why;
      }
    }
  }
  if (orbit.converged && options.stability) {
    try {
      orbit.bracket = growth_rate_bracket(orbit.return_map, orbit.tangent_basis, options);
      orbit.growth_rate_lower = orbit.bracket.lower;
      orbit.growth_rate_upper = orbit.bracket.upper;
      orbit.stability = classify(orbit.bracket);
    } catch (const InvalidArgument& e) {
      // Too many pieces to enumerate: the orbit stands, its stability is not judged.
      orbit.growth_rate_lower = 0.0;
      orbit.growth_rate_upper = std::numeric_limits<double>::infinity();
      orbit.stability = OrbitStability::kUndecided;
      orbit.decisions.push_back(std::string("the growth-rate bracket was not computed: ") +
                                e.what());
    }
  }
  return orbit;
}

}  // namespace bflow

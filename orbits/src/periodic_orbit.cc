#include "bflow/orbits/periodic_orbit.h"

#include <algorithm>
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

namespace bflow {
namespace {

using Eigen::MatrixXcd;
using Eigen::MatrixXd;
using Eigen::VectorXd;

double inf_norm(const VectorXd& v) { return v.size() == 0 ? 0.0 : v.cwiseAbs().maxCoeff(); }

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
  if (!(o.min_return_time >= 0.0 && o.min_return_time < o.max_return_time))
    bad("min_return_time must be in [0, max_return_time), got " + format_number(o.min_return_time));
  if (o.growth_directions < 0 || o.growth_iterations < 1 || o.max_product_length < 1 ||
      o.max_products < 1)
    bad("growth_directions >= 0, growth_iterations >= 1, max_product_length >= 1 and "
        "max_products >= 1 are required, got " +
        std::to_string(o.growth_directions) + ", " + std::to_string(o.growth_iterations) + ", " +
        std::to_string(o.max_product_length) + ", " + std::to_string(o.max_products));
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
VectorXd project(const PoincareSection& section, VectorXd x) {
  for (int k = 0; k < 30; ++k) {
    const double s = section.value(x);
    const VectorXd g = section.gradient(x);
    const double gg = g.squaredNorm();
    if (!(gg > 0.0) || !std::isfinite(gg)) {
      throw InvalidArgument(
          "find_periodic_orbit: the section's gradient vanishes or is not "
          "finite at the point (|Ds|^2 = " +
          format_number(gg) + ")");
    }
    if (std::abs(s) <= 1e-15 * (1.0 + inf_norm(x)) * std::sqrt(gg)) break;
    x -= (s / gg) * g;
  }
  return x;
}

// The piecewise-linear Newton equation B^T DP(x; B c) - c = rhs, by iterating on the active piece.
VectorXd newton_direction(const FlowDerivative& dp, const MatrixXd& basis, const VectorXd& rhs) {
  const int m = static_cast<int>(basis.cols());
  VectorXd c = rhs;  // a first direction to pick the active piece
  VectorXd best = VectorXd::Zero(m);
  double best_error = std::numeric_limits<double>::infinity();
  for (int k = 0; k < 12; ++k) {
    const VectorXd probe = basis * (c.norm() > 0.0 ? c : rhs);
    const MatrixXd a =
        basis.transpose() * dp.active_jacobian(probe) * basis - MatrixXd::Identity(m, m);
    const VectorXd next = a.completeOrthogonalDecomposition().solve(rhs);
    const double error = (basis.transpose() * dp.apply(basis * next) - next - rhs).norm();
    if (error < best_error) {
      best_error = error;
      best = next;
    }
    if (error <= 1e-12 * (1.0 + rhs.norm())) break;
    c = next;
  }
  return best;
}

// The distinct pieces of map restricted to span(basis).
std::vector<MatrixXd> restricted_pieces(const FlowDerivative& map, const MatrixXd& basis) {
  std::vector<MatrixXd> out;
  for (const FlowPiece& piece : map.pieces()) {
    const MatrixXd a = basis.transpose() * piece.matrix * basis;
    bool seen = false;
    for (const MatrixXd& b : out) {
      if ((a - b).norm() <= FlowDerivative::kLinearTolerance * (1.0 + b.norm())) seen = true;
    }
    if (!seen) out.push_back(a);
  }
  return out;
}

struct LowerCandidate {
  double rate = 0.0;
  int period = 0;
};

// Checks whether L^p z is a positive multiple of z for p = 1, 2; returns the growth c^(1/p).
LowerCandidate periodic_direction(const FlowDerivative& map, const MatrixXd& basis,
                                  const VectorXd& z, double tolerance) {
  LowerCandidate found;
  if (!(z.norm() > 0.0)) return found;
  VectorXd w = z;
  for (int p = 1; p <= 2; ++p) {
    w = basis.transpose() * map.apply(basis * w);
    const double c = z.dot(w) / z.squaredNorm();
    if (c > 0.0 && (w - c * z).norm() <= tolerance * w.norm()) {
      found.rate = std::pow(c, 1.0 / p);
      found.period = p;
      return found;
    }
  }
  return found;
}

// The largest singular value of a complex matrix.
double operator_norm(const MatrixXcd& a) {
  if (a.size() == 0) return 0.0;
  Eigen::JacobiSVD<MatrixXcd> svd(a);
  return svd.singularValues()(0);
}

// A unitary Q whose leading columns span a flag the pieces share as far as they share one: at
// each level the unit vector of the remaining subspace that is closest to an eigenvector of every
// piece (among the pieces' own eigenvectors there) is taken next. Where the pieces are
// simultaneously triangularisable, Q^H A Q is upper triangular for every piece.
MatrixXcd common_flag(const std::vector<MatrixXd>& pieces) {
  const int m = static_cast<int>(pieces.front().rows());
  MatrixXcd q = MatrixXcd::Identity(m, m);
  for (int level = 0; level + 1 < m; ++level) {
    const int size = m - level;
    const MatrixXcd sub = q.rightCols(size);
    std::vector<MatrixXcd> local;
    for (const MatrixXd& a : pieces)
      local.push_back(sub.adjoint() * a.cast<std::complex<double>>() * sub);
    Eigen::VectorXcd best = Eigen::VectorXcd::Unit(size, 0);
    double best_miss = std::numeric_limits<double>::infinity();
    for (const MatrixXcd& c : local) {
      const Eigen::ComplexEigenSolver<MatrixXcd> eig(c);
      for (int i = 0; i < size; ++i) {
        Eigen::VectorXcd v = eig.eigenvectors().col(i);
        if (!(v.norm() > 0.0)) continue;
        v.normalize();
        double miss = 0.0;
        for (const MatrixXcd& other : local) {
          const Eigen::VectorXcd w = other * v;
          miss = std::max(miss, (w - v.dot(w) * v).norm() / (1.0 + other.norm()));
        }
        if (miss < best_miss) {
          best_miss = miss;
          best = v;
        }
      }
    }
    // A unitary matrix of the subspace whose first column is `best`.
    MatrixXcd basis(size, size);
    basis.col(0) = best;
    basis.rightCols(size - 1) = MatrixXcd::Identity(size, size).rightCols(size - 1);
    const MatrixXcd h = Eigen::HouseholderQR<MatrixXcd>(basis).householderQ();
    q.rightCols(size) = sub * h;
  }
  return q;
}

// min over k <= max_length of max over products of k pieces of |product|^(1/k), the pieces
// already in the norm's coordinates.
std::pair<double, int> product_bound(const std::vector<MatrixXcd>& pieces, int max_length,
                                     long max_products) {
  const int count = static_cast<int>(pieces.size());
  const int m = static_cast<int>(pieces.front().rows());
  double best = std::numeric_limits<double>::infinity();
  int best_length = 0;
  std::vector<MatrixXcd> level{MatrixXcd::Identity(m, m)};
  for (int k = 1; k <= max_length; ++k) {
    if (static_cast<double>(level.size()) * count > static_cast<double>(max_products)) break;
    std::vector<MatrixXcd> next;
    next.reserve(level.size() * static_cast<std::size_t>(count));
    double worst = 0.0;
    for (const MatrixXcd& prefix : level) {
      for (const MatrixXcd& piece : pieces) {
        next.push_back(piece * prefix);
        worst = std::max(worst, operator_norm(next.back()));
      }
    }
    const double bound = std::pow(worst, 1.0 / k);
    if (bound < best) {
      best = bound;
      best_length = k;
    }
    level = std::move(next);
  }
  return {best, best_length};
}

}  // namespace

CoordinateSection parse_coordinate_section(const std::string& text, int states) {
  auto fail = [&](const std::string& why) {
    throw InvalidArgument("section \"" + text + "\": " + why +
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
    const double value = std::strtod(number.c_str(), &end);
    if (number.empty() || end != number.c_str() + number.size() || !std::isfinite(value)) {
      fail("\"" + number + "\" is not a finite number");
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
  return options;
}

MatrixXd orthogonal_complement(const Eigen::Ref<const VectorXd>& g) {
  const int d = static_cast<int>(g.size());
  if (!(g.norm() > 0.0) || !g.allFinite()) {
    throw InvalidArgument("orthogonal_complement: the vector must be finite and nonzero, |g| = " +
                          format_number(g.norm()));
  }
  Eigen::HouseholderQR<MatrixXd> qr(g);
  const MatrixXd q = qr.householderQ() * MatrixXd::Identity(d, d);
  return q.rightCols(d - 1);
}

OrbitStability classify(const GrowthBracket& bracket) {
  if (bracket.upper < 1.0) return OrbitStability::kStable;
  if (bracket.lower > 1.0) return OrbitStability::kUnstable;
  return OrbitStability::kUndecided;
}

ReturnMap return_map(const SegmentModel& model, const PoincareSection& section,
                     const Eigen::Ref<const VectorXd>& x_in, const OrbitOptions& options) {
  check_options(options);
  check_point("return_map", model, x_in);
  const VectorXd x = x_in;
  const int n = model.surfaces();
  const Signs sides = sides_at(model, x, options.flow);
  if (sides.size() != n) {
    throw InvalidArgument("return_map: initial_sides has " + std::to_string(sides.size()) +
                          " surfaces, the model " + std::to_string(n));
  }
  // Crossings of the section before the flow has moved x by more than 100 times the integration
  // tolerance are round-off (x on the section, s(x) = -1e-17): they do not count. A point the
  // flow cannot move that far within max_return_time is (nearly) an equilibrium: no period.
  const int d = model.states();
  VectorXd f0(d);
  model.field(x.data(), sides, f0.data());
  const IntegratorOptions& integ = options.flow.integrator;
  const double floor = 100.0 * (integ.atol.value_or(1e-2 * integ.rtol) + integ.rtol * inf_norm(x));
  const double speed = inf_norm(f0);
  if (!(speed * options.max_return_time > floor)) {
    throw InvalidArgument(
        "return_map: the point is (nearly) an equilibrium: |F(x)| = " + format_number(speed) +
        " moves it by at most " + format_number(speed * options.max_return_time) + " within " +
        format_number(options.max_return_time) +
        ", not more than 100 times the integration tolerance " + format_number(floor / 100.0));
  }
  const double earliest = std::max(options.min_return_time, floor / speed);
  // Locate the return on the model with the section as an extra surface, window by window.
  const SectionModel augmented(model, section);
  FlowOptions search = options.flow;
  const double s0 = section.value(x);
  std::uint64_t bits = sides.bits();
  if (!(s0 < 0.0)) bits |= std::uint64_t{1} << n;
  Signs aug_sides(n + 1, bits);
  VectorXd y = x;
  double elapsed = 0.0;
  double tau = -1.0;
  while (tau < 0.0) {
    if (elapsed >= options.max_return_time) {
      throw InvalidArgument("return_map: no crossing of the section from s < 0 to s > 0 within " +
                            format_number(options.max_return_time) +
                            " after leaving the point (OrbitOptions::max_return_time)");
    }
    const double window = std::min(options.return_search_window, options.max_return_time - elapsed);
    search.initial_sides = aug_sides;
    const FlowResult run = simulate(augmented, y, window, search);
    if (!run.ok()) {
      throw InvalidArgument("return_map: the simulation stopped at t = " +
                            format_number(elapsed + run.t) + ": " + run.message);
    }
    for (const EventRecord& event : run.events) {
      const bool section_up =
          std::find(event.surfaces.begin(), event.surfaces.end(), n) != event.surfaces.end() &&
          event.sides_after.plus(n);
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
  const VectorXd g = section.gradient(trajectory.x);
  const double rate = g.dot(f);
  if (!(std::abs(rate) > 1e-12 * g.norm() * f.norm()) || !std::isfinite(rate)) {
    throw InvalidArgument("return_map: the trajectory grazes the section at t = " +
                          format_number(tau) + " (Ds . F = " + format_number(rate) + ")");
  }
  const double shift = -section.value(trajectory.x) / rate;
  ReturnMap out;
  out.x = x;
  out.image = trajectory.x + shift * f;
  out.time = tau + shift;
  derivative.append_transition(MatrixXd::Identity(d, d) - f * g.transpose() / rate);
  out.derivative = std::move(derivative);
  out.events = std::move(trajectory.events);
  out.notices = std::move(trajectory.notices);
  return out;
}

GrowthBracket growth_rate_bracket(const FlowDerivative& map, const MatrixXd& basis,
                                  const OrbitOptions& options) {
  check_options(options);
  GrowthBracket bracket;
  const int m = static_cast<int>(basis.cols());
  if (m == 0) return bracket;
  const std::vector<MatrixXd> pieces = restricted_pieces(map, basis);
  bracket.pieces = static_cast<int>(pieces.size());
  if (pieces.size() == 1) {
    Eigen::EigenSolver<MatrixXd> eig(pieces.front());
    for (Eigen::Index i = 0; i < eig.eigenvalues().size(); ++i) {
      bracket.multipliers.push_back(eig.eigenvalues()[i]);
    }
    std::sort(bracket.multipliers.begin(), bracket.multipliers.end(),
              [](const std::complex<double>& a, const std::complex<double>& b) {
                return std::abs(a) > std::abs(b);
              });
    bracket.lower = bracket.upper = std::abs(bracket.multipliers.front());
    bracket.lower_period = bracket.upper_length = 1;
    return bracket;
  }
  // Lower: directions that L maps (in one or two steps) onto positive multiples of themselves.
  const double check = 1e-7;
  auto consider = [&](const VectorXd& z) {
    const LowerCandidate c = periodic_direction(map, basis, z, check);
    if (c.period > 0 && c.rate > bracket.lower) {
      bracket.lower = c.rate;
      bracket.lower_period = c.period;
    }
  };
  for (const MatrixXd& a : pieces) {
    Eigen::EigenSolver<MatrixXd> eig(a);
    for (Eigen::Index i = 0; i < eig.eigenvalues().size(); ++i) {
      if (std::abs(eig.eigenvalues()[i].imag()) > 1e-12 * std::abs(eig.eigenvalues()[i])) continue;
      const VectorXd v = eig.eigenvectors().col(i).real();
      consider(v);
      consider(-v);
    }
  }
  std::mt19937 random(12345);
  std::normal_distribution<double> normal;
  for (int k = 0; k < options.growth_directions; ++k) {
    VectorXd z(m);
    if (k < 2 * m) {
      z.setZero();
      z[k / 2] = (k % 2 == 0) ? 1.0 : -1.0;
    } else {
      for (int i = 0; i < m; ++i) z[i] = normal(random);
    }
    for (int it = 0; it < options.growth_iterations; ++it) {
      const VectorXd w = basis.transpose() * map.apply(basis * z);
      const double norm = w.norm();
      if (!(norm > 0.0) || !std::isfinite(norm)) break;
      z = w / norm;
    }
    consider(z);
  }
  // Upper: the joint spectral radius bound in several norms.
  bracket.upper = std::numeric_limits<double>::infinity();
  std::vector<MatrixXcd> frames{MatrixXcd::Identity(m, m)};
  for (const MatrixXd& a : pieces) {
    Eigen::ComplexSchur<MatrixXcd> schur(a.cast<std::complex<double>>());
    for (double t : {1.0, 1e-2, 1e-4}) {
      MatrixXcd frame = schur.matrixU();
      double scale = 1.0;
      for (int j = 0; j < m; ++j) {
        frame.col(j) *= scale;
        scale *= t;
      }
      frames.push_back(frame);
    }
  }
  // A common flag of the pieces, when they have one (a common triangular form): in it, scaled,
  // every piece's norm tends to its diagonal's largest entry, so single pieces (k = 1) bound
  // rho(L) tightly.
  {
    const MatrixXcd q = common_flag(pieces);
    for (double t : {1e-2, 1e-4, 1e-6, 1e-8}) {
      MatrixXcd frame = q;
      double scale = 1.0;
      for (int j = 0; j < m; ++j) {
        frame.col(j) *= scale;
        scale *= t;
      }
      const Eigen::FullPivLU<MatrixXcd> lu(frame);
      if (!lu.isInvertible()) continue;
      const MatrixXcd inverse = lu.inverse();
      double worst = 0.0;
      for (const MatrixXd& b : pieces) {
        worst = std::max(worst, operator_norm(inverse * b.cast<std::complex<double>>() * frame));
      }
      if (worst < bracket.upper) {
        bracket.upper = worst;
        bracket.upper_length = 1;
      }
    }
  }
  for (const MatrixXcd& frame : frames) {
    const Eigen::FullPivLU<MatrixXcd> lu(frame);
    if (!lu.isInvertible()) continue;
    const MatrixXcd inverse = lu.inverse();
    std::vector<MatrixXcd> local;
    for (const MatrixXd& a : pieces)
      local.push_back(inverse * a.cast<std::complex<double>>() * frame);
    const auto [bound, length] =
        product_bound(local, options.max_product_length, options.max_products);
    if (bound < bracket.upper) {
      bracket.upper = bound;
      bracket.upper_length = length;
    }
  }
  bracket.upper = std::max(bracket.upper, bracket.lower);
  return bracket;
}

PeriodicOrbit find_periodic_orbit(const SegmentModel& model, const PoincareSection& section,
                                  const Eigen::Ref<const VectorXd>& x_guess,
                                  const OrbitOptions& options) {
  check_options(options);
  check_point("find_periodic_orbit", model, x_guess);
  PeriodicOrbit orbit;
  VectorXd x = project(section, x_guess);
  ReturnMap current;
  try {
    current = return_map(model, section, x, options);
  } catch (const InvalidArgument& e) {
    orbit.x = x;
    orbit.message = std::string("the guess has no return map: ") + e.what();
    return orbit;
  }
  double step_length = 0.0;
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
    orbit.steps.push_back(step);
    if (options.progress) options.progress(step);
    orbit.newton_iterations = iteration;
    if (residual <= options.tolerance * (1.0 + inf_norm(x))) {
      orbit.converged = true;
      break;
    }
    if (iteration >= options.max_newton_iterations) {
      orbit.message = "Newton's method did not converge in " + std::to_string(iteration) +
                      " iterations: |P(x) - x| = " + format_number(residual) + " > " +
                      format_number(options.tolerance * (1.0 + inf_norm(x)));
      break;
    }
    const MatrixXd basis = orthogonal_complement(section.gradient(x));
    const VectorXd c = newton_direction(current.derivative, basis, -(basis.transpose() * r));
    double alpha = 1.0;
    bool accepted = false;
    std::string last_error;
    for (int backtrack = 0; backtrack <= options.max_backtracks; ++backtrack, alpha *= 0.5) {
      const VectorXd trial = project(section, x + alpha * (basis * c));
      try {
        ReturnMap next = return_map(model, section, trial, options);
        if (inf_norm(next.image - trial) < residual) {
          x = trial;
          current = std::move(next);
          accepted = true;
          break;
        }
      } catch (const InvalidArgument& e) {
        last_error = e.what();
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
          (last_error.empty() ? "" : " (last failure: " + last_error + ")");
      break;
    }
  }
  orbit.x = x;
  orbit.period = current.time;
  orbit.residual = inf_norm(current.image - x);
  orbit.events = current.events;
  orbit.notices = current.notices;
  orbit.tangent_basis = orthogonal_complement(section.gradient(x));
  orbit.return_map = std::move(current.derivative);
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

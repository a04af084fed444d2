// Periodic orbits through simultaneous events: the return map to a Poincare section, its
// B-derivative, a nonsmooth Newton method for its fixed points, and a stability verdict.
//
//   struct Apex {                                  // the section s(x) = 0, crossed from s < 0 to s
//   > 0
//     template <typename T> T operator()(const T* x) const { return -x[4]; }
//   };
//   bflow::OrbitOptions options;                   // options.flow: every simulation's FlowOptions
//   bflow::PeriodicOrbit orbit =
//       bflow::find_periodic_orbit(bflow::adapt(MyModel{}), Apex{}, x_guess, options);
//   orbit.converged;                  // with orbit.message when not
//   orbit.x, orbit.period;            // the fixed point (on the section) and the return time
//   orbit.return_map.apply(dx);       // DP(x*; dx), and pieces(), crossing_orders(), ...
//   orbit.growth_rate_lower, orbit.growth_rate_upper, orbit.stability;
//
// The return map. P(x) is the first point, after leaving x, where the trajectory crosses the
// section from s < 0 to s > 0; the return time tau(x) is when. By the implicit function theorem
// for tau, its B-derivative is
//     DP(x; v) = Pi D phi_tau(x; v),   Pi = I - F(P(x)) Ds(P(x)) / (Ds(P(x)) . F(P(x))),
// so a v along the field F(x) maps to 0 and every image lies in the section's tangent space.
// return_map is the flow's FlowDerivative with Pi appended as its last transition: it has the
// flow's pieces, crossing orders and active Jacobians, and no single Jacobian where an event
// crosses several surfaces at once.
//
// The fixed point. Newton's method on P(x) - x = 0 restricted to the section: each step solves
// the piecewise-linear equation  DP(x_k; delta) - delta = -(P(x_k) - x_k)  for delta in the
// section's tangent space exactly (solve_newton_equation: the linear system of every distinct
// piece, each solution checked on the map; none or several are reported in `decisions`), then
// backtracks until |P(x) - x| decreases. It has converged when both |P(x) - x| and the Newton
// correction |delta| at x are within tolerance (1 + |x|_inf): a small residual alone proves
// nothing where the orbits are small (near a point of a switching surface where both fields
// cross it, every small loop returns close to its start while P(x) / x stays away from 1). Where
// the residual meets the tolerance but the correction is at least 0.1 of the orbit's whole
// excursion (sampled as below), the iterates approach a vanishing orbit (period and amplitude
// shrinking to 0): the run stops there, converged = false, and the message says so.
// It converges to unstable orbits as well as stable ones;
// the iterates stay on the section (projected back along Ds for a curved section). A guess that
// does not cross the section upwards is replaced by its return P(guess); a run that ends where
// the trajectory stays within 1000 min(tolerance, 1e-8) (1 + |x|_inf) of x over the return time
// (sampled at the events and at 32 equal times) is an equilibrium, not an orbit (converged =
// false): the iterates can slide to rest while |P(x) - x| shrinks. At a tolerance above 1e-8, a
// point that meets it while its trajectory stays within 1000 tolerances of x is refined by
// further Newton steps to 1e-8 first (decisions says so): there a genuine orbit keeps its
// motion and a rest point loses it. Every loop is bounded by an option and names it when it
// ends there (docs/orbits.md).
//
// The verdict. L = DP(x*) restricted to the tangent space T of the section is piecewise linear and
// positively homogeneous: one linear piece per combination of the events' crossing orders, each
// active on a closed polyhedral cone of T (the tangent arriving at every event takes that event's
// order, crossing_order_cone). Its growth rate  rho(L) = max over z of lim |L^k z|^(1/k)  is the
// spectral radius when L is linear; rho(L) < 1 implies the orbit is locally exponentially
// stable, rho(L) > 1 that it is unstable. The bracket [lower, upper] holds rho(L):
//   lower: a direction cycle L^p z = c z with c > 0 and p <= max_product_length gives
//     rho(L) >= c^(1/p). Candidates are the real eigenvectors of every piece and the ends of a
//     normalised power iteration of L from many directions; where L^p z comes back near a
//     positive multiple of z, c is computed exactly, as a real eigenvalue of the product P of
//     the pieces active along the p steps, and counts only when its eigenvector lies in the
//     closed cones of those pieces in turn (so L^p z = P z = c z) and L^p z = c z holds on the
//     map itself. lower_direction and lower_period are the certificate; lower = 0 when none.
//   upper: rho(L) <= (max |P|)^(1/k) for every k and every norm, the max over the products P of
//     k pieces that some direction realises (z in the first piece's cone, its image in the
//     second's, ...). For any z, L^{nk} z is n blocks of k steps, each the product realised by
//     the block's first direction, so |L^{nk} z| <= (max |P|)^n |z|. Whether a product is
//     realised is a linear program (its cone is polyhedral); the products form a tree in which
//     a prefix no direction realises is not extended; a cone counts as nonempty when it is so to
//     within 1e-9, so rounding only ever adds products and loosens the bound. bflow takes the
//     least over k <= max_product_length (while a length has at most max_products realisable
//     products) and over the norms of the pieces' Schur bases and of a flag the pieces share (a
//     common triangular form, where they have one), scaled to shrink their off-diagonal parts;
//     in that flag every single piece, realised or not, is counted (k = 1).
//   Rounding. The bracket is about L as formed from the pieces B^T M B in floating point. Each
//   end is moved outwards by a bound on its own rounding (lower_margin, upper_margin): for the
//   upper end the rounding of the products (their factors' norms times the product length and
//   u) and of the norm in the frame, amplified by the frame's scaling (its condition number
//   t^-(m-1)); for the lower end and for a linear L the eigenvalue's error, by Bauer-Fike with
//   the computed eigenvectors' condition or by Henrici's theorem, max(theta, theta^(1/m)) with
//   theta the backward error times the powers of the Schur form's departure from normality: for
//   a defective (Jordan) product about (u |P|)^(1/m), not u. Pieces are merged only when
//   equal: pieces that differ by 1e-10 can differ in rate by 1e-5. The cones are judged with a
//   slack of 1e-9 (products realised only within it count, which only raises the upper end), and
//   a cycle counts only when L^p z = c z holds on the map to 1e-8 relative and z lies in its
//   cones to 1e-9. The ends bound one number, so an upper end below the lower one is an error
//   of bflow: it throws std::logic_error, never lifted to the lower end.
//   Scale. rho(c L) = c rho(L): the map is brought to pieces of size about 1 by a power of two
//   (exact) before bracketing and the ends scaled back, so the bracket of c L is c times that of
//   L (up to the pieces' own rounding) for any c whose pieces stay in the normal double range;
//   pieces that are not finite or below it are refused.
// With one piece (every event crosses one surface) both ends are the spectral radius of the
// Jacobian within its rounding margin: the classic Floquet multipliers (multipliers lists
// them). Stable when upper < 1,
// unstable when lower > 1, undecided otherwise. The verdict is about L; where the return map is
// computed to the integrator's tolerance, a bracket within that tolerance of 1 decides nothing.
#ifndef BFLOW_ORBITS_PERIODIC_ORBIT_H_
#define BFLOW_ORBITS_PERIODIC_ORBIT_H_

#include <complex>
#include <functional>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/ad/tangent_jet.h"
#include "bflow/core/flow_derivative.h"
#include "bflow/core/flow_notice.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/segment.h"

namespace bflow {

/** A Poincare section s(x) = 0, crossed from s < 0 to s > 0. */
class PoincareSection {
 public:
  virtual ~PoincareSection() = default;
  virtual double value(const Eigen::Ref<const Eigen::VectorXd>& x) const = 0;
  /** Ds(x), d numbers (the library checks the count and that they are finite). */
  virtual Eigen::VectorXd gradient(const Eigen::Ref<const Eigen::VectorXd>& x) const = 0;
  /** Called once with the model's state count before the section is evaluated: throws
      InvalidArgument when the section cannot be evaluated on such states (an index out of
      range). The default accepts every count. */
  virtual void check(int /*states*/) const {}
};

namespace orbits_detail {
template <typename Section, typename = void>
struct HasCheck : std::false_type {};
template <typename Section>
struct HasCheck<Section, std::void_t<decltype(std::declval<const Section&>().check(0))>>
    : std::true_type {};
}  // namespace orbits_detail

/** A templated functor `template <typename T> T operator()(const T* x) const` as a section; its
    gradient by Jets (one pass per state). */
template <typename Section>
class SectionAdapter final : public PoincareSection {
 public:
  explicit SectionAdapter(Section section) : section_(std::move(section)) {}
  double value(const Eigen::Ref<const Eigen::VectorXd>& x) const override {
    return section_(x.data());  // a Ref<const VectorXd> is contiguous: no copy per step
  }
  Eigen::VectorXd gradient(const Eigen::Ref<const Eigen::VectorXd>& x) const override {
    const int d = static_cast<int>(x.size());
    std::vector<Jet1> xj(static_cast<std::size_t>(d));
    Eigen::VectorXd g(d);
    for (int i = 0; i < d; ++i) xj[static_cast<std::size_t>(i)] = Jet1(x[i]);
    for (int i = 0; i < d; ++i) {
      xj[static_cast<std::size_t>(i)].v[0] = 1.0;
      g[i] = section_(xj.data()).v[0];
      xj[static_cast<std::size_t>(i)].v[0] = 0.0;
    }
    return g;
  }
  /** Forwards to the functor's `void check(int states) const` when it has one. */
  void check(int states) const override {
    if constexpr (orbits_detail::HasCheck<Section>::value) section_.check(states);
  }

 private:
  Section section_;
};

/** s(x) = sign (x[index] - value): the section through x[index] = value, crossed upwards for
    sign = +1 and downwards for sign = -1 (e.g. {4, 0.0, -1.0}: the apex of a vertical hop). */
struct CoordinateSection {
  int index = 0;
  double value = 0.0;
  double sign = 1.0;
  template <typename T>
  T operator()(const T* x) const {
    return T(sign) * (x[index] - T(value));
  }
  /** @throws InvalidArgument unless 0 <= index < states, value is finite and sign is +-1. */
  void check(int states) const;
};

/** s(x) = normal . x - offset: the hyperplane normal . x = offset, crossed in the direction of
    the normal (e.g. normal (1, 1), offset 0: the diagonal x_0 + x_1 = 0, crossed upwards). */
struct HyperplaneSection {
  Eigen::VectorXd normal;
  double offset = 0.0;
  template <typename T>
  T operator()(const T* x) const {
    T s = T(-offset);
    for (Eigen::Index i = 0; i < normal.size(); ++i) s += T(normal[i]) * x[i];
    return s;
  }
  /** @throws InvalidArgument unless the normal has `states` finite entries, not all zero, and
      the offset is finite. */
  void check(int states) const;
};

/** Parses "x4" (s = x_4), "-x4" (s = -x_4), "x1=0.3" (s = x_1 - 0.3), "-x1=0.3".
    @throws InvalidArgument quoting the text when it is none of these or index >= states. */
CoordinateSection parse_coordinate_section(const std::string& text, int states);
/** The text form parse_coordinate_section() reads. */
std::string to_string(const CoordinateSection& section);

enum class OrbitStability { kStable, kUnstable, kUndecided };
/** "stable", "unstable", "undecided". */
const char* to_string(OrbitStability stability);

/** FlowOptions with the tolerances an orbit needs by default: rtol 1e-10, atol 1e-12, the
    tangents in the error norm (the return map's derivative held to the tolerance as well), and
    dopri5, whose return-map derivative is the tighter one on the hopping orbits at this
    tolerance (periodic_orbit.cc). */
FlowOptions default_orbit_flow_options();

/** One Newton step, for progress reports. */
struct OrbitNewtonStep {
  int iteration = 0;
  double residual = 0.0;  ///< |P(x) - x|_inf at the step's start
  double period = 0.0;
  double step_length = 0.0;  ///< the line search's factor (0 before the first step)
  int events = 0;            ///< events in one period
  int largest_event = 0;     ///< the most surfaces crossed at one event
  /** The Newton equation of the step that led here (0 before the first step): its solutions
      found, the distinct pieces checked, and whether the piece active at the solution differs
      from the piece active at the right-hand side (where iterating on the active piece from the
      right-hand side would have needed a second round). */
  int solutions = 0;
  int pieces_checked = 0;
  bool piece_changed = false;
};

struct OrbitOptions {
  FlowOptions flow = default_orbit_flow_options();
  /** Converged when |P(x) - x|_inf <= tolerance (1 + |x|_inf) and Newton's correction there,
      |dx|_inf, is within the same bound (tightened to 1e-8 where the equilibrium check needs
      it: see the header comment). */
  double tolerance = 1e-8;
  int max_newton_iterations = 40;
  /** Backtracking halvings per Newton step (<= kMaxBacktracks); a step that shrinks below the
      round-off of x ends the line search earlier. */
  int max_backtracks = 20;
  static constexpr int kMaxBacktracks = 1100;
  /** A return is searched for up to this time after leaving x (> 0); the search simulates in
      windows of return_search_window (> 0), the last return time when one is known. */
  double max_return_time = 100.0;
  double return_search_window = 1.0;
  /** At most this many windows cover max_return_time (a smaller window is refused). The whole
      search takes at most flow.integrator.max_steps steps. */
  static constexpr long kMaxReturnWindows = 100000;
  /** Crossings of the section earlier than this after leaving x do not count (>= 0). */
  double min_return_time = 0.0;
  /** The stability bracket: directions for the power iteration and its steps (the lower end);
      the longest products of pieces, which is also the longest direction cycle looked for, and
      at most max_products realisable products per length (the upper end; a length with more, or
      with more than 64 max_products candidate products to test, is not used). Each is bounded
      (the k... constants below); max_products also by the memory its products may take, an
      estimate from m (the basis's columns), max_product_length and the cones' rows that must
      stay within kMaxGrowthBytes (the message gives the estimate and the most that fit). */
  int growth_directions = 64;
  int growth_iterations = 400;
  int max_product_length = 12;
  long max_products = 4000;
  static constexpr int kMaxGrowthDirections = 100000;
  static constexpr int kMaxGrowthIterations = 1000000;
  static constexpr int kMaxProductLength = 64;
  static constexpr long kMaxGrowthBytes = long{1} << 30;  ///< 1 GiB
  /** Compute the bracket and verdict (the fixed point only when false). */
  bool stability = true;
  /** Called after every Newton step's residual is known. */
  std::function<void(const OrbitNewtonStep&)> progress;
};

/** The solutions of a piecewise-linear equation  B^T DP(B c) - c = rhs  (see
    solve_newton_equation). */
struct NewtonEquationSolution {
  /** Every solution found, the least |c| first; empty when there is none. */
  std::vector<Eigen::VectorXd> solutions;
  /** The c used: solutions[0], or when there is none the c of least residual among the pieces'
      solutions (a least-squares step). */
  Eigen::VectorXd c;
  /** |B^T DP(B c) - c - rhs|_2 at c. */
  double residual = 0.0;
  /** Distinct pieces of B^T DP B solved on. */
  int pieces_checked = 0;
  /** True when every piece was checked (the solution list is complete); false when the pieces
      were too many to enumerate and the equation was solved by iterating on the active piece. */
  bool exhaustive = true;
  /** Rounds of the active-piece iteration (0 when exhaustive). */
  int rounds = 0;
  /** Pieces whose matrix B^T M B - I is singular: their solutions form an affine set of which
      only the least-norm point was checked, so a solution in such a piece may be missed. */
  int singular_pieces = 0;
  /** The piece active at the solution (or at c) is not the one active at rhs. */
  bool piece_changed = false;
};

/** P(x), the return time and the return map's B-derivative at x. */
struct ReturnMap {
  Eigen::VectorXd x;                ///< where the map was evaluated
  Eigen::VectorXd image;            ///< P(x)
  double time = 0.0;                ///< tau(x)
  FlowDerivative derivative{1};     ///< DP(x; .)
  std::vector<EventRecord> events;  ///< the period's events
  std::vector<FlowNotice> notices;
  /** What the search decided (a crossing resolved on its own because an event grouped with the
      section could not be resolved). */
  std::vector<std::string> decisions;
};

/** The growth-rate bracket of a piecewise-linear map and how each end was obtained. */
struct GrowthBracket {
  double lower = 0.0;
  double upper = 0.0;
  /** Pieces of L (restricted to the section's tangent space) counted for the upper bound. */
  int pieces = 0;
  /** The product length that gave the upper bound, and the period p of the lower bound's
      direction (0 when none was found, then lower = 0). */
  int upper_length = 0;
  int lower_period = 0;
  /** The lower end's certificate: z (m numbers, unit length) with L^p z = c z, lower = c^(1/p)
      (up to the rounding margin); empty when lower_period = 0 or L is linear. */
  Eigen::VectorXd lower_direction;
  /** realisable_products[k - 1]: the products of k pieces that some direction realises, counted
      for the upper end (the tree of products, pruned where no direction realises a prefix). Ends
      before the first length with more than max_products of them (OrbitOptions); empty when L
      is linear. */
  std::vector<long> realisable_products;
  /** When L is linear: its eigenvalues (the nontrivial Floquet multipliers), by modulus. */
  std::vector<std::complex<double>> multipliers;
  /** How far each end was moved outwards for rounding (absolute): lower is the computed rate of
      its cycle (or the computed spectral radius) less lower_margin, upper the computed bound
      plus upper_margin (at most: products below the largest are not all computed exactly). */
  double lower_margin = 0.0;
  double upper_margin = 0.0;
};

struct PeriodicOrbit {
  bool converged = false;
  std::string message;
  Eigen::VectorXd x;
  double period = 0.0;
  /** DP(x*; .) (see the header comment). */
  FlowDerivative return_map{1};
  int newton_iterations = 0;
  double residual = 0.0;  ///< |P(x) - x|_inf at x
  /** |dx|_inf of Newton's correction at x (the step to the fixed point of the linearised map,
      solve_newton_equation): converged requires it within the tolerance as well. */
  double correction = 0.0;
  double growth_rate_lower = 0.0;
  double growth_rate_upper = 0.0;
  OrbitStability stability = OrbitStability::kUndecided;
  GrowthBracket bracket;
  /** An orthonormal basis of the section's tangent space at x (d x (d - 1)). */
  Eigen::MatrixXd tangent_basis;
  std::vector<EventRecord> events;  ///< one period's events
  std::vector<FlowNotice> notices;
  std::vector<OrbitNewtonStep> steps;
  /** What the solver decided for the caller: a guess that does not cross the section upwards,
      replaced by its return; a search for the return that resolved crossings one by one; every
      Newton equation with no solution or several (and the step taken); every Newton step it
      shortened (or gave up) because the return map could not be evaluated at a longer one, with
      the reason (e.g. an event whose surfaces' normals are dependent); and a bracket not
      computed because growth_rate_bracket refused it (the return map has too many pieces to
      enumerate, its products would take more than OrbitOptions::kMaxGrowthBytes, or a model of
      one state leaves the section no direction), then [0, inf] and kUndecided. Empty when every
      step was taken as solved or shortened only for lack of decrease. */
  std::vector<std::string> decisions;
};

/** P(x) and DP(x; .). x need not lie on the section (the first crossing counts). The sides of
    the model's surfaces at x are options.flow.initial_sides or the signs of h(x).
    @throws InvalidArgument for bad input, no return within max_return_time (quoting the times
    searched), or a simulation that fails (quoting its message). */
ReturnMap return_map(const SegmentModel& model, const PoincareSection& section,
                     const Eigen::Ref<const Eigen::VectorXd>& x, const OrbitOptions& options = {});

template <typename Section,
          typename = std::enable_if_t<!std::is_base_of_v<PoincareSection, Section>>>
ReturnMap return_map(const SegmentModel& model, const Section& section,
                     const Eigen::Ref<const Eigen::VectorXd>& x, const OrbitOptions& options = {}) {
  return return_map(model, SectionAdapter<Section>(section), x, options);
}

/** The fixed point of P near x_guess (projected onto the section first), its return map and,
    unless options.stability is false, the growth-rate bracket and verdict. A Newton run that
    does not converge returns converged = false with a message (no throw).
    @throws InvalidArgument for bad input (sizes, non-finite values, options out of range,
    options.flow included: the values every simulation would refuse, initial_sides naming another
    number of surfaces, max_events < 1), before any simulation. */
PeriodicOrbit find_periodic_orbit(const SegmentModel& model, const PoincareSection& section,
                                  const Eigen::Ref<const Eigen::VectorXd>& x_guess,
                                  const OrbitOptions& options = {});

template <typename Section,
          typename = std::enable_if_t<!std::is_base_of_v<PoincareSection, Section>>>
PeriodicOrbit find_periodic_orbit(const SegmentModel& model, const Section& section,
                                  const Eigen::Ref<const Eigen::VectorXd>& x_guess,
                                  const OrbitOptions& options = {}) {
  return find_periodic_orbit(model, SectionAdapter<Section>(section), x_guess, options);
}

/** Solves the piecewise-linear equation  B^T DP(B c) - c = rhs  (B = basis, d x m) exactly: on
    each distinct piece M of DP, the linear system (B^T M B - I) c = rhs, keeping the c that
    solve the equation on the map itself (each c is checked with DP.apply, not with the piece it
    came from). Every solution lies in the closed cone of some piece, where DP(B c) = M B c, so
    when every piece's B^T M B - I is invertible the list is complete. Up to max_pieces distinct
    pieces are enumerated; beyond, the active piece is iterated on (at most 50 rounds) and
    `exhaustive` is false. A c counts as a solution only when its residual is finite (a residual
    that overflows proves nothing). @throws InvalidArgument on sizes that do not match,
    non-finite input, |rhs| beyond the double range, or max_pieces outside
    [1, FlowDerivative::kMaxPieces]. */
NewtonEquationSolution solve_newton_equation(const FlowDerivative& map,
                                             const Eigen::Ref<const Eigen::MatrixXd>& basis,
                                             const Eigen::Ref<const Eigen::VectorXd>& rhs,
                                             long max_pieces = 4096);

/** The bracket of the growth rate of L = map restricted to span(basis) (d x m, 1 <= m <= d,
    orthonormal columns; the map's images must lie in that span): see "The verdict" above.
    @throws InvalidArgument for options out of range (internal::check_growth_options, with the
    memory estimate for max_products), a basis of the wrong size, with no columns (nothing to
    bracket) or not orthonormal (|B^T B - I|_max > 1e-8), a basis that does not span the map's
    images (some piece M with |(I - B B^T) M B|_F > 1e-6 |M B|_F, quoting it), or a map with
    too many pieces to enumerate (FlowDerivative::pieces()).
    @throws std::logic_error when the ends cross (upper < lower): an error of bflow's. */
GrowthBracket growth_rate_bracket(const FlowDerivative& map, const Eigen::MatrixXd& basis,
                                  const OrbitOptions& options = {});

/** The verdict from a bracket: stable when upper < 1, unstable when lower > 1. */
OrbitStability classify(const GrowthBracket& bracket);

/** The cone where a jump takes the crossing order sigma (surface indices of the jump, first
    crossed first), as n - 1 rows R (n - 1 x d): the tangent dx takes order sigma exactly when
    R dx >= 0 (closed: at a tie both orders hold; order() then reports the lower index first).
    Row k - 1 is the time from the k-th to the (k+1)-th crossing, t_sigma(k+1) - t_sigma(k) of
    [B] (6.8)-(6.9), as a linear function of dx (the differences of CrossingOrder::times).
    Where a row's update would leave the double range it is dropped (the cone only grows).
    @throws InvalidArgument unless sigma is a permutation of 0..n-1. */
Eigen::MatrixXd crossing_order_cone(const JumpMap& jump, const std::vector<int>& sigma);

/** An orthonormal basis of the orthogonal complement of the vector g (d x (d - 1)). */
Eigen::MatrixXd orthogonal_complement(const Eigen::Ref<const Eigen::VectorXd>& g);

}  // namespace bflow

#endif  // BFLOW_ORBITS_PERIODIC_ORBIT_H_

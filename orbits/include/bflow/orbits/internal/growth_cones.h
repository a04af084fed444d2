// The parts of bflow::growth_rate_bracket (periodic_orbit.h) that its tests check on their own:
// a dense simplex, the nontriviality of a polyhedral cone, the pieces of a return map with their
// cones, the bracket's final consistency check and the check of its options (shared with
// find_periodic_orbit). Not a stable interface.
#ifndef BFLOW_ORBITS_INTERNAL_GROWTH_CONES_H_
#define BFLOW_ORBITS_INTERNAL_GROWTH_CONES_H_

#include <limits>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/flow_derivative.h"
#include "bflow/orbits/periodic_orbit.h"

namespace bflow {

namespace internal {

/** The result of simplex_from_origin. */
struct SimplexResult {
  enum class Status { kOptimal, kTargetReached, kUnbounded, kIterationLimit };
  Status status = Status::kOptimal;
  double value = 0.0;  ///< c . x at the x returned
  Eigen::VectorXd x;
  int pivots = 0;
};

/** Maximises c . x subject to G x <= h and x >= 0, where h >= 0 (so x = 0 is feasible and the
    dense simplex starts there, on the slack basis). Dantzig's rule, then Bland's after a run of
    degenerate pivots (no cycling). Stops early with kTargetReached once c . x >= target.
    @throws InvalidArgument on mismatched sizes, non-finite numbers or a negative h. */
SimplexResult simplex_from_origin(const Eigen::MatrixXd& g, const Eigen::VectorXd& h,
                                  const Eigen::VectorXd& c,
                                  double target = std::numeric_limits<double>::infinity());

/** Whether the cone {z : rows z >= 0} (r rows of unit length) holds a z != 0, erring only
    towards yes: true whenever it does exactly, and also for cones empty only to within the
    tolerance. True when the rows have a numerical kernel (r < m, or smallest singular value
    <= 1e-9 times the largest); otherwise one LP from z = 0, max 1 . R z subject to
    -tolerance <= R z <= 1, answers true when it reaches 1/2 (a nonempty cone reaches >= 1; a
    solution reaching 1/2 lies in the cone relaxed by 2 r tolerance) or does not finish.
    witness, when given and the answer is true, gets a unit z in that relaxed cone. */
bool cone_is_nontrivial(const Eigen::MatrixXd& rows, double tolerance,
                        Eigen::VectorXd* witness = nullptr);

/** A linear piece of L = B^T DP(B z): the crossing order at every event (model indices, as in
    FlowPiece), its matrix B^T M B and its cone, unit rows R with R z >= 0 exactly where every
    event's tangent (Phi_{i-1} M_{i-1} ... Phi_0 B z) takes its order; and how far M maps
    span(B) out of itself, |(I - B B^T) M B|_F, beside |M B|_F. */
struct ConePiece {
  std::vector<std::vector<int>> orders;
  Eigen::MatrixXd matrix;
  Eigen::MatrixXd cone;
  double outside = 0.0;
  double image_norm = 0.0;
};

/** growth_rate_bracket refuses a basis when some piece has |(I - B B^T) M B|_F above this
    times |M B|_F: the basis does not span the map's images. Rounding leaves a return map's
    images out of the section's tangent space by a few u |Pi| (Pi the projection along the field,
    |Pi| = 1 / cos of the field's angle to the normal), and a curved section turns between x*
    and P(x*) by its curvature times Newton's tolerance (1e-8 by default); 1e-6 leaves room for
    both, while a basis of the wrong subspace leaves O(1). */
inline constexpr double kSpanTolerance = 1e-6;

/** An upper bound on the bytes growth_rate_bracket's realisable products take per product
    allowed (OrbitOptions::max_products), for m directions, products of up to max_length pieces
    and cone_rows inequalities per piece (the sum over the events of surfaces - 1). */
double growth_bytes_per_product(int m, int max_length, int cone_rows);

/** The bracket's options: growth_directions in [0, kMaxGrowthDirections], growth_iterations in
    [1, kMaxGrowthIterations], max_product_length in [1, kMaxProductLength], max_products >= 1
    with max_products growth_bytes_per_product(dimension, max_product_length, cone_rows) at
    most OrbitOptions::kMaxGrowthBytes (dimension 1 and no cone rows when not yet known: the
    least the bracket can take).
    @throws InvalidArgument "OrbitOptions: ..." naming the option, its value and its range (for
    max_products the estimate and the most that fit). */
void check_growth_options(const OrbitOptions& options, int dimension = 1, int cone_rows = 0);

/** Every combination of the events' orders (as FlowDerivative::pieces(), which it calls and
    whose throws it passes on) with its cone. */
std::vector<ConePiece> cone_pieces(const FlowDerivative& map, const Eigen::MatrixXd& basis);

/** The bracket's last step, after its ends have been moved outwards by their rounding margins:
    upper >= lower must hold.
    @throws std::logic_error quoting both ends when upper < lower (or either is NaN): the ends
    bound the same number, so one of them is wrong; it is reported, never repaired. */
void finish_bracket(GrowthBracket& bracket);

}  // namespace internal

}  // namespace bflow

#endif  // BFLOW_ORBITS_INTERNAL_GROWTH_CONES_H_

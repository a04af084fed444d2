// The hybrid flow driver: simulates a model across its switching surfaces and returns the
// B-derivative of the flow ([B] (2.10), Theorem 5.3).
//
//   auto model = bflow::adapt(MyModel{});
//   bflow::FlowOptions options;                               // auto backend, rtol 1e-8, ...
//   bflow::FlowResult plain = bflow::simulate(model, x0, 0.6, options);        // no tangents
//   bflow::FlowResult some = bflow::simulate(model, x0, 0.6, directions, options);  // k tangents
//   bflow::FlowDerivative full = bflow::flow_derivative(model, x0, 0.6, options);   // any later
//   Eigen::VectorXd image = full.apply(dx);
//
// Between events a backend integrates x' = F_b(x) (and the tangents). At a crossing the driver
// decides which surfaces cross together (grouping, below), checks transversality, builds the
// JumpMap at rho (normals Dh_j(rho) oriented by the flow, limits F_w(rho) for the words w
// reachable from the current sides) and maps each tangent through it: one surface gives the
// saltation matrix, several give Algorithm 2.1. Then the sides of the crossed surfaces flip and
// integration goes on.
//
// Grouping (FlowOptions::grouping). Crossings that happen at one point of the exact trajectory
// reach the integrator's trajectory at times spread by its error: a state error e with
// |e_i| <= tol_i moves h_j by at most sum_i |dh_j/dx_i| tol_i, its crossing by that over
// |Dh_j . F|. The automatic policy (the default) measures that uncertainty for every surface at
// the first crossing rho, t1:
//     sigma_j = sum_i |dh_j/dx_i(rho)| tol_i(rho) / max(|Dh_j(rho) . F(rho)|,
//                                                       0.01 |Dh_j(rho)| |F(rho)|) + 16 eps |t1|,
//     tol_i(rho) = atol + rtol |rho_i|,
// so a coordinate the surface does not depend on does not widen its window (a crossing slower
// than 1 % of |Dh_j| |F| counts as that fast; as sum_i |dh_j/dx_i| tol_i <= |Dh_j| |tol|, no
// window exceeds 200 grouping_safety times the time |tol| / |F| the trajectory takes to move by
// one tolerance, plus the rounding floor)
// and groups with the first crossing every surface whose LOCATED crossing time t_j (the
// backend's root in the same step; else the linearised time to reach it from rho) satisfies
//     t_j - t1 <= window_j = grouping_safety x (sigma_j + max over the first crossing's sigma).
// Guarantee: crossings whose located times are within the window are never split; the window
// scales with the tolerances and the normal speeds, in the problem's own units, and is at least
// grouping_safety times the spread that one step's error puts on a truly simultaneous crossing.
// Cost: a crossing truly dt <= window after the first is flipped early, a state error of at most
// dt |F_after - F_before|, i.e. a few times the integration tolerance; no extra field
// evaluations (the normals and the field at rho are needed anyway). kFixedWindow groups by a
// window in time given by the user; kNone groups only crossings located at the same time.
//
// Range. Every quantity of the rule (tol_i, the products |dh_j/dx_i| tol_i and their sums, |Dh_j|,
// |F|, Dh_j . F, sigma_j, the linearised times, the windows) is computed with a binary exponent
// of its own, so none overflows or underflows on the way: from x0 = (-1e200, -0.625), where
// tol_0 = 1e192, surface 0, 8e199 ahead, stays out of its window of 8e192, and the event of
// surface 1 at t = 0.5 has the window 1.6e-9 of x_1's tolerance. A quantity that is undefined (a
// normal, field or surface value that is not finite, a vanishing normal or field) makes no surface
// join, since every comparison with it is false; a crossed surface with a vanishing normal or field
// is then reported as grazing. No surface is grouped on an infinite window: the numbers an
// EventRecord reports (window, automatic_window, crossing_times, spread, gap unless +infinity for
// "none") and a notice's gap and band are finite, and when one of them is beyond the double range
// (an automatic window above 1.8e308, from tolerances huge against the flow's speed, under any
// grouping policy) the run ends with status kOverflow and a message naming it, with the events
// completed before it.
//
// Every decision is reported: each EventRecord has the located times of its crossings, their
// spread, the window and the gap to the nearest crossing not grouped with it; crossings of
// different surfaces not grouped but closer than near_simultaneity_band windows give a FlowNotice
// (FlowResult::notices, FlowDerivative::notices()).
//
// Errors. Bad input, grazing (eta . F below grazing_threshold |eta||F| before the crossing) and
// sliding (after the crossing the field points back into the surface; use FESD) throw
// bflow::InvalidArgument with the time, the surface and the values. Outcomes a caller may
// handle (step-size underflow, too many steps, the event limit, a non-finite state, a reported
// number beyond the double range) come back as FlowResult::status with a message.
#ifndef BFLOW_INTEGRATORS_HYBRID_FLOW_H_
#define BFLOW_INTEGRATORS_HYBRID_FLOW_H_

#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/flow_derivative.h"
#include "bflow/core/flow_notice.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/signs.h"
#include "bflow/integrators/segment.h"

namespace bflow {

/** The integrator between events. kAutomatic (the default) picks dopri5 or dop853 for each run
    by choose_backend(); FlowResult::backend names the one that ran. */
enum class Backend { kDopri5, kCvodesBdf, kCvodesAdams, kDop853, kAutomatic };

/** Parses "auto", "dopri5", "dop853", "cvodes-bdf", "cvodes-adams".
    @throws InvalidArgument otherwise. */
Backend parse_backend(const std::string& name);
const char* to_string(Backend backend);

/** The relative tolerance at and below which kAutomatic takes dop853 for a model with surfaces
    and fewer than kAutomaticHighOrderStates states. */
inline constexpr double kAutomaticHighOrderRtol = 3e-8;
/** From this many states on, kAutomatic takes dop853 at every tolerance. */
inline constexpr int kAutomaticHighOrderStates = 8;

/** The backend a run with `backend` uses for a model of `states` states and `surfaces` surfaces
    at relative tolerance `rtol`: `backend` itself unless it is kAutomatic; then dop853 (order 8)
    when rtol <= kAutomaticHighOrderRtol, when states >= kAutomaticHighOrderStates or when the
    model has no surface, else dopri5 (order 5). Why (docs/flow.md, "Which backend"): at loose
    tolerances on small models with events, most of a run is the per-step and per-event work
    (locating crossings, the jump), where dopri5's 6 stages and free dense output beat
    dop853's 12 stages and 3 dense-output stages; with tighter tolerances, more states or long
    smooth segments, dop853's order takes fewer steps. Measured on the peer problems (CPU per run
    at equal rtol, bench/peer_flow, docs/flow.md "Which backend"): the 12-state chain is 1.15x
    to 1.8x faster on dop853 from rtol 1e-4 to 1e-8; the ball and the 6-state bipeds are up to
    1.6x faster on dopri5 from 1e-4 to 1e-7 (the ball 1.06x slower at 1e-7), and dop853 is as
    fast or faster from 1e-8. */
Backend choose_backend(Backend backend, double rtol, int states, int surfaces);

/** How the driver decides that crossings of different surfaces are one event (see the header
    comment for the rule and what it guarantees). */
enum class Grouping {
  kAutomatic,    // a window from the tolerances and the normal speeds (the default)
  kFixedWindow,  // FlowOptions::simultaneity_window, in units of time
  kNone,         // only crossings located at the same time
};

/** Parses "auto", "none" or "window". @throws InvalidArgument otherwise. */
Grouping parse_grouping(const std::string& name);
const char* to_string(Grouping grouping);

struct FlowOptions {
  IntegratorOptions integrator;
  /** kAutomatic: dopri5 or dop853 by choose_backend(); FlowResult::backend says which. */
  Backend backend = Backend::kAutomatic;
  Grouping grouping = Grouping::kAutomatic;
  /** kAutomatic: the window is this many times the crossing-time uncertainty, > 0. */
  double grouping_safety = 10.0;
  /** kFixedWindow: crossings of different surfaces closer in time than this form one event. */
  double simultaneity_window = 1e-9;
  /** Crossings of different surfaces that are not grouped but closer than this many automatic
      windows give a kNearSimultaneous notice, >= 1. */
  double near_simultaneity_band = 100.0;
  /** A crossing with eta . F_before < grazing_threshold |eta| |F_before| is grazing. */
  double grazing_threshold = 1e-12;
  /** More events than this ends the simulation with kTooManyEvents (Zeno behaviour?). */
  int max_events = 10000;
  /** Sides at x0; by default the signs of h(x0), which must then be nonzero. A side given
      must agree with the sign of h_j(x0) unless |h_j(x0)| is within what the integration
      tolerance moves h_j, |Dh_j(x0)|_1 (atol + rtol |x0|_inf) (the accuracy of any state the
      engine computes, and how far its own states may sit across a surface: a run that ends at
      a crossing it did not take): there, on the surface, it is the caller's choice; beyond it,
      simulate() and flow_derivative() throw InvalidArgument naming the surface, the side and
      h_j(x0). */
  std::optional<Signs> initial_sides;
};

/** One event: where, which surfaces, how transversal, and how the grouping was decided. */
struct EventRecord {
  /** The first crossing's located time: where the jump is applied. */
  double t = 0.0;
  Eigen::VectorXd rho;
  /** Surfaces crossed together (model indices, lowest first). */
  std::vector<int> surfaces;
  /** Per crossed surface, its located crossing time (see the header comment). */
  std::vector<double> crossing_times;
  /** max - min of crossing_times: how far apart the grouped crossings were located. */
  double spread = 0.0;
  /** The grouping window used at this event (time; 0 for Grouping::kNone). Finite, like every
      number here (see "Range" in the header comment). */
  double window = 0.0;
  /** Time to the nearest crossing not grouped with this event (an earlier or a later event),
      +infinity when there is none. */
  double gap = std::numeric_limits<double>::infinity();
  /** The automatic window at this event, the unit of near_simultaneity_band. */
  double automatic_window = 0.0;
  Signs sides_before;
  Signs sides_after;
  /** Per crossed surface, eta_j . F / (|eta_j| |F|) for F before and after the crossing. */
  std::vector<double> margin_before;
  std::vector<double> margin_after;
  int group_size() const { return static_cast<int>(surfaces.size()); }
};

struct FlowResult {
  IntegrationStatus status = IntegrationStatus::kReachedEnd;
  std::string message;
  double t = 0.0;
  Eigen::VectorXd x;
  /** Final sides of the surfaces. */
  Signs sides;
  /** Images of the requested directions (d x k): the B-derivative applied to them. */
  Eigen::MatrixXd v;
  std::vector<EventRecord> events;
  /** Near-simultaneous crossings not grouped, near grazing (flow_notice.h). */
  std::vector<FlowNotice> notices;
  long steps = 0;
  long field_evaluations = 0;
  /** The backend that ran: FlowOptions::backend, or for kAutomatic the one choose_backend()
      picked (never kAutomatic). */
  Backend backend = Backend::kDopri5;
  bool ok() const { return status == IntegrationStatus::kReachedEnd; }
};

/** x(t_final) with no tangents. */
FlowResult simulate(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                    double t_final, const FlowOptions& options = {});
/** x(t_final) and the B-derivative of the flow applied to each column of `directions`. */
FlowResult simulate(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                    double t_final, const Eigen::Ref<const Eigen::MatrixXd>& directions,
                    const FlowOptions& options = {});
/** The full B-derivative as transition matrices and jump maps, reusable for any direction; its
    notices() are the run's notices.
    @throws InvalidArgument (also for a status other than kReachedEnd, quoting its message). */
FlowDerivative flow_derivative(const SegmentModel& model,
                               const Eigen::Ref<const Eigen::VectorXd>& x0, double t_final,
                               const FlowOptions& options = {}, FlowResult* trajectory = nullptr);

/** A backend for `backend`. @throws InvalidArgument for kAutomatic, which names no backend
    before the run's tolerance and model are known (choose_backend()). */
std::unique_ptr<SegmentIntegrator> make_integrator(Backend backend);

}  // namespace bflow

#endif  // BFLOW_INTEGRATORS_HYBRID_FLOW_H_

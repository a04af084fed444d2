// The hybrid flow driver: simulates a model across its switching surfaces and returns the
// B-derivative of the flow ([B] (2.10), Theorem 5.3).
//
//   auto model = bflow::adapt(MyModel{});
//   bflow::FlowOptions options;                               // dopri5, rtol 1e-8, ...
//   bflow::FlowResult plain = bflow::simulate(model, x0, 0.6, options);        // no tangents
//   bflow::FlowResult some = bflow::simulate(model, x0, 0.6, directions, options);  // k tangents
//   bflow::FlowDerivative full = bflow::flow_derivative(model, x0, 0.6, options);   // any later
//   Eigen::VectorXd image = full.apply(dx);
//
// Between events a backend integrates x' = F_b(x) (and the tangents). At a crossing the driver
// groups every surface that crosses within `simultaneity_window` of the first (by the
// linearised time to reach it), checks transversality, builds the JumpMap at rho (normals
// Dh_j(rho) oriented by the flow, limits F_w(rho) for the words w reachable from the current
// sides) and maps each tangent through it: one surface gives the saltation matrix, several
// give Algorithm 2.1. Then the sides of the crossed surfaces flip and integration goes on.
//
// Errors. Bad input, grazing (eta . F below grazing_threshold |eta||F| before the crossing) and
// sliding (after the crossing the field points back into the surface; use FESD) throw
// bflow::InvalidArgument with the time, the surface and the values. Outcomes a caller may
// handle (step-size underflow, too many steps, the event limit, a non-finite state) come back
// as FlowResult::status with a message.
#ifndef BFLOW_INTEGRATORS_HYBRID_FLOW_H_
#define BFLOW_INTEGRATORS_HYBRID_FLOW_H_

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/flow_derivative.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/signs.h"
#include "bflow/integrators/segment.h"

namespace bflow {

enum class Backend { kDopri5, kCvodesBdf, kCvodesAdams };

/** Parses "dopri5", "cvodes-bdf", "cvodes-adams". @throws InvalidArgument otherwise. */
Backend parse_backend(const std::string& name);
const char* to_string(Backend backend);

struct FlowOptions {
  IntegratorOptions integrator;
  Backend backend = Backend::kDopri5;
  /** Crossings of different surfaces closer in time than this form one event. Grouping
      flips the sides of the later surfaces up to this much early, an error of at most
      window x |F_after - F_before| in the state: keep it below the tolerance you need, and
      above the spread that integration error puts on truly simultaneous crossings. */
  double simultaneity_window = 1e-9;
  /** A crossing with eta . F_before < grazing_threshold |eta| |F_before| is grazing. */
  double grazing_threshold = 1e-12;
  /** More events than this ends the simulation with kTooManyEvents (Zeno behaviour?). */
  int max_events = 10000;
  /** Sides at x0; by default the signs of h(x0), which must then be nonzero. */
  std::optional<Signs> initial_sides;
};

/** One event: where, which surfaces, and how transversal the crossing was. */
struct EventRecord {
  double t = 0.0;
  Eigen::VectorXd rho;
  /** Surfaces crossed together (model indices, lowest first). */
  std::vector<int> surfaces;
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
  long steps = 0;
  long field_evaluations = 0;
  bool ok() const { return status == IntegrationStatus::kReachedEnd; }
};

/** x(t_final) with no tangents. */
FlowResult simulate(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                    double t_final, const FlowOptions& options = {});
/** x(t_final) and the B-derivative of the flow applied to each column of `directions`. */
FlowResult simulate(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                    double t_final, const Eigen::Ref<const Eigen::MatrixXd>& directions,
                    const FlowOptions& options = {});
/** The full B-derivative as transition matrices and jump maps, reusable for any direction.
    @throws InvalidArgument (also for a status other than kReachedEnd, quoting its message). */
FlowDerivative flow_derivative(const SegmentModel& model,
                               const Eigen::Ref<const Eigen::VectorXd>& x0, double t_final,
                               const FlowOptions& options = {}, FlowResult* trajectory = nullptr);

/** A backend for `backend`. */
std::unique_ptr<SegmentIntegrator> make_integrator(Backend backend);

}  // namespace bflow

#endif  // BFLOW_INTEGRATORS_HYBRID_FLOW_H_

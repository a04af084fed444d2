// FlowDerivative: the B-derivative of a flow phi_t at x0 as the chain
//   D phi_t(x0; dx) = Phi_m J_m( ... Phi_1 J_1(Phi_0 dx))                     ([B] (5.17a))
// of smooth transition matrices Phi_i (between events) and jump maps J_i (one per event; a
// single surface is a saltation matrix, several are the piecewise-linear B of Algorithm 2.1).
//
// It evaluates any direction without simulating again, gives the Jacobian active for a
// direction, enumerates the pieces (capped), and has a jacobian() only where the derivative
// really is linear: a multi-surface event has no single Jacobian and the API never pretends
// it does.
#ifndef BFLOW_CORE_FLOW_DERIVATIVE_H_
#define BFLOW_CORE_FLOW_DERIVATIVE_H_

#include <cstddef>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/flow_notice.h"
#include "bflow/core/jump_map.h"

namespace bflow {

/** One linear piece of the flow's B-derivative: the crossing order chosen at each event and
    the product Phi_m M_m ... M_1 Phi_0. */
struct FlowPiece {
  /** orders[i] is the order in which event i's surfaces are crossed, first crossed first, in the
      model's surface indices (as in EventRecord::surfaces and event_surfaces()). */
  std::vector<std::vector<int>> orders;
  Eigen::MatrixXd matrix;
};

class FlowDerivative {
 public:
  /** Largest number of pieces pieces() returns. */
  static constexpr std::size_t kMaxPieces = 100000;
  /** Pieces of one jump that agree to this relative tolerance count as one linear map. */
  static constexpr double kLinearTolerance = 1e-9;

  /** The identity of R^d (no time elapsed). */
  explicit FlowDerivative(int dim);

  /** Left-multiplies by a smooth transition matrix (d x d). */
  void append_transition(const Eigen::Ref<const Eigen::MatrixXd>& phi);
  /** Appends a jump at an event at time t. `surfaces` are the model indices of the jump's surfaces,
      in the jump's row order (strictly increasing); empty means 0, 1, ..., n - 1. */
  void append_jump(JumpMap jump, double t, std::vector<int> surfaces = {});
  /** Records a notice of the engine that produced this derivative (see flow_notice.h). */
  void add_notice(FlowNotice notice) { notices_.push_back(std::move(notice)); }
  /** d/dt of phi_t(x0) at the final time: the field at the final state (set by the driver). */
  void set_time_derivative(const Eigen::Ref<const Eigen::VectorXd>& field);

  int dim() const { return dim_; }
  int events() const { return static_cast<int>(jumps_.size()); }
  const std::vector<Eigen::MatrixXd>& transitions() const { return transitions_; }
  const std::vector<JumpMap>& jumps() const { return jumps_; }
  const std::vector<double>& event_times() const { return times_; }
  /** event_surfaces()[i]: the model indices of event i's surfaces, in its jump's row order. */
  const std::vector<std::vector<int>>& event_surfaces() const { return surfaces_; }
  /** What the engine decided for the user or could not decide (near-simultaneous crossings not
      grouped, near grazing). Empty when nothing calls for a second look. */
  const std::vector<FlowNotice>& notices() const { return notices_; }
  const Eigen::VectorXd& time_derivative() const { return time_derivative_; }

  /** D phi_t(x0; dx). @throws InvalidArgument on a size mismatch, non-finite dx, or a tangent
      carried beyond the double range (at an event or at the final time). */
  Eigen::VectorXd apply(const Eigen::Ref<const Eigen::VectorXd>& dx) const;
  /** apply() on each column. @throws InvalidArgument on a row count other than d (whatever the
      number of columns) or a non-finite number, naming its column, before any column is
      mapped; then as apply(). */
  Eigen::MatrixXd apply_block(const Eigen::Ref<const Eigen::MatrixXd>& dx) const;
  /** Which crossing order the perturbation dx takes at each event: for event i, the order in
      which the perturbed trajectory crosses the event's surfaces, in the MODEL's surface indices,
      and when, relative to the nominal event time, to first order (dt = -eta . v / eta . F by the
      implicit function theorem, never by differentiating a root finder; v is the tangent arriving
      at the event). With one surface the order is that surface and the time its shift. */
  std::vector<CrossingOrder> crossing_orders(const Eigen::Ref<const Eigen::VectorXd>& dx) const;
  /** The matrix of the piece active at dx: Phi_m M_sigma_m ... M_sigma_1 Phi_0, with each
      sigma_i the crossing order of the tangent arriving at event i. */
  Eigen::MatrixXd active_jacobian(const Eigen::Ref<const Eigen::VectorXd>& dx) const;
  /** Every combination of the events' pieces. @throws InvalidArgument above kMaxPieces or
      when an event has more than JumpMap::kMaxEnumeratedSurfaces surfaces. */
  std::vector<FlowPiece> pieces() const;
  /** True when every jump is linear: one surface, or all its pieces equal to
      kLinearTolerance relative. It describes the events as grouped: crossings of different
      surfaces that were resolved as separate events give a linear derivative, valid for
      perturbations that do not reorder them; notices() names any pair closer than the
      near-simultaneity band. */
  bool is_linear() const;
  /** The Jacobian, when is_linear(). @throws InvalidArgument naming the first event whose
      jump is piecewise linear (its time, surfaces and how far its pieces differ). */
  Eigen::MatrixXd jacobian() const;

 private:
  // The stages: transitions_[0], jumps_[0], transitions_[1], ..., transitions_[m].
  int dim_;
  std::vector<Eigen::MatrixXd> transitions_;
  std::vector<JumpMap> jumps_;
  std::vector<double> times_;
  std::vector<std::vector<int>> surfaces_;
  std::vector<FlowNotice> notices_;
  Eigen::VectorXd time_derivative_;
};

}  // namespace bflow

#endif  // BFLOW_CORE_FLOW_DERIVATIVE_H_

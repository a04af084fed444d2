#include "bflow/core/flow_derivative.h"

#include <string>

#include "bflow/core/errors.h"

namespace bflow {

FlowDerivative::FlowDerivative(int dim) : dim_(dim) {
  if (dim < 1)
    throw InvalidArgument("FlowDerivative: dimension must be positive, got " + std::to_string(dim));
  transitions_.push_back(Eigen::MatrixXd::Identity(dim, dim));
  time_derivative_.setZero(dim);
}

void FlowDerivative::append_transition(const Eigen::Ref<const Eigen::MatrixXd>& phi) {
  if (phi.rows() != dim_ || phi.cols() != dim_ || !phi.allFinite()) {
    throw InvalidArgument("FlowDerivative: a transition must be a finite " + std::to_string(dim_) +
                          " x " + std::to_string(dim_) + " matrix, got " +
                          std::to_string(phi.rows()) + " x " + std::to_string(phi.cols()));
  }
  transitions_.back() = phi * transitions_.back();
}

void FlowDerivative::append_jump(JumpMap jump, double t, std::vector<int> surfaces) {
  if (jump.dim() != dim_) {
    throw InvalidArgument("FlowDerivative: jump of dimension " + std::to_string(jump.dim()) +
                          ", expected " + std::to_string(dim_));
  }
  if (surfaces.empty()) {
    for (int j = 0; j < jump.surfaces(); ++j) surfaces.push_back(j);
  }
  bool increasing = surfaces.size() == static_cast<std::size_t>(jump.surfaces());
  for (std::size_t k = 0; increasing && k < surfaces.size(); ++k) {
    increasing = surfaces[k] >= 0 && (k == 0 || surfaces[k] > surfaces[k - 1]);
  }
  if (!increasing) {
    std::string text;
    for (int j : surfaces) text += (text.empty() ? "" : ", ") + std::to_string(j);
    throw InvalidArgument("FlowDerivative: a jump of " + std::to_string(jump.surfaces()) +
                          " surfaces needs as many increasing, nonnegative model indices, got [" +
                          text + "]");
  }
  jumps_.push_back(std::move(jump));
  times_.push_back(t);
  surfaces_.push_back(std::move(surfaces));
  transitions_.push_back(Eigen::MatrixXd::Identity(dim_, dim_));
}

void FlowDerivative::set_time_derivative(const Eigen::Ref<const Eigen::VectorXd>& field) {
  if (field.size() != dim_) {
    throw InvalidArgument("FlowDerivative: time derivative has " + std::to_string(field.size()) +
                          " numbers, expected " + std::to_string(dim_));
  }
  time_derivative_ = field;
}

Eigen::VectorXd FlowDerivative::apply(const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  if (dx.size() != dim_ || !dx.allFinite()) {
    throw InvalidArgument("FlowDerivative::apply: tangent must have " + std::to_string(dim_) +
                          " finite numbers, got " + format_vector(dx));
  }
  // A transition can carry a finite tangent beyond the double range: said so, not passed on as
  // inf or NaN.
  const auto check_range = [&](const Eigen::VectorXd& v, std::size_t i) {
    if (v.allFinite()) return;
    throw InvalidArgument("FlowDerivative::apply: the tangent " +
                          (i < jumps_.size() ? "arriving at event " + std::to_string(i)
                                             : std::string("at the final time")) +
                          " is beyond the double range");
  };
  Eigen::VectorXd v = transitions_[0] * dx;
  for (std::size_t i = 0; i < jumps_.size(); ++i) {
    check_range(v, i);
    jumps_[i].apply(v, v);
    v = transitions_[i + 1] * v;
  }
  check_range(v, jumps_.size());
  return v;
}

Eigen::MatrixXd FlowDerivative::apply_block(const Eigen::Ref<const Eigen::MatrixXd>& dx) const {
  if (dx.rows() != dim_) {
    throw InvalidArgument("FlowDerivative::apply_block: tangents must have " +
                          std::to_string(dim_) + " rows, got " + std::to_string(dx.rows()) + " x " +
                          std::to_string(dx.cols()));
  }
  for (Eigen::Index k = 0; k < dx.cols(); ++k) {
    if (!dx.col(k).allFinite()) {
      throw InvalidArgument("FlowDerivative::apply_block: tangent is not finite in column " +
                            std::to_string(k) + " of " + std::to_string(dx.cols()) + ": " +
                            format_vector(dx.col(k)));
    }
  }
  Eigen::MatrixXd out(dim_, dx.cols());
  for (Eigen::Index k = 0; k < dx.cols(); ++k) out.col(k) = apply(dx.col(k));
  return out;
}

std::vector<CrossingOrder> FlowDerivative::crossing_orders(
    const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  if (dx.size() != dim_ || !dx.allFinite()) {
    throw InvalidArgument("FlowDerivative::crossing_orders: tangent must have " +
                          std::to_string(dim_) + " finite numbers, got " + format_vector(dx));
  }
  std::vector<CrossingOrder> orders;
  Eigen::VectorXd v = transitions_[0] * dx;
  for (std::size_t i = 0; i < jumps_.size(); ++i) {
    CrossingOrder order = jumps_[i].order(v);
    for (int& k : order.order) k = surfaces_[i][static_cast<std::size_t>(k)];
    orders.push_back(std::move(order));
    jumps_[i].apply(v, v);
    v = transitions_[i + 1] * v;
  }
  return orders;
}

Eigen::MatrixXd FlowDerivative::active_jacobian(const Eigen::Ref<const Eigen::VectorXd>& dx) const {
  if (dx.size() != dim_ || !dx.allFinite()) {
    throw InvalidArgument("FlowDerivative::active_jacobian: tangent must have " +
                          std::to_string(dim_) + " finite numbers, got " + format_vector(dx));
  }
  Eigen::MatrixXd m = transitions_[0];
  Eigen::VectorXd v = m * dx;
  for (std::size_t i = 0; i < jumps_.size(); ++i) {
    m = transitions_[i + 1] * jumps_[i].active_jacobian(v) * m;
    jumps_[i].apply(v, v);
    v = transitions_[i + 1] * v;
  }
  return m;
}

std::vector<FlowPiece> FlowDerivative::pieces() const {
  double count = 1;
  for (const JumpMap& jump : jumps_) {
    for (int k = 2; k <= jump.surfaces(); ++k) count *= k;
    if (jump.surfaces() > JumpMap::kMaxEnumeratedSurfaces || count > kMaxPieces) {
      throw InvalidArgument("FlowDerivative::pieces: the events have " + format_number(count) +
                            "+ pieces (product of n! over events); at most " +
                            std::to_string(kMaxPieces) + " are enumerated");
    }
  }
  std::vector<FlowPiece> result{FlowPiece{{}, transitions_[0]}};
  for (std::size_t i = 0; i < jumps_.size(); ++i) {
    const Pieces event_pieces = jumps_[i].pieces();
    std::vector<FlowPiece> next;
    next.reserve(result.size() * event_pieces.size());
    for (const FlowPiece& prefix : result) {
      for (std::size_t p = 0; p < event_pieces.size(); ++p) {
        FlowPiece piece{prefix.orders,
                        transitions_[i + 1] * event_pieces.matrix(p) * prefix.matrix};
        std::vector<int> order = event_pieces.order(p);
        for (int& k : order) k = surfaces_[i][static_cast<std::size_t>(k)];
        piece.orders.push_back(std::move(order));
        next.push_back(std::move(piece));
      }
    }
    result = std::move(next);
  }
  return result;
}

namespace {
// Largest difference between a jump's pieces relative to the largest piece; 0 for n = 1.
double piece_spread(const JumpMap& jump) {
  if (jump.surfaces() == 1) return 0.0;
  if (jump.surfaces() > JumpMap::kMaxEnumeratedSurfaces) return INFINITY;
  const Pieces pieces = jump.pieces();
  double largest = 0, spread = 0;
  for (std::size_t p = 0; p < pieces.size(); ++p) {
    largest = std::max(largest, pieces.matrix(p).norm());
    spread = std::max(spread, (pieces.matrix(p) - pieces.matrix(0)).norm());
  }
  return spread / std::max(largest, 1e-300);
}
}  // namespace

bool FlowDerivative::is_linear() const {
  for (const JumpMap& jump : jumps_) {
    if (!(piece_spread(jump) <= kLinearTolerance)) return false;
  }
  return true;
}

Eigen::MatrixXd FlowDerivative::jacobian() const {
  Eigen::MatrixXd m = transitions_[0];
  for (std::size_t i = 0; i < jumps_.size(); ++i) {
    const double spread = piece_spread(jumps_[i]);
    if (!(spread <= kLinearTolerance)) {
      throw InvalidArgument(
          "FlowDerivative::jacobian: the derivative is only piecewise linear: the event at t = " +
          format_number(times_[i]) + " crosses " + std::to_string(jumps_[i].surfaces()) +
          " surfaces at once and its pieces differ by " + format_number(spread) +
          " (relative); use apply() or active_jacobian(dx)");
    }
    std::vector<int> first(static_cast<std::size_t>(jumps_[i].surfaces()));
    for (std::size_t j = 0; j < first.size(); ++j) first[j] = static_cast<int>(j);
    m = transitions_[i + 1] * jumps_[i].saltation(first) * m;
  }
  return m;
}

}  // namespace bflow

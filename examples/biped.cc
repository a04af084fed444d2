// Example: the vertical-plane biped of [B] Section 3.2.4 (Figure 3.2).
//
// State (x, y, theta, xdot, ydot, thetadot); m = 1, J = 1, g = 9.8; two massless legs of
// length 0.5 at +-pi/4 from the body's vertical; ground y = -x^2; each foot j has penetration
// a_j = -foot_x^2 - foot_y and, while a_j > 0, the force -(kappa a_j + beta_j Da_j . qdot) Da_j^T
// with kappa = 1, beta = 1. From (0, 1, 0) at rest both feet touch at the same instant
// (t = 0.3968), an event where two surfaces are crossed at once.
//
//   conservative  beta_j = 0 ([B] (3.5)): the field is continuous, both pieces are I.
//   dissipative   beta_j = beta ([B] (3.6)): the saltation matrices (3.7) commute: a C^1 flow.
//   mode-damping  beta_j = beta/2 with one foot down, beta with both: a true kink.
//
// For each variant this prints the touchdown's pieces M_01 (foot 0 first) and M_10, and the
// B-derivative of phi_0.6 on several directions next to one-sided finite differences of the
// simulated flow. Run: build/examples/biped (exits 1 if a check fails).
#include <cstdio>
#include <string>
#include <vector>

#include "bflow/core/biped.h"
#include "bflow/integrators/finite_differences.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"

namespace {

void print_matrix(const char* name, const Eigen::MatrixXd& m) {
  for (Eigen::Index i = 0; i < m.rows(); ++i) {
    std::printf("  %-6s[", i == 0 ? name : "");
    for (Eigen::Index j = 0; j < m.cols(); ++j) std::printf(" %9.5f", m(i, j));
    std::printf(" ]\n");
  }
}

// Runs one variant; returns whether its checks pass.
template <typename Scene>
bool run(const bflow::BipedParams& params, const Scene& scene) {
  const auto model = bflow::adapt(scene);
  const Eigen::VectorXd x0 = bflow::biped_initial_state();
  const double t = 0.6;
  bflow::FlowOptions options;
  options.integrator.rtol = 1e-11;
  options.integrator.atol = 1e-13;
  bflow::FlowResult trajectory;
  const bflow::FlowDerivative derivative =
      bflow::flow_derivative(model, x0, t, options, &trajectory);
  std::printf("\n== %s ==\n", bflow::biped_variant_name(params.variant));
  bool ok = trajectory.events.size() == 1 && trajectory.events[0].group_size() == 2;
  for (const bflow::EventRecord& event : trajectory.events) {
    std::printf("event at t = %.10f: surfaces", event.t);
    for (int j : event.surfaces) std::printf(" %d", j);
    std::printf(" (%s -> %s)\n", event.sides_before.str().c_str(), event.sides_after.str().c_str());
  }
  if (!ok) {
    std::printf("expected one event where both feet touch\n");
    return false;
  }
  const bflow::JumpMap& jump = derivative.jumps()[0];
  const Eigen::MatrixXd m01 = jump.saltation({0, 1});
  const Eigen::MatrixXd m10 = jump.saltation({1, 0});
  print_matrix("M_01", m01);
  print_matrix("M_10", m10);
  const double spread = (m01 - m10).norm() / m01.norm();
  std::printf("|M_01 - M_10| / |M_01| = %.3e; the flow's derivative is %s\n", spread,
              derivative.is_linear() ? "linear (C^1 flow)" : "piecewise linear (a kink)");
  const bool kinked = params.variant == bflow::BipedVariant::kModeDamping;
  ok = ok && (kinked ? spread > 1e-3 : spread < 1e-12) && derivative.is_linear() == !kinked;

  std::printf("  %-28s %-6s %-58s %s\n", "dx", "order", "D phi_0.6(x0; dx)", "|D - FD| / |D|");
  const double alpha = 1e-7;
  double worst = 0;
  using Vector6 = Eigen::Matrix<double, 6, 1>;
  const std::vector<Vector6> directions = {
      Vector6::Unit(0), Vector6::Unit(2),  Vector6::Unit(3),
      Vector6::Unit(5), -Vector6::Unit(5), (Vector6() << 0.5, 0.2, -0.3, 0.0, 0.1, 1.0).finished()};
  for (const Vector6& dx : directions) {
    const Eigen::VectorXd image = derivative.apply(dx);
    const Eigen::VectorXd fd = bflow::fd::one_sided(model, x0, t, dx, alpha, options);
    const double error = (image - fd).norm() / image.norm();
    worst = std::max(worst, error);
    std::string order;
    for (int j : jump.order(derivative.transitions()[0] * dx).order) order += std::to_string(j);
    std::string dx_text, image_text;
    char buffer[32];
    for (int i = 0; i < 6; ++i) {
      std::snprintf(buffer, sizeof buffer, "%s%.1f", i ? "," : "", dx[i]);
      dx_text += buffer;
      std::snprintf(buffer, sizeof buffer, "%s%+.5f", i ? " " : "", image[i]);
      image_text += buffer;
    }
    std::printf("  (%-26s) %-6s %-58s %.2e\n", dx_text.c_str(), order.c_str(), image_text.c_str(),
                error);
  }
  // One-sided differences: truncation O(alpha) plus rtol / alpha.
  std::printf("worst |D - FD| / |D| = %.2e (alpha = %g)\n", worst, alpha);
  return ok && worst < 1e-4;
}

}  // namespace

int main() {
  bool ok = true;
  for (bflow::BipedVariant variant :
       {bflow::BipedVariant::kConservative, bflow::BipedVariant::kDissipative,
        bflow::BipedVariant::kModeDamping}) {
    bflow::BipedParams params;
    params.variant = variant;
    ok = bflow::visit_biped(params, [&](const auto& scene) { return run(params, scene); }) && ok;
  }
  std::printf("%s\n", ok ? "OK" : "MISMATCH");
  return ok ? 0 : 1;
}

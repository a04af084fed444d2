// Example: the B-derivative of the piecewise-constant field of [B] Section 3.1.
//
//   xdot = 1 + Delta(sign(x)),  h(x) = x:  d coordinate planes meet at rho = 0.
//
// From rho- = -F_-(0)/2 the trajectory reaches rho+ = F_+(0)/2 in unit time, crossing all d
// surfaces at once at rho. Between surfaces the field is constant, so the flow derivative over
// that unit time is the jump's B ([B] (2.10) with identity transition matrices).
//
// 1. Linear case Delta(b) = -delta b, d = 8: B = (1 - delta)/(1 + delta) I ([B] (3.2)).
// 2. Generic case, d = 4, Delta drawn at random (all components > -1): B has 4! = 24 pieces.
//    Each direction is checked against a one-sided finite difference of the exact flow (the
//    flow of a piecewise-constant field is computed exactly, event by event), which equals B
//    up to rounding because the flow is piecewise affine. The central difference is shown
//    too: it is wrong wherever B(-dx) != -B(dx).
//
// Both cases build the JumpMap from the model alone: normals from Dh(rho) and limits F_b(rho)
// by Ceres Jets (bflow::ad::jump_map_at).
//
// 3. The flow itself: bflow::flow_derivative of the simulated field for d = 2 ... 8 equals (3.2)
//    in the linear case and the jump module's B for a random Delta.
//
// Run: build/examples/jump_pwconst   (prints three tables, then OK; exits 1 on any mismatch)
#include <algorithm>
#include <cstdio>
#include <numeric>
#include <random>

#include "bflow/ad/model_jump.h"
#include "bflow/examples/piecewise_constant.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"

namespace {

using bflow::examples::PiecewiseConstantField;

std::string format(const Eigen::VectorXd& v) {
  std::string s = "[";
  for (Eigen::Index i = 0; i < v.size(); ++i) {
    char buffer[32];
    std::snprintf(buffer, sizeof buffer, "%s%+.5f", i ? ", " : "", v[i]);
    s += buffer;
  }
  return s + "]";
}

}  // namespace

int main() {
  bool ok = true;
  std::mt19937_64 rng(2024);
  std::normal_distribution<double> normal;

  // 1. Linear case.
  {
    const int d = 8;
    const double delta = 0.4;
    const PiecewiseConstantField model = PiecewiseConstantField::linear(d, delta);
    std::vector<int> all(d);
    std::iota(all.begin(), all.end(), 0);
    const bflow::JumpMap jump = bflow::ad::jump_map_at(model, Eigen::VectorXd::Zero(d), all);
    double worst = 0;
    for (int trial = 0; trial < 100; ++trial) {
      Eigen::VectorXd dx(d);
      for (int i = 0; i < d; ++i) dx[i] = normal(rng);
      worst = std::max(worst, (jump.apply(dx) - (1 - delta) / (1 + delta) * dx).norm() / dx.norm());
    }
    std::printf(
        "linear case d=%d: max error %.3g relative to |dx| over 100 directions "
        "(B = %.6f I expected)\n",
        d, worst, (1 - delta) / (1 + delta));
    ok = ok && worst < 1e-13;
  }

  // 2. Generic case.
  {
    const int d = 4;
    std::uniform_real_distribution<double> uniform(-0.8, 1.5);
    Eigen::MatrixXd delta(d, 1 << d);
    for (Eigen::Index i = 0; i < delta.size(); ++i) delta.data()[i] = uniform(rng);
    const PiecewiseConstantField model(delta);
    const bflow::JumpMap jump =
        bflow::ad::jump_map_at(model, Eigen::VectorXd::Zero(d), {0, 1, 2, 3});
    const Eigen::VectorXd rho_minus = -0.5 * jump.limit(bflow::Signs(d));
    const Eigen::VectorXd rho_plus = model.flow(rho_minus, 1.0);
    const double alpha = 1e-6;
    const std::size_t pieces = jump.pieces().size();
    std::printf("\n%-9s %-44s %-44s %-10s %-10s\n", "order", "dx", "B(dx)", "|B-FD+|", "|B-FDc|");
    double worst = 0;
    for (int trial = 0; trial < 8; ++trial) {
      Eigen::VectorXd dx(d);
      for (int i = 0; i < d; ++i) dx[i] = normal(rng);
      const Eigen::VectorXd image = jump.apply(dx);
      const Eigen::VectorXd forward = (model.flow(rho_minus + alpha * dx, 1.0) - rho_plus) / alpha;
      const Eigen::VectorXd central =
          (model.flow(rho_minus + alpha * dx, 1.0) - model.flow(rho_minus - alpha * dx, 1.0)) /
          (2 * alpha);
      const double error = (image - forward).norm() / dx.norm();
      worst = std::max(worst, error);
      std::string order;
      for (int j : jump.order(dx).order) order += std::to_string(j);
      std::printf("%-9s %-44s %-44s %-10.2e %-10.2e\n", order.c_str(), format(dx).c_str(),
                  format(image).c_str(), error, (image - central).norm() / dx.norm());
    }
    // Rounding in the finite difference: eps |rho| / alpha ~ 1e-10.
    std::printf(
        "generic case d=%d: %zu pieces, max error %.3g of B against one-sided FD "
        "(alpha = %g)\n",
        d, pieces, worst, alpha);
    ok = ok && worst < 1e-8 && pieces == 24;
  }

  // 3. The simulated flow: bflow::flow_derivative from rho- for unit time, d = 2 ... 8, against
  //    (3.2) in the linear case and against the jump module's B for random Delta.
  std::printf("\n%-3s %-26s %-26s\n", "d", "linear: |D - (3.2)| / |dx|", "random: |D - B| / |B|");
  for (int d = 2; d <= 8; ++d) {
    const double delta = 0.4;
    const PiecewiseConstantField linear = PiecewiseConstantField::linear(d, delta);
    const PiecewiseConstantField random = PiecewiseConstantField::random(d, 11);
    const bflow::FlowDerivative linear_flow =
        bflow::flow_derivative(bflow::adapt(linear), -0.5 * linear.limits().col(0), 1.0);
    const bflow::FlowDerivative random_flow =
        bflow::flow_derivative(bflow::adapt(random), -0.5 * random.limits().col(0), 1.0);
    const bflow::JumpMap b(Eigen::MatrixXd::Identity(d, d), random.limits());
    double linear_error = 0, random_error = 0;
    for (int trial = 0; trial < 20; ++trial) {
      Eigen::VectorXd dx(d);
      for (int i = 0; i < d; ++i) dx[i] = normal(rng);
      linear_error =
          std::max(linear_error,
                   (linear_flow.apply(dx) - (1 - delta) / (1 + delta) * dx).norm() / dx.norm());
      const Eigen::VectorXd image = b.apply(dx);
      random_error = std::max(random_error, (random_flow.apply(dx) - image).norm() / image.norm());
    }
    std::printf("%-3d %-26.3g %-26.3g\n", d, linear_error, random_error);
    // Constant fields between events: only rounding. The random case is exactly 0 when the
    // driver builds its jump from the same limits with the same arithmetic.
    ok = ok && linear_error < 1e-12 && random_error < 1e-11;
  }
  std::printf("%s\n", ok ? "OK" : "MISMATCH");
  return ok ? 0 : 1;
}

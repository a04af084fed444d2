// A separate project using all of an installed bflow through bflow::bflow: a jump map from a
// model by Jets, the flow derivative by SUNDIALS CVODES, and a FESD run (IPOPT).
#include <cmath>
#include <iostream>

#include "bflow/ad/model_jump.h"
#include "bflow/fesd/fesd.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"

// [B] (3.1) in d = 2 with delta = 1/3: B = (1 - delta) / (1 + delta) I = I / 2.
struct PiecewiseConstant {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 2;
  template <typename T>
  void field(const T*, bflow::Signs b, T* xdot) const {
    for (int i = 0; i < 2; ++i) xdot[i] = T(1.0 - b.sign(i) / 3.0);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
    h[1] = x[1];
  }
};

// x' in 2 - sign(x) from x = -1: the switch at t = 1/3, x(1) = 2/3.
struct Crossing {
  static constexpr int kStates = 1, kSwitches = 1;
  template <typename T>
  void switching(const T* x, T* c) const {
    c[0] = x[0];
  }
  template <typename T>
  void field(const T*, const T* a, T* xdot) const {
    xdot[0] = 3.0 - 2.0 * a[0];
  }
};

int main() {
  const Eigen::Vector2d dx(1.0, 2.0);
  const bflow::JumpMap jump =
      bflow::ad::jump_map_at(PiecewiseConstant{}, Eigen::Vector2d::Zero(), {0, 1});
  const Eigen::VectorXd jump_image = jump.apply(dx);

  // From (-2/3, -2/3) both surfaces are crossed at t = 1/2; D phi_1 = B.
  bflow::FlowOptions options;
  options.backend = bflow::Backend::kCvodesBdf;
  const bflow::FlowDerivative derivative = bflow::flow_derivative(
      bflow::adapt(PiecewiseConstant{}), Eigen::Vector2d(-2.0 / 3.0, -2.0 / 3.0), 1.0, options);
  const Eigen::VectorXd flow_image = derivative.apply(dx);

  const bflow::FesdResult fesd =
      bflow::fesd_simulate(bflow::adapt_step(Crossing{}), Eigen::VectorXd::Constant(1, -1.0), 1.0);

  std::cout << "consumer: B(dx) = [" << jump_image[0] << ", " << jump_image[1]
            << "], cvodes D phi_1(dx) = [" << flow_image[0] << ", " << flow_image[1]
            << "], fesd x(1) = " << fesd.x_end[0] << "\n";
  const bool ok = (jump_image - Eigen::Vector2d(0.5, 1.0)).norm() < 1e-14 &&
                  (flow_image - Eigen::Vector2d(0.5, 1.0)).norm() < 1e-6 && fesd.ok() &&
                  std::abs(fesd.x_end[0] - 2.0 / 3.0) < 1e-9;
  return ok ? 0 : 1;
}

// A separate project using bflow::ad, found with find_package(bflow COMPONENTS ad): ceres::Jet
// comes from the include directory the imported target bflow::ad carries.
#include <cmath>
#include <iostream>

#include "bflow/ad/jet_bridge.h"
#include "bflow/ad/model_jump.h"
#include "ceres/jet.h"

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

int main() {
  // d/dx x^3 at x = 2 is 12.
  const ceres::Jet<double, 1> x(2.0, 0);
  const ceres::Jet<double, 1> cube = x * x * x;
  // The Jacobian of (x0 x1, sin x0) at (1, 3) is [[3, 1], [cos 1, 0]].
  const auto f = [](const auto* in, auto* out) {
    using std::sin;
    out[0] = in[0] * in[1];
    out[1] = sin(in[0]);
  };
  const Eigen::MatrixXd jac = bflow::ad::jacobian(f, 2, Eigen::Vector2d(1.0, 3.0));
  const bflow::JumpMap jump =
      bflow::ad::jump_map_at(PiecewiseConstant{}, Eigen::Vector2d::Zero(), {0, 1});
  const Eigen::VectorXd image = jump.apply(Eigen::Vector2d(1.0, 2.0));
  std::cout << "consumer_ad: d(x^3)/dx = " << cube.v[0] << ", J = [" << jac(0, 0) << ", "
            << jac(0, 1) << "; " << jac(1, 0) << ", " << jac(1, 1) << "], B(dx) = [" << image[0]
            << ", " << image[1] << "]\n";
  Eigen::Matrix2d expected;
  expected << 3.0, 1.0, std::cos(1.0), 0.0;
  const bool ok = cube.v[0] == 12.0 && (jac - expected).norm() < 1e-15 &&
                  (image - Eigen::Vector2d(0.5, 1.0)).norm() < 1e-14;
  return ok ? 0 : 1;
}

// A separate project using bflow::core alone, found with find_package(bflow COMPONENTS core):
// Eigen is its only dependency.
#include <iostream>

#include "bflow/core/jump_map.h"

int main() {
  // Linear piecewise-constant field, delta = 1/3: B = (1 - delta)/(1 + delta) I = I / 2.
  const double delta = 1.0 / 3.0;
  Eigen::MatrixXd limits(2, 4);
  for (int w = 0; w < 4; ++w) {
    for (int i = 0; i < 2; ++i) limits(i, w) = ((w >> i) & 1) ? 1 - delta : 1 + delta;
  }
  const bflow::JumpMap jump(Eigen::MatrixXd::Identity(2, 2), limits);
  const Eigen::VectorXd image = jump.apply(Eigen::Vector2d(1.0, 2.0));
  std::cout << "consumer_core: B(dx) = [" << image[0] << ", " << image[1] << "]\n";
  return (image - Eigen::Vector2d(0.5, 1.0)).norm() < 1e-14 ? 0 : 1;
}

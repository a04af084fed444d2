// A separate project using bflow's FESD component alone (find_package(bflow COMPONENTS fesd)):
// x' in 3 - 2 a, a in the Heaviside step of x, from x = -1 crosses x = 0 at t = 1/3, so
// x(1) = 1/3 + (2/3) 1 = 2/3 - no SUNDIALS, no event-driven engine.
#include <cmath>
#include <iostream>

#include "bflow/fesd/fesd.h"

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
  const bflow::FesdResult r =
      bflow::fesd_simulate(bflow::adapt_step(Crossing{}), Eigen::VectorXd::Constant(1, -1.0), 1.0);
  std::cout << "consumer_fesd: x(1) = " << r.x_end[0] << ", switch at "
            << (r.switch_times.empty() ? -1.0 : r.switch_times[0]) << "\n";
  const bool ok = r.ok() && std::abs(r.x_end[0] - 2.0 / 3.0) < 1e-9 && r.switch_times.size() == 1 &&
                  std::abs(r.switch_times[0] - 1.0 / 3.0) < 1e-9;
  return ok ? 0 : 1;
}

// CornerOrbit: a field whose periodic orbit passes through the corner where n switching
// surfaces meet, so that all n are crossed at one instant once per period. Its orbit, period and
// return map are known in closed form (docs/orbits.md).
//
// State x = (p, q, w, z_1, ..., z_m), m = max(0, n - 2), r^2 = p^2 + q^2. With s_j = b.sign(j)
// (+1 on side + of surface j):
//
//   p'   = -omega q + k p (1 - r^2)
//   q'   =  omega p + k q (1 - r^2)
//   w'   = -a w + g_b,    g_b = g0 + sum_j c_j s_j + e s_0 s_1 ... s_{n-1}
//   z_i' = -a_z z_i
//
// and the surfaces, all through the point p = 1, q = 0, z = 0 (w does not enter):
//
//   h_0 = q - kappa_0 (1 - p),   h_1 = q - kappa_1 (1 - p),
//   h_j = q - kappa_j (1 - p) + z_{j-1}   (j >= 2).
//
// Their normals there, (kappa_j, 1, 0, e_{j-1}), are independent for kappa_0 != kappa_1: each
// surface beyond the second has a direction of its own, which n surfaces need (in the plane
// alone at most two normals are independent). The orbit has z = 0, so on it the unit circle
// crosses every surface at theta = 0 (the corner) and surface j again at
// theta_j = 2 atan(1 / kappa_j) (pi for kappa_j = 0), one at a time. (p, q) is a smooth limit
// cycle on r = 1 with angular speed omega (period T = 2 pi / omega), stable for k > 0 and
// unstable for k < 0: radial perturbations grow by exp(-2 k t). Only w switches: it integrates
// the piecewise-constant g_b, so the order in which a perturbed trajectory crosses the surfaces
// at the corner changes w, and the return map is piecewise linear for n >= 2 (with the product
// term e != 0; without it the surfaces act one at a time and the map is linear).
//
// On the section s = p - q (theta = 5 pi / 4, crossed upwards), in the basis
// e_r = -(1, 1, 0, ...)/sqrt 2 (radial), e_w and the e_z of its tangent space, the return map's
// pieces are lower triangular with the diagonal mu_r = exp(-2 k T), mu_w = exp(-a T),
// mu_z = exp(-a_z T): the growth rate is the largest of them.
#ifndef BFLOW_EXAMPLES_CORNER_ORBIT_H_
#define BFLOW_EXAMPLES_CORNER_ORBIT_H_

#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "bflow/core/errors.h"
#include "bflow/core/model.h"
#include "bflow/core/signs.h"

namespace bflow::examples {

struct CornerOrbit {
  static constexpr int kStates = kDynamic;
  static constexpr int kSurfaces = kDynamic;

  double omega = 2.0 * 3.14159265358979323846;
  double k = 1.0;
  double a = 1.0;
  double a_z = 1.5;
  double g0 = 0.5;
  double e = 0.7;
  /** kappa_j and c_j, one per surface (n = kappas.size() >= 1, equal sizes). */
  std::vector<double> kappas{0.0, 2.0};
  std::vector<double> c{0.3, -0.2};

  /** n surfaces with the kappas 0, 2, -1, 4, -3, 0.5, 6, -5 (second crossings at distinct
      angles, none at the section) and c_j = 0.3, -0.2, 0.25, ... (n <= 8).
      @throws InvalidArgument for n outside [1, 8]. */
  static CornerOrbit with_surfaces(int n) {
    if (n < 1 || n > 8) {
      throw InvalidArgument("CornerOrbit::with_surfaces: n must be in [1, 8], got " +
                            std::to_string(n));
    }
    static const double kKappas[8] = {0.0, 2.0, -1.0, 4.0, -3.0, 0.5, 6.0, -5.0};
    static const double kCs[8] = {0.3, -0.2, 0.25, -0.15, 0.2, -0.1, 0.15, -0.05};
    CornerOrbit model;
    model.kappas.assign(kKappas, kKappas + n);
    model.c.assign(kCs, kCs + n);
    return model;
  }

  int states() const { return 3 + extra_states(); }
  /** m = max(0, n - 2): the z states, one per surface beyond the second. */
  int extra_states() const { return surfaces() > 2 ? surfaces() - 2 : 0; }
  int surfaces() const { return static_cast<int>(kappas.size()); }
  double period() const { return 2.0 * 3.14159265358979323846 / omega; }

  /** g_b for the sides b. */
  double g(Signs b) const {
    double value = g0;
    double product = 1.0;
    for (int j = 0; j < surfaces(); ++j) {
      value += c[static_cast<std::size_t>(j)] * b.sign(j);
      product *= b.sign(j);
    }
    return value + e * product;
  }

  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    const T radial = T(k) * (T(1.0) - x[0] * x[0] - x[1] * x[1]);
    xdot[0] = -T(omega) * x[1] + radial * x[0];
    xdot[1] = T(omega) * x[0] + radial * x[1];
    xdot[2] = -T(a) * x[2] + T(g(b));
    for (int i = 0; i < extra_states(); ++i) xdot[3 + i] = -T(a_z) * x[3 + i];
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    for (int j = 0; j < surfaces(); ++j) {
      h[j] = x[1] - T(kappas[static_cast<std::size_t>(j)]) * (T(1.0) - x[0]);
      if (j >= 2) h[j] += x[1 + j];
    }
  }
};

/** The section s = p - q of CornerOrbit: theta = 5 pi / 4, crossed from s < 0 to s > 0. */
struct CornerOrbitSection {
  template <typename T>
  T operator()(const T* x) const {
    return x[0] - x[1];
  }
};

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_CORNER_ORBIT_H_

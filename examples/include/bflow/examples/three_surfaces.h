// ThreeSurfaces: a nonlinear five-state model whose nominal trajectory crosses three curved
// switching surfaces at one instant, for testing the B-derivative of a simultaneous crossing.
//
// State x = (x0, ..., x4). With s_j = b.sign(j) (+1 on side + of surface j) and w = b.bits()
// (0 ... 7, bit j set = side + of surface j), the field F_b is
//
//   x0' = 2 + 0.3 s0 + 0.1 s1 s2 + 0.2 sin(x3 + 0.4 w) - 0.2 x0 x1
//   x1' = 2 - 0.25 s1 + 0.1 s0 + 0.3 (1 + 0.2 s2) x0 x2 + 0.15 cos(x4 + 0.3 w)
//   x2' = 2 + 0.2 s2 - 0.1 s0 s1 + 0.2 (2 + s0) x1^2 + 0.1 (1 + 0.1 w) sin(2 x3)
//   x3' = x4 + 0.4 s0 + 0.1 s1 x3^2
//   x4' = -x3 + 0.3 s2 cos(x0) - 0.1 (1 + s1) x4
//
// and the surfaces h_j(x) = 0 are
//
//   h0 = x0 + 0.3 sin(x1 - x2) + 0.5 x0^2 - 0.2 (x3 - 0.5)(1 + x4)
//   h1 = x1 - 0.25 (exp(x0) - 1) + 0.3 x2^2 + 0.2 sin(x4 + 0.25)
//   h2 = x2 + 0.2 x0 x1 - 0.3 (x3 - 0.5)^2 + 0.25 sin(x0 + x4 + 0.25).
//
// All three vanish at rho = (0, 0, 0, 0.5, -0.25) (exactly, in any precision), with normals
// eta_0 = (1, 0.3, -0.3, -0.15, 0), eta_1 = (-0.25, 1, 0, 0, 0.2), eta_2 = (0.25, 0, 1, 0, 0.25)
// (linearly independent). The nominal trajectory is the one through rho at time
// kCrossingTime: it starts at nominal_start() = phi_{-kCrossingTime}(rho) under F_{---} (all
// sides -), reaches rho at t = kCrossingTime = 1, crosses all three surfaces there at once and
// runs in the +++ region, with no further crossing, up to kFinalTime = 1.5.
//
// Why it is a good test:
//  - every one of the 8 sign words has its own nonlinear field (the w-dependent phases and
//    gains make the 8 fields differ in more than a constant), so the B-derivative at rho has 6
//    distinct pieces M_sigma and each crossing order gives a different image;
//  - the surfaces are curved and their normals are not coordinate axes, so the normals must be
//    evaluated at rho (Dh at the wrong point is a visible error), and the transition matrices
//    before and after the event are far from the identity (the x3, x4 oscillator couples in);
//  - the crossing is transversal by a wide margin: eta_j . F_b(rho) >= 0.5 |eta_j| for every
//    surface j and every word b (the smallest is 1.106 |eta_1|, word -++; checked in
//    reference_flow_test.cc), so every crossing order is realised by a perturbation in the
//    matching cone, of any small size, and no sliding or grazing occurs near rho;
//  - it is cheap: a few transcendental functions per evaluation, templated on the scalar
//    (double, long double, ceres::Jet).
#ifndef BFLOW_EXAMPLES_THREE_SURFACES_H_
#define BFLOW_EXAMPLES_THREE_SURFACES_H_

#include <array>
#include <cmath>

#include <Eigen/Core>
#include <Eigen/LU>

#include "bflow/core/model.h"
#include "bflow/core/signs.h"

namespace bflow::examples {

struct ThreeSurfaces {
  static constexpr int kStates = 5;
  static constexpr int kSurfaces = 3;
  /** Time at which the nominal trajectory from nominal_start() reaches crossing_point(). */
  static constexpr double kCrossingTime = 1.0;
  /** A final time after the crossing: the nominal trajectory stays in +++ on (1, 1.5]. */
  static constexpr double kFinalTime = 1.5;

  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    using std::cos;
    using std::sin;
    const double s0 = b.sign(0);
    const double s1 = b.sign(1);
    const double s2 = b.sign(2);
    const double w = static_cast<double>(b.bits());
    xdot[0] =
        T(2.0 + 0.3 * s0 + 0.1 * s1 * s2) + T(0.2) * sin(x[3] + T(0.4 * w)) - T(0.2) * x[0] * x[1];
    xdot[1] = T(2.0 - 0.25 * s1 + 0.1 * s0) + T(0.3 * (1.0 + 0.2 * s2)) * x[0] * x[2] +
              T(0.15) * cos(x[4] + T(0.3 * w));
    xdot[2] = T(2.0 + 0.2 * s2 - 0.1 * s0 * s1) + T(0.2 * (2.0 + s0)) * x[1] * x[1] +
              T(0.1 * (1.0 + 0.1 * w)) * sin(T(2.0) * x[3]);
    xdot[3] = x[4] + T(0.4 * s0) + T(0.1 * s1) * x[3] * x[3];
    xdot[4] = -x[3] + T(0.3 * s2) * cos(x[0]) - T(0.1 * (1.0 + s1)) * x[4];
  }

  template <typename T>
  void surfaces(const T* x, T* h) const {
    using std::exp;
    using std::sin;
    const T u = x[3] - T(0.5);
    h[0] = x[0] + T(0.3) * sin(x[1] - x[2]) + T(0.5) * x[0] * x[0] - T(0.2) * u * (T(1.0) + x[4]);
    h[1] =
        x[1] - T(0.25) * (exp(x[0]) - T(1.0)) + T(0.3) * x[2] * x[2] + T(0.2) * sin(x[4] + T(0.25));
    h[2] = x[2] + T(0.2) * x[0] * x[1] - T(0.3) * u * u + T(0.25) * sin(x[0] + x[4] + T(0.25));
  }

  /** rho = (0, 0, 0, 0.5, -0.25), where all three surfaces meet (h(rho) = 0 exactly). */
  static Eigen::Matrix<double, 5, 1> crossing_point() {
    Eigen::Matrix<double, 5, 1> rho;
    rho << 0.0, 0.0, 0.0, 0.5, -0.25;
    return rho;
  }

  /** phi_{-kCrossingTime}(rho) under F_{---}, rounded to double: computed by
      ReferenceFlow::backward in long double (sixth-order Runge-Kutta, step 2^-9, accurate to
      ~1e-17; reference_flow_test.cc recomputes it). h(x0) = (-0.487, -0.767, -1.552), and the
      backward trajectory stays in the --- region all the way. */
  static Eigen::Matrix<double, 5, 1> nominal_start() {
    Eigen::Matrix<double, 5, 1> x0;
    x0 << -1.6411722630479521558, -2.5761076853860374787, -2.2025718167592446719,
        0.75798231288511820484, 0.61717639156830518305;
    return x0;
  }

  /** A tangent delta rho at rho that crosses the surfaces in `order` (a permutation of
      0, 1, 2): its first-order crossing times -eta_j . delta rho / eta_j . F_{---}(rho) are
      -1, 0 and 2 for order[0], order[1], order[2], spread enough that the field's change at
      the first crossings (at most a factor 1.6 along each normal) cannot swap the later ones;
      plus a fixed component along the surfaces, so that it is not in the span of the normals.
      Pull it back to a start with the inverse transition matrix. */
  static Eigen::Matrix<double, 5, 1> tangent_in_order(const std::array<int, 3>& order) {
    const Eigen::Matrix<double, 3, 5> eta = normals();
    const Eigen::Matrix<double, 5, 1> rho = crossing_point();
    Eigen::Matrix<double, 5, 1> f;
    ThreeSurfaces{}.field(rho.data(), Signs(3), f.data());
    const double times[3] = {-1.0, 0.0, 2.0};
    Eigen::Vector3d c;
    for (int k = 0; k < 3; ++k) c[order[k]] = -times[k] * eta.row(order[k]).dot(f);
    const Eigen::Matrix3d gram = eta * eta.transpose();
    const Eigen::Matrix<double, 5, 3> pinv = eta.transpose() * gram.inverse();
    Eigen::Matrix<double, 5, 1> v;
    v << 0.3, -0.5, 0.2, 1.0, 0.7;
    const Eigen::Matrix<double, 5, 1> along = v - pinv * (eta * v);
    return pinv * c + 0.5 * along;
  }

  /** Dh(rho), rows eta_j (oriented so that eta_j . F_b(rho) > 0 for every word b). */
  static Eigen::Matrix<double, 3, 5> normals() {
    Eigen::Matrix<double, 3, 5> eta;
    eta << 1.0, 0.3, -0.3, -0.15, 0.0,  //
        -0.25, 1.0, 0.0, 0.0, 0.2,      //
        0.25, 0.0, 1.0, 0.0, 0.25;
    return eta;
  }
};

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_THREE_SURFACES_H_

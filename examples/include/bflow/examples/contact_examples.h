// Lagrangian systems with a unilateral frictional contact, for time-freezing
// (bflow/ocp/time_freezing.h), with their closed-form motion.
//
// Falling ball. A point mass m at q = (x, z) over the ground z = 0 under gravity g and linear air
// drag (rate k: force -k m v), with Coulomb friction mu and an inelastic impact (e = 0):
// M = m I, f_v = -m (k vx, g + k vz), f_c = z, J_n = (0, 1), J_t = (1, 0). In flight
//   vx = vx0 e^{-kt},  vz = (vz0 + g/k) e^{-kt} - g/k  (k -> 0: vx0, vz0 - g t),
// it lands at the root t_i of z(t) with vz- < 0; the impact takes the normal velocity to 0 and
// the tangential one down by mu |vz-|, not below 0 (the friction cone):
//   vx+ = max(vx(t_i) - mu |vz-|, 0);
// the ball then slides on the ground, vx' = -mu g - k vx, and sticks where vx reaches 0.
#ifndef BFLOW_EXAMPLES_CONTACT_EXAMPLES_H_
#define BFLOW_EXAMPLES_CONTACT_EXAMPLES_H_

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Core>

namespace bflow::examples {

struct FallingBall {
  static constexpr int kDof = 2, kControls = 0;
  double m = 1.0;
  double g = 9.81;
  double k = 0.0;  ///< drag rate, >= 0

  template <typename T>
  void mass(const T*, T* M) const {
    M[0] = T(m);
    M[1] = T(0.0);
    M[2] = T(0.0);
    M[3] = T(m);
  }
  template <typename T>
  void forces(const T*, const T* v, const T*, T* f) const {
    f[0] = T(-m * k) * v[0];
    f[1] = T(-m * g) - T(m * k) * v[1];
  }
  template <typename T>
  T gap(const T* q) const {
    return q[1];
  }
  template <typename T>
  void normal(const T*, T* jn) const {
    jn[0] = T(0.0);
    jn[1] = T(1.0);
  }
  template <typename T>
  void tangent(const T*, T* jt) const {
    jt[0] = T(1.0);
    jt[1] = T(0.0);
  }
  /** The contact point's tangential coordinate, whose gradient J_t is (check_contact_jacobians). */
  template <typename T>
  T tangential_position(const T* q) const {
    return q[0];
  }

  /** The closed-form motion from (x0, z0 > 0, vx0 >= 0, vz0) with drag rate k >= 0 and friction
      mu >= 0 (see the top); the impact time by Newton's method on z(t) = 0. */
  struct Motion {
    double x0, z0, vx0, vz0, g, k, mu;

    // (x, z, vx, vz) in flight at time t.
    Eigen::Vector4d flight(double t) const {
      if (k == 0.0) return {x0 + vx0 * t, z0 + vz0 * t - 0.5 * g * t * t, vx0, vz0 - g * t};
      const double e = std::exp(-k * t), w = vz0 + g / k;
      return {x0 + vx0 * (1.0 - e) / k, z0 + w * (1.0 - e) / k - g * t / k, vx0 * e, w * e - g / k};
    }
    double impact_time() const {
      double t = (vz0 + std::sqrt(vz0 * vz0 + 2.0 * g * z0)) / g;  // without drag
      for (int it = 0; it < 60; ++it) {
        const Eigen::Vector4d s = flight(t);
        const double step = s[1] / s[3];
        t -= step;
        if (std::abs(step) <= 1e-16 * t) break;
      }
      return t;
    }
    double normal_velocity_before() const { return flight(impact_time())[3]; }
    double tangential_velocity_after() const {
      const Eigen::Vector4d s = flight(impact_time());
      return std::max(s[2] + mu * s[3], 0.0);
    }
    /** Sliding time after the impact until the ball sticks (infinite without friction). */
    double sliding_time() const {
      const double v = tangential_velocity_after(), a = mu * g;
      if (v == 0.0) return 0.0;
      if (a == 0.0) return std::numeric_limits<double>::infinity();
      return k == 0.0 ? v / a : std::log1p(k * v / a) / k;
    }
    double stop_time() const { return impact_time() + sliding_time(); }
    /** (x, z, vx, vz) at physical time t; at t_i the state after the impact. */
    Eigen::Vector4d at(double t) const {
      const double ti = impact_time();
      if (t < ti) return flight(t);
      const double xi = flight(ti)[0], v = tangential_velocity_after(), a = mu * g;
      const double s = std::min(t - ti, sliding_time());
      if (k == 0.0) return {xi + v * s - 0.5 * a * s * s, 0.0, v - a * s, 0.0};
      const double e = std::exp(-k * s), w = v + a / k;
      return {xi + w * (1.0 - e) / k - a * s / k, 0.0, w * e - a / k, 0.0};
    }
  };
  Motion motion(double x0, double z0, double vx0, double vz0, double mu) const {
    return {x0, z0, vx0, vz0, g, k, mu};
  }
};

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_CONTACT_EXAMPLES_H_

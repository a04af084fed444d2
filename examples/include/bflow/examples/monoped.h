// The two-link hopping robot of [F] Section 7.2 (the "Capler" monoped), as a Lagrangian system
// with one frictional contact for time-freezing (bflow/ocp/time_freezing.h).
//
// Configuration q = (q_x, q_z, phi_hip, phi_knee): the base point B = (q_x, q_z) of the main
// body, which translates only and carries the hip joint; the thigh from B at the absolute angle
// phi_hip, the shank from the knee K at phi_hip + phi_knee, angles measured from the downward
// vertical, positive when the foot swings forward, so a link of angle theta points along
// d(theta) = (sin theta, -cos theta). At q = (0, 0.4, 0, 0) the leg hangs straight and the foot
// touches the ground: the robot stands, as at the start and the target of [F] Section 7.2.
// Points:
//   main body's centre of mass   B + (0, s_BM)
//   thigh's centre of mass       B + s_thigh d(phi_hip),     knee K = B + l_thigh d(phi_hip)
//   shank's centre of mass       K + s_shank d(phi_hip + phi_knee)
//   foot                         F = K + l_shank d(phi_hip + phi_knee)
// The contact is the foot: gap f_c = F_z ([F] Section 7.2: f_c(q) = p_foot,z(q)), tangential
// position F_x, so J_n = grad F_z and J_t = grad F_x. The published l_BH and r_foot do not enter:
// with the hip below the base, or the gap measured to the bottom of a foot of radius r_foot, the
// published standing state q = (0, 0.4, 0, 0) would be 4.3 cm or 2.8 cm inside the ground.
//
// Dynamics (Lagrange). With p_i(q) the centres of mass, J_i = dp_i/dq and the link inertias
// about their centres I_thigh (angular velocity phi_hip') and I_shank (phi_hip' + phi_knee'):
//   M(q) = sum_i m_i J_i^T J_i + I_thigh e_3 e_3^T + I_shank (e_3 + e_4)(e_3 + e_4)^T,
//   f_v(q, v, u) = -sum_i m_i J_i^T (J_i' v) - g sum_i m_i grad p_i,z + (0, 0, u_hip, u_knee),
// where J_i' v = s theta'^2 (-sin theta, cos theta) for a point at distance s along a link of
// angle theta (the centripetal acceleration; the terms of the chain add up). The Coriolis terms
// of d/dt dT/dv - dT/dq reduce to this because the second derivatives of each p_i are symmetric.
// Parameters as published with nosnoc's hopping-robot example.
#ifndef BFLOW_EXAMPLES_MONOPED_H_
#define BFLOW_EXAMPLES_MONOPED_H_

#include <cmath>

#include <Eigen/Core>

namespace bflow::examples {

struct Monoped {
  static constexpr int kDof = 4, kControls = 2;
  double m_body = 3.975, m_thigh = 1.782, m_shank = 0.548;  // kg
  double l_bh = 0.043, l_thigh = 0.2, l_shank = 0.2;        // m (l_bh: see the top)
  double s_bm = 0.02, s_thigh = 0.016, s_shank = 0.1;       // m, centres of mass
  double r_foot = 0.028;                                    // m (not used: see the top)
  double i_thigh = 0.001, i_shank = 0.0032;                 // kg m^2, about the centres
  double g = 9.81;

  /** Position of a point at distances (a along the thigh, b along the shank) from the hip, and
      its Jacobian (2 x 4, row-major) and centripetal acceleration J' v. */
  template <typename T>
  void point(const T* q, const T* v, double a, double b, T* p, T* jac, T* bias) const {
    using std::cos;
    using std::sin;
    const T t1 = q[2], t2 = q[2] + q[3];
    const T c1 = cos(t1), s1 = sin(t1), c2 = cos(t2), s2 = sin(t2);
    p[0] = q[0] + T(a) * s1 + T(b) * s2;
    p[1] = q[1] - T(a) * c1 - T(b) * c2;
    if (jac != nullptr) {
      // d/dq_x, d/dq_z, d/dphi_hip (both links turn), d/dphi_knee (the shank turns)
      jac[0] = T(1.0);
      jac[1] = T(0.0);
      jac[2] = T(a) * c1 + T(b) * c2;
      jac[3] = T(b) * c2;
      jac[4] = T(0.0);
      jac[5] = T(1.0);
      jac[6] = T(a) * s1 + T(b) * s2;
      jac[7] = T(b) * s2;
    }
    if (bias != nullptr) {
      const T w1 = v[2], w2 = v[2] + v[3];
      bias[0] = -T(a) * w1 * w1 * s1 - T(b) * w2 * w2 * s2;
      bias[1] = T(a) * w1 * w1 * c1 + T(b) * w2 * w2 * c2;
    }
  }

  template <typename T>
  void mass(const T* q, T* M) const {
    for (int k = 0; k < 16; ++k) M[k] = T(0.0);
    const auto add = [&](double m, double a, double b) {
      T p[2], j[8];
      point<T>(q, nullptr, a, b, p, j, nullptr);
      for (int r = 0; r < 4; ++r) {
        for (int c = 0; c < 4; ++c) M[r * 4 + c] += T(m) * (j[r] * j[c] + j[4 + r] * j[4 + c]);
      }
    };
    M[0] += T(m_body);  // the main body translates with the base
    M[5] += T(m_body);
    add(m_thigh, s_thigh, 0.0);
    add(m_shank, l_thigh, s_shank);
    M[10] += T(i_thigh + i_shank);
    M[11] += T(i_shank);
    M[14] += T(i_shank);
    M[15] += T(i_shank);
  }

  /** f_v(q, v, u); u = (u_hip, u_knee), or nullptr for no torques. */
  template <typename T>
  void forces(const T* q, const T* v, const T* u, T* f) const {
    f[0] = T(0.0);
    f[1] = T(-m_body * g);
    f[2] = u != nullptr ? u[0] : T(0.0);
    f[3] = u != nullptr ? u[1] : T(0.0);
    const auto add = [&](double m, double a, double b) {
      T p[2], j[8], bias[2];
      point<T>(q, v, a, b, p, j, bias);
      for (int r = 0; r < 4; ++r) {
        f[r] -= T(m) * (j[r] * bias[0] + j[4 + r] * (bias[1] + T(g)));
      }
    };
    add(m_thigh, s_thigh, 0.0);
    add(m_shank, l_thigh, s_shank);
  }

  /** Kinetic plus potential energy (free flight conserves it without torques). */
  template <typename T>
  T energy(const T* q, const T* v) const {
    T M[16];
    mass(q, M);
    T kinetic(0.0);
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) kinetic += T(0.5) * v[r] * M[r * 4 + c] * v[c];
    }
    T pt[2], ps[2];
    point<T>(q, nullptr, s_thigh, 0.0, pt, nullptr, nullptr);
    point<T>(q, nullptr, l_thigh, s_shank, ps, nullptr, nullptr);
    return kinetic +
           T(g) * (T(m_body) * (q[1] + T(s_bm)) + T(m_thigh) * pt[1] + T(m_shank) * ps[1]);
  }

  template <typename T>
  void knee(const T* q, T* p) const {
    point<T>(q, nullptr, l_thigh, 0.0, p, nullptr, nullptr);
  }
  template <typename T>
  void foot(const T* q, T* p) const {
    point<T>(q, nullptr, l_thigh, l_shank, p, nullptr, nullptr);
  }
  template <typename T>
  T gap(const T* q) const {
    T p[2];
    foot(q, p);
    return p[1];
  }
  template <typename T>
  T tangential_position(const T* q) const {
    T p[2];
    foot(q, p);
    return p[0];
  }
  template <typename T>
  void normal(const T* q, T* jn) const {
    T p[2], j[8];
    point<T>(q, nullptr, l_thigh, l_shank, p, j, nullptr);
    for (int k = 0; k < 4; ++k) jn[k] = j[4 + k];
  }
  template <typename T>
  void tangent(const T* q, T* jt) const {
    T p[2], j[8];
    point<T>(q, nullptr, l_thigh, l_shank, p, j, nullptr);
    for (int k = 0; k < 4; ++k) jt[k] = j[k];
  }
};

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_MONOPED_H_

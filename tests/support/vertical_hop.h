// The vertical hop of a body on two identical legs, written by hand as one scalar equation: the
// reference for the hopping orbits of the biped (core/biped.h) and the pronking body
// (core/pronk.h), independent of the library's flow and jump code.
//
// On the symmetric orbit both feet act alike: flight y'' = -g; stance (y below the touchdown
// height y_td, a = y_td - y)
//   m y'' = -m g + 2 kappa a - 2 beta y' + 2 thrust tanh(y' / thrust_speed)
// (beta: the damping with both feet down). Flight in closed form, stance by a classic RK4 with
// step 2e-5, liftoff located by Newton on the last step; the periodic apex by the secant method.
#ifndef BFLOW_TESTS_SUPPORT_VERTICAL_HOP_H_
#define BFLOW_TESTS_SUPPORT_VERTICAL_HOP_H_

#include <cmath>

namespace bflow::testing {

struct VerticalHop {
  double m = 1.0, g = 9.8, kappa = 0.0, beta = 0.0, thrust = 0.0, thrust_speed = 0.1;
  double touchdown = 0.0;  ///< y_td: the height at which both feet touch the ground
};

struct Hop {
  double apex = 0.0;
  double time = 0.0;
};

/** From the apex at height y (at rest): the next apex height and the time it takes. */
inline Hop vertical_hop(const VerticalHop& p, double y) {
  const double y_td = p.touchdown;
  auto accel = [&](double yy, double v) {
    const double a = y_td - yy;
    return (-p.m * p.g + 2.0 * p.kappa * a - 2.0 * p.beta * v +
            2.0 * p.thrust * std::tanh(v / p.thrust_speed)) /
           p.m;
  };
  auto rk4 = [&](double& yy, double& v, double h) {
    const double k1y = v, k1v = accel(yy, v);
    const double k2y = v + 0.5 * h * k1v, k2v = accel(yy + 0.5 * h * k1y, v + 0.5 * h * k1v);
    const double k3y = v + 0.5 * h * k2v, k3v = accel(yy + 0.5 * h * k2y, v + 0.5 * h * k2v);
    const double k4y = v + h * k3v, k4v = accel(yy + h * k3y, v + h * k3v);
    yy += h / 6.0 * (k1y + 2.0 * k2y + 2.0 * k3y + k4y);
    v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
  };
  const double fall = std::sqrt(2.0 * (y - y_td) / p.g);
  double yy = y_td;
  double v = -p.g * fall;
  double t = fall;
  const double h = 2e-5;
  while (true) {
    double y1 = yy, v1 = v;
    rk4(y1, v1, h);
    if (y1 > y_td && v1 > 0.0) {
      // Liftoff inside this step: Newton on the step length.
      double step = h * (y_td - yy) / (y1 - yy);
      for (int k = 0; k < 8; ++k) {
        double y2 = yy, v2 = v;
        rk4(y2, v2, step);
        step -= (y2 - y_td) / v2;
      }
      rk4(yy, v, step);
      t += step;
      break;
    }
    yy = y1;
    v = v1;
    t += h;
  }
  return {y_td + v * v / (2.0 * p.g), t + v / p.g};
}

/** The apex height of the vertical periodic hop (secant method from y0) and its period. */
inline Hop vertical_orbit(const VerticalHop& p, double y0) {
  double a = y0, b = y0 + 0.01;
  double fa = vertical_hop(p, a).apex - a, fb = vertical_hop(p, b).apex - b;
  for (int k = 0; k < 40 && std::abs(fb) > 1e-13; ++k) {
    const double c = b - fb * (b - a) / (fb - fa);
    a = b;
    fa = fb;
    b = c;
    fb = vertical_hop(p, b).apex - b;
  }
  return {b, vertical_hop(p, b).time};
}

}  // namespace bflow::testing

#endif  // BFLOW_TESTS_SUPPORT_VERTICAL_HOP_H_

// The vertical-plane biped of [B] Section 3.2.4 (Figure 3.2), built from scene effects.
//
// State x = (x, y, theta, xdot, ydot, thetadot): a body of mass m and inertia J with two
// massless legs of length l at angles +-psi from the body's vertical, falling under gravity g
// onto the ground y = -x^2. Foot j (s_0 = +1, s_1 = -1) is
//
//   foot_j = (x, y) + l R(theta) (s_j sin psi, -cos psi)
//          = (x + l sin(theta + s_j psi),  y - l cos(theta + s_j psi)),
//
// its penetration a_j = -foot_{j,x}^2 - foot_{j,y} (> 0 iff the foot is below the ground), and
// surface j is h_j = a_j (side + = foot j in contact). With q = (x, y, theta),
// M = diag(m, m, J):
//
//   M qddot = (0, -m g, 0) - sum over contacts j active in b of (kappa a_j + beta_j Da_j.qdot)
//   Da_j^T
//
// Variants (beta_j):
//   conservative   beta_j = 0                      [B] (3.5): F continuous, C^1 flow
//   dissipative    beta_j = beta                   [B] (3.6): F jumps, saltations commute, C^1
//   mode-damping   beta/2 with one foot down, beta with both: a true kink (two pieces)
//
// An energy source (not in [B]): with thrust > 0 every foot in contact also pushes along its own
// motion, thrust tanh(Da_j.qdot / thrust_speed) Da_j^T (scene.h, LegThrust), so that the biped
// hops periodically: from rest at a suitable height both feet land and lift off together, an
// orbit through simultaneous events (docs/orbits.md). thrust = 0 (the default) is [B]'s biped.
//
// Defaults m = J = 1, g = 9.8, l = 0.5, psi = pi/4, kappa = 1, beta = 1. From (0, 1, 0) at
// rest the body falls straight down and both feet touch at the same instant
// (biped_touchdown()).
//
//   bflow::BipedParams p;                               // defaults, mode-damping
//   bflow::set_param(p, "kappa", "10");                 // from "kappa=10" on a command line
//   bflow::BipedTouchdown td = bflow::biped_touchdown(p);   // t = 0.3968, rho
//   bflow::visit_biped(p, [&](const auto& biped) {      // the scene type of p.variant
//     bflow::JumpMap jump = bflow::ad::jump_map_at(biped, td.state, {0, 1});
//     Eigen::MatrixXd m01 = jump.saltation({0, 1});     // foot 0 first
//     Eigen::MatrixXd m10 = jump.saltation({1, 0});     // foot 1 first
//   });
#ifndef BFLOW_CORE_BIPED_H_
#define BFLOW_CORE_BIPED_H_

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <string>
#include <string_view>
#include <utility>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/scene.h"
#include "bflow/core/text.h"

namespace bflow {

/** pi, to double precision. */
inline constexpr double kBipedPi = 3.14159265358979323846;

enum class BipedVariant { kConservative, kDissipative, kModeDamping };

/** "conservative", "dissipative" or "mode-damping". */
inline const char* biped_variant_name(BipedVariant variant) {
  switch (variant) {
    case BipedVariant::kConservative:
      return "conservative";
    case BipedVariant::kDissipative:
      return "dissipative";
    case BipedVariant::kModeDamping:
      return "mode-damping";
  }
  return "unknown";
}

/** Parses biped_variant_name() ("mode_damping" is accepted too).
    @throws InvalidArgument quoting the text and the accepted names. */
inline BipedVariant parse_biped_variant(std::string_view text) {
  if (text == "conservative") return BipedVariant::kConservative;
  if (text == "dissipative") return BipedVariant::kDissipative;
  if (text == "mode-damping" || text == "mode_damping") return BipedVariant::kModeDamping;
  throw InvalidArgument("biped variant " + quote(std::string(text)) +
                        " is not one of conservative, dissipative, mode-damping");
}

struct BipedParams {
  double m = 1.0;               ///< body mass, > 0
  double J = 1.0;               ///< body moment of inertia, > 0
  double g = 9.8;               ///< gravity, finite
  double leg_length = 0.5;      ///< l, > 0
  double psi = kBipedPi / 4.0;  ///< leg angle from the body's vertical, in (0, pi/2)
  double kappa = 1.0;           ///< penalty stiffness, > 0
  double beta = 1.0;            ///< damping, >= 0
  /** The legs' energy source (LegThrust): 0 for the passive biped of [B]; > 0 makes it hop. */
  double thrust = 0.0;        ///< >= 0
  double thrust_speed = 0.1;  ///< > 0
  BipedVariant variant = BipedVariant::kModeDamping;
};

/** Foot j's penetration of the ground y = -x^2 (see the file comment), with its gradient by
    hand: Da = (-2 foot_x, -1, -2 foot_x l cos(theta + s psi) - l sin(theta + s psi)). */
struct BipedFoot {
  double leg_length = 0.5;
  double psi = kBipedPi / 4.0;
  int side = 1;  ///< s_j: +1 for foot 0, -1 for foot 1

  /** foot_j(q) = (x + l sin(theta + s psi), y - l cos(theta + s psi)). */
  template <typename T>
  void foot(const T* q, T* point) const {
    using std::cos;
    using std::sin;
    const T angle = q[2] + T(side * psi);
    point[0] = q[0] + T(leg_length) * sin(angle);
    point[1] = q[1] - T(leg_length) * cos(angle);
  }

  template <typename T>
  T operator()(const T* q, T* grad) const {
    using std::cos;
    using std::sin;
    const T angle = q[2] + T(side * psi);
    const T s = sin(angle);
    const T c = cos(angle);
    const T foot_x = q[0] + T(leg_length) * s;
    const T foot_y = q[1] - T(leg_length) * c;
    if (grad != nullptr) {
      grad[0] = T(-2.0) * foot_x;
      grad[1] = T(-1.0);
      grad[2] = T(-2.0 * leg_length) * foot_x * c - T(leg_length) * s;
    }
    return -foot_x * foot_x - foot_y;
  }
};

using BipedContact = SoftContact<BipedFoot>;
/** Conservative or dissipative biped: body, gravity and two soft contacts (own damper beta_j). */
using BipedScene = Scene<PlanarBody, Gravity, BipedContact, BipedContact, LegThrust<2>>;
/** Mode-damping biped: two soft contacts without their own damper, plus
    ContactDependentDamping {0, beta/2, beta}. */
using BipedModeDampingScene = Scene<PlanarBody, Gravity, BipedContact, BipedContact,
                                    ContactDependentDamping<2>, LegThrust<2>>;

namespace internal {

// Checks one biped parameter; returns an empty string when it is valid, else the requirement.
inline const char* biped_param_requirement(std::string_view key, double value) {
  if (!std::isfinite(value)) return "finite";
  if (key == "m" || key == "J" || key == "leg_length" || key == "kappa") {
    return value > 0.0 ? "" : "> 0";
  }
  if (key == "beta" || key == "thrust") return value >= 0.0 ? "" : ">= 0";
  if (key == "thrust_speed") return value > 0.0 ? "" : "> 0";
  if (key == "psi") return (value > 0.0 && value < kBipedPi / 2.0) ? "" : "in (0, pi/2)";
  return "";
}

inline void check_biped_param(const char* caller, std::string_view key, double value) {
  const char* requirement = biped_param_requirement(key, value);
  if (requirement[0] != '\0') {
    throw InvalidArgument(std::string(caller) + ": biped parameter \"" + std::string(key) +
                          "\" must be " + requirement + ", got " + format_number(value));
  }
}

inline void check_biped_params(const char* caller, const BipedParams& p) {
  check_biped_param(caller, "m", p.m);
  check_biped_param(caller, "J", p.J);
  check_biped_param(caller, "g", p.g);
  check_biped_param(caller, "leg_length", p.leg_length);
  check_biped_param(caller, "psi", p.psi);
  check_biped_param(caller, "kappa", p.kappa);
  check_biped_param(caller, "beta", p.beta);
  check_biped_param(caller, "thrust", p.thrust);
  check_biped_param(caller, "thrust_speed", p.thrust_speed);
}

inline BipedContact biped_contact(const BipedParams& p, int side, double damping) {
  return BipedContact{BipedFoot{p.leg_length, p.psi, side}, p.kappa, damping};
}

}  // namespace internal

/** The keys set_param() accepts. */
inline constexpr const char* kBipedParamKeys =
    "m, J, g, leg_length, psi, kappa, beta, thrust, thrust_speed, variant";

/** Sets one parameter from text, as in "kappa=1e6" on a command line: key is one of
    kBipedParamKeys; numbers are read whole by strtod, variant by parse_biped_variant().
    @throws InvalidArgument naming an unknown key (and listing the known ones), a value that is
    not a number, or a value out of range (m, J, leg_length, kappa > 0; beta >= 0;
    psi in (0, pi/2); g finite; thrust >= 0; thrust_speed > 0). params is unchanged on error. */
inline void set_param(BipedParams& params, std::string_view key, std::string_view value) {
  if (key == "variant") {
    try {
      params.variant = parse_biped_variant(value);
    } catch (const InvalidArgument& e) {
      throw InvalidArgument(std::string("set_param: ") + e.what());
    }
    return;
  }
  double* field = nullptr;
  if (key == "m") field = &params.m;
  if (key == "J") field = &params.J;
  if (key == "g") field = &params.g;
  if (key == "leg_length") field = &params.leg_length;
  if (key == "psi") field = &params.psi;
  if (key == "kappa") field = &params.kappa;
  if (key == "beta") field = &params.beta;
  if (key == "thrust") field = &params.thrust;
  if (key == "thrust_speed") field = &params.thrust_speed;
  if (field == nullptr) {
    throw InvalidArgument("set_param: unknown biped parameter " + quote(std::string(key)) +
                          " (known: " + kBipedParamKeys + ")");
  }
  const std::string text(value);
  char* end = nullptr;
  errno = 0;
  const double number = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size() || errno == ERANGE) {
    throw InvalidArgument("set_param: biped parameter " + quote(std::string(key)) + " = " +
                          quote(text) + " is not a number");
  }
  internal::check_biped_param("set_param", key, number);
  *field = number;
}

/** Throws InvalidArgument (prefixed "validate_biped_params") if a parameter is out of range. */
inline void validate_biped_params(const BipedParams& params) {
  internal::check_biped_params("validate_biped_params", params);
}

/** The conservative (beta_j = 0) or dissipative (beta_j = beta) biped.
    @throws InvalidArgument for the mode-damping variant (use make_biped_mode_damping() or
    visit_biped()) or a parameter out of range. */
inline BipedScene make_biped(const BipedParams& p) {
  internal::check_biped_params("make_biped", p);
  if (p.variant == BipedVariant::kModeDamping) {
    throw InvalidArgument(
        "make_biped: the mode-damping variant is a BipedModeDampingScene; use "
        "make_biped_mode_damping() or visit_biped()");
  }
  const double damping = p.variant == BipedVariant::kDissipative ? p.beta : 0.0;
  return BipedScene(PlanarBody{p.m, p.J}, Gravity{p.g}, internal::biped_contact(p, +1, damping),
                    internal::biped_contact(p, -1, damping),
                    LegThrust<2>{p.thrust, p.thrust_speed});
}

/** The mode-damping biped: beta/2 with one foot down, beta with both.
    @throws InvalidArgument unless p.variant is kModeDamping, or a parameter is out of range. */
inline BipedModeDampingScene make_biped_mode_damping(const BipedParams& p) {
  internal::check_biped_params("make_biped_mode_damping", p);
  if (p.variant != BipedVariant::kModeDamping) {
    throw InvalidArgument(std::string("make_biped_mode_damping: variant is ") +
                          biped_variant_name(p.variant) + ", use make_biped()");
  }
  return BipedModeDampingScene(
      PlanarBody{p.m, p.J}, Gravity{p.g}, internal::biped_contact(p, +1, 0.0),
      internal::biped_contact(p, -1, 0.0), ContactDependentDamping<2>{{0.0, 0.5 * p.beta, p.beta}},
      LegThrust<2>{p.thrust, p.thrust_speed});
}

/** Builds the scene of p.variant and returns visitor(scene); the visitor is called with a
    const BipedScene& or a const BipedModeDampingScene& (a generic lambda takes both) and must
    return the same type for both. @throws InvalidArgument as the factories. */
template <typename Visitor>
auto visit_biped(const BipedParams& p, Visitor&& visitor) {
  if (p.variant == BipedVariant::kModeDamping) {
    const BipedModeDampingScene scene = make_biped_mode_damping(p);
    return std::forward<Visitor>(visitor)(scene);
  }
  const BipedScene scene = make_biped(p);
  return std::forward<Visitor>(visitor)(scene);
}

/** (0, 1, 0, 0, 0, 0): the start of [B] Section 3.2.4, at rest above the ground. */
inline Eigen::Matrix<double, 6, 1> biped_initial_state() {
  Eigen::Matrix<double, 6, 1> x;
  x << 0.0, 1.0, 0.0, 0.0, 0.0, 0.0;
  return x;
}

/** When and where both feet first touch the ground, falling from rest. */
struct BipedTouchdown {
  double time = 0.0;                  ///< since the start at rest
  Eigen::Matrix<double, 6, 1> state;  ///< rho = (0, y_td, 0, 0, -g t, 0)
};

/** Free fall from (0, start_height, 0) at rest: x = theta = 0 stay 0 and no contact is active
    before touchdown, so y(t) = start_height - g t^2 / 2 exactly. The feet are at
    (+-l sin psi, y - l cos psi) and touch y = -x^2 together when
      y_td = l cos psi - l^2 sin^2 psi,   t = sqrt(2 (start_height - y_td) / g),
    with velocity ydot = -sqrt(2 g (start_height - y_td)). For the defaults y_td = 0.2286,
    t = 0.3968, ydot = -3.888.
    @throws InvalidArgument for parameters out of range, g <= 0, or start_height <= y_td (the
    feet already touch). */
inline BipedTouchdown biped_touchdown(const BipedParams& p, double start_height = 1.0) {
  internal::check_biped_params("biped_touchdown", p);
  const double sin_psi = std::sin(p.psi);
  const double y_td =
      p.leg_length * std::cos(p.psi) - p.leg_length * p.leg_length * sin_psi * sin_psi;
  if (!(p.g > 0.0)) {
    throw InvalidArgument("biped_touchdown: the body falls only for g > 0, got g = " +
                          format_number(p.g));
  }
  if (!(std::isfinite(start_height) && start_height > y_td)) {
    throw InvalidArgument("biped_touchdown: start_height " + format_number(start_height) +
                          " must be above the touchdown height " + format_number(y_td));
  }
  const double drop = start_height - y_td;
  BipedTouchdown td;
  td.time = std::sqrt(2.0 * drop / p.g);
  td.state << 0.0, y_td, 0.0, 0.0, -std::sqrt(2.0 * p.g * drop), 0.0;
  return td;
}

}  // namespace bflow

#endif  // BFLOW_CORE_BIPED_H_

// Scenes: a bflow model composed at compile time from the effects it calls for.
//
// A scene is one planar rigid body plus the effects that act on it. Its state is
// x = (q, qdot) with q = (x, y, theta), and its field is the body's equation of motion
//
//   d/dt q = qdot,   M qddot = f_b(q, qdot) = the sum of the declared effects' generalized
//   forces,   M = diag(m, m, J).
//
// Each effect adds its own term to f_b and nothing else runs for effects that are not
// declared. Every SoftContact owns one switching surface h_j = a_j(q) (the penetration; side
// `+` <=> a_j > 0 <=> in contact), in the order the contacts are declared; the other effects own
// none. A scene without contacts therefore has kSurfaces = 0, surfaces() writes nothing, and
// no contact code is compiled into its field.
//
// Worked example: a body dropped on flat ground y = 0 with a penalty spring-damper
// (kappa = 100, beta = 3):
//
//   using Drop = bflow::Scene<bflow::PlanarBody, bflow::Gravity,
//                             bflow::SoftContact<bflow::FlatGround>>;
//   Drop drop(bflow::PlanarBody{2.0, 0.5}, bflow::Gravity{9.8},
//             bflow::SoftContact<bflow::FlatGround>{bflow::FlatGround{0.0}, 100.0, 3.0});
//   static_assert(Drop::kStates == 6 && Drop::kSurfaces == 1);
//   double x[6] = {0, -0.1, 0, 0, -0.7, 0};        // 0.1 below the ground, falling at 0.7
//   double h[1], xdot[6];
//   drop.surfaces(x, h);                           // h = a = -y = 0.1 (side +)
//   drop.field(x, bflow::Signs::parse("+"), xdot);
//   // a = -y, Da = (0, -1, 0), Da.qdot = -ydot = 0.7: force -(kappa a + beta Da.qdot) Da^T
//   // = (0, 10 + 2.1, 0), so yddot = 12.1 / 2 - 9.8 = -3.75.
//   drop.field(x, bflow::Signs::parse("-"), xdot);
//   // yddot = -9.8: with b = "-" the contact force is off even though y < 0 (the smooth
//   // extension F_b; the engine, not the field, decides b).
//
// Writing an effect. An effect is a copyable struct with
//
//   static constexpr int kSurfaces;      // 0, or 1 for a contact
//   void check() const;                  // throws bflow::InvalidArgument on bad parameters
//   template <typename T, int N>
//   void add_force(const SceneState<T, N>& s, int first_surface, T* force) const;
//   template <typename T, int N>
//   T potential(const SceneState<T, N>& s, int first_surface) const;   // 0 if dissipative
//
// plus, when kSurfaces == 1, `T surface(const T* q)` (= a_j(q)) and
// `void kinematics(const T* q, const T* qdot, ContactKinematics<T>* c)`. add_force adds to the
// three generalized force components; `first_surface` is the index of the effect's surface
// (the scene's count of surfaces declared before it). An effect reads the side of a surface
// from s.b only, never from the sign of a_j(q): F_b is the smooth extension.
//
// Constraint geometry. SoftContact<Constraint> takes a callable
//   template <typename T> T operator()(const T* q, T* grad) const;
// returning a_j(q) and, when grad is not null, writing the gradient Da_j(q) (3 numbers). The
// gradient is written by hand rather than by nested Jets: the geometry is a few lines, and a
// nested Jet<Jet<double, 8>, 3> would make every field-Jacobian pass several times dearer.
// Check a hand gradient once with bflow::ad::TangentChecker::check_against_ad (the tests do so
// for FlatGround and BipedFoot).
#ifndef BFLOW_CORE_SCENE_H_
#define BFLOW_CORE_SCENE_H_

#include <array>
#include <cmath>
#include <cstddef>
#include <string>
#include <tuple>
#include <type_traits>
#include <utility>

#include "bflow/core/errors.h"
#include "bflow/core/signs.h"

namespace bflow {

struct PlanarBody;

/** What an active contact j knows at (q, qdot): the penetration a_j(q), its gradient Da_j(q)
    (w.r.t. q = (x, y, theta)) and its rate Da_j(q).qdot. */
template <typename T>
struct ContactKinematics {
  T a;
  T da[3];
  T rate;
};

/** The quantities a scene evaluates once per field call and hands to every effect.
    contact[j] is filled only when b.plus(j) (contact j active); the others are zero. */
template <typename T, int kContacts>
struct SceneState {
  const PlanarBody& body;
  const T* q;     ///< (x, y, theta)
  const T* qdot;  ///< (xdot, ydot, thetadot)
  Signs b;
  int active_contacts;  ///< b.count_plus(); 0 when the scene has no contacts
  std::array<ContactKinematics<T>, kContacts> contact;
};

namespace internal {
[[noreturn]] inline void throw_bad_effect_parameter(const char* effect, const char* name,
                                                    const char* requirement, double value) {
  throw InvalidArgument(std::string(effect) + ": " + name + " must be " + requirement + ", got " +
                        format_number(value));
}

template <int... kSurfaces>
constexpr std::array<int, sizeof...(kSurfaces)> first_surfaces() {
  const int sizes[] = {kSurfaces...};
  std::array<int, sizeof...(kSurfaces)> first{};
  int count = 0;
  for (std::size_t i = 0; i < sizeof...(kSurfaces); ++i) {
    first[i] = count;
    count += sizes[i];
  }
  return first;
}
}  // namespace internal

/** The planar rigid body every scene is made of: mass m and moment of inertia J about the
    centre of mass, M = diag(m, m, J). It contributes the 6 states
    (x, y, theta, xdot, ydot, thetadot) and no force (no Coriolis terms in these coordinates). */
struct PlanarBody {
  static constexpr int kSurfaces = 0;
  double mass = 1.0;
  double inertia = 1.0;

  /** @throws InvalidArgument unless mass and inertia are positive and finite. */
  void check() const {
    if (!(std::isfinite(mass) && mass > 0.0)) {
      internal::throw_bad_effect_parameter("PlanarBody", "mass", "positive and finite", mass);
    }
    if (!(std::isfinite(inertia) && inertia > 0.0)) {
      internal::throw_bad_effect_parameter("PlanarBody", "inertia", "positive and finite", inertia);
    }
  }
  template <typename T, int N>
  void add_force(const SceneState<T, N>&, int, T*) const {}
  template <typename T, int N>
  T potential(const SceneState<T, N>&, int) const {
    return T(0.0);
  }
};

/** Uniform gravity g along -y: force (0, -m g, 0), potential m g y. */
struct Gravity {
  static constexpr int kSurfaces = 0;
  double g = 9.8;

  /** @throws InvalidArgument unless g is finite. */
  void check() const {
    if (!std::isfinite(g)) internal::throw_bad_effect_parameter("Gravity", "g", "finite", g);
  }
  template <typename T, int N>
  void add_force(const SceneState<T, N>& s, int, T* force) const {
    force[1] -= T(s.body.mass * g);
  }
  template <typename T, int N>
  T potential(const SceneState<T, N>& s, int) const {
    return T(s.body.mass * g) * s.q[1];
  }
};

/** Flat ground at height `height`: a(q) = height - y (penetration), Da = (0, -1, 0). */
struct FlatGround {
  double height = 0.0;

  template <typename T>
  T operator()(const T* q, T* grad) const {
    if (grad != nullptr) {
      grad[0] = T(0.0);
      grad[1] = T(-1.0);
      grad[2] = T(0.0);
    }
    return T(height) - q[1];
  }
};

/** A penalty spring (stiffness kappa) and damper (beta) on one unilateral constraint a_j(q) >= 0,
    active on side `+` of its surface h_j = a_j (penetration a_j > 0):
      force = -(kappa a_j + beta Da_j.qdot) Da_j^T  if b.plus(j),  0 otherwise;
      potential = 1/2 kappa a_j^2  if b.plus(j),  0 otherwise.
    With Da_j pointing into the constraint (a_j grows with penetration), -kappa a_j Da_j^T pushes
    the body out and -beta (Da_j.qdot) Da_j^T opposes the penetration rate. beta = 0 is the
    conservative penalty of [B] (3.5); beta > 0 the dissipative one of [B] (3.6).
    At the surface (a_j = 0) the spring force vanishes; the damper does not, so F_b jumps. */
template <typename Constraint>
struct SoftContact {
  static constexpr int kSurfaces = 1;
  Constraint constraint{};
  double stiffness = 1.0;  ///< kappa
  double damping = 0.0;    ///< beta

  /** @throws InvalidArgument unless stiffness and damping are finite and >= 0. */
  void check() const {
    if (!(std::isfinite(stiffness) && stiffness >= 0.0)) {
      internal::throw_bad_effect_parameter("SoftContact", "stiffness", "finite and >= 0",
                                           stiffness);
    }
    if (!(std::isfinite(damping) && damping >= 0.0)) {
      internal::throw_bad_effect_parameter("SoftContact", "damping", "finite and >= 0", damping);
    }
  }
  /** h_j(q) = a_j(q). */
  template <typename T>
  T surface(const T* q) const {
    return constraint(q, static_cast<T*>(nullptr));
  }
  template <typename T>
  void kinematics(const T* q, const T* qdot, ContactKinematics<T>* c) const {
    c->a = constraint(q, c->da);
    c->rate = c->da[0] * qdot[0] + c->da[1] * qdot[1] + c->da[2] * qdot[2];
  }
  template <typename T, int N>
  void add_force(const SceneState<T, N>& s, int j, T* force) const {
    if (!s.b.plus(j)) return;
    const ContactKinematics<T>& c = s.contact[static_cast<std::size_t>(j)];
    const T magnitude = T(stiffness) * c.a + T(damping) * c.rate;
    for (int i = 0; i < 3; ++i) force[i] -= magnitude * c.da[i];
  }
  template <typename T, int N>
  T potential(const SceneState<T, N>& s, int j) const {
    if (!s.b.plus(j)) return T(0.0);
    const ContactKinematics<T>& c = s.contact[static_cast<std::size_t>(j)];
    return T(0.5 * stiffness) * c.a * c.a;
  }
};

/** Damping set by how many contacts are active: with k >= 1 contacts active in b, every active
    contact j gets the damper force -beta(k) (Da_j.qdot) Da_j^T, beta(k) = damping_by_count[k]
    (entry 0 is never used). kContacts must equal the scene's number of SoftContacts; it adds
    to, and does not replace, each SoftContact's own damping (set those to 0 for a purely
    count-dependent damper). With {0, beta/2, beta} and two contacts this is the mode-dependent
    damping of [B] Section 3.2.4, whose flow has a true kink. */
template <int kContacts>
struct ContactDependentDamping {
  static_assert(kContacts >= 1 && kContacts <= Signs::kMaxSurfaces,
                "ContactDependentDamping<K>: K (the number of contacts) must be in [1, 64]");
  static constexpr int kSurfaces = 0;
  std::array<double, kContacts + 1> damping_by_count{};

  /** @throws InvalidArgument unless every beta(k) is finite and >= 0. */
  void check() const {
    for (double beta : damping_by_count) {
      if (!(std::isfinite(beta) && beta >= 0.0)) {
        internal::throw_bad_effect_parameter("ContactDependentDamping", "every damping_by_count",
                                             "finite and >= 0", beta);
      }
    }
  }
  template <typename T, int N>
  void add_force(const SceneState<T, N>& s, int, T* force) const {
    static_assert(N == kContacts,
                  "ContactDependentDamping<K>: K must equal the scene's number of SoftContacts");
    if (s.active_contacts == 0) return;
    const T beta(damping_by_count[static_cast<std::size_t>(s.active_contacts)]);
    for (int j = 0; j < N; ++j) {
      if (!s.b.plus(j)) continue;
      const ContactKinematics<T>& c = s.contact[static_cast<std::size_t>(j)];
      const T magnitude = beta * c.rate;
      for (int i = 0; i < 3; ++i) force[i] -= magnitude * c.da[i];
    }
  }
  template <typename T, int N>
  T potential(const SceneState<T, N>&, int) const {
    return T(0.0);
  }
};

/** An energy source for hopping: every active contact j pushes along its own motion with
      force = thrust tanh(Da_j.qdot / speed) Da_j^T,
    a negative damper that saturates at `thrust`. It feeds a hop about thrust x the travel of the
    contact per stance, while a damper takes an amount growing with the square of the speed, so
    the two balance at one amplitude: an isolated periodic hop. thrust = 0 (the default) adds
    nothing and costs one comparison. kContacts must equal the scene's number of SoftContacts. */
template <int kContacts>
struct LegThrust {
  static_assert(kContacts >= 1 && kContacts <= Signs::kMaxSurfaces,
                "LegThrust<K>: K (the number of contacts) must be in [1, 64]");
  static constexpr int kSurfaces = 0;
  double thrust = 0.0;
  double speed = 0.1;

  /** @throws InvalidArgument unless thrust is finite and >= 0 and speed finite and > 0. */
  void check() const {
    if (!(std::isfinite(thrust) && thrust >= 0.0)) {
      internal::throw_bad_effect_parameter("LegThrust", "thrust", "finite and >= 0", thrust);
    }
    if (!(std::isfinite(speed) && speed > 0.0)) {
      internal::throw_bad_effect_parameter("LegThrust", "speed", "finite and > 0", speed);
    }
  }
  template <typename T, int N>
  void add_force(const SceneState<T, N>& s, int, T* force) const {
    static_assert(N == kContacts, "LegThrust<K>: K must equal the scene's number of SoftContacts");
    if (thrust == 0.0 || s.active_contacts == 0) return;
    using std::tanh;
    for (int j = 0; j < N; ++j) {
      if (!s.b.plus(j)) continue;
      const ContactKinematics<T>& c = s.contact[static_cast<std::size_t>(j)];
      const T magnitude = T(thrust) * tanh(c.rate / T(speed));
      for (int i = 0; i < 3; ++i) force[i] += magnitude * c.da[i];
    }
  }
  template <typename T, int N>
  T potential(const SceneState<T, N>&, int) const {
    return T(0.0);
  }
};

/** A model (bflow/core/model.h) made of a PlanarBody (the first effect) and the given effects.
    kStates = 6; kSurfaces = the number of SoftContacts, surface j being the j-th declared. */
template <typename... Effects>
class Scene {
  static_assert(sizeof...(Effects) >= 1, "bflow::Scene needs at least a PlanarBody");
  static_assert(std::is_same_v<std::tuple_element_t<0, std::tuple<Effects...>>, PlanarBody>,
                "bflow::Scene: the first effect must be bflow::PlanarBody (it owns the states)");
  static_assert((0 + ... + static_cast<int>(std::is_same_v<Effects, PlanarBody>)) == 1,
                "bflow::Scene: exactly one PlanarBody");
  static_assert(((Effects::kSurfaces == 0 || Effects::kSurfaces == 1) && ...),
                "bflow::Scene: an effect owns 0 or 1 surfaces");

 public:
  static constexpr int kStates = 6;
  static constexpr int kSurfaces = (0 + ... + Effects::kSurfaces);
  static_assert(kSurfaces <= Signs::kMaxSurfaces, "bflow::Scene: at most 64 contacts");

  /** @throws InvalidArgument if an effect's check() fails (the message names the effect and
      the value). */
  explicit Scene(Effects... effects) : effects_(std::move(effects)...) {
    std::apply([](const auto&... e) { (e.check(), ...); }, effects_);
  }

  const PlanarBody& body() const { return std::get<0>(effects_); }
  /** The I-th declared effect (0 is the body). */
  template <std::size_t I>
  const auto& effect() const {
    return std::get<I>(effects_);
  }

  /** F_b(x): (qdot, M^{-1} f_b(q, qdot)). Contact j's force is on iff b.plus(j). */
  template <typename T>
  void field(const T* x, Signs b, T* xdot) const {
    T force[3];
    generalized_force(x, b, force);
    xdot[0] = x[3];
    xdot[1] = x[4];
    xdot[2] = x[5];
    xdot[3] = force[0] / T(body().mass);
    xdot[4] = force[1] / T(body().mass);
    xdot[5] = force[2] / T(body().inertia);
  }

  /** h_j(x) = a_j(q) for each contact (nothing is written when kSurfaces == 0). */
  template <typename T>
  void surfaces(const T* x, T* h) const {
    if constexpr (kSurfaces > 0) {
      for_each_effect([&](const auto& e, int first) {
        if constexpr (std::decay_t<decltype(e)>::kSurfaces > 0) h[first] = e.surface(x);
      });
    } else {
      static_cast<void>(x);
      static_cast<void>(h);
    }
  }

  /** f_b(q, qdot), the sum of the effects' generalized forces (3 numbers). */
  template <typename T>
  void generalized_force(const T* x, Signs b, T* force) const {
    const SceneState<T, kSurfaces> s = state(x, b);
    force[0] = T(0.0);
    force[1] = T(0.0);
    force[2] = T(0.0);
    for_each_effect([&](const auto& e, int first) { e.add_force(s, first, force); });
  }

  /** Kinetic energy 1/2 qdot^T M qdot plus the effects' potentials for word b (gravity m g y, 1/2
     kappa a_j^2 per active contact). Conserved along F_b when every effect is conservative. */
  template <typename T>
  T energy(const T* x, Signs b) const {
    const SceneState<T, kSurfaces> s = state(x, b);
    T e =
        T(0.5 * body().mass) * (x[3] * x[3] + x[4] * x[4]) + T(0.5 * body().inertia) * x[5] * x[5];
    for_each_effect([&](const auto& term, int first) { e += term.potential(s, first); });
    return e;
  }

 private:
  // kFirstSurface[i]: the number of surfaces declared before effect i.
  static constexpr std::array<int, sizeof...(Effects)> kFirstSurface =
      internal::first_surfaces<Effects::kSurfaces...>();

  // Calls f(effect, index of its first surface) for every effect, in declaration order.
  template <typename F>
  void for_each_effect(F&& f) const {
    for_each_effect_impl(f, std::index_sequence_for<Effects...>{});
  }
  template <typename F, std::size_t... I>
  void for_each_effect_impl(F& f, std::index_sequence<I...>) const {
    (f(std::get<I>(effects_), kFirstSurface[I]), ...);
  }

  // Contact kinematics are evaluated only for contacts active in b, and only in scenes that
  // have contacts.
  template <typename T>
  SceneState<T, kSurfaces> state(const T* x, Signs b) const {
    SceneState<T, kSurfaces> s{body(), x, x + 3, b, 0, {}};
    if constexpr (kSurfaces > 0) {
      s.active_contacts = b.count_plus();
      for_each_effect([&](const auto& e, int first) {
        if constexpr (std::decay_t<decltype(e)>::kSurfaces > 0) {
          if (b.plus(first)) e.kinematics(x, x + 3, &s.contact[static_cast<std::size_t>(first)]);
        }
      });
    }
    return s;
  }

  std::tuple<Effects...> effects_;
};

}  // namespace bflow

#endif  // BFLOW_CORE_SCENE_H_

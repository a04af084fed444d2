// Time-freezing ([F] Remark 2 and Section 7.2; Nurkanovic et al., IEEE Control Syst. Lett. 5(2),
// 2021): a Lagrangian system with a unilateral frictional contact, whose impacts make the
// velocity jump, rewritten as a piecewise-smooth system (PSS) without jumps that FESD simulates
// and optimises. The state is x = (q, v, t): positions, velocities and a clock.
//
// Where the contact is open or separating (region R1) the system flies freely and the clock
// runs:            f_1 = (v, M(q)^-1 f_v(q, v, u), 1).
// Where the contact point is below the ground and approaching (f_c < 0, J_n^T v < 0), auxiliary
// dynamics push the velocity along the frictional impact's direction while q and the clock
// stand still:     f_2 = (0, M(q)^-1 (J_n - mu J_t) a_n, 0)   for J_t^T v > 0 (R2),
//                  f_3 = (0, M(q)^-1 (J_n + mu J_t) a_n, 0)   for J_t^T v < 0 (R3).
// They run until the normal velocity reaches 0, where the trajectory slides on J_n^T v = 0 (the
// clock runs again, slower) or leaves. The pieces where the clock runs are the solution of the
// system with jumps; an inelastic frictional impact (e = 0): normal velocity to 0, tangential
// velocity reduced by mu times the normal impulse, down to 0 (the friction cone). In persistent
// contact the sliding on J_n^T v = 0 gives Coulomb friction mu times the normal force.
//
// Switching functions c = (f_c(q), J_n(q)^T v, J_t(q)^T v) and the sign matrix ([F] Section
// 7.2): R1 is the union of the first six base sets {c_1 > 0} u {c_1 < 0, c_2 > 0}, written as two
// rows (+1, 0, 0), (-1, +1, 0); R2 = (-1, -1, +1), R3 = (-1, -1, -1). With `kBaseSets` the
// eight base sets are the regions instead (the first six all with f_1), as Stewart's
// formulation needs.
//
// A system (one contact; n_q = kDof, n_u = kControls >= 0):
//
//   struct Ball {                                   // a point mass over the ground z = 0
//     static constexpr int kDof = 2, kControls = 0;
//     template <typename T> void mass(const T* q, T* M) const;             // M(q), row-major, SPD
//     template <typename T> void forces(const T* q, const T* v, const T* u, T* f) const;  // f_v
//     template <typename T> T gap(const T* q) const;                       // f_c(q), >= 0 allowed
//     template <typename T> void normal(const T* q, T* jn) const;          // J_n(q) = grad f_c
//     template <typename T> void tangent(const T* q, T* jt) const;         // J_t(q)
//   };
//   bflow::TimeFreezing<Ball> tf(Ball{}, {0.8, 200.0});                     // mu, a_n
//   bflow::PiecewiseSmoothAsStep<bflow::TimeFreezing<Ball>> model(tf, tf.sign_matrix());
//
// (u is nullptr in `forces` when kControls = 0.) Every function is a template on the scalar, so
// FESD and the OCP differentiate the PSS by Jets; check_contact_jacobians() compares J_n and
// J_t with Jets of the gap and of the contact point's `tangential_position<T>(q)`, if given.
// M(q)^-1 b is a Cholesky solve written on the scalar type, which the Hessian scalar (HessianJet)
// needs (Eigen's decompositions do not compile with it).
//
// In an optimal control problem (kSpeedOfTime), the last control is the speed of time
// s in [s_min, s_max]: every mode is multiplied by s, so the physical time advances as s dtau
// while the clock runs, and the stage-wise clock constraint t(tau_k) = k T / N (OcpProblem's
// stage bounds) ties the clock to the stages.
#ifndef BFLOW_OCP_TIME_FREEZING_H_
#define BFLOW_OCP_TIME_FREEZING_H_

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <ceres/jet.h>
#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/filippov.h"

namespace bflow {

/** The contact's data: friction coefficient mu >= 0 and the auxiliary constant a_n > 0 (the
    auxiliary dynamics' acceleration scale, [F] Section 7.2 uses 200). */
struct ContactParameters {
  double mu = 0.0;
  double a_n = 100.0;
};

namespace detail {
/** The Cholesky factor L (lower triangle, row-major) of a small symmetric positive definite
    M = L L^T, in place. Written on the scalar type so that every scalar bflow differentiates
    with (double, Jets, HessianJet) goes through it. */
template <typename T, int N>
void cholesky_factor(T* m) {
  using std::sqrt;
  for (int j = 0; j < N; ++j) {
    T diag = m[j * N + j];
    for (int k = 0; k < j; ++k) diag -= m[j * N + k] * m[j * N + k];
    m[j * N + j] = sqrt(diag);
    for (int i = j + 1; i < N; ++i) {
      T sum = m[i * N + j];
      for (int k = 0; k < j; ++k) sum -= m[i * N + k] * m[j * N + k];
      m[i * N + j] = sum / m[j * N + j];
    }
  }
}

/** b <- M^-1 b with L from cholesky_factor. */
template <typename T, int N>
void cholesky_solve(const T* l, T* b) {
  for (int i = 0; i < N; ++i) {
    for (int k = 0; k < i; ++k) b[i] -= l[i * N + k] * b[k];
    b[i] /= l[i * N + i];
  }
  for (int i = N - 1; i >= 0; --i) {
    for (int k = i + 1; k < N; ++k) b[i] -= l[k * N + i] * b[k];
    b[i] /= l[i * N + i];
  }
}
}  // namespace detail

/** The regions of the time-freezing PSS: three, R1 a union of six base sets (the Heaviside step
    formulation), or the eight base sets (Stewart's formulation needs them). */
enum class TimeFreezingRegions { kUnions, kBaseSets };

/** The time-freezing PSS of `System` (see the top of this file). kSpeedOfTime: the speed of
    time s is the last control and multiplies every mode (optimal control). */
template <typename System, TimeFreezingRegions kRegions = TimeFreezingRegions::kUnions,
          bool kSpeedOfTime = false>
class TimeFreezing {
 public:
  static constexpr bool kBaseSets = kRegions == TimeFreezingRegions::kBaseSets;
  static constexpr int kDof = System::kDof;
  static constexpr int kStates = 2 * kDof + 1;
  /** The system's controls, then s with kSpeedOfTime. */
  static constexpr int kControls = System::kControls + (kSpeedOfTime ? 1 : 0);
  static constexpr int kSwitches = 3;
  static constexpr int kModes = kBaseSets ? 8 : 3;
  static_assert(kDof >= 1, "TimeFreezing: the system needs kDof >= 1");
  static_assert(System::kControls >= 0, "TimeFreezing: kControls must be >= 0");
  /** Index of the clock in x. */
  static constexpr int kClock = 2 * kDof;

  /** @throws InvalidArgument if mu < 0 or a_n <= 0 or either is not finite. */
  TimeFreezing(System system, ContactParameters contact)
      : system_(std::move(system)), contact_(contact) {
    if (!(std::isfinite(contact.mu) && contact.mu >= 0.0)) {
      throw InvalidArgument(
          "TimeFreezing: the friction coefficient mu must be finite and >= 0, "
          "got " +
          format_number(contact.mu));
    }
    if (!(std::isfinite(contact.a_n) && contact.a_n > 0.0)) {
      throw InvalidArgument(
          "TimeFreezing: the auxiliary constant a_n must be finite and > 0, "
          "got " +
          format_number(contact.a_n));
    }
  }

  const System& system() const { return system_; }
  const ContactParameters& contact() const { return contact_; }

  /** c(x) = (f_c(q), J_n(q)^T v, J_t(q)^T v). */
  template <typename T>
  void switching(const T* x, T* c) const {
    const T* q = x;
    const T* v = x + kDof;
    T jn[kDof], jt[kDof];
    system_.normal(q, jn);
    system_.tangent(q, jt);
    c[0] = system_.gap(q);
    c[1] = T(0.0);
    c[2] = T(0.0);
    for (int i = 0; i < kDof; ++i) {
      c[1] += jn[i] * v[i];
      c[2] += jt[i] * v[i];
    }
  }

  /** The modes without controls (kControls = 0), F[i * d + k] = f_i(x)_k. */
  template <typename T>
  void modes(const T* x, T* f) const {
    static_assert(kControls == 0, "TimeFreezing: a system with controls needs modes(x, u, F)");
    modes(x, static_cast<const T*>(nullptr), f);
  }

  /** The modes, F[i * d + k] = f_i(x, u)_k, with u the kControls values (nullptr if none). */
  template <typename T>
  void modes(const T* x, const T* u, T* f) const {
    const T* q = x;
    const T* v = x + kDof;
    T factor[kDof * kDof];
    system_.mass(q, factor);
    detail::cholesky_factor<T, kDof>(factor);
    T free_flight[kDof];
    system_.forces(q, v, System::kControls > 0 ? u : nullptr, free_flight);
    detail::cholesky_solve<T, kDof>(factor, free_flight);  // M^-1 f_v
    T jn[kDof], jt[kDof], plus[kDof], minus[kDof];
    system_.normal(q, jn);
    system_.tangent(q, jt);
    const T mu(contact_.mu), an(contact_.a_n);
    for (int i = 0; i < kDof; ++i) {
      plus[i] = (jn[i] - mu * jt[i]) * an;   // R2: tangential velocity > 0, friction against it
      minus[i] = (jn[i] + mu * jt[i]) * an;  // R3
    }
    detail::cholesky_solve<T, kDof>(factor, plus);
    detail::cholesky_solve<T, kDof>(factor, minus);
    const T s = kSpeedOfTime ? u[System::kControls] : T(1.0);
    T* f1 = f;
    for (int i = 0; i < kDof; ++i) {
      f1[i] = s * v[i];
      f1[kDof + i] = s * free_flight[i];
    }
    f1[kClock] = s;
    const int first_auxiliary = kBaseSets ? 6 : 1;
    for (int r = 1; r < first_auxiliary; ++r) {
      for (int k = 0; k < kStates; ++k) f[r * kStates + k] = f1[k];
    }
    T* f2 = f + first_auxiliary * kStates;
    T* f3 = f2 + kStates;
    for (int i = 0; i < kDof; ++i) {
      f2[i] = T(0.0);
      f3[i] = T(0.0);
      f2[kDof + i] = s * plus[i];
      f3[kDof + i] = s * minus[i];
    }
    f2[kClock] = T(0.0);
    f3[kClock] = T(0.0);
  }

  /** The sign matrix of the regions: three rows for R1 (a union of two), R2, R3, or the eight
      base sets with kBaseSets. */
  static SignMatrix sign_matrix() {
    if constexpr (kBaseSets) {
      // Rows in the order of SignMatrix::dense(3): the last two are (-,-,+) and (-,-,-).
      return SignMatrix(SignMatrix::dense(3).matrix(), {0, 1, 2, 3, 4, 5, 6, 7});
    } else {
      Eigen::MatrixXi s(4, 3);
      s << 1, 0, 0,   //
          -1, 1, 0,   //
          -1, -1, 1,  //
          -1, -1, -1;
      return SignMatrix(s, {0, 0, 1, 2});
    }
  }

 private:
  System system_;
  ContactParameters contact_;
};

/** The physical trajectory of a time-freezing run: the columns of `states` (one time-freezing
    state per grid point, the clock in row `clock`) where the clock runs. A point is kept when the
    clock moved (by more than `tolerance`) from the point before or to the point after, and the
    first and last points always: so the start and the end of every frozen phase stay (the state
    before and after the jump, at the same physical time) and the points inside it are dropped.
    @throws InvalidArgument if `clock` is no row of `states` or `tolerance` < 0. */
inline std::vector<int> clock_running_points(const Eigen::Ref<const Eigen::MatrixXd>& states,
                                             int clock, double tolerance = 1e-9) {
  if (clock < 0 || clock >= states.rows() || !(tolerance >= 0.0)) {
    throw InvalidArgument("clock_running_points: clock row " + std::to_string(clock) + " of " +
                          std::to_string(states.rows()) + " rows, tolerance " +
                          format_number(tolerance));
  }
  std::vector<int> kept;
  const Eigen::Index n = states.cols();
  for (Eigen::Index j = 0; j < n; ++j) {
    const bool moved_in = j == 0 || states(clock, j) > states(clock, j - 1) + tolerance;
    const bool moves_on = j + 1 == n || states(clock, j + 1) > states(clock, j) + tolerance;
    if (moved_in || moves_on) kept.push_back(static_cast<int>(j));
  }
  return kept;
}

/** The hops of a time-freezing run of `system`: flight phases that start from the ground.
    Walking through the columns of `states` (time-freezing states (q, v, clock) in time order),
    the contact is on the ground where its gap is at most `contact` and in flight where it is above
    `lift`; a hop is counted when the gap rises above `lift` after having been on the ground, so a
    fall from a state in the air is no hop.
    @throws InvalidArgument if `states` has other than 2 kDof + 1 rows or 0 <= contact < lift
    fails. */
template <typename System>
int count_hops(const System& system, const Eigen::Ref<const Eigen::MatrixXd>& states,
               double contact = 1e-4, double lift = 1e-2) {
  constexpr int rows = 2 * System::kDof + 1;
  if (states.rows() != rows || !(contact >= 0.0 && contact < lift)) {
    throw InvalidArgument("count_hops: the states have " + std::to_string(states.rows()) +
                          " rows (" + std::to_string(rows) + " expected), contact " +
                          format_number(contact) + ", lift " + format_number(lift) +
                          " (0 <= contact < lift expected)");
  }
  int count = 0;
  bool grounded = false, flying = false;
  for (Eigen::Index j = 0; j < states.cols(); ++j) {
    const double gap = system.gap(states.col(j).data());  // q leads each column
    if (gap <= contact) {
      grounded = true;
      flying = false;
    } else if (gap > lift && grounded && !flying) {
      ++count;
      flying = true;
    }
  }
  return count;
}

namespace detail {
template <typename S, typename = void>
struct HasTangentialPosition : std::false_type {};
template <typename S>
struct HasTangentialPosition<S, std::void_t<decltype(std::declval<const S&>().tangential_position(
                                    std::declval<const double*>()))>> : std::true_type {};
}  // namespace detail

/** How far a system's J_n and J_t are from the gradients of its gap and of its tangential
    position, each by Jets: the largest entry of the difference over the largest entry of the
    gradient (or 1, if smaller). */
struct ContactJacobianCheck {
  double normal_error = 0.0;
  /** NaN when the system has no `tangential_position<T>(q)` to differentiate. */
  double tangent_error = std::numeric_limits<double>::quiet_NaN();
};

/** Compares J_n(q) with grad f_c(q) and, where the system provides `tangential_position<T>(q)`,
    J_t(q) with its gradient, both by Jets, at q.
    @throws InvalidArgument if q has other than kDof entries or is not finite. */
template <typename System>
ContactJacobianCheck check_contact_jacobians(const System& system,
                                             const Eigen::Ref<const Eigen::VectorXd>& q) {
  constexpr int n = System::kDof;
  if (q.size() != n || !q.allFinite()) {
    throw InvalidArgument("check_contact_jacobians: q needs " + std::to_string(n) +
                          " finite entries, got " + std::to_string(q.size()));
  }
  using J = ceres::Jet<double, n>;
  J qj[n];
  for (int i = 0; i < n; ++i) qj[i] = J(q[i], i);
  const auto error = [&](const J& f, const double* given) {
    double worst = 0.0, scale = 1.0;
    for (int i = 0; i < n; ++i) {
      worst = std::max(worst, std::abs(f.v[i] - given[i]));
      scale = std::max(scale, std::abs(f.v[i]));
    }
    return worst / scale;
  };
  ContactJacobianCheck check;
  double jn[n], jt[n];
  system.normal(q.data(), jn);
  check.normal_error = error(system.gap(qj), jn);
  if constexpr (detail::HasTangentialPosition<System>::value) {
    system.tangent(q.data(), jt);
    check.tangent_error = error(system.tangential_position(qj), jt);
  }
  return check;
}

}  // namespace bflow

#endif  // BFLOW_OCP_TIME_FREEZING_H_

// The monoped's optimal control problem of [F] Section 7.2: from x(0) = (0, 0.4, 0, 0, 0, ..., 0)
// to q_target = (3, 0.4, 0, 0) at rest in T = 3, by time-freezing (time_freezing.h) of the
// monoped (monoped.h) with the speed of time s as a third control and the stage-wise clock
// constraint. Least squares: Q = diag(1, 1, 10, 1, 1e-6 x 4, 0 for the clock), rho_u = 0.01 on
// the torques (none on s), Q_T = diag(1e3 x 4, 10 x 4, 0), |u| <= 100, s in [s_min, s_max], the
// state bounds of Section 7.2, and the foot's gap at least -5 mm at every element boundary (the
// path constraint of the published experiment, MonopedTimeFreezingOcp). The reference passes
// through q_x = 3 t / T and the heights 0.4, 0.6, 0.4, 0.6, 0.4 at t / T = 0, 1/4, 1/2, 3/4, 1 (two
// hops) as the smooth curve q_z = 0.5 - 0.1 cos(4 pi t / T), with the angles and velocities 0; it
// is also the initial guess of the states.
#ifndef BFLOW_EXAMPLES_MONOPED_OCP_H_
#define BFLOW_EXAMPLES_MONOPED_OCP_H_

#include <cmath>
#include <limits>
#include <string>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/examples/monoped.h"
#include "bflow/ocp/ocp.h"
#include "bflow/ocp/time_freezing.h"

namespace bflow::examples {

/** The time-freezing PSS of the monoped with the speed of time, in the three regions (Heaviside
    step formulation) or the eight base sets (Stewart). */
template <TimeFreezingRegions kRegions>
using MonopedTimeFreezing = TimeFreezing<Monoped, kRegions, true>;

/** The time-freezing PSS of the monoped with the path constraint of the published experiment:
    the foot's gap g = f_c(q) >= kGapLower at every element boundary (MonopedTask::problem gives
    the bound). Time-freezing reproduces an impact only where the foot meets the ground from
    above; inside the ground it stands on the auxiliary dynamics at any depth. The relaxed NLPs
    of the homotopy mix free flight into the auxiliary region and so let the foot sink, and the
    later NLPs keep it there: measured at N = 30 without this constraint (on an earlier form of
    the model, hip under the base), 59 of 91 element boundaries had the foot 1 mm to 6.3 cm
    deep. */
template <TimeFreezingRegions kRegions>
struct MonopedTimeFreezingOcp : MonopedTimeFreezing<kRegions> {
  static constexpr int kPath = 1;
  static constexpr double kGapLower = -0.005;  ///< m, as nosnoc's experiment
  using Base = MonopedTimeFreezing<kRegions>;
  using Base::Base;
  template <typename T>
  void path(const T* x, const T*, T* g) const {
    g[0] = this->system().gap(x);
  }
};

template <TimeFreezingRegions kRegions>
ControlledPiecewiseSmoothAsStep<MonopedTimeFreezingOcp<kRegions>> monoped_model() {
  const MonopedTimeFreezingOcp<kRegions> tf(Monoped{}, {0.8, 200.0});
  return {tf, MonopedTimeFreezing<kRegions>::sign_matrix()};
}

struct MonopedTask {
  static constexpr double kHorizon = 3.0;
  static constexpr double kTargetX = 3.0;
  static constexpr double kHeight = 0.4;
  double s_min = 1.0, s_max = 25.0;  ///< the speed of time's bounds

  /** The reference: (q, v, clock) at time t, computed from s = t / T. The homotopy's path
      depends on round-off: measured at N = 30, with q_x = 3 t / T in place of 3 (t / T) the
      iterates part within the first NLP and the last NLP ends far from the target
      (docs/ocp.md, the monoped). */
  static Eigen::VectorXd reference(double t) {
    const double pi = 3.14159265358979323846;
    Eigen::VectorXd x = Eigen::VectorXd::Zero(9);
    const double s = t / kHorizon;
    x[0] = kTargetX * s;
    x[1] = 0.5 - 0.1 * std::cos(4.0 * pi * s);
    x[8] = t;
    return x;
  }

  /** The solver options of the published experiment at N control stages (N_FE = 3 elements of
      Radau IIA, n_s = 2, as the library's defaults): the homotopy from sigma = 1 down by factors
      of 10 to 1e-7, IPOPT's tolerance 1e-6 and a complementarity tolerance of 1e-6 (the last
      NLP's products are at most 1e-7), at most 10000 IPOPT iterations per NLP (as the published
      example), every NLP started cold from the previous solution (warm_start = false) and no
      polish. Measured at N = 30 (step formulation): with the warm start the sigma = 0.1 NLP
      starts infeasible by 1.4 and crawls (1464 iterations, primal steps of 1e-3 to 1e-5), and
      the homotopy ended locally infeasible below sigma = 5.6e-5; started cold, sigma = 0.1 takes
      1555 iterations and the homotopy reaches sigma = 1e-7, "solved", in 11784 iterations
      (1531 s; one hop, the foot sliding inside the 5 mm band below the ground, docs/ocp.md),
      or, with the reference rounded otherwise, ends acceptable-only far from the target. The polish
     (the active set of sigma = 1e-4 fixed) was found locally infeasible. */
  static OcpOptions options(int stages) {
    OcpOptions o;
    o.stages = stages;
    o.sigma_initial = 1.0;
    o.sigma_factor = 0.1;
    o.sigma_final = 1e-7;
    o.nlp_tolerance = 1e-6;
    o.complementarity_tolerance = 1e-6;
    o.polish = false;
    o.warm_start = false;
    o.max_nlp_iterations = 10000;
    return o;
  }

  /** The target q(T) = (3, 0.4, 0, 0). */
  static Eigen::Vector4d target() { return {kTargetX, kHeight, 0.0, 0.0}; }

  /** The largest |q_i - q_target,i| of a time-freezing state x = (q, v, clock). */
  static double target_error(const Eigen::Ref<const Eigen::VectorXd>& x) {
    return (x.head(4) - target()).cwiseAbs().maxCoeff();
  }

  /** The number of hops in a run: flight phases that start from the ground. Walking through the
      columns of `x` (time-freezing states (q, v, clock) in time order), the foot is on the ground
      where its gap is at most `contact` and in flight where it is above `lift`; a hop is counted
      when the foot rises above `lift` after having been on the ground (the published start
      stands on it), so a fall from a state in the air is no hop.
      @throws InvalidArgument if x has other than 9 rows or 0 <= contact < lift fails. */
  static int hops(const Eigen::Ref<const Eigen::MatrixXd>& x, double contact = 1e-4,
                  double lift = 1e-2) {
    if (x.rows() != 9 || !(contact >= 0.0 && contact < lift)) {
      throw InvalidArgument("MonopedTask::hops: x has " + std::to_string(x.rows()) +
                            " rows (9 expected), contact " + format_number(contact) + ", lift " +
                            format_number(lift) + " (0 <= contact < lift expected)");
    }
    const Monoped robot;
    int count = 0;
    bool grounded = false, flying = false;
    for (Eigen::Index j = 0; j < x.cols(); ++j) {
      const Eigen::Vector4d q = x.col(j).head(4);
      const double gap = robot.gap(q.data());
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

  OcpProblem problem() const {
    const double inf = std::numeric_limits<double>::infinity();
    const double pi = 3.14159265358979323846;
    OcpProblem p;
    p.x0 = Eigen::VectorXd::Zero(9);
    p.x0[1] = kHeight;
    p.horizon = kHorizon;
    p.clock_state = 8;
    p.x_lower.resize(9);
    p.x_upper.resize(9);
    p.x_lower << -0.5, 0.0, -pi, -pi, -100, -100, -100, -100, -inf;
    p.x_upper << kTargetX + 0.5, 10.0, pi, pi, 100, 100, 100, 100, inf;
    p.u_lower = Eigen::Vector3d(-100.0, -100.0, s_min);
    p.u_upper = Eigen::Vector3d(100.0, 100.0, s_max);
    p.track_Q.resize(9);
    p.track_Q << 1.0, 1.0, 10.0, 1.0, 1e-6, 1e-6, 1e-6, 1e-6, 0.0;
    p.track_R = Eigen::Vector3d(0.01, 0.01, 0.0);
    p.u_ref = Eigen::Vector3d(0.0, 0.0, 1.0);
    p.track_Q_terminal.resize(9);
    p.track_Q_terminal << 1e3, 1e3, 1e3, 1e3, 10.0, 10.0, 10.0, 10.0, 0.0;
    p.path_lower = Eigen::VectorXd::Constant(
        1, MonopedTimeFreezingOcp<TimeFreezingRegions::kUnions>::kGapLower);
    p.path_upper = Eigen::VectorXd::Constant(1, inf);
    p.x_ref = reference;
    p.guess = OcpGuess::kReference;
    p.guess_trajectory = reference;
    p.guess_u = Eigen::Vector3d(0.0, 0.0, 1.0);
    return p;
  }
};

}  // namespace bflow::examples

#endif  // BFLOW_EXAMPLES_MONOPED_OCP_H_

// A family of periodic orbits along one parameter, by natural-parameter continuation: each
// member's Newton run starts from a prediction made from the members found before it.
//
//   bflow::OrbitFamilyOptions options;
//   const std::vector<bflow::OrbitFamilyMember> family = bflow::continue_orbits(
//       {1.0, 1.5, 2.0}, guess,
//       [&](double value, const Eigen::VectorXd& start) {
//         return bflow::find_periodic_orbit(bflow::adapt(MyModel{value}), section, start);
//       },
//       options);
//   family[k].orbit.converged;   // each member is a PeriodicOrbit, found or not
//
// The prediction. From two members found at consecutive values the guess is the secant
// extrapolation x_k + (v - v_k) / (v_k - v_{k-1}) (x_k - x_{k-1}); from one, that member's point;
// before any, the caller's guess. When the run from a secant prediction does not converge, the
// member is solved once more from the last point found, and member.decisions says so. A member
// that is not found (a Newton run that does not converge, or a solver that throws
// InvalidArgument: its message is the member's message) does not end the family: the next member
// is predicted from the members found before it, as if the one not found were not there. A point
// the solver calls converged but that is not finite or not of the guess's size is no member
// found either (converged is set to false, the message and decisions say why): it never starts
// another member's run.
#ifndef BFLOW_ORBITS_ORBIT_FAMILY_H_
#define BFLOW_ORBITS_ORBIT_FAMILY_H_

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "bflow/orbits/periodic_orbit.h"

namespace bflow {

struct OrbitFamilyMember {
  double value = 0.0;
  PeriodicOrbit orbit;
  /** Where the accepted Newton run started. */
  Eigen::VectorXd guess;
  /** "secant", "previous" (the last member found) or "guess" (the caller's). */
  std::string predictor;
  /** A secant prediction that failed and was replaced, with the reason; a converged point
      refused (not finite, or not of the guess's size). */
  std::vector<std::string> decisions;
  /** Newton runs made for this member (1 or 2). */
  int runs = 0;
};

struct OrbitFamilyOptions {
  /** Extrapolate from the last two members found (off: start from the last member found). */
  bool secant = true;
  /** Called after each member, with its index. */
  std::function<void(int, const OrbitFamilyMember&)> progress;
};

/** The orbit at value and guess: typically find_periodic_orbit on the model at that value. */
using OrbitSolver = std::function<PeriodicOrbit(double value, const Eigen::VectorXd& guess)>;

/** One member per value, in the order given (see the header comment).
    @throws InvalidArgument when a value is not finite or the guess is empty or not finite. */
std::vector<OrbitFamilyMember> continue_orbits(const std::vector<double>& values,
                                               const Eigen::Ref<const Eigen::VectorXd>& guess,
                                               const OrbitSolver& solve,
                                               const OrbitFamilyOptions& options = {});

}  // namespace bflow

#endif  // BFLOW_ORBITS_ORBIT_FAMILY_H_

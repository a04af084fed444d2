#include "bflow/orbits/orbit_family.h"

#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "bflow/core/errors.h"

namespace bflow {
namespace {

// The solver's result, or a member not found with the solver's message.
PeriodicOrbit attempt(const OrbitSolver& solve, double value, const Eigen::VectorXd& guess) {
  try {
    return solve(value, guess);
  } catch (const InvalidArgument& e) {
    PeriodicOrbit failed;
    failed.x = guess;
    failed.message = e.what();
    return failed;
  }
}

// Why a point the solver calls converged cannot start the next member (empty when it can): it
// must have the guess's size and be finite, or the predictions would read past its end or carry
// NaN on.
std::string unusable_point(const Eigen::VectorXd& x, Eigen::Index size) {
  if (x.size() != size) {
    return "the solver returned a converged point with " + std::to_string(x.size()) +
           " entries for a guess of " + std::to_string(size);
  }
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    if (!std::isfinite(x[i])) {
      return "the solver returned a converged point whose entry " + std::to_string(i) + " is " +
             format_number(x[i]);
    }
  }
  return {};
}

}  // namespace

std::vector<OrbitFamilyMember> continue_orbits(const std::vector<double>& values,
                                               const Eigen::Ref<const Eigen::VectorXd>& guess,
                                               const OrbitSolver& solve,
                                               const OrbitFamilyOptions& options) {
  if (guess.size() == 0 || !guess.allFinite()) {
    throw InvalidArgument("continue_orbits: the guess must be nonempty and finite");
  }
  for (std::size_t k = 0; k < values.size(); ++k) {
    if (!std::isfinite(values[k])) {
      throw InvalidArgument("continue_orbits: value " + std::to_string(k) + " is " +
                            format_number(values[k]));
    }
  }
  std::vector<OrbitFamilyMember> family;
  family.reserve(values.size());
  // The last two members found, in order: their values and points.
  std::vector<std::pair<double, Eigen::VectorXd>> found;
  for (std::size_t k = 0; k < values.size(); ++k) {
    OrbitFamilyMember member;
    member.value = values[k];
    Eigen::VectorXd start = found.empty() ? Eigen::VectorXd(guess) : found.back().second;
    member.predictor = found.empty() ? "guess" : "previous";
    if (options.secant && found.size() == 2 && found[1].first != found[0].first) {
      const double ratio = (member.value - found[1].first) / (found[1].first - found[0].first);
      const Eigen::VectorXd predicted =
          found[1].second + ratio * (found[1].second - found[0].second);
      if (predicted.allFinite()) {
        start = predicted;
        member.predictor = "secant";
      }
    }
    member.guess = start;
    member.orbit = attempt(solve, member.value, start);
    member.runs = 1;
    if (!member.orbit.converged && member.predictor == "secant") {
      member.decisions.push_back("the run from the secant prediction did not converge (" +
                                 member.orbit.message +
                                 "); solved again from the last member found");
      member.guess = found.back().second;
      member.predictor = "previous";
      member.orbit = attempt(solve, member.value, member.guess);
      member.runs = 2;
    }
    if (member.orbit.converged) {
      const std::string why = unusable_point(member.orbit.x, guess.size());
      if (!why.empty()) {
        member.orbit.converged = false;
        member.orbit.message = why + ": the member is not found and predicts no other";
        member.decisions.push_back(member.orbit.message);
      }
    }
    if (member.orbit.converged) {
      found.emplace_back(member.value, member.orbit.x);
      if (found.size() > 2) found.erase(found.begin());
    }
    if (options.progress) options.progress(static_cast<int>(k), member);
    family.push_back(std::move(member));
  }
  return family;
}

}  // namespace bflow

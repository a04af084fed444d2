// Finite differences of the simulated flow: the ground truth a B-derivative is checked against.
//
// One-sided differences (phi_t(x0 + a dx) - phi_t(x0)) / a converge to D phi_t(x0; dx) as
// a -> 0+ ([B] (2.3)), also at a kink. Central differences (phi_t(x0 + a dx) -
// phi_t(x0 - a dx)) / (2a) converge to (D phi(x0; dx) - D phi(x0; -dx)) / 2, which differs
// from the B-derivative wherever it is not linear: compare() shows both.
//
// Every run here simulates with Grouping::kNone, whatever `options` say: a perturbed run must
// resolve crossings however close they come, since grouping them would flip a side up to one
// window early, an error of O(window / alpha) in the quotient.
#ifndef BFLOW_INTEGRATORS_FINITE_DIFFERENCES_H_
#define BFLOW_INTEGRATORS_FINITE_DIFFERENCES_H_

#include <string>
#include <vector>

#include <Eigen/Core>

#include "bflow/integrators/hybrid_flow.h"

namespace bflow::fd {

/** (phi_t(x0 + alpha dx) - phi_t(x0)) / alpha. @throws InvalidArgument if a run fails. */
Eigen::VectorXd one_sided(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                          double t, const Eigen::Ref<const Eigen::VectorXd>& dx, double alpha,
                          const FlowOptions& options = {});
/** (phi_t(x0 + alpha dx) - phi_t(x0 - alpha dx)) / (2 alpha). */
Eigen::VectorXd central(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                        double t, const Eigen::Ref<const Eigen::VectorXd>& dx, double alpha,
                        const FlowOptions& options = {});

struct ReportRow {
  double alpha = 0.0;
  Eigen::VectorXd one_sided;
  Eigen::VectorXd central;
  /** |one_sided - derivative| / max(1, |derivative|), and the same for central. */
  double one_sided_error = 0.0;
  double central_error = 0.0;
};

struct Report {
  Eigen::VectorXd derivative;
  std::vector<ReportRow> rows;
  /** The row whose one-sided error is smallest. */
  const ReportRow& best_one_sided() const;
  /** A table, one row per alpha. */
  std::string str() const;
};

/** alpha = 1e-2, 1e-3, ..., 1e-10. */
std::vector<double> default_steps();

/** Differences at each alpha against `derivative` (e.g. FlowDerivative::apply(dx)). */
Report compare(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0, double t,
               const Eigen::Ref<const Eigen::VectorXd>& dx,
               const Eigen::Ref<const Eigen::VectorXd>& derivative, const FlowOptions& options = {},
               const std::vector<double>& alphas = default_steps());

}  // namespace bflow::fd

#endif  // BFLOW_INTEGRATORS_FINITE_DIFFERENCES_H_

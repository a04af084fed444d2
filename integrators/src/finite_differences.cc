#include "bflow/integrators/finite_differences.h"

#include <algorithm>
#include <cstdio>

#include "bflow/core/errors.h"

namespace bflow::fd {

namespace {
Eigen::VectorXd end_state(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                          double t, const FlowOptions& options) {
  // A perturbed run must resolve crossings however close they come: grouping them would flip a
  // side up to one window early, an error of O(window / alpha) in the quotient.
  FlowOptions ungrouped = options;
  ungrouped.grouping = Grouping::kNone;
  const FlowResult r = simulate(model, x0, t, ungrouped);
  if (!r.ok()) {
    throw InvalidArgument(std::string("finite differences: the run from x0 = ") +
                          format_vector(x0) + " ended with " + to_string(r.status) + ": " +
                          r.message);
  }
  return r.x;
}

void check_alpha(double alpha) {
  if (!(alpha > 0.0) || !std::isfinite(alpha)) {
    throw InvalidArgument("finite differences: alpha must be positive, got " +
                          format_number(alpha));
  }
}
}  // namespace

Eigen::VectorXd one_sided(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                          double t, const Eigen::Ref<const Eigen::VectorXd>& dx, double alpha,
                          const FlowOptions& options) {
  check_alpha(alpha);
  const Eigen::VectorXd moved = x0 + alpha * dx;
  return (end_state(model, moved, t, options) - end_state(model, x0, t, options)) / alpha;
}

Eigen::VectorXd central(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                        double t, const Eigen::Ref<const Eigen::VectorXd>& dx, double alpha,
                        const FlowOptions& options) {
  check_alpha(alpha);
  const Eigen::VectorXd plus = x0 + alpha * dx;
  const Eigen::VectorXd minus = x0 - alpha * dx;
  return (end_state(model, plus, t, options) - end_state(model, minus, t, options)) / (2 * alpha);
}

std::vector<double> default_steps() {
  std::vector<double> alphas;
  for (int e = 2; e <= 10; ++e) alphas.push_back(std::pow(10.0, -e));
  return alphas;
}

const ReportRow& Report::best_one_sided() const {
  if (rows.empty()) throw InvalidArgument("finite differences: the report has no rows");
  return *std::min_element(rows.begin(), rows.end(), [](const ReportRow& a, const ReportRow& b) {
    return a.one_sided_error < b.one_sided_error;
  });
}

std::string Report::str() const {
  std::string text = "   alpha   one-sided error   central error\n";
  for (const ReportRow& row : rows) {
    char line[96];
    std::snprintf(line, sizeof line, "%8.0e   %15.3e   %13.3e\n", row.alpha, row.one_sided_error,
                  row.central_error);
    text += line;
  }
  return text;
}

Report compare(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0, double t,
               const Eigen::Ref<const Eigen::VectorXd>& dx,
               const Eigen::Ref<const Eigen::VectorXd>& derivative, const FlowOptions& options,
               const std::vector<double>& alphas) {
  Report report;
  report.derivative = derivative;
  const Eigen::VectorXd base = end_state(model, x0, t, options);
  const double scale = std::max(1.0, derivative.norm());
  for (double alpha : alphas) {
    check_alpha(alpha);
    ReportRow row;
    row.alpha = alpha;
    const Eigen::VectorXd plus = x0 + alpha * dx;
    const Eigen::VectorXd minus = x0 - alpha * dx;
    const Eigen::VectorXd at_plus = end_state(model, plus, t, options);
    row.one_sided = (at_plus - base) / alpha;
    row.central = (at_plus - end_state(model, minus, t, options)) / (2 * alpha);
    row.one_sided_error = (row.one_sided - derivative).norm() / scale;
    row.central_error = (row.central - derivative).norm() / scale;
    report.rows.push_back(std::move(row));
  }
  return report;
}

}  // namespace bflow::fd

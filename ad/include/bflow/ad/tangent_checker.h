// TangentChecker: compares derivatives with central finite differences (or with AD), so that
// a model's field and surfaces, and any analytic Jacobian a user writes by hand, can be
// trusted before they are used.
//
//   bflow::ad::TangentChecker checker;                    // default step and tolerance
//   auto f = [&](const auto* x, auto* y) { model.field(x, b, y); };
//   bflow::ad::TangentReport r = checker.check_ad_jacobian(f, d, x);    // AD vs differences
//   if (!r.ok) std::cerr << r.str() << "\n";
//
//   Eigen::MatrixXd mine = my_hand_written_jacobian(x);
//   r = checker.check_against_ad(f, d, x, mine);          // exact reference: tight tolerance
//   r = checker.check_jacobian(f, d, x, mine);            // f may be a double-only function
//
// Central differences. Column i of the reference is (f(x + h_i e_i) - f(x - h_i e_i)) /
// (2 h_i) with h_i = relative_step * max(1, |x_i|) (the denominator uses the representable
// difference of the two points). With the default relative_step = cbrt(eps) ~ 6.1e-6 the error
// is about 1e-11 times the size of f''' h^2 and f / h, so the default tolerance 1e-6 on the
// relative error leaves room for badly scaled functions yet catches a wrong derivative.
// A model's field F_b is the smooth extension on all of U, so differences of F_b are valid at
// any x, also on or across a surface; differences of the flow at a kink are not (use one-sided
// differences there, see DESIGN.md).
//
// Errors are measured entrywise: absolute |c - r| and relative |c - r| / max(1, |r|), where c
// is the entry being checked and r the reference entry.
#ifndef BFLOW_AD_TANGENT_CHECKER_H_
#define BFLOW_AD_TANGENT_CHECKER_H_

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <utility>

#include <Eigen/Core>

#include "bflow/ad/jet_bridge.h"
#include "bflow/core/errors.h"
#include "bflow/core/model.h"
#include "bflow/core/signs.h"

namespace bflow {
namespace ad {

struct TangentCheckerOptions {
  /** Finite-difference step relative to max(1, |x_i|); must be positive and finite. */
  double relative_step = std::cbrt(std::numeric_limits<double>::epsilon());
  /** A check is ok when the worst relative error is at most this; must be >= 0. */
  double tolerance = 1e-6;
};

/** The result of one comparison of a matrix (or vector) with a reference. */
struct TangentReport {
  /** What was compared, e.g. "AD Jacobian vs central differences". */
  std::string what;
  int rows = 0;
  int cols = 0;
  /** Largest |candidate - reference| over all entries (+inf if an entry is not finite). */
  double max_abs_error = 0.0;
  /** Largest |candidate - reference| / max(1, |reference|) (+inf if not finite). */
  double max_rel_error = 0.0;
  /** Entry of the largest relative error; -1 when the matrices are empty. */
  int worst_row = -1;
  int worst_col = -1;
  /** Candidate and reference at (worst_row, worst_col). */
  double candidate_value = 0.0;
  double reference_value = 0.0;
  /** Finite-difference step used for column worst_col (0 if the reference is not a finite
      difference). For a directional check, the step along the direction. */
  double step = 0.0;
  double tolerance = 0.0;
  /** max_rel_error <= tolerance (false whenever an entry is not finite). */
  bool ok = true;

  /** One line: what, size, OK/FAILED, worst errors with their entry and values, step and
      tolerance. */
  std::string str() const {
    auto g = [](double value) {
      char buffer[32];
      std::snprintf(buffer, sizeof(buffer), "%.3g", value);
      return std::string(buffer);
    };
    std::string s = what + " (" + std::to_string(rows) + " x " + std::to_string(cols) +
                    "): " + (ok ? "OK" : "FAILED") + ", worst relative error " + g(max_rel_error);
    if (worst_row >= 0) {
      s += " at (" + std::to_string(worst_row) + ", " + std::to_string(worst_col) +
           ") [candidate " + format_number(candidate_value) + ", reference " +
           format_number(reference_value) + "]";
    }
    s += ", worst absolute error " + g(max_abs_error) + ", step " + g(step) + ", tolerance " +
         g(tolerance);
    return s;
  }
};

class TangentChecker {
 public:
  /** @throws InvalidArgument unless relative_step > 0 is finite and tolerance >= 0. */
  explicit TangentChecker(TangentCheckerOptions options = {}) : options_(options) {
    if (!(std::isfinite(options_.relative_step) && options_.relative_step > 0.0)) {
      throw InvalidArgument("TangentChecker: relative_step must be positive and finite, got " +
                            format_number(options_.relative_step));
    }
    if (!(options_.tolerance >= 0.0)) {
      throw InvalidArgument("TangentChecker: tolerance must be >= 0, got " +
                            format_number(options_.tolerance));
    }
  }

  const TangentCheckerOptions& options() const { return options_; }

  /** The step h_i = relative_step * max(1, |x_i|) used for coordinate i. */
  double step_for(double xi) const { return options_.relative_step * std::max(1.0, std::abs(xi)); }

  /** Central-difference Jacobian of f (n_out x d); f is evaluated with doubles only, so it
      need not be a template. Writes the step of each column to `steps` if not null.
      @throws InvalidArgument if x is not finite or f is non-finite at some x +- h_i e_i
      (quoting the row and the point). */
  template <typename Function>
  Eigen::MatrixXd central_jacobian(const Function& f, int n_out,
                                   const Eigen::Ref<const Eigen::VectorXd>& x,
                                   Eigen::VectorXd* steps = nullptr) const {
    const internal::Context ctx{"central_jacobian", "f", nullptr};
    internal::check_count(ctx, "n_out", n_out);
    internal::check_input(ctx, "x", x, x.size(), "d");
    const Eigen::Index d = x.size();
    Eigen::MatrixXd jac(n_out, d);
    Eigen::VectorXd plus(d), minus(d);
    Eigen::VectorXd f_plus(n_out), f_minus(n_out);
    if (steps != nullptr) steps->resize(d);
    for (Eigen::Index i = 0; i < d; ++i) {
      const double h = step_for(x[i]);
      plus = x;
      minus = x;
      plus[i] += h;
      minus[i] -= h;
      internal::evaluate_value(f, n_out, plus, f_plus.data(), ctx);
      internal::evaluate_value(f, n_out, minus, f_minus.data(), ctx);
      jac.col(i) = (f_plus - f_minus) / (plus[i] - minus[i]);
      if (steps != nullptr) (*steps)[i] = h;
    }
    return jac;
  }

  /** Central difference of f along v: (f(x + h v) - f(x - h v)) / (2h) with
      h = relative_step * max(1, |x|_inf) / |v|_inf (h = relative_step * max(1, |x|_inf) for
      v = 0). Writes h to `step` if not null.
      @throws InvalidArgument if x or v is not finite, the sizes differ, or f is non-finite at
      x +- h v. */
  template <typename Function>
  Eigen::VectorXd central_jvp(const Function& f, int n_out,
                              const Eigen::Ref<const Eigen::VectorXd>& x,
                              const Eigen::Ref<const Eigen::VectorXd>& v,
                              double* step = nullptr) const {
    const internal::Context ctx{"central_jvp", "f", nullptr};
    internal::check_count(ctx, "n_out", n_out);
    internal::check_input(ctx, "x", x, x.size(), "d");
    internal::check_input(ctx, "v", v, x.size(), "d = x.size()");
    const double x_norm = x.size() == 0 ? 0.0 : x.lpNorm<Eigen::Infinity>();
    const double v_norm = v.size() == 0 ? 0.0 : v.lpNorm<Eigen::Infinity>();
    const double h = step_for(x_norm) / (v_norm > 0.0 ? v_norm : 1.0);
    const Eigen::VectorXd plus = x + h * v;
    const Eigen::VectorXd minus = x - h * v;
    Eigen::VectorXd f_plus(n_out), f_minus(n_out);
    internal::evaluate_value(f, n_out, plus, f_plus.data(), ctx);
    internal::evaluate_value(f, n_out, minus, f_minus.data(), ctx);
    if (step != nullptr) *step = h;
    return (f_plus - f_minus) / (2.0 * h);
  }

  /** Entrywise comparison of `candidate` with `reference` (same shape), with the tolerance of
      the options; the report's step is 0.
      @throws InvalidArgument if the shapes differ or the reference is not finite. */
  TangentReport compare(const Eigen::Ref<const Eigen::MatrixXd>& candidate,
                        const Eigen::Ref<const Eigen::MatrixXd>& reference,
                        std::string what = "candidate vs reference") const {
    if (candidate.rows() != reference.rows() || candidate.cols() != reference.cols()) {
      throw InvalidArgument(
          "TangentChecker: " + what + ": the candidate is " + std::to_string(candidate.rows()) +
          " x " + std::to_string(candidate.cols()) + ", the reference is " +
          std::to_string(reference.rows()) + " x " + std::to_string(reference.cols()));
    }
    TangentReport report;
    report.what = std::move(what);
    report.rows = static_cast<int>(candidate.rows());
    report.cols = static_cast<int>(candidate.cols());
    report.tolerance = options_.tolerance;
    for (Eigen::Index j = 0; j < candidate.cols(); ++j) {
      for (Eigen::Index i = 0; i < candidate.rows(); ++i) {
        const double c = candidate(i, j);
        const double r = reference(i, j);
        if (!std::isfinite(r)) {
          throw InvalidArgument("TangentChecker: " + report.what + ": reference entry (" +
                                std::to_string(i) + ", " + std::to_string(j) + ") is " +
                                format_number(r));
        }
        const double abs_error =
            std::isfinite(c) ? std::abs(c - r) : std::numeric_limits<double>::infinity();
        const double rel_error = abs_error / std::max(1.0, std::abs(r));
        report.max_abs_error = std::max(report.max_abs_error, abs_error);
        if (report.worst_row < 0 || rel_error > report.max_rel_error) {
          report.max_rel_error = rel_error;
          report.worst_row = static_cast<int>(i);
          report.worst_col = static_cast<int>(j);
          report.candidate_value = c;
          report.reference_value = r;
        }
      }
    }
    report.ok = report.max_rel_error <= options_.tolerance;
    return report;
  }

  /** Checks a Jacobian the caller computed (by hand, or any other way) against central
      differences of f; f is evaluated with doubles only.
      @throws InvalidArgument on a wrong shape of `candidate` or as central_jacobian(). */
  template <typename Function>
  TangentReport check_jacobian(const Function& f, int n_out,
                               const Eigen::Ref<const Eigen::VectorXd>& x,
                               const Eigen::Ref<const Eigen::MatrixXd>& candidate) const {
    Eigen::VectorXd steps;
    const Eigen::MatrixXd reference = central_jacobian(f, n_out, x, &steps);
    return with_column_step(compare(candidate, reference, "Jacobian vs central differences"),
                            steps);
  }

  /** Checks a Jacobian the caller computed against the AD Jacobian of f (an exact reference
      up to rounding, so a tolerance near 1e-12 is meaningful).
      @throws InvalidArgument on a wrong shape of `candidate` or as jacobian(). */
  template <int Stride = kDefaultStride, typename Function>
  TangentReport check_against_ad(const Function& f, int n_out,
                                 const Eigen::Ref<const Eigen::VectorXd>& x,
                                 const Eigen::Ref<const Eigen::MatrixXd>& candidate) const {
    return compare(candidate, jacobian<Stride>(f, n_out, x), "Jacobian vs AD");
  }

  /** Checks the AD Jacobian of f against central differences.
      @throws InvalidArgument as jacobian() and central_jacobian(). */
  template <int Stride = kDefaultStride, typename Function>
  TangentReport check_ad_jacobian(const Function& f, int n_out,
                                  const Eigen::Ref<const Eigen::VectorXd>& x) const {
    Eigen::VectorXd steps;
    const Eigen::MatrixXd reference = central_jacobian(f, n_out, x, &steps);
    return with_column_step(
        compare(jacobian<Stride>(f, n_out, x), reference, "AD Jacobian vs central differences"),
        steps);
  }

  /** Checks the AD Jacobian-vector product Df(x) v (jvp()) against central_jvp(); the report
      is n_out x 1. @throws InvalidArgument as jvp() and central_jvp(). */
  template <typename Function>
  TangentReport check_jvp(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x,
                          const Eigen::Ref<const Eigen::VectorXd>& v) const {
    double step = 0.0;
    const Eigen::VectorXd reference = central_jvp(f, n_out, x, v, &step);
    TangentReport report = compare(jvp(f, n_out, x, v), reference, "AD JVP vs central differences");
    report.step = step;
    return report;
  }

  /** Checks DF_b(x) by AD (field_jacobian()) against central differences of F_b.
      @throws InvalidArgument as field_jacobian(). */
  template <int Stride = kDefaultStride, typename Model>
  TangentReport check_field_jacobian(const Model& model, const Eigen::Ref<const Eigen::VectorXd>& x,
                                     Signs b) const {
    const Eigen::MatrixXd candidate = field_jacobian<Stride>(model, x, b);
    Eigen::VectorXd steps;
    const Eigen::MatrixXd reference =
        central_jacobian([&model, b](const auto* in, auto* out) { model.field(in, b, out); },
                         model_states(model), x, &steps);
    return with_column_step(
        compare(candidate, reference,
                "AD field Jacobian DF_b (b = \"" + b.str() + "\") vs central differences"),
        steps);
  }

  /** Checks the normals Dh(x) by AD (normals()) against central differences of h.
      @throws InvalidArgument as normals(). */
  template <int Stride = kDefaultStride, typename Model>
  TangentReport check_normals(const Model& model,
                              const Eigen::Ref<const Eigen::VectorXd>& x) const {
    const Eigen::MatrixXd candidate = normals<Stride>(model, x);
    Eigen::VectorXd steps;
    const Eigen::MatrixXd reference =
        central_jacobian([&model](const auto* in, auto* out) { model.surfaces(in, out); },
                         model_surfaces(model), x, &steps);
    return with_column_step(compare(candidate, reference, "AD normals Dh vs central differences"),
                            steps);
  }

 private:
  static TangentReport with_column_step(TangentReport report, const Eigen::VectorXd& steps) {
    if (report.worst_col >= 0) report.step = steps[report.worst_col];
    return report;
  }

  TangentCheckerOptions options_;
};

}  // namespace ad
}  // namespace bflow

#endif  // BFLOW_AD_TANGENT_CHECKER_H_

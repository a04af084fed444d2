#include "bflow/fesd/fesd.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <deque>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/LU>
#include <Eigen/QR>

#include "bflow/core/errors.h"
#include "bflow/fesd/dcs.h"
#include "bflow/fesd/element.h"
#include "bflow/fesd/transcription.h"

namespace bflow {

const char* to_string(FesdStatus status) {
  switch (status) {
    case FesdStatus::kConverged:
      return "converged";
    case FesdStatus::kStepFailed:
      return "step failed";
    case FesdStatus::kInvalidModel:
      return "invalid model";
    case FesdStatus::kCancelled:
      return "cancelled";
  }
  return "unknown";
}

namespace {

using fesd::Pair;
using fesd::PairState;
using fesd::PointDcs;
using fesd::Transcription;
// One integration step: one stage of N_FE elements, absolute lengths, no controls.
using Layout = fesd::TranscriptionLayout;

// Whether h_n lies in (0, h_max] and the algebraic variables of w within their bounds; round-off
// just outside a bound (a member that is zero at the solution) is clamped.
bool within_bounds(const Layout& l, Eigen::VectorXd& w, double h_max) {
  for (int n = 0; n < l.elements; ++n) {
    const double h = w[l.var(n, 0)];
    if (!(h > 0.0 && h <= h_max)) return false;
    for (int m = 0; m < l.points; ++m) {
      for (int k = 0; k < l.nz; ++k) {
        double& value = w[l.z(n, m, k)];
        if (value < l.dcs->lower(k) - 1e-13 || value > l.dcs->upper(k) + 1e-13) {
          return false;
        }
        value = std::clamp(value, l.dcs->lower(k), l.dcs->upper(k));
      }
    }
  }
  return true;
}

// One integration step's FESD equations with the active set fixed: the element equalities, each
// fixed complementarity variable (index, value), sum h_n = H, and h_n = h_{n-1} at the listed
// boundaries n. assemble() writes the residual and the Jacobians in w and in the step's start x.
struct FixedActiveSet {
  std::vector<std::pair<int, double>> fixed;
  std::vector<int> equal_lengths;

  int rows(const Layout& l) const {
    return l.elements * l.equalities + static_cast<int>(fixed.size()) + 1 +
           static_cast<int>(equal_lengths.size());
  }

  void assemble(const Transcription& nlp, const Layout& l, const Eigen::VectorXd& w, double step,
                Eigen::MatrixXd& jac_w, Eigen::MatrixXd& jac_x, Eigen::VectorXd& residual) const {
    const int count = rows(l);
    jac_w.setZero(count, l.variables());
    jac_x.setZero(count, l.d);
    residual.resize(count);
    int row = 0;
    Eigen::VectorXd values;
    for (int n = 0; n < l.elements; ++n) {
      const Eigen::MatrixXd local = nlp.element_jacobian(w, n, &values);
      for (int r = 0; r < l.equalities; ++r, ++row) {
        residual[row] = values[r];
        for (int k = 0; k < l.local; ++k) {
          const int g = l.global(n, k);
          if (g >= 0) {
            jac_w(row, g) += local(r, k);
          } else if (k < l.d) {
            jac_x(row, k) += local(r, k);
          }
        }
      }
    }
    for (const auto& [index, value] : fixed) {
      residual[row] = w[index] - value;
      jac_w(row++, index) = 1.0;
    }
    double sum = 0;
    for (int n = 0; n < l.elements; ++n) {
      sum += w[l.var(n, 0)];
      jac_w(row, l.var(n, 0)) = 1.0;
    }
    residual[row++] = sum - step;
    for (int n : equal_lengths) {
      residual[row] = w[l.var(n, 0)] - w[l.var(n - 1, 0)];
      jac_w(row, l.var(n, 0)) = 1.0;
      jac_w(row++, l.var(n - 1, 0)) = -1.0;
    }
  }
};

// dx_end/dx_start by the implicit function theorem on the converged active set, or an empty
// matrix with *why set when the fixed-active-set system is not square or is singular.
Eigen::MatrixXd step_sensitivity(const Transcription& nlp, const Layout& l,
                                 const Eigen::VectorXd& w, double step, double tol,
                                 std::string* why) {
  const int nv = l.variables();
  FixedActiveSet active;
  for (int n = 0; n < l.elements; ++n) {
    for (int m = 0; m < l.points; ++m) {
      for (const Pair& pair : l.dcs->pairs()) {
        const int iu = l.z(n, m, pair.u), iv = l.z(n, m, pair.v);
        if (std::abs(w[iu] - PointDcs::u_zero(pair)) <= tol) {
          active.fixed.push_back({iu, PointDcs::u_zero(pair)});
        }
        if (w[iv] <= tol) active.fixed.push_back({iv, 0.0});
      }
    }
  }
  for (int n = 1; n < l.elements; ++n) {
    if (nlp.sides(w, n - 1, tol) == nlp.sides(w, n, tol)) {
      active.equal_lengths.push_back(n);
    }
  }
  // A switch that falls on the step's end, or a pair that is degenerate at the solution (both
  // members zero), adds an equation that the others already imply: the system is then tall but
  // consistent, and its least-squares solution is the derivative.
  const int count = active.rows(l);
  if (count < nv) {
    *why = "the fixed-active-set system has " + std::to_string(count) + " equations for " +
           std::to_string(nv) + " unknowns (no switch condition for a free element length)";
    return {};
  }
  Eigen::MatrixXd gw, gx;
  Eigen::VectorXd residual;
  active.assemble(nlp, l, w, step, gw, gx, residual);
  const Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(gw);
  if (qr.rank() < nv) {
    // Singular at a solution: the solution may not be isolated, and then other FESD solutions lie
    // arbitrarily close (e.g. a selection that no equation fixes where the state lies on a
    // surface at an element's end, the end of a time-freezing impact: docs/ocp.md).
    *why = "the fixed-active-set system is singular (rank " + std::to_string(qr.rank()) + " of " +
           std::to_string(nv) +
           "), so the step's FESD solution may not be isolated and its end state may be one of "
           "many the FESD equations allow (a selection no equation fixes, e.g. where the state "
           "lies on a switching surface at an element's end); compare with another N_sim or N_FE";
    return {};
  }
  const Eigen::MatrixXd dw = qr.solve(-gx);
  const double inconsistency = (gw * dw + gx).norm();
  if (!(inconsistency <= 1e-8 * std::max(1.0, gx.norm()))) {
    *why = "the fixed-active-set system is inconsistent (residual " + format_number(inconsistency) +
           ")";
    return {};
  }
  return dw.middleRows(l.var(l.elements - 1, l.off_x), l.d);
}

// Newton's method on a step's FESD equations with its active set guessed: the sides of every
// element (`sides[n]`, +1, -1 or 0 per switching function). On an element each complementarity
// pair has the member its sides make zero fixed (step: a = 1 and lambda^n = 0 on +, a = 0 and
// lambda^p = 0 on -, lambda^p = lambda^n = 0 when sliding; Stewart: lambda_i = 0 for the active
// modes, theta_i = 0 for the others). Neighbouring elements with the same sides have equal
// lengths; where the sides change, the switch condition replaces that equation:
//  * a pair whose u becomes free has v = 0 at the boundary (the cross complementarity with the
//    next element's start: c_j(x_n) = 0 when crossing or entering a sliding arc);
//  * a pair whose u becomes zero after its group slid has u = 0 at the boundary (the selection
//    is continuous where a trajectory leaves a surface).
// Each boundary must get at least one condition; more (Stewart: the modes that enter together
// while a surface slides) make the system tall, solved in least squares and accepted only if
// consistent. At the step's
// start a pair whose u is free must have v <= tol. Its solution is
// an FESD solution (every complementarity product 0) if the free members come out within their
// bounds and 0 < h_n <= 2 H / N_FE. Returns false otherwise (a wrong guess, or no convergence).
bool solve_guess(const Transcription& nlp, const Layout& l,
                 const std::vector<std::vector<int>>& sides, double step, double tol,
                 Eigen::VectorXd& w, int* iterations) {
  const PointDcs& dcs = *l.dcs;
  FixedActiveSet active;
  std::vector<bool> taken(static_cast<std::size_t>(l.variables()), false);
  const auto fix = [&](int index, double value) {
    if (taken[static_cast<std::size_t>(index)]) return false;
    taken[static_cast<std::size_t>(index)] = true;
    active.fixed.push_back({index, value});
    return true;
  };
  std::vector<PairState> before;
  for (int n = 0; n < l.elements; ++n) {
    const std::vector<int>& here = sides[static_cast<std::size_t>(n)];
    const std::vector<PairState> states = dcs.states(here);
    if (n == 0) {
      // The first element's cross complementarity with the step's start: a pair whose u is free
      // needs v = 0 there (c_j(x) = 0 for a switch at the start).
      for (int k = 0; k < l.npairs; ++k) {
        if (states[static_cast<std::size_t>(k)] == PairState::kVZero && nlp.start_v(k) > tol) {
          return false;
        }
      }
    }
    for (int m = 0; m < l.points; ++m) {
      for (int k = 0; k < l.npairs; ++k) {
        const Pair& pair = dcs.pairs()[static_cast<std::size_t>(k)];
        if (states[static_cast<std::size_t>(k)] == PairState::kUZero) {
          fix(l.z(n, m, pair.u), PointDcs::u_zero(pair));
        } else {
          fix(l.z(n, m, pair.v), 0.0);
        }
      }
    }
    if (n > 0 && here == sides[static_cast<std::size_t>(n - 1)]) {
      active.equal_lengths.push_back(n);
    } else if (n > 0) {
      const std::vector<int>& prior = sides[static_cast<std::size_t>(n - 1)];
      int conditions = 0;
      for (int k = 0; k < l.npairs; ++k) {
        const Pair& pair = dcs.pairs()[static_cast<std::size_t>(k)];
        const PairState was = before[static_cast<std::size_t>(k)];
        const PairState is = states[static_cast<std::size_t>(k)];
        if (was == PairState::kUZero && is == PairState::kVZero) {
          conditions += fix(l.z(n - 1, l.points - 1, pair.v), 0.0) ? 1 : 0;
        } else if (was == PairState::kVZero && is == PairState::kUZero &&
                   dcs.leaves_sliding(prior, here, pair.group)) {
          conditions += fix(l.z(n - 1, l.points - 1, pair.u), PointDcs::u_zero(pair)) ? 1 : 0;
        }
      }
      if (conditions < 1) return false;
    }
    before = states;
  }
  if (active.rows(l) < l.variables()) return false;
  const bool tall = active.rows(l) > l.variables();
  for (const auto& [index, value] : active.fixed) w[index] = value;
  Eigen::MatrixXd jac, jac_x;
  Eigen::VectorXd residual;
  for (int it = 0; it < 20; ++it) {
    active.assemble(nlp, l, w, step, jac, jac_x, residual);
    const Eigen::VectorXd delta = tall ? Eigen::VectorXd(jac.colPivHouseholderQr().solve(-residual))
                                       : Eigen::VectorXd(jac.partialPivLu().solve(-residual));
    if (!delta.allFinite()) return false;
    w += delta;
    *iterations += 1;
    for (const auto& [index, value] : active.fixed) w[index] = value;
    if (delta.lpNorm<Eigen::Infinity>() <= 1e-14 * (1.0 + w.lpNorm<Eigen::Infinity>())) break;
    if (it == 19) return false;
  }
  if (tall) {
    // Least squares: the extra conditions must be implied by the others (Stewart: two modes
    // entering together where a surface already slides), not contradict them.
    active.assemble(nlp, l, w, step, jac, jac_x, residual);
    if (!(residual.lpNorm<Eigen::Infinity>() <= 1e-10)) return false;
  }
  return within_bounds(l, w, 2.0 * step / l.elements);
}

// The guesses of switch_step for the functions `changed`; the best FESD solution found, if any.
bool guess_switches(const Transcription& nlp, const Layout& l, const std::vector<int>& sides,
                    const std::vector<int>& changed, const Eigen::VectorXd& tried, double step,
                    double tol, Eigen::VectorXd& w, int* iterations) {
  // Every assignment of distinct boundaries and new sides to the changed functions.
  // Boundary 0 is the step's start (a switch exactly there: every element on the new side).
  std::vector<std::vector<int>> boundaries;
  for (int k1 = 0; k1 < l.elements; ++k1) {
    if (changed.size() == 1) {
      boundaries.push_back({k1});
      continue;
    }
    for (int k2 = 0; k2 < l.elements; ++k2) {
      if (k2 != k1 || k1 == 0) boundaries.push_back({k1, k2});
    }
  }
  Eigen::VectorXd start = tried;
  for (int n = 0; n < l.elements; ++n) {
    start[l.var(n, 0)] = step / l.elements;
    for (int m = 0; m < l.points; ++m) {
      for (int k = 0; k < l.nz; ++k) {
        double& value = start[l.z(n, m, k)];
        value = std::clamp(value, l.dcs->lower(k), l.dcs->upper(k));
      }
    }
  }
  double best = std::numeric_limits<double>::infinity();
  const int choices = 1 << changed.size();
  for (const std::vector<int>& at : boundaries) {
    for (int choice = 0; choice < choices; ++choice) {
      std::vector<std::vector<int>> guess(static_cast<std::size_t>(l.elements), sides);
      for (std::size_t q = 0; q < changed.size(); ++q) {
        const int j = changed[q];
        const int old_side = sides[static_cast<std::size_t>(j)];
        const bool second = (choice >> q) & 1;
        const int new_side = old_side != 0 ? (second ? 0 : -old_side) : (second ? -1 : 1);
        for (int n = at[q]; n < l.elements; ++n) {
          guess[static_cast<std::size_t>(n)][static_cast<std::size_t>(j)] = new_side;
        }
      }
      Eigen::VectorXd candidate = start;
      if (!solve_guess(nlp, l, guess, step, tol, candidate, iterations)) continue;
      const double value = nlp.equilibration(candidate);
      if (value < best) {
        best = value;
        w = candidate;
      }
    }
  }
  return best < std::numeric_limits<double>::infinity();
}

// A step with one switch (or two at different boundaries), solved by guessing its active set
// after the no-switch guess failed with solution `tried`: a switching function that `tried`
// takes across its surface changes to the other side or to sliding, a sliding one leaves to
// either side, at every element boundary in turn (the step's start included). Each guess is solved
// by solve_guess; among the FESD solutions found, the one the step equilibration prefers (the NLP's
// objective) is taken. Returns false when no guess is an FESD solution (the caller then runs the
// homotopy).
bool switch_step(const StepModel& model, const Transcription& nlp, const Layout& l,
                 const std::vector<int>& sides, const Eigen::VectorXd& tried, double step,
                 double tol, Eigen::VectorXd& w, int* iterations) {
  std::vector<int> crossed, sliding;
  Eigen::VectorXd c(l.nc);
  for (int j = 0; j < l.nc; ++j) {
    const int side = sides[static_cast<std::size_t>(j)];
    if (side == 0) {
      sliding.push_back(j);
      continue;
    }
    bool across = false;
    for (int n = 0; n < l.elements && !across; ++n) {
      for (int m = 0; m < l.points && !across; ++m) {
        const int at = m < l.s ? l.var(n, 1 + m * l.d) : l.var(n, l.off_x);
        model.switching(tried.data() + at, c.data());
        across = side * c[j] < 0.0;
      }
    }
    if (across) crossed.push_back(j);
  }
  // The crossed functions alone; else one sliding function leaving; else both kinds.
  std::vector<std::vector<int>> attempts;
  if (!crossed.empty()) attempts.push_back(crossed);
  for (int j : sliding) attempts.push_back({j});
  if (!crossed.empty() && !sliding.empty()) {
    std::vector<int> both = crossed;
    both.insert(both.end(), sliding.begin(), sliding.end());
    attempts.push_back(both);
  }
  for (const std::vector<int>& changed : attempts) {
    if (changed.size() <= 2 &&
        guess_switches(nlp, l, sides, changed, tried, step, tol, w, iterations)) {
      return true;
    }
  }
  return false;
}

void check_options(const StepModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                   double t_end, const FesdOptions& o) {
  if (x0.size() != model.states()) {
    throw InvalidArgument("fesd: x0 has " + std::to_string(x0.size()) + " entries, the model " +
                          std::to_string(model.states()) + " states");
  }
  if (!x0.allFinite()) throw InvalidArgument("fesd: x0 is not finite: " + format_vector(x0));
  if (!(t_end > 0.0) || !std::isfinite(t_end)) {
    throw InvalidArgument("fesd: T must be finite and > 0, got " + format_number(t_end));
  }
  if (o.steps >= 1 && o.elements >= 1) {
    // An element's length lies in [0, 2 T / (N_sim N_FE)], a bound IPOPT takes as none from
    // 1e19 on; below the smallest normal double the lengths and their squares (the step
    // equilibration) lose their digits.
    const double step = t_end / o.steps, element = step / o.elements;
    if (!(step <= kFesdMaxStepLength) || !(element >= std::numeric_limits<double>::min())) {
      throw InvalidArgument(
          "fesd: T = " + format_number(t_end) + " over N_sim = " + std::to_string(o.steps) +
          " steps of N_FE = " + std::to_string(o.elements) + " elements gives steps of " +
          format_number(step) + " and elements of " + format_number(element) +
          ", which cannot be integrated: need T / N_sim <= " + format_number(kFesdMaxStepLength) +
          " and T / (N_sim N_FE) >= " + format_number(std::numeric_limits<double>::min()));
    }
  }
  if (!std::isfinite(o.homotopy.sigma_initial) || !(o.homotopy.sigma_initial > 0.0) ||
      !(o.homotopy.sigma_final > 0.0) || o.homotopy.sigma_final > o.homotopy.sigma_initial ||
      !(o.homotopy.sigma_factor > 0.0 && o.homotopy.sigma_factor < 1.0)) {
    throw InvalidArgument(
        "fesd: need 0 < sigma_final <= sigma_initial and 0 < sigma_factor < 1, "
        "got sigma_initial = " +
        format_number(o.homotopy.sigma_initial) +
        ", sigma_final = " + format_number(o.homotopy.sigma_final) +
        ", sigma_factor = " + format_number(o.homotopy.sigma_factor));
  }
  if (!(o.homotopy.nlp_tolerance > 0.0) || !std::isfinite(o.homotopy.nlp_tolerance) ||
      o.homotopy.max_nlp_iterations < 1) {
    throw InvalidArgument(
        "fesd: need a finite nlp_tolerance > 0 and max_nlp_iterations >= 1, got "
        "nlp_tolerance = " +
        format_number(o.homotopy.nlp_tolerance) +
        ", max_nlp_iterations = " + std::to_string(o.homotopy.max_nlp_iterations));
  }
  check_solver_options(o.solver, o.exact_hessian, "fesd");
}

// The options that decide the problem's shape.
void check_structure(const StepModel& model, const FesdOptions& o) {
  if (o.elements < 1 || o.steps < 1) {
    throw InvalidArgument("fesd: need N_FE >= 1 and N_sim >= 1, got N_FE = " +
                          std::to_string(o.elements) + ", N_sim = " + std::to_string(o.steps));
  }
  if (o.lifting_depth == 1 || o.lifting_depth < 0) {
    throw InvalidArgument("fesd: the lifting depth n_d must be 0 (none) or >= 2, got " +
                          std::to_string(o.lifting_depth));
  }
  if (o.formulation == DcsFormulation::kStewart && o.lifting_depth != 0) {
    throw InvalidArgument("fesd: lifting (n_d = " + std::to_string(o.lifting_depth) +
                          ") applies to the step formulation only, not to Stewart's");
  }
  constexpr int kMaxStewartSwitches = 10;
  if (o.formulation == DcsFormulation::kStewart && model.switches() > kMaxStewartSwitches) {
    throw InvalidArgument("fesd: Stewart's formulation has 2^n_c modes per point; n_c = " +
                          std::to_string(model.switches()) + " is more than " +
                          std::to_string(kMaxStewartSwitches) + " (use the step formulation)");
  }
}

// Non-negative counts that saturate at the largest std::int64_t instead of overflowing.
constexpr std::int64_t kMaxCount = std::numeric_limits<std::int64_t>::max();
std::int64_t add(std::int64_t a, std::int64_t b) { return a > kMaxCount - b ? kMaxCount : a + b; }
std::int64_t mul(std::int64_t a, std::int64_t b) {
  if (a == 0 || b == 0) return 0;
  return a > kMaxCount / b ? kMaxCount : a * b;
}
// k (k + 1) / 2: the lower triangle of a k x k block.
std::int64_t triangle(std::int64_t k) {
  return k % 2 == 0 ? mul(k / 2, add(k, 1)) : mul(k, add(k, 1) / 2);
}

std::string count_text(std::int64_t count) {
  return count == kMaxCount ? "more than " + std::to_string(kMaxCount - 1) : std::to_string(count);
}

std::string bytes_text(double bytes) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.2g", bytes);
  return buffer;
}

std::string memory_limit_text() {
  return "above the limit of 4 GiB = " +
         std::to_string(static_cast<std::int64_t>(kFesdMaxMemoryBytes)) + " bytes";
}

}  // namespace

std::string FesdProblemSize::step_excess() const {
  const std::string index_limit = ", above IPOPT's limit of " + std::to_string(kFesdMaxIndex);
  if (unknowns > kFesdMaxIndex) {
    return count_text(unknowns) + " NLP unknowns per integration step" + index_limit;
  }
  if (constraints > kFesdMaxIndex) {
    return count_text(constraints) + " NLP constraints per integration step" + index_limit;
  }
  if (jacobian_nonzeros > kFesdMaxIndex) {
    return count_text(jacobian_nonzeros) + " Jacobian nonzeros per integration step" + index_limit;
  }
  if (hessian_nonzeros > kFesdMaxIndex) {
    return "up to " + count_text(hessian_nonzeros) + " Hessian nonzeros per integration step" +
           index_limit;
  }
  if (!(step_bytes <= kFesdMaxMemoryBytes)) {
    return std::to_string(unknowns) + " NLP unknowns per integration step, needing about " +
           bytes_text(step_bytes) + " bytes, " + memory_limit_text();
  }
  return "";
}

std::string FesdProblemSize::run_excess() const {
  if (step_bytes + run_bytes <= kFesdMaxMemoryBytes) return "";
  return count_text(total_elements) + " finite elements in all, needing about " +
         bytes_text(step_bytes + run_bytes) + " bytes, " + memory_limit_text();
}

FesdProblemSize fesd_problem_size(const StepModel& model, const FesdOptions& options) {
  return fesd_problem_size(model, options, /*end_apart=*/true);
}

FesdProblemSize fesd_problem_size(const StepModel& model, const FesdOptions& options,
                                  bool end_apart) {
  check_structure(model, options);
  const ButcherTableau tab = collocation_tableau(options.scheme, options.stages);
  const int n_c = model.switches();
  FesdProblemSize size;
  if (options.formulation == DcsFormulation::kStewart || options.lifting_depth != 0) {
    // [F] Table 4: the lifted step and Stewart's point DCS (dcs.h) are exactly its sizes.
    const SignMatrix* signs = model.sign_matrix();
    const DcsSize table = options.formulation == DcsFormulation::kStewart
                              ? dcs_size_dense(n_c, DcsFormulation::kStewart)
                          : signs != nullptr
                              ? dcs_size(*signs, DcsFormulation::kStep, options.lifting_depth)
                              : dcs_size_dense(n_c, DcsFormulation::kStep, options.lifting_depth);
    size.point_variables = table.algebraic;
    size.point_equalities = table.equalities;
    size.point_pairs = table.complementarity;
  } else {
    // The step DCS with theta eliminated: a, lambda^p, lambda^n; c = lambda^p - lambda^n.
    size.point_variables = 3 * std::int64_t{n_c};
    size.point_equalities = n_c;
    size.point_pairs = 2 * std::int64_t{n_c};
  }
  const std::int64_t d = model.states(), s = tab.stages, n_fe = options.elements;
  size.points = s + (tab.stiffly_accurate() ? 0 : 1);
  // Layout (element.h): per element [h | X_1..X_s | x_{n+1} (unless it is X_s) | z of every
  // point]; its rows the collocation and end equations, the algebraic equalities and one
  // aggregated product per pair.
  const std::int64_t ends = end_apart || !tab.stiffly_accurate() ? d : 0;
  const std::int64_t block = add(1 + s * d + ends, mul(size.points, size.point_variables));
  const std::int64_t rows =
      add(add(s * d + ends, mul(size.points, size.point_equalities)), size.point_pairs);
  // Inputs of element n >= 1: the previous end x_n and its last point's v of every pair.
  const std::int64_t local = add(d + size.point_pairs, block);
  size.unknowns = mul(n_fe, block);
  size.constraints = add(mul(n_fe, rows), options.standard ? 0 : 1);  // + sum h_n = H
  size.jacobian_nonzeros = add(add(mul(rows, block), mul(n_fe - 1, mul(rows, local))),
                               options.standard ? 0 : n_fe);  // + the row sum h
  if (options.exact_hessian) {
    // Each equilibration term: h_{n-1}, h_n, the pairs' v at n - 1's start, z of n - 1 and n.
    const std::int64_t term = add(2 + size.point_pairs, mul(2 * size.points, size.point_variables));
    size.hessian_nonzeros =
        add(add(triangle(block), mul(n_fe - 1, triangle(local))), mul(n_fe - 1, triangle(term)));
  }
  size.total_elements = mul(options.steps, n_fe);
  const double unknowns = static_cast<double>(size.unknowns);
  const bool dense = (options.newton && !options.standard) || options.sensitivities;
  size.step_bytes = (dense ? 16.0 * unknowns * unknowns : 0.0) +
                    24.0 * static_cast<double>(size.jacobian_nonzeros) +
                    80.0 * static_cast<double>(size.hessian_nonzeros) +
                    200.0 * (unknowns + static_cast<double>(size.constraints));
  size.run_bytes = static_cast<double>(size.total_elements) *
                       (96.0 + 16.0 * static_cast<double>(d) + 4.0 * n_c) +
                   16.0 * options.steps;
  return size;
}

FesdResult fesd_simulate(const StepModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                         double t_end, const FesdOptions& options) {
  check_options(model, x0, t_end, options);
  // Every size is checked before anything of the problem is allocated.
  const FesdProblemSize size = fesd_problem_size(model, options);
  if (const std::string excess = size.step_excess(); !excess.empty()) {
    throw InvalidArgument("fesd: N_FE = " + std::to_string(options.elements) +
                          " finite elements of n_s = " + std::to_string(options.stages) +
                          " stages give " + excess + " (see docs/fesd.md)");
  }
  if (const std::string excess = size.run_excess(); !excess.empty()) {
    throw InvalidArgument("fesd: N_sim = " + std::to_string(options.steps) +
                          " integration steps of N_FE = " + std::to_string(options.elements) +
                          " finite elements give " + excess + " (see docs/fesd.md)");
  }
  const ButcherTableau tab = collocation_tableau(options.scheme, options.stages);
  const PointDcs dcs(model, options.formulation, options.lifting_depth);
  // The element's end stays an unknown of its own here (ocp_solve identifies it with the last
  // Radau stage): the same solutions, but Newton's method and the homotopy take other paths, and
  // at the end of a time-freezing impact, where a selection is free, other paths can reach other
  // FESD solutions (docs/ocp.md, "The element's end as its last Radau stage").
  const Layout l(dcs, model.states(), model.switches(), /*controls=*/0, tab, /*stages=*/1,
                 options.elements, /*time_scaled=*/false, /*end_apart=*/true);
  // The closed forms against the layout (its int sizes cannot overflow within kFesdMaxIndex).
  BFLOW_ASSERT(l.nz == size.point_variables && l.neq == size.point_equalities &&
               l.npairs == size.point_pairs && l.points == size.points);
  BFLOW_ASSERT(l.variables() == size.unknowns);
  const double step = t_end / options.steps;
  // A complementarity variable counts as zero below this: with products <= sigma_final, the zero
  // member of a pair whose other member is O(1e-3) or more is below sqrt(sigma_final).
  const double active_tol = std::clamp(std::sqrt(options.homotopy.sigma_final), 1e-9, 1e-4);

  fesd::HomotopySolver solver(fesd::ipopt_settings(options, "fesd"));
  // The objective (step equilibration) only selects among the FESD solutions; when IPOPT crawls
  // along its flat directions (lengths inside a sliding arc), a point that satisfies the
  // constraints to the tolerance is the answer: HomotopyRules' defaults accept at 1e-4 with the
  // violation at tol after 5 iterations.
  const fesd::HomotopyRules rules = fesd::homotopy_schedule(options);

  FesdResult result;
  result.ipopt = ipopt_description();
  result.linear_solver =
      linear_solver_description(solver.linear_solver(), solver.linear_solver_library());
  result.blas = blas_description(options.solver.blas_threads);
  // The derivatives' programs summed over the steps' transcriptions, in the result at each
  // step's end (a step that returns early included).
  fesd::DerivativeCounts derivative_counts;
  result.derivatives =
      fesd::describe_derivatives(options.solver.derivative_programs, derivative_counts);
  struct CountDerivatives {
    const Transcription& nlp;
    fesd::DerivativeCounts& sum;
    FesdResult& result;
    bool programs;
    ~CountDerivatives() {
      const fesd::DerivativeCounts c = nlp.derivative_counts();
      sum.traced += c.traced;
      sum.on_jets += c.on_jets;
      result.derivatives = fesd::describe_derivatives(programs, sum);
    }
  };
  Eigen::VectorXd x = x0;
  result.grid.push_back(0.0);
  std::vector<Eigen::VectorXd> states{x};
  Eigen::MatrixXd sensitivity = Eigen::MatrixXd::Identity(l.d, l.d);
  bool sensitivities = options.sensitivities;
  std::vector<int> previous_sides;
  // Integration steps still to take, as (length, times halved); a step whose homotopy fails is
  // replaced by its two halves, at most kMaxHalvings times.
  constexpr int kMaxHalvings = 4;
  std::deque<std::pair<double, int>> pending(static_cast<std::size_t>(options.steps),
                                             std::make_pair(step, 0));
  double t0 = 0.0;
  int taken = 0;
  // The steps done so far as the result, ended by a cancellation at t0.
  const auto cancelled_result = [&]() {
    result.status = FesdStatus::kCancelled;
    result.message += std::string(result.message.empty() ? "" : "; ") +
                      "fesd: cancelled at t = " + format_number(t0) + " after " +
                      std::to_string(taken) + " integration steps; the result covers [0, " +
                      format_number(t0) + "]";
    result.x_end = x;
    result.states.resize(l.d, static_cast<Eigen::Index>(states.size()));
    for (std::size_t k = 0; k < states.size(); ++k)
      result.states.col(static_cast<Eigen::Index>(k)) = states[k];
    return result;
  };
  while (!pending.empty()) {
    if (options.cancelled && options.cancelled()) return cancelled_result();
    const auto [length, halvings] = pending.front();
    pending.pop_front();
    fesd::TranscriptionSetup setup;
    setup.x0 = x;
    setup.horizon = length;
    setup.standard = options.standard;
    setup.relaxation = fesd::Relaxation::kScholtes;
    setup.equilibration_weight = 1.0;
    setup.equilibration_fades = false;
    setup.exact_hessian = options.exact_hessian;
    setup.exact_hessian_scale = options.solver.exact_hessian_scale;
    setup.derivative_programs = options.solver.derivative_programs;
    Transcription nlp(tab, l, setup, nullptr);
    const CountDerivatives count_derivatives{nlp, derivative_counts, result,
                                             options.solver.derivative_programs};
    BFLOW_ASSERT(nlp.constraints() <= size.constraints);
    // Predicted sides: from c(x) where it is clearly nonzero, else the last element's.
    bool solved_by_newton = false;
    if (options.newton && !options.standard) {
      Eigen::VectorXd c(l.nc);
      model.switching(x.data(), c.data());
      std::vector<int> sides(static_cast<std::size_t>(l.nc));
      std::vector<int> unknown;
      for (int j = 0; j < l.nc; ++j) {
        if (std::abs(c[j]) > active_tol) {
          sides[static_cast<std::size_t>(j)] = c[j] > 0 ? 1 : -1;
        } else if (!previous_sides.empty()) {
          sides[static_cast<std::size_t>(j)] = previous_sides[static_cast<std::size_t>(j)];
        } else {
          unknown.push_back(j);
        }
      }
      Eigen::VectorXd w = nlp.solution();
      int newton_iterations = 0;
      bool known = unknown.empty();
      if (!known && unknown.size() <= 2) {
        // On a surface at the start of the run: the first of sliding, +, - (for every such
        // function) whose no-switch solution is an FESD solution. Where several are (a
        // spontaneous switch), the trajectory stays on the surface.
        int combinations = 1;
        for (std::size_t k = 0; k < unknown.size(); ++k) combinations *= 3;
        for (int code = 0; code < combinations && !known; ++code) {
          int rest = code;
          for (int j : unknown) {
            sides[static_cast<std::size_t>(j)] = rest % 3 == 0 ? 0 : rest % 3 == 1 ? 1 : -1;
            rest /= 3;
          }
          Eigen::VectorXd trial = nlp.solution();
          const std::vector<std::vector<int>> same(static_cast<std::size_t>(l.elements), sides);
          if (solve_guess(nlp, l, same, length, active_tol, trial, &newton_iterations)) {
            known = true;
            w = trial;
          }
        }
        if (!known) w = nlp.solution();
      }
      const std::vector<std::vector<int>> same(static_cast<std::size_t>(l.elements), sides);
      Eigen::VectorXd switched;
      if (known && !unknown.empty()) {
        nlp.set_solution(w);
        solved_by_newton = true;
        ++result.newton_steps;
      } else if (known && solve_guess(nlp, l, same, length, active_tol, w, &newton_iterations)) {
        nlp.set_solution(w);
        solved_by_newton = true;
        ++result.newton_steps;
      } else if (known && w.allFinite() &&
                 switch_step(model, nlp, l, sides, w, length, active_tol, switched,
                             &newton_iterations)) {
        nlp.set_solution(switched);
        solved_by_newton = true;
        ++result.newton_steps;
        ++result.newton_switch_steps;
      } else if (known && w.allFinite()) {
        // The no-switch solution still follows the trajectory up to the switch, a better start
        // for the homotopy than the held state.
        for (int n = 0; n < l.elements; ++n) {
          w[l.var(n, 0)] = length / l.elements;
          for (int m = 0; m < l.points; ++m) {
            for (int k = 0; k < l.nz; ++k) {
              double& value = w[l.z(n, m, k)];
              value = std::clamp(value, dcs.lower(k), dcs.upper(k));
            }
          }
        }
        nlp.set_solution(w);
      }
    }
    int iterations = 0;
    bool acceptable_level = false;
    double last_sigma = 0.0;
    if (!solved_by_newton) {
      const fesd::HomotopyOutcome outcome = solver.run(nlp, rules);
      iterations = outcome.iterations;
      if (outcome.cancelled) return cancelled_result();
      if (!outcome.done && halvings < kMaxHalvings) {
        pending.push_front({length / 2, halvings + 1});
        pending.push_front({length / 2, halvings + 1});
        ++result.halved_steps;
        continue;
      }
      if (!outcome.done) {
        result.status = FesdStatus::kStepFailed;
        result.message =
            "fesd: the integration step at t = " + format_number(t0) + " of length " +
            format_number(length) + " (halved " + std::to_string(halvings) +
            " times) did not converge at sigma = " + format_number(outcome.failed_sigma) +
            ": IPOPT status " + outcome.failed_status + ", complementarity residual " +
            format_number(outcome.failed_complementarity);
        result.x_end = x;
        result.nlp_iterations.push_back(iterations);
        return result;
      }
      acceptable_level = outcome.acceptable_only;
      last_sigma = outcome.last_sigma;
    }
    const Eigen::VectorXd& w = nlp.solution();
    result.nlp_iterations.push_back(iterations);
    const double residual = nlp.complementarity(w);
    result.max_complementarity = std::max(result.max_complementarity, residual);
    // IPOPT's acceptable level bounds neither the complementarity products nor the objective's
    // optimality by `tol`; only a residual within the final relaxation makes it an FESD solution.
    if (acceptable_level &&
        !(residual <= options.homotopy.sigma_final + options.homotopy.nlp_tolerance)) {
      if (!result.acceptable_only) {
        result.message +=
            std::string(result.message.empty() ? "" : "; ") +
            "fesd: the integration step at t = " + format_number(t0) + " of length " +
            format_number(length) +
            " was solved by IPOPT only to its acceptable level at sigma = " +
            format_number(last_sigma) + ": complementarity residual " + format_number(residual) +
            " > sigma_final + nlp_tolerance = " +
            format_number(options.homotopy.sigma_final + options.homotopy.nlp_tolerance);
      }
      result.acceptable_only = true;
      ++result.acceptable_only_steps;
    }
    double t = t0;
    for (int n = 0; n < l.elements; ++n) {
      const double h = w[l.var(n, 0)];
      t += h;
      result.step_sizes.push_back(h);
      result.grid.push_back(n + 1 == l.elements ? t0 + length : t);
      states.push_back(w.segment(l.var(n, l.off_x), l.d));
      std::vector<int> sides = nlp.sides(w, n, active_tol);
      if (!previous_sides.empty() && sides != previous_sides) {
        result.switch_times.push_back(result.grid[result.grid.size() - 2]);
      }
      previous_sides = sides;
      result.active_sets.push_back(std::move(sides));
    }
    if (sensitivities) {
      std::string why;
      const Eigen::MatrixXd s = step_sensitivity(nlp, l, w, length, active_tol, &why);
      if (s.size() == 0) {
        sensitivities = false;
        result.message += std::string(result.message.empty() ? "" : "; ") +
                          "fesd: no sensitivity at the step from t = " + format_number(t0) + ": " +
                          why;
      } else {
        sensitivity = s * sensitivity;
      }
    }
    x = w.segment(l.var(l.elements - 1, l.off_x), l.d);
    if (options.progress) {
      FesdStepReport report;
      report.index = taken;
      report.planned = options.steps;
      report.t = t0;
      report.length = length;
      report.halvings = halvings;
      report.newton = solved_by_newton;
      report.nlp_iterations = iterations;
      report.complementarity = residual;
      options.progress(report);
    }
    ++taken;
    t0 += length;
  }
  result.x_end = x;
  result.states.resize(l.d, static_cast<Eigen::Index>(states.size()));
  for (std::size_t k = 0; k < states.size(); ++k)
    result.states.col(static_cast<Eigen::Index>(k)) = states[k];
  if (sensitivities) result.sensitivity = sensitivity;
  return result;
}

}  // namespace bflow

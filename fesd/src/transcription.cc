#include "bflow/fesd/transcription.h"

#include <time.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "bflow/core/errors.h"
#include "bflow/fesd/linear_solver.h"
#include "bflow/fesd/sparsity.h"
#include "homotopy_nlp.h"

namespace bflow {
namespace fesd {

namespace {

constexpr double kInfinity = 1e19;  // IPOPT's default nlp_upper_bound_inf

// Lower or upper bound k of an optional bound vector.
double bound(const Eigen::VectorXd& v, int k, double fallback) {
  return v.size() == 0 ? fallback : std::clamp(v[k], -kInfinity, kInfinity);
}

}  // namespace

// The transcription as one IPOPT problem at relaxation sigma.
class Transcription::Nlp final : public HomotopyNlp {
 public:
  using ElementEnds = Transcription::ElementEnds;
  // A function of a few unknowns that enters the objective.
  enum class TermKind { kStage, kStageEnd, kTerminal, kEquilibration, kStepDeviation };
  // Its inputs: the unknowns `globals` (-1: the constant of the same place in `constants`); the
  // last `factors` of them multiply the rest (term_value = their product times term_part).
  struct Term {
    TermKind kind;
    int stage;
    std::vector<int> globals;
    std::vector<double> constants;
    int point = 0;    // kStage: the stage point of the quadrature
    int factors = 0;  // kStage: 2 (T, or the constant 1, and h)
  };

  Nlp(const ButcherTableau& tab, const TranscriptionLayout& layout, const TranscriptionSetup& setup,
      const TranscriptionTerms* terms)
      : tab_(tab), l_(layout), p_(setup), terms_(terms != nullptr ? *terms : no_terms_) {
    const int d = l_.d, nu = l_.nu;
    BFLOW_ASSERT(p_.x0.size() == d);
    // Standard time-stepping writes one row per pair (complementarity_rows).
    BFLOW_ASSERT(!p_.standard || l_.cross == CrossComplementarity::kElementSums);
    Eigen::VectorXd y0 = Eigen::VectorXd::Zero(d + nu);
    y0.head(d) = p_.x0;
    v_start_.resize(l_.npairs);
    l_.dcs->start(y0.data(), v_start_.data());  // (17)
    // Lengths: relative (T h) when time-scaled, else absolute.
    unit_ = l_.scaled ? 1.0 : p_.horizon;
    h0_ = unit_ / l_.elements;
    element_globals_.resize(static_cast<std::size_t>(l_.elements));
    for (int e = 0; e < l_.elements; ++e) {
      std::vector<int>& g = element_globals_[static_cast<std::size_t>(e)];
      for (int k = 0; k < l_.local; ++k) g.push_back(l_.global(e, k));
    }
    // Objective terms.
    if (terms_.has_stage_cost()) {
      // T h b_m L(X_m, u) per element and stage point: inputs [X_m, u, T (or 1), h].
      for (int e = 0; e < l_.elements; ++e) {
        for (int m = 0; m < l_.s; ++m) {
          Term t{TermKind::kStage, e / l_.per_stage, {}, {}, m, 2};
          for (int i = 0; i < d; ++i) t.globals.push_back(l_.var(e, 1 + m * d + i));
          for (int j = 0; j < nu; ++j) t.globals.push_back(l_.u(t.stage, j));
          t.constants.assign(t.globals.size(), 0.0);
          t.globals.push_back(l_.scaled ? TranscriptionLayout::kT : -1);
          t.constants.push_back(1.0);
          t.globals.push_back(l_.var(e, 0));
          t.constants.push_back(0.0);
          objective_terms_.push_back(std::move(t));
        }
      }
    }
    if (terms_.has_stage_end_cost()) {
      for (int k = 0; k < l_.stages; ++k) {
        Term t{TermKind::kStageEnd, k, {}, {}};
        for (int i = 0; i < d; ++i) t.globals.push_back(l_.x_end((k + 1) * l_.per_stage - 1, i));
        for (int j = 0; j < nu; ++j) t.globals.push_back(l_.u(k, j));
        t.constants.assign(t.globals.size(), 0.0);
        objective_terms_.push_back(std::move(t));
      }
    }
    if (!p_.standard && p_.step_deviation_weight > 0.0) {
      for (int e = 0; e < l_.elements; ++e) {
        objective_terms_.push_back(
            Term{TermKind::kStepDeviation, e / l_.per_stage, {l_.var(e, 0)}, {0.0}});
      }
    }
    if (terms_.has_terminal_cost()) {
      Term t{TermKind::kTerminal, l_.stages - 1, {}, {}};
      for (int i = 0; i < d; ++i) t.globals.push_back(l_.x_end(l_.elements - 1, i));
      t.constants.assign(t.globals.size(), 0.0);
      objective_terms_.push_back(std::move(t));
    }
    if (!p_.standard && p_.equilibration_weight > 0.0) {
      for (int e = 0; e < l_.elements; ++e) {
        if (e % l_.per_stage == 0) continue;  // only between elements of one stage
        Term t{TermKind::kEquilibration, e / l_.per_stage, {}, {}};
        t.globals.push_back(l_.var(e - 1, 0));
        t.globals.push_back(l_.var(e, 0));
        t.constants.assign(2, 0.0);
        for (int k = 0; k < l_.npairs; ++k) {
          const int g = l_.global(e - 1, d + k);
          t.globals.push_back(g);
          t.constants.push_back(g < 0 ? v_start_[k] : 0.0);
        }
        for (int f : {e - 1, e}) {
          for (int k = 0; k < l_.points * l_.nz; ++k) {
            t.globals.push_back(l_.var(f, l_.off_z + k));
            t.constants.push_back(0.0);
          }
        }
        objective_terms_.push_back(std::move(t));
      }
    }
    // Constraint rows.
    rows_elements_ = l_.elements * l_.rows_per_element();
    rows_sums_ = p_.standard ? 0 : l_.stages;
    npath_ = terms_.path_constraints();
    nterm_ = terms_.terminal_constraints();
    rows_path_ = (l_.elements + 1) * npath_;
    constraints_ = rows_elements_ + rows_sums_ + rows_path_ + nterm_;
    set_guess(Eigen::MatrixXd::Zero(nu, 1), [&](int) { return std::make_pair(p_.x0, p_.x0); }, {});
  }

  const TranscriptionLayout& layout() const override { return l_; }
  int constraints() const { return constraints_ + static_cast<int>(equal_.size()); }
  std::size_t jacobian_nonzeros() {
    ensure_structure();
    return jac_rows_.size();
  }
  std::size_t hessian_nonzeros() {
    ensure_structure();
    return hessian_.size();
  }
  DerivativeCounts derivative_counts() const {
    return {hessian_.traces() + jac_traces_, hessian_.jet_only_blocks() + jac_on_jets_};
  }
  // The structure IPOPT is given, built when first asked for (a step fesd_simulate solves by
  // Newton's method never needs it): probed (sparsity.h) unless the setup or an earlier miss
  // asks for every candidate.
  void ensure_structure() {
    if (!structure_ready_) build_structure(!p_.probe_sparsity);
  }
  bool full_structure() const override { return full_structure_; }
  // A derivative outside the declared structure was met (and left out) since clear_missed().
  bool structure_missed() const override { return jac_missed_ || hessian_.missed() > 0; }
  void clear_missed() override {
    jac_missed_ = false;
    hessian_.clear_missed();
  }
  // Every candidate entry from now on.
  void widen_structure() override { build_structure(true); }
  // The starting point of the NLP about to be solved, kept so that it can be solved again.
  void keep_start() override { start_ = {w_, z_l_, z_u_, lambda_}; }
  // Polled by IPOPT after every iteration (intermediate_callback); true ends the NLP with
  // User_Requested_Stop.
  void set_cancel(const std::function<bool()>* cancelled) override { cancelled_ = cancelled; }
  bool go_on() override { return cancelled_ == nullptr || !*cancelled_ || !(*cancelled_)(); }
  void back_to_start() override {
    w_ = start_[0];
    z_l_ = start_[1];
    z_u_ = start_[2];
    lambda_ = start_[3];
  }
  double start_v(int k) const { return v_start_[k]; }

  // The active set read from the solution: which member of each complementarity pair is zero on
  // every element (a member is fixed at its zero value through its bounds), plus equal lengths
  // of neighbouring elements of a stage with the same sides.
  void enter_polish(const std::vector<std::vector<int>>& sides) override {
    polish_ = true;
    fixed_.clear();
    equal_.clear();
    const Eigen::VectorXd& w = w_;
    const PointDcs& dcs = *l_.dcs;
    const int P = l_.points;
    std::vector<bool> u_fixed_prev(static_cast<std::size_t>(l_.npairs), false);
    const auto n = static_cast<std::size_t>(l_.npairs);
    // Two pairs that share their u member (the step formulation's alpha with lambda+ and
    // 1 - alpha with lambda-) cannot both fix it, to 0 and to 1: far up the homotopy both
    // multipliers can outweigh their selections. The pair whose u member is nearer its zero keeps
    // it fixed; the other fixes its v.
    const auto resolve = [&](const std::vector<double>& su, std::vector<char>& fix_u) {
      for (std::size_t a = 0; a < n; ++a) {
        for (std::size_t b = a + 1; b < n; ++b) {
          const Pair& pa = dcs.pairs()[a];
          const Pair& pb = dcs.pairs()[b];
          if (pa.u != pb.u || PointDcs::u_zero(pa) == PointDcs::u_zero(pb)) continue;
          if (fix_u[a] && fix_u[b]) (su[a] <= su[b] ? fix_u[b] : fix_u[a]) = 0;
        }
      }
    };
    // Stewart's theta sum to one at every point, and lambda_i = g_i - min_j g_j vanishes for one
    // region at least: when every pair would fix its theta at 0 (a relaxed point spread over
    // several regions, each theta below its lambda), the pair least sure of it, with the
    // smallest margin, keeps theta free and fixes lambda instead.
    const bool stewart = dcs.kind() == PointDcs::Kind::kStewart;
    const auto keep_one_region = [&](const std::vector<double>& margin, std::vector<char>& fix_u) {
      if (!stewart || std::find(fix_u.begin(), fix_u.end(), 0) != fix_u.end()) return;
      std::size_t least = 0;
      for (std::size_t k = 1; k < n; ++k)
        if (margin[k] < margin[least]) least = k;
      fix_u[least] = 0;
    };
    std::vector<double> su(n), sv(n), v0(n), margin(n);
    std::vector<char> fix_u(n);
    for (int e = 0; e < l_.elements; ++e) {
      std::vector<bool> u_fixed(n, false);
      if (p_.standard) {
        for (int m = 0; m < P; ++m) {
          for (std::size_t k = 0; k < n; ++k) {
            const Pair& pair = dcs.pairs()[k];
            su[k] = PointDcs::member_u(pair, &w[l_.z(e, m, 0)]);
            fix_u[k] = su[k] <= w[l_.z(e, m, pair.v)];
            margin[k] = w[l_.z(e, m, pair.v)] - su[k];
          }
          resolve(su, fix_u);
          keep_one_region(margin, fix_u);
          for (std::size_t k = 0; k < n; ++k) {
            const Pair& pair = dcs.pairs()[k];
            if (fix_u[k]) {
              fixed_.push_back({l_.z(e, m, pair.u), PointDcs::u_zero(pair)});
            } else {
              fixed_.push_back({l_.z(e, m, pair.v), 0.0});
            }
          }
        }
        u_fixed_prev = std::move(u_fixed);
        continue;
      }
      for (std::size_t k = 0; k < n; ++k) {
        const Pair& pair = dcs.pairs()[k];
        su[k] = sv[k] = 0.0;
        for (int m = 0; m < P; ++m) {
          su[k] += PointDcs::member_u(pair, &w[l_.z(e, m, 0)]);
          sv[k] += w[l_.z(e, m, pair.v)];
        }
        v0[k] = e == 0 ? v_start_[k] : w[l_.z(e - 1, P - 1, pair.v)];
        fix_u[k] = su[k] <= sv[k] + v0[k] || (e == 0 && v0[k] > 0.0);
        margin[k] =
            e == 0 && v0[k] > 0.0 ? std::numeric_limits<double>::infinity() : sv[k] + v0[k] - su[k];
      }
      resolve(su, fix_u);
      keep_one_region(margin, fix_u);
      // Stewart's selection is continuous where a sliding arc is left for one of its own regions;
      // where no region is free on both elements it is a crossing, and fixing the theta left at
      // the earlier element's end would leave none there.
      bool continues = !stewart || e == 0;
      for (std::size_t k = 0; k < n && !continues; ++k) continues = !u_fixed_prev[k] && !fix_u[k];
      for (std::size_t k = 0; k < n; ++k) {
        const Pair& pair = dcs.pairs()[k];
        if (fix_u[k]) {
          u_fixed[k] = true;
          for (int m = 0; m < P; ++m)
            fixed_.push_back({l_.z(e, m, pair.u), PointDcs::u_zero(pair)});
          // Leaving a sliding arc: the selection is continuous there.
          if (e > 0 && continues && !u_fixed_prev[k] &&
              dcs.leaves_sliding(sides[static_cast<std::size_t>(e - 1)],
                                 sides[static_cast<std::size_t>(e)], pair.group)) {
            fixed_.push_back({l_.z(e - 1, P - 1, pair.u), PointDcs::u_zero(pair)});
          }
        } else {
          for (int m = 0; m < P; ++m) fixed_.push_back({l_.z(e, m, pair.v), 0.0});
          if (e > 0) fixed_.push_back({l_.z(e - 1, P - 1, pair.v), 0.0});
        }
      }
      u_fixed_prev = std::move(u_fixed);
      // The exact step equilibration: equal lengths of neighbours with the same sides; with the
      // step deviation penalty instead (nosnoc's heuristic), the polish keeps that penalty, as
      // the relaxed NLPs had it, and imposes no lengths.
      if (!p_.standard && p_.step_deviation_weight == 0.0 && e % l_.per_stage != 0 &&
          sides[static_cast<std::size_t>(e)] == sides[static_cast<std::size_t>(e - 1)]) {
        equal_.push_back(e);
      }
    }
    for (const auto& [index, value] : fixed_) w_[index] = value;
    if (elastic()) w_[slack()] = 0.0;
    const int base = constraints_;
    polish_jac_.clear();
    for (std::size_t r = 0; r < equal_.size(); ++r) {
      polish_jac_.push_back({base + static_cast<int>(r), l_.var(equal_[r], 0)});
      polish_jac_.push_back({base + static_cast<int>(r), l_.var(equal_[r] - 1, 0)});
    }
  }
  void leave_polish() override {
    polish_ = false;
    fixed_.clear();
    equal_.clear();
    polish_jac_.clear();
  }
  void set_sigma(double sigma) override { sigma_ = sigma; }
  void set_solution(const Eigen::VectorXd& w) { w_ = w; }
  const Eigen::VectorXd& solution() const override { return w_; }
  double kkt_error() const override { return kkt_error_; }
  double constraint_violation() const override { return constraint_violation_; }
  // The last solved iterate, kept so that a failed solve can go back to it.
  void save() override { saved_ = {w_, z_l_, z_u_, lambda_}; }
  // A warm start from the primal point only: every multiplier 0 (IPOPT pushes the bounds' up to
  // warm_start_mult_bound_push).
  void forget_multipliers() override {
    z_l_.setZero(variables());
    z_u_.setZero(variables());
    lambda_.setZero(constraints_);
  }
  void restore() override {
    w_ = saved_[0];
    z_l_ = saved_[1];
    z_u_ = saved_[2];
    lambda_ = saved_[3];
  }

  // Inputs of element e at w (constants from x0).
  template <typename T>
  void element_inputs(const double* w, int e, std::vector<T>& in) const {
    const std::vector<int>& g = element_globals_[static_cast<std::size_t>(e)];
    in.resize(g.size());
    for (int k = 0; k < l_.local; ++k) {
      const int col = g[static_cast<std::size_t>(k)];
      double value;
      if (col >= 0) {
        value = w[col];
      } else if (k < l_.d) {
        value = p_.x0[k];
      } else {
        value = v_start_[k - l_.d];
      }
      in[static_cast<std::size_t>(k)] = T(value);
    }
  }

  Eigen::MatrixXd element_jacobian(const double* w, int e, Eigen::VectorXd* values) const {
    std::vector<double> base;
    element_inputs(w, e, base);
    Eigen::MatrixXd jac;
    fesd::element_jacobian(l_, p_.standard, base, jac, values);
    return jac;
  }

  double cost(const double* w) const override {
    double value = p_.time_optimal ? w[TranscriptionLayout::kT] : 0.0;
    std::vector<double> in;
    for (const Term& t : objective_terms_) {
      if (t.kind == TermKind::kEquilibration || t.kind == TermKind::kStepDeviation) continue;
      gather(t, w, in);
      value += term_value(t, in.data());
    }
    return value;
  }

  double equilibration(const double* w) const {
    double value = 0.0;
    std::vector<double> in;
    for (const Term& t : objective_terms_) {
      if (t.kind != TermKind::kEquilibration) continue;
      gather(t, w, in);
      value += p_.equilibration_weight * equilibration_term(l_, h0_, in.data());
    }
    return value;
  }

  double complementarity(const double* w) const override {
    double worst = 0.0;
    std::vector<double> in, out(static_cast<std::size_t>(l_.rows_per_element()));
    for (int e = 0; e < l_.elements; ++e) {
      element_inputs(w, e, in);
      element_residual(l_, p_.standard, in.data(), out.data());
      for (int r = l_.equalities; r < l_.rows_per_element(); ++r) {
        worst = std::max(worst, std::abs(out[static_cast<std::size_t>(r)]));
      }
    }
    return worst;
  }

  // Constraint row `row` by kind and place, e.g. "element 17 (stage 5) end row of state 8".
  std::string row_name(int row) const {
    const int per = l_.rows_per_element(), s = l_.s, d = l_.d;
    std::string what;
    if (row < rows_elements_) {
      const int e = row / per, r = row % per;
      what = "element " + std::to_string(e) + " (stage " + std::to_string(e / l_.per_stage) + ") ";
      if (r < s * d) {
        what += "collocation row of point " + std::to_string(r / d) + ", state " +
                std::to_string(r % d);
      } else if (r < l_.dynamics) {
        what += "end row of state " + std::to_string(r - s * d);
      } else if (r < l_.equalities) {
        const int a = r - l_.dynamics;
        what += "algebraic row " + std::to_string(a % l_.neq) + " of point " +
                std::to_string(a / l_.neq);
      } else {
        what += "complementarity row " + std::to_string(r - l_.equalities);
      }
    } else if (row < rows_elements_ + rows_sums_) {
      what = "stage " + std::to_string(row - rows_elements_) + "'s sum of element lengths";
    } else if (row < rows_elements_ + rows_sums_ + rows_path_) {
      const int b = (row - rows_elements_ - rows_sums_) / std::max(npath_, 1);
      what = "path constraint " +
             std::to_string((row - rows_elements_ - rows_sums_) % std::max(npath_, 1)) +
             " at element boundary " + std::to_string(b);
    } else if (row < constraints_) {
      what =
          "terminal constraint " + std::to_string(row - rows_elements_ - rows_sums_ - rows_path_);
    } else {
      const int e = equal_[static_cast<std::size_t>(row - constraints_)];
      what = "polish: equal lengths of elements " + std::to_string(e - 1) + " and " +
             std::to_string(e);
    }
    return what;
  }

  // "" when the objective, its gradient, the constraints and their Jacobian (and, with the
  // exact Hessian, the Lagrangian's Hessian at unit multipliers) are finite at w; else the
  // first that is not, named by row or unknown, with its value.
  std::string non_finite_at(const double* w) override {
    ensure_structure();
    int n = 0, m = 0, nnz_jac = 0, nnz_hess = 0;
    sizes(n, m, nnz_jac, nnz_hess);
    const auto text = [](double v) { return format_number(v); };
    const double f = objective(w);
    if (!std::isfinite(f)) return "the objective is " + text(f);
    std::vector<double> grad(static_cast<std::size_t>(n));
    gradient(n, w, grad.data());
    for (int i = 0; i < n; ++i) {
      if (!std::isfinite(grad[static_cast<std::size_t>(i)])) {
        return "the objective's derivative in unknown " + std::to_string(i) + " is " +
               text(grad[static_cast<std::size_t>(i)]);
      }
    }
    std::vector<double> g(static_cast<std::size_t>(m));
    constraints(w, g.data());
    for (int r = 0; r < m; ++r) {
      if (!std::isfinite(g[static_cast<std::size_t>(r)])) {
        return "the " + row_name(r) + " is " + text(g[static_cast<std::size_t>(r)]);
      }
    }
    std::vector<int> rows(static_cast<std::size_t>(nnz_jac)),
        cols(static_cast<std::size_t>(nnz_jac));
    std::vector<double> values(static_cast<std::size_t>(nnz_jac));
    jacobian_structure(nnz_jac, rows.data(), cols.data());
    jacobian_values(w, nnz_jac, values.data());
    for (std::size_t k = 0; k < values.size(); ++k) {
      if (!std::isfinite(values[k])) {
        return "the derivative of the " + row_name(rows[k]) + " in unknown " +
               std::to_string(cols[k]) + " is " + text(values[k]);
      }
    }
    if (p_.exact_hessian && nnz_hess > 0) {
      std::vector<int> hr(static_cast<std::size_t>(nnz_hess)),
          hc(static_cast<std::size_t>(nnz_hess));
      std::vector<double> h(static_cast<std::size_t>(nnz_hess));
      const std::vector<double> ones(static_cast<std::size_t>(m), 1.0);
      hessian_structure(nnz_hess, hr.data(), hc.data());
      hessian_values(w, 1.0, ones.data(), nnz_hess, h.data());
      for (std::size_t k = 0; k < h.size(); ++k) {
        if (!std::isfinite(h[k])) {
          return "the second derivative in unknowns " + std::to_string(hr[k]) + " and " +
                 std::to_string(hc[k]) + " is " + text(h[k]);
        }
      }
    }
    return "";
  }

  // The rows the current point violates most (at most `count`, largest first), named by kind
  // and place, e.g. "element 17 (stage 5) end row of state 8: 0.012"; "" when none is violated.
  std::string worst_rows(int count) override {
    const int n = variables(), m = constraints();
    Eigen::VectorXd x_l(n), x_u(n), g_l(m), g_u(m), g(m);
    bounds(n, x_l.data(), x_u.data(), m, g_l.data(), g_u.data());
    constraints(w_.data(), g.data());
    std::vector<std::pair<double, int>> worst;
    for (int r = 0; r < m; ++r) {
      const double v = std::max({g_l[r] - g[r], g[r] - g_u[r], 0.0});
      if (v > 0.0) worst.push_back({v, r});
    }
    const auto shown = std::min(worst.size(), static_cast<std::size_t>(std::max(count, 0)));
    std::partial_sort(worst.begin(), worst.begin() + static_cast<std::ptrdiff_t>(shown),
                      worst.end(), std::greater<>());
    std::string out;
    for (std::size_t k = 0; k < shown; ++k) {
      const std::string what = row_name(worst[k].second);
      char value[32];
      std::snprintf(value, sizeof value, ": %.4g", worst[k].first);
      out += (out.empty() ? "" : "; ") + what + value;
    }
    return out;
  }

  // The multipliers of the rows relaxed to <= sigma (Scholtes, not in a polish) at the last
  // point IPOPT returned: their sum and the largest; zeros otherwise.
  std::pair<double, double> product_multipliers() const override {
    if (p_.relaxation != Relaxation::kScholtes || polish_ || lambda_.size() != constraints_)
      return {0.0, 0.0};
    double sum = 0.0, largest = 0.0;
    for (int e = 0; e < l_.elements; ++e) {
      for (int r = l_.equalities; r < l_.rows_per_element(); ++r) {
        const double mu = lambda_[e * l_.rows_per_element() + r];
        sum += mu;
        largest = std::max(largest, mu);
      }
    }
    return {sum, largest};
  }

  void set_guess(const Eigen::MatrixXd& u_guess, const ElementEnds& ends,
                 const std::vector<double>& lengths) {
    const int d = l_.d, nu = l_.nu;
    BFLOW_ASSERT(u_guess.rows() == nu);
    BFLOW_ASSERT(lengths.empty() || static_cast<int>(lengths.size()) == l_.elements);
    w_.setZero(variables());
    if (l_.scaled) w_[TranscriptionLayout::kT] = p_.horizon;
    Eigen::VectorXd y(d + nu), z(l_.nz);
    for (int k = 0; k < l_.stages; ++k) {
      const Eigen::VectorXd uk = u_guess.col(u_guess.cols() == 1 ? 0 : k);
      for (int j = 0; j < nu; ++j) w_[l_.u(k, j)] = uk[j];
      for (int n = 0; n < l_.per_stage; ++n) {
        const int e = k * l_.per_stage + n;
        const auto [xa, xb] = ends(e);
        BFLOW_ASSERT(xa.size() == d && xb.size() == d);
        w_[l_.var(e, 0)] = lengths.empty() ? h0_ : lengths[static_cast<std::size_t>(e)];
        y.tail(nu) = uk;
        for (int m = 0; m < l_.points; ++m) {
          const double c = m < l_.s ? tab_.c(m) : 1.0;
          y.head(d) = (1.0 - c) * xa + c * xb;
          if (m < l_.s) w_.segment(l_.var(e, 1 + m * d), d) = y.head(d);
          if (p_.algebraic_guess != AlgebraicGuess::kSides) {
            l_.dcs->neutral(z.data(), p_.algebraic_guess);
          } else {
            l_.dcs->initial(y.data(), z.data());
          }
          w_.segment(l_.z(e, m, 0), l_.nz) = z;
        }
        w_.segment(l_.var(e, l_.off_x), d) = xb;
      }
    }
    // The elastic slack starts where every relaxed row of the guess holds.
    if (elastic()) w_[slack()] = complementarity(w_.data());
  }

  // --- NlpProblem (ipopt_adapter.h) ---
  void sizes(int& n, int& m, int& nnz_jac, int& nnz_hess) override {
    ensure_structure();
    n = variables();
    m = constraints();
    nnz_jac = static_cast<int>(jac_rows_.size() + polish_jac_.size());
    nnz_hess = static_cast<int>(hessian_.size());
  }

  void bounds(int n, double* x_l, double* x_u, int, double* g_l, double* g_u) override {
    std::fill(x_l, x_l + n, -kInfinity);
    std::fill(x_u, x_u + n, kInfinity);
    if (l_.scaled && p_.time_optimal) {
      x_l[TranscriptionLayout::kT] = std::max(p_.T_min, 1e-9 * p_.horizon);
      x_u[TranscriptionLayout::kT] = std::min(p_.T_max, kInfinity);
    } else if (l_.scaled) {
      x_l[TranscriptionLayout::kT] = x_u[TranscriptionLayout::kT] = p_.horizon;
    }
    if (elastic()) {
      x_l[slack()] = 0.0;
      x_u[slack()] = polish_ ? 0.0 : kInfinity;
    }
    for (int k = 0; k < l_.stages; ++k) {
      for (int j = 0; j < l_.nu; ++j) {
        x_l[l_.u(k, j)] = bound(p_.u_lower, j, -kInfinity);
        x_u[l_.u(k, j)] = bound(p_.u_upper, j, kInfinity);
      }
    }
    for (int e = 0; e < l_.elements; ++e) {
      x_l[l_.var(e, 0)] = p_.standard ? h0_ : 0.0;
      x_u[l_.var(e, 0)] = p_.standard ? h0_ : 2.0 * h0_;
      for (int i = 0; i < l_.d; ++i) {
        x_l[l_.x_end(e, i)] = bound(p_.x_lower, i, -kInfinity);
        x_u[l_.x_end(e, i)] = bound(p_.x_upper, i, kInfinity);
        for (int m = 0; p_.x_bounds_at_stage_points && m < l_.s; ++m) {
          x_l[l_.var(e, 1 + m * l_.d + i)] = bound(p_.x_lower, i, -kInfinity);
          x_u[l_.var(e, 1 + m * l_.d + i)] = bound(p_.x_upper, i, kInfinity);
        }
      }
      if (p_.clock_state >= 0 && (e + 1) % l_.per_stage == 0) {
        const double clock = (e + 1) / l_.per_stage * p_.horizon / l_.stages;
        x_l[l_.x_end(e, p_.clock_state)] = clock - p_.clock_tolerance;
        x_u[l_.x_end(e, p_.clock_state)] = clock + p_.clock_tolerance;
      }
      for (int m = 0; m < l_.points; ++m) {
        for (int k = 0; k < l_.nz; ++k) {
          x_l[l_.z(e, m, k)] = std::max(l_.dcs->lower(k), -kInfinity);
          x_u[l_.z(e, m, k)] = std::min(l_.dcs->upper(k), kInfinity);
        }
      }
      for (int r = 0; r < l_.rows_per_element(); ++r) {
        const int row = e * l_.rows_per_element() + r;
        const bool equality = r < l_.equalities;
        g_l[row] = equality ? 0.0 : -kInfinity;
        g_u[row] = equality                                               ? 0.0
                   : (p_.relaxation == Relaxation::kScholtes && !polish_) ? sigma_
                   : (elastic() && !polish_)                              ? 0.0
                                                                          : kInfinity;
      }
    }
    for (int k = 0; k < rows_sums_; ++k) {
      g_l[rows_elements_ + k] = g_u[rows_elements_ + k] = unit_ / l_.stages;
    }
    for (int b = 0; b <= l_.elements; ++b) {
      for (int r = 0; r < npath_; ++r) {
        const int row = rows_elements_ + rows_sums_ + b * npath_ + r;
        g_l[row] = bound(p_.path_lower, r, -kInfinity);
        g_u[row] = bound(p_.path_upper, r, 0.0);
      }
    }
    for (int r = 0; r < nterm_; ++r) {
      const int row = rows_elements_ + rows_sums_ + rows_path_ + r;
      g_l[row] = bound(p_.terminal_lower, r, 0.0);
      g_u[row] = bound(p_.terminal_upper, r, 0.0);
    }
    for (const auto& [index, value] : fixed_) x_l[index] = x_u[index] = value;
    for (std::size_t r = 0; r < equal_.size(); ++r) {
      g_l[constraints_ + static_cast<int>(r)] = g_u[constraints_ + static_cast<int>(r)] = 0.0;
    }
  }

  bool start(int n, bool init_x, double* x, bool init_z, double* z_l, double* z_u, int m,
             bool init_lambda, double* lambda) override {
    if (init_x) std::copy(w_.data(), w_.data() + n, x);
    if (init_z) {
      if (z_l_.size() != n) return false;
      std::copy(z_l_.data(), z_l_.data() + n, z_l);
      std::copy(z_u_.data(), z_u_.data() + n, z_u);
    }
    if (init_lambda) {
      if (lambda_.size() != m) return false;
      std::copy(lambda_.data(), lambda_.data() + m, lambda);
    }
    return true;
  }

  double objective(const double* x) override {
    double value = p_.time_optimal ? x[TranscriptionLayout::kT] : 0.0;
    std::vector<double>& in = inputs_;
    for (const Term& t : objective_terms_) {
      if (polish_ && t.kind == TermKind::kEquilibration) continue;
      gather(t, x, in);
      value += term_value(t, in.data());
    }
    if (elastic() && !polish_) value += x[slack()] / sigma_;
    if (penalty()) {
      std::vector<double> out(static_cast<std::size_t>(l_.rows_per_element()));
      for (int e = 0; e < l_.elements; ++e) {
        element_inputs(x, e, in);
        element_residual(l_, p_.standard, in.data(), out.data());
        for (int r = l_.equalities; r < l_.rows_per_element(); ++r) {
          value += out[static_cast<std::size_t>(r)] / sigma_;
        }
      }
    }
    return value;
  }

  void gradient(int n, const double* x, double* grad) override {
    std::fill(grad, grad + n, 0.0);
    if (p_.time_optimal) grad[TranscriptionLayout::kT] = 1.0;
    if (elastic() && !polish_) grad[slack()] = 1.0 / sigma_;
    std::vector<double>& in = inputs_;
    for (const Term& t : objective_terms_) {
      if (polish_ && t.kind == TermKind::kEquilibration) continue;
      gather(t, x, in);
      add_gradient(
          t.globals, in, 1.0, [&](const JetChunk* v) { return term_value(t, v); }, grad);
    }
    if (penalty()) {
      std::vector<JetChunk> out(static_cast<std::size_t>(l_.rows_per_element()));
      for (int e = 0; e < l_.elements; ++e) {
        element_inputs(x, e, in);
        add_gradient(
            element_globals_[static_cast<std::size_t>(e)], in, 1.0 / sigma_,
            [&](const JetChunk* v) {
              element_residual(l_, p_.standard, v, out.data());
              JetChunk sum(0.0);
              for (int r = l_.equalities; r < l_.rows_per_element(); ++r)
                sum += out[static_cast<std::size_t>(r)];
              return sum;
            },
            grad);
      }
    }
  }

  void constraints(const double* x, double* g) override {
    std::vector<double>& in = inputs_;
    for (int e = 0; e < l_.elements; ++e) {
      element_inputs(x, e, in);
      double* rows = g + e * l_.rows_per_element();
      element_residual(l_, p_.standard, in.data(), rows);
      // Products <= s (s = 0 in the polish).
      for (int r = l_.equalities; elastic() && r < l_.rows_per_element(); ++r)
        rows[r] -= x[slack()];
    }
    for (int k = 0; k < rows_sums_; ++k) {
      double sum = 0.0;
      for (int n = 0; n < l_.per_stage; ++n) sum += x[l_.var(k * l_.per_stage + n, 0)];
      g[rows_elements_ + k] = sum;
    }
    for (int b = 0; b <= l_.elements && npath_ > 0; ++b) {
      path_inputs(x, b, in);
      terms_.path(in.data(), in.data() + l_.d, g + rows_elements_ + rows_sums_ + b * npath_);
    }
    if (nterm_ > 0) {
      terminal_inputs(x, in);
      terms_.terminal(in.data(), g + rows_elements_ + rows_sums_ + rows_path_);
    }
    for (std::size_t r = 0; r < equal_.size(); ++r) {
      g[constraints_ + static_cast<int>(r)] = x[l_.var(equal_[r], 0)] - x[l_.var(equal_[r] - 1, 0)];
    }
  }

  void jacobian_structure(int nele, int* rows, int* cols) override {
    const int own = static_cast<int>(jac_rows_.size());
    for (int k = 0; k < own; ++k) {
      rows[k] = jac_rows_[static_cast<std::size_t>(k)];
      cols[k] = jac_cols_[static_cast<std::size_t>(k)];
    }
    for (int k = own; k < nele; ++k) {
      rows[k] = polish_jac_[static_cast<std::size_t>(k - own)].first;
      cols[k] = polish_jac_[static_cast<std::size_t>(k - own)].second;
    }
  }

  void jacobian_values(const double* x, int nele, double* values) override {
    std::vector<double>& base = inputs_;
    const int rpe = l_.rows_per_element();
    // Each element's entries straight into `values` (their range zeroed first), the candidates
    // left out of the pattern into `left_out`, checked and cleared.
    for (int e = 0; e < l_.elements; ++e) {
      element_inputs(x, e, base);
      const int first = jac_start_[static_cast<std::size_t>(e)];
      const SlotMap& map =
          slot_maps_[static_cast<std::size_t>(jac_map_[static_cast<std::size_t>(e)])];
      if (program_jacobian(e, map, base, values + first)) continue;
      std::fill(values + first, values + jac_start_[static_cast<std::size_t>(e) + 1], 0.0);
      JacobianSlots view{values + first, map.slot.data(), l_.local, left_out_values_.data()};
      fesd::element_jacobian_into(l_, p_.standard, base, view);
      for (int i = 0; i < map.left_out; ++i) {
        double& v = left_out_values_[static_cast<std::size_t>(i)];
        if (v != 0.0) jac_missed_ = true;
        v = 0.0;
      }
    }
    int k = jac_start_.back();
    for (int s = 0; s < rows_sums_ * l_.per_stage; ++s) values[k++] = 1.0;
    Eigen::MatrixXd& dense = dense_jacobian_;
    for (int b = 0; b <= l_.elements && npath_ > 0; ++b) {
      path_inputs(x, b, base);
      dense_jacobian(base, npath_, dense,
                     [&](const JetChunk* in, JetChunk* out) { terms_.path(in, in + l_.d, out); });
      const std::vector<int> g = path_globals(b);
      for (int r = 0; r < npath_; ++r) {
        for (std::size_t c = 0; c < g.size(); ++c) {
          if (g[c] >= 0) values[k++] = dense(r, static_cast<Eigen::Index>(c));
        }
      }
    }
    if (nterm_ > 0) {
      terminal_inputs(x, base);
      dense_jacobian(base, nterm_, dense,
                     [&](const JetChunk* in, JetChunk* out) { terms_.terminal(in, out); });
      for (int r = 0; r < nterm_; ++r) {
        for (int i : term_pattern_[static_cast<std::size_t>(r)]) values[k++] = dense(r, i);
        for (int i : term_left_out_[static_cast<std::size_t>(r)]) {
          if (dense(r, i) != 0.0) jac_missed_ = true;
        }
      }
    }
    for (int e = 0; elastic() && e < l_.elements; ++e) {
      for (int r = l_.equalities; r < rpe; ++r) values[k++] = -1.0;
    }
    for (std::size_t r = 0; r < equal_.size(); ++r) {
      values[k++] = 1.0;
      values[k++] = -1.0;
    }
    BFLOW_ASSERT(k == nele);
  }

  void hessian_structure(int nele, int* rows, int* cols) override {
    for (int k = 0; k < nele; ++k) {
      rows[k] = hessian_.rows()[static_cast<std::size_t>(k)];
      cols[k] = hessian_.cols()[static_cast<std::size_t>(k)];
    }
  }

  void hessian_values(const double* x, double obj_factor, const double* lambda, int nele,
                      double* values) override {
    std::fill(values, values + nele, 0.0);
    hessian_.begin_evaluation();
    std::vector<double>& base = inputs_;
    std::vector<double>& weights = hessian_weights_;
    weights.resize(static_cast<std::size_t>(l_.rows_per_element()));
    // The stage cost joins the field pieces' passes (the same factor h, or h T, and inputs).
    for (int m = 0; m < l_.s; ++m)
      cost_weights_[static_cast<std::size_t>(m)] = obj_factor * tab_.b(m);
    for (int e = 0; e < l_.elements; ++e) {
      element_inputs(x, e, base);
      const double* lam = lambda + e * l_.rows_per_element();
      std::copy(lam, lam + l_.rows_per_element(), weights.begin());
      if (penalty()) {
        for (int r = l_.equalities; r < l_.rows_per_element(); ++r)
          weights[static_cast<std::size_t>(r)] += obj_factor / sigma_;
      }
      const StageCostAt cost(terms_, e / l_.per_stage);
      add_element_hessian(l_, pieces_, comp_, element_globals_[static_cast<std::size_t>(e)], base,
                          weights.data(), hessian_, values,
                          terms_.has_stage_cost() ? &cost : nullptr, cost_weights_.data());
    }
    for (const Term& t : objective_terms_) {
      if (polish_ && t.kind == TermKind::kEquilibration) continue;
      if (t.kind == TermKind::kStage) continue;  // in add_element_hessian
      if (t.kind == TermKind::kStepDeviation) {
        // rho (c (h - h0))^2 with c = horizon / unit: the constant 2 rho c^2.
        const double c = p_.horizon / unit_;
        step_term_[0] = obj_factor * (p_.step_deviation_weight * (c * c + c * c));
        hessian_.add_constant(t.globals, kDiagonal, step_term_, values);
        continue;
      }
      gather(t, x, base);
      if (t.kind == TermKind::kEquilibration) {
        // Its weight (which fades with sigma) as add's weight: eval reads its inputs alone
        // (a traced program, hessian_tape.h, keeps every other number it reads).
        step_term_[0] = obj_factor * equilibration_factor();
        hessian_.add_scaled(
            t.globals, base, t.factors, 1, step_term_.data(),
            [&](const auto* in, auto* out) { out[0] = equilibration_term(l_, h0_, in); }, values);
        continue;
      }
      hessian_.add_scaled(
          t.globals, base, t.factors, 1, &obj_factor,
          [&](const auto* in, auto* out) { out[0] = term_part(t, in); }, values);
    }
    for (int b = 0; b <= l_.elements && npath_ > 0; ++b) {
      path_inputs(x, b, base);
      hessian_.add(
          path_globals(b), base, npath_, lambda + rows_elements_ + rows_sums_ + b * npath_,
          [&](const auto* in, auto* out) { terms_.path(in, in + l_.d, out); }, values);
    }
    if (nterm_ > 0) {
      terminal_inputs(x, base);
      hessian_.add(
          terminal_globals(), base, nterm_, lambda + rows_elements_ + rows_sums_ + rows_path_,
          [&](const auto* in, auto* out) { terms_.terminal(in, out); }, values);
    }
    hessian_.end_evaluation();
    if (p_.exact_hessian_scale != 1.0) {
      for (int k = 0; k < nele; ++k) values[k] *= p_.exact_hessian_scale;
    }
  }

  void finish(int n, const double* x, const double* z_l, const double* z_u, int m,
              const double* lambda, double kkt_error, double constraint_violation) override {
    kkt_error_ = kkt_error;
    constraint_violation_ = constraint_violation;
    w_ = Eigen::Map<const Eigen::VectorXd>(x, n);
    z_l_ = Eigen::Map<const Eigen::VectorXd>(z_l, n);
    z_u_ = Eigen::Map<const Eigen::VectorXd>(z_u, n);
    lambda_ = Eigen::Map<const Eigen::VectorXd>(lambda, m);
  }

  // Where element_jacobian_into's entry (r, c) of an element goes (r * local + c): >= 0 its
  // position among the element's values, -1 nowhere (not a candidate, or a constant's column),
  // <= -2 the left-out candidate -2 - slot (checked to be zero).
  struct SlotMap {
    std::vector<int> slot;
    int left_out = 0;
    // (row, local input) of every slot, in slot order, then of every left-out candidate.
    std::vector<std::pair<int, int>> entries;
  };
  // An element's Jacobian program (program_jacobian).
  struct JacobianPlan {
    std::unique_ptr<JacobianProgram> program;
    long runs = 0;
    bool jets_only = false;
  };
  SlotMap slot_map(const std::vector<int>& g) const {
    SlotMap map;
    map.slot.assign(static_cast<std::size_t>(l_.rows_per_element() * l_.local), -1);
    int next = 0;
    std::vector<std::pair<int, int>> left_out;
    for (int r = 0; r < l_.rows_per_element(); ++r) {
      for (int c : jac_pattern_[static_cast<std::size_t>(r)]) {
        if (g[static_cast<std::size_t>(c)] >= 0) {
          map.slot[static_cast<std::size_t>(r * l_.local + c)] = next++;
          map.entries.emplace_back(r, c);
        }
      }
      for (int c : jac_left_out_[static_cast<std::size_t>(r)]) {
        if (g[static_cast<std::size_t>(c)] >= 0) {
          map.slot[static_cast<std::size_t>(r * l_.local + c)] = -2 - map.left_out++;
          left_out.emplace_back(r, c);
        }
      }
    }
    map.entries.insert(map.entries.end(), left_out.begin(), left_out.end());
    return map;
  }
  // Element e's Jacobian entries into `into` (its range of IPOPT's values, in slot order) by
  // the element's program (hessian_tape.h: element_residual traced, differentiated once), its
  // left-out candidates checked; checked against element_jacobian_into at the program's 1st,
  // 2nd, 4th, ... run. False: to be computed by element_jacobian_into (programs off, the
  // element's program disagreed once, or a number not finite).
  bool program_jacobian(int e, const SlotMap& map, const std::vector<double>& base, double* into) {
    if (!p_.derivative_programs) return false;
    JacobianPlan& plan = jac_programs_[static_cast<std::size_t>(e)];
    if (plan.jets_only) return false;
    const int total = static_cast<int>(map.entries.size());
    const int pattern = total - map.left_out;
    std::vector<double>& v = jac_program_values_;
    v.resize(static_cast<std::size_t>(total));
    const auto eval = [&](const auto* in, auto* out) {
      element_residual(l_, p_.standard, in, out);
    };
    for (int attempt = 0; attempt < 2; ++attempt) {
      if (plan.program == nullptr) {
        plan.program =
            JacobianProgram::trace(l_.local, l_.rows_per_element(), map.entries, base.data(), eval);
        plan.runs = 0;
        ++jac_traces_;
      }
      const HessianProgram::Outcome outcome = plan.program->run(base.data(), v.data());
      if (outcome == HessianProgram::Outcome::kGuardFailed) {
        plan.program.reset();  // the model branches otherwise here: trace again
        continue;
      }
      if (outcome == HessianProgram::Outcome::kNotFinite) return false;
      ++plan.runs;
      if ((plan.runs & (plan.runs - 1)) == 0) {
        std::vector<double>& jets = jac_check_values_;
        jets.assign(static_cast<std::size_t>(total), 0.0);
        JacobianSlots view{jets.data(), map.slot.data(), l_.local, jets.data() + pattern};
        fesd::element_jacobian_into(l_, p_.standard, base, view);
        if (!programs_agree(v.data(), jets.data(), total)) {
          plan.program.reset();
          plan.jets_only = true;
          ++jac_on_jets_;
          return false;
        }
      }
      std::copy(v.begin(), v.begin() + pattern, into);
      for (int i = pattern; i < total; ++i) {
        if (v[static_cast<std::size_t>(i)] != 0.0) jac_missed_ = true;
      }
      return true;
    }
    return false;
  }
  // element_jacobian_into's view of IPOPT's values through a SlotMap.
  struct JacobianSlots {
    double* base;
    const int* slot;
    int local;
    double* left_out;
    double trash = 0.0;
    double& operator()(int r, int c) {
      const int at = slot[r * local + c];
      return at >= 0 ? base[at] : at == -1 ? trash : left_out[-2 - at];
    }
  };

  // The Jacobian's and the Hessian's structure: each element row's inputs and each Hessian
  // piece's pairs as probed (sparsity.h), or with `full` every candidate (what each row reads,
  // every pair of a field or algebraic piece's unknowns, the complementarity products' pairs);
  // objective terms and terminal constraints likewise (a terminal row's states, every pair of
  // the states); path constraints keep every input and every pair of their inputs.
  void build_structure(bool full) {
    structure_ready_ = true;
    full_structure_ = full;
    const int d = l_.d, rpe = l_.rows_per_element();
    const auto residual = [&](const JetChunk* in, JetChunk* out) {
      element_residual(l_, p_.standard, in, out);
    };
    const std::vector<std::vector<int>> candidates = element_jacobian_pattern(l_, p_.standard);
    jac_pattern_ = full ? candidates : probe_jacobian_pattern(l_.local, rpe, candidates, residual);
    // Per row, the candidates a pattern leaves out (checked at every evaluation).
    const auto left_out = [](const std::vector<std::vector<int>>& all,
                             const std::vector<std::vector<int>>& pattern, int count) {
      std::vector<std::vector<int>> out(all.size());
      std::vector<char> kept(static_cast<std::size_t>(count));
      for (std::size_t r = 0; r < all.size(); ++r) {
        std::fill(kept.begin(), kept.end(), 0);
        for (int c : pattern[r]) kept[static_cast<std::size_t>(c)] = 1;
        for (int c : all[r]) {
          if (!kept[static_cast<std::size_t>(c)]) out[r].push_back(c);
        }
      }
      return out;
    };
    jac_left_out_ = left_out(candidates, jac_pattern_, l_.local);
    // The terminal constraints' rows: every state, or those found nonzero at random points.
    std::vector<std::vector<int>> every_state(static_cast<std::size_t>(nterm_));
    for (std::vector<int>& row : every_state) {
      for (int i = 0; i < d; ++i) row.push_back(i);
    }
    term_pattern_ = full || nterm_ == 0
                        ? every_state
                        : probe_jacobian_pattern(
                              d, nterm_, every_state,
                              [&](const JetChunk* in, JetChunk* out) { terms_.terminal(in, out); });
    term_left_out_ = left_out(every_state, term_pattern_, d);
    jac_rows_.clear();
    jac_cols_.clear();
    jac_start_.clear();
    jac_map_.clear();
    slot_maps_.clear();
    jac_programs_.clear();
    jac_programs_.resize(static_cast<std::size_t>(l_.elements));
    for (int e = 0; e < l_.elements; ++e) {
      const std::vector<int>& g = element_globals_[static_cast<std::size_t>(e)];
      jac_start_.push_back(static_cast<int>(jac_rows_.size()));
      for (int r = 0; r < rpe; ++r) {
        for (int c : jac_pattern_[static_cast<std::size_t>(r)]) {
          const int col = g[static_cast<std::size_t>(c)];
          if (col < 0) continue;
          jac_rows_.push_back(e * rpe + r);
          jac_cols_.push_back(col);
        }
      }
      // The element's slots: elements with the same constants share one map.
      SlotMap map = slot_map(g);
      std::size_t at = 0;
      while (at < slot_maps_.size() && slot_maps_[at].slot != map.slot) ++at;
      if (at == slot_maps_.size()) slot_maps_.push_back(std::move(map));
      jac_map_.push_back(static_cast<int>(at));
    }
    jac_start_.push_back(static_cast<int>(jac_rows_.size()));
    int most = 0;
    for (const SlotMap& m : slot_maps_) most = std::max(most, m.left_out);
    left_out_values_.assign(static_cast<std::size_t>(most), 0.0);
    for (int k = 0; k < rows_sums_; ++k) {
      for (int n = 0; n < l_.per_stage; ++n) {
        jac_rows_.push_back(rows_elements_ + k);
        jac_cols_.push_back(l_.var(k * l_.per_stage + n, 0));
      }
    }
    for (int b = 0; b <= l_.elements; ++b) {
      const std::vector<int> g = path_globals(b);
      for (int r = 0; r < npath_; ++r) {
        for (int col : g) {
          if (col < 0) continue;
          jac_rows_.push_back(rows_elements_ + rows_sums_ + b * npath_ + r);
          jac_cols_.push_back(col);
        }
      }
    }
    for (int r = 0; r < nterm_; ++r) {
      for (int i : term_pattern_[static_cast<std::size_t>(r)]) {
        jac_rows_.push_back(rows_elements_ + rows_sums_ + rows_path_ + r);
        jac_cols_.push_back(l_.x_end(l_.elements - 1, i));
      }
    }
    for (int e = 0; elastic() && e < l_.elements; ++e) {
      for (int r = l_.equalities; r < rpe; ++r) {
        jac_rows_.push_back(e * rpe + r);
        jac_cols_.push_back(slack());
      }
    }
    hessian_.clear();
    hessian_.set_programs(p_.derivative_programs);
    if (!p_.exact_hessian) return;
    pieces_ = element_hessian_pieces(l_);
    complementarity_hessian(l_, p_.standard, comp_);
    std::vector<int> identity(static_cast<std::size_t>(l_.local));
    for (int k = 0; k < l_.local; ++k) identity[static_cast<std::size_t>(k)] = k;
    std::vector<std::pair<int, int>> element_pairs;
    if (!full) {
      element_pairs = probe_hessian_pattern(
          l_.local, rpe, pieces_,
          [&](HessianBlocks& probe, const std::vector<double>& base, const double* weights,
              double* values) {
            add_element_hessian(l_, pieces_, comp_, identity, base, weights, probe, values);
          });
    }
    std::vector<std::pair<int, int>> global_pairs;
    const auto register_pairs = [&](const std::vector<std::pair<int, int>>& pairs,
                                    const std::vector<int>& g) {
      global_pairs.clear();
      for (const auto& [a, b] : pairs) {
        global_pairs.emplace_back(g[static_cast<std::size_t>(a)], g[static_cast<std::size_t>(b)]);
      }
      hessian_.add_pairs(global_pairs);
    };
    // Every pair of a field or algebraic piece's unknowns, and of the complementarity piece the
    // pairs its products multiply (complementarity_hessian: by construction, whatever the
    // model).
    for (const std::vector<int>& g : element_globals_) {
      if (full) {
        for (std::size_t p = 0; p + 1 < pieces_.size(); ++p) {
          std::vector<int> globals;
          for (int k : pieces_[p]) globals.push_back(g[static_cast<std::size_t>(k)]);
          hessian_.add_block(globals);
        }
        global_pairs.clear();
        for (const auto& [a, b] : comp_.pairs) {
          global_pairs.emplace_back(
              g[static_cast<std::size_t>(pieces_.back()[static_cast<std::size_t>(a)])],
              g[static_cast<std::size_t>(pieces_.back()[static_cast<std::size_t>(b)])]);
        }
        hessian_.add_pairs(global_pairs);
      } else {
        register_pairs(element_pairs, g);
      }
    }
    for (const Term& t : objective_terms_) {
      if (full) {
        hessian_.add_block(t.globals);
        continue;
      }
      const int count = static_cast<int>(t.globals.size());
      std::vector<int> local(static_cast<std::size_t>(count));
      for (int k = 0; k < count; ++k) local[static_cast<std::size_t>(k)] = k;
      register_pairs(probe_hessian_pattern(
                         count, 1, {local},
                         [&](HessianBlocks& probe, const std::vector<double>& base,
                             const double* weights, double* values) {
                           probe.add(
                               local, base, 1, weights,
                               [&](const auto* in, auto* out) { out[0] = term_value(t, in); },
                               values);
                         }),
                     t.globals);
    }
    for (int b = 0; b <= l_.elements && npath_ > 0; ++b) hessian_.add_block(path_globals(b));
    if (nterm_ > 0 && full) {
      hessian_.add_block(terminal_globals());
    } else if (nterm_ > 0) {
      std::vector<int> local(static_cast<std::size_t>(d));
      for (int i = 0; i < d; ++i) local[static_cast<std::size_t>(i)] = i;
      register_pairs(
          probe_hessian_pattern(d, nterm_, {local},
                                [&](HessianBlocks& probe, const std::vector<double>& base,
                                    const double* weights, double* values) {
                                  probe.add(
                                      local, base, nterm_, weights,
                                      [&](const auto* in, auto* out) { terms_.terminal(in, out); },
                                      values);
                                }),
          terminal_globals());
    }
  }

 private:
  bool penalty() const { return p_.relaxation == Relaxation::kL1Penalty && !polish_; }
  bool elastic() const { return p_.relaxation == Relaxation::kElastic; }
  // The elastic slack's index, the last unknown.
  int slack() const { return l_.variables(); }
  int variables() const { return l_.variables() + (elastic() ? 1 : 0); }

  void gather(const Term& t, const double* w, std::vector<double>& out) const {
    out.resize(t.globals.size());
    for (std::size_t k = 0; k < t.globals.size(); ++k) {
      out[k] = t.globals[k] >= 0 ? w[t.globals[k]] : t.constants[k];
    }
  }

  // Path constraints at boundary b (0: x0 with u_0; b < N_e: the start of element b with its
  // stage's control; N_e: x(T) with u_{N-1}): inputs [x (d), u (nu)], -1 for x0.
  std::vector<int> path_globals(int b) const {
    std::vector<int> g;
    for (int i = 0; i < l_.d; ++i) g.push_back(b == 0 ? -1 : l_.x_end(b - 1, i));
    const int stage = std::min(b, l_.elements - 1) / l_.per_stage;
    for (int j = 0; j < l_.nu; ++j) g.push_back(l_.u(stage, j));
    return g;
  }
  template <typename T>
  void path_inputs(const double* w, int b, std::vector<T>& in) const {
    const std::vector<int> g = path_globals(b);
    in.resize(g.size());
    for (std::size_t k = 0; k < g.size(); ++k) {
      in[k] = T(g[k] >= 0 ? w[g[k]] : p_.x0[static_cast<Eigen::Index>(k)]);
    }
  }
  std::vector<int> terminal_globals() const {
    std::vector<int> g;
    for (int i = 0; i < l_.d; ++i) g.push_back(l_.x_end(l_.elements - 1, i));
    return g;
  }
  template <typename T>
  void terminal_inputs(const double* w, std::vector<T>& in) const {
    in.resize(static_cast<std::size_t>(l_.d));
    for (int i = 0; i < l_.d; ++i)
      in[static_cast<std::size_t>(i)] = T(w[l_.x_end(l_.elements - 1, i)]);
  }

  // The stage cost of one stage as add_element_hessian's StageCostTerm.
  class StageCostAt final : public StageCostTerm {
   public:
    StageCostAt(const TranscriptionTerms& terms, int stage) : terms_(terms), stage_(stage) {}
    JetChunk value(const JetChunk* x, const JetChunk* u) const override {
      return terms_.stage_cost(stage_, x, u);
    }
    HessianScalar value(const HessianScalar* x, const HessianScalar* u) const override {
      return terms_.stage_cost(stage_, x, u);
    }

   private:
    const TranscriptionTerms& terms_;
    int stage_;
  };

  // The value of an objective term from its inputs: its factors' product times term_part.
  template <typename T>
  T term_value(const Term& t, const T* in) const {
    const std::size_t n = t.globals.size() - static_cast<std::size_t>(t.factors);
    T value = term_part(t, in);
    for (std::size_t k = n; k < t.globals.size(); ++k) value = in[k] * value;
    return value;
  }
  // The step equilibration's weight, faded with sigma where the setup asks.
  double equilibration_factor() const {
    const double fade = p_.equilibration_fades ? std::min(1.0, sigma_) : 1.0;
    return fade * p_.equilibration_weight;
  }
  // The term without its factors (which it does not read).
  template <typename T>
  T term_part(const Term& t, const T* in) const {
    switch (t.kind) {
      case TermKind::kStage:  // [X_m, u]: b_m L(X_m, u)
        return tab_.b(t.point) * terms_.stage_cost(t.stage, in, in + l_.d);
      case TermKind::kStageEnd:
        return terms_.stage_end_cost(t.stage, in, in + l_.d);
      case TermKind::kTerminal:
        return terms_.terminal_cost(in);
      case TermKind::kStepDeviation: {
        const T e = p_.horizon / unit_ * (in[0] - T(h0_));
        return p_.step_deviation_weight * e * e;
      }
      case TermKind::kEquilibration:
        return equilibration_factor() * equilibration_term(l_, h0_, in);
    }
    return T(0.0);
  }

  const ButcherTableau& tab_;
  const TranscriptionLayout& l_;
  const TranscriptionSetup& p_;
  const TranscriptionTerms no_terms_;
  const TranscriptionTerms& terms_;
  Eigen::VectorXd v_start_;
  double unit_ = 1.0, h0_ = 1.0;
  double sigma_ = 1.0;
  std::vector<std::vector<int>> element_globals_;
  std::vector<Term> objective_terms_;
  std::vector<double> inputs_;      // an element's or a term's inputs (the evaluations' scratch)
  Eigen::MatrixXd dense_jacobian_;  // a path or terminal row block's Jacobian
  std::vector<int> jac_start_;      // per element, where its Jacobian entries start (and end)
  std::vector<int> jac_map_;        // per element, its map in slot_maps_
  std::vector<SlotMap> slot_maps_;
  std::vector<double> left_out_values_;     // an element's left-out candidates (zero between)
  std::vector<JacobianPlan> jac_programs_;  // per element
  long jac_traces_ = 0, jac_on_jets_ = 0;
  std::vector<double> jac_program_values_, jac_check_values_;
  std::vector<double> hessian_weights_;  // hessian_values' multipliers of an element
  std::vector<double> cost_weights_ = std::vector<double>(static_cast<std::size_t>(l_.s));
  static inline const std::vector<std::pair<int, int>> kDiagonal{{0, 0}};  // one term's pair
  std::vector<double> step_term_ = std::vector<double>(1);
  int rows_elements_ = 0, rows_sums_ = 0, rows_path_ = 0, npath_ = 0, nterm_ = 0;
  int constraints_ = 0;
  std::vector<int> jac_rows_, jac_cols_;
  HessianBlocks hessian_;
  std::vector<std::vector<int>> pieces_;        // an element's Hessian pieces (local indices)
  ComplementarityHessian comp_;                 // its complementarity piece's constant pairs
  std::vector<std::vector<int>> jac_pattern_;   // per element row: the local inputs it reads
  std::vector<std::vector<int>> jac_left_out_;  // per element row: candidates not declared
  // Per terminal constraint row: the states it reads (declared) and the others (checked).
  std::vector<std::vector<int>> term_pattern_, term_left_out_;
  bool structure_ready_ = false, full_structure_ = false, jac_missed_ = false;
  std::array<Eigen::VectorXd, 4> start_;
  bool polish_ = false;
  std::vector<std::pair<int, double>> fixed_;
  std::vector<int> equal_;
  std::vector<std::pair<int, int>> polish_jac_;
  Eigen::VectorXd w_, z_l_, z_u_, lambda_;
  double kkt_error_ = std::numeric_limits<double>::infinity();
  double constraint_violation_ = std::numeric_limits<double>::infinity();
  std::array<Eigen::VectorXd, 4> saved_;
  const std::function<bool()>* cancelled_ = nullptr;
};

double process_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

struct Transcription::Handle {
  std::unique_ptr<Nlp> nlp;
};

Transcription::Transcription(const ButcherTableau& tableau, const TranscriptionLayout& layout,
                             const TranscriptionSetup& setup, const TranscriptionTerms* terms)
    : handle_(new Handle{std::make_unique<Nlp>(tableau, layout, setup, terms)}) {}
Transcription::~Transcription() = default;
const TranscriptionLayout& Transcription::layout() const { return handle_->nlp->layout(); }
int Transcription::constraints() const { return handle_->nlp->constraints(); }
std::size_t Transcription::jacobian_nonzeros() const { return handle_->nlp->jacobian_nonzeros(); }
std::size_t Transcription::hessian_nonzeros() const { return handle_->nlp->hessian_nonzeros(); }
DerivativeCounts Transcription::derivative_counts() const {
  return handle_->nlp->derivative_counts();
}

std::string describe_derivatives(bool programs, const DerivativeCounts& counts) {
  if (!programs) return "Jets (derivative_programs off)";
  return "programs: " + std::to_string(counts.traced) + " traced, " +
         (counts.on_jets == 0 ? std::string("none") : std::to_string(counts.on_jets)) +
         " kept on Jets";
}
void Transcription::set_guess(const Eigen::MatrixXd& u, const ElementEnds& ends,
                              const std::vector<double>& lengths) {
  handle_->nlp->set_guess(u, ends, lengths);
}
const Eigen::VectorXd& Transcription::solution() const { return handle_->nlp->solution(); }
void Transcription::set_solution(const Eigen::VectorXd& w) { handle_->nlp->set_solution(w); }
double Transcription::cost(const Eigen::VectorXd& w) const { return handle_->nlp->cost(w.data()); }
double Transcription::equilibration(const Eigen::VectorXd& w) const {
  return handle_->nlp->equilibration(w.data());
}
double Transcription::complementarity(const Eigen::VectorXd& w) const {
  return handle_->nlp->complementarity(w.data());
}
std::string Transcription::non_finite_at(const Eigen::VectorXd& w) const {
  return handle_->nlp->non_finite_at(w.data());
}
double Transcription::start_v(int k) const { return handle_->nlp->start_v(k); }
std::vector<double> Transcription::element_inputs(const Eigen::VectorXd& w, int e) const {
  std::vector<double> in;
  handle_->nlp->element_inputs(w.data(), e, in);
  return in;
}
Eigen::MatrixXd Transcription::element_jacobian(const Eigen::VectorXd& w, int e,
                                                Eigen::VectorXd* values) const {
  return handle_->nlp->element_jacobian(w.data(), e, values);
}

std::vector<int> Transcription::sides(const Eigen::VectorXd& w, int e, double tol) const {
  const TranscriptionLayout& l = layout();
  std::vector<double> vmax(static_cast<std::size_t>(l.npairs), 0.0);
  for (int k = 0; k < l.npairs; ++k) {
    const int v = l.dcs->pairs()[static_cast<std::size_t>(k)].v;
    for (int m = 0; m < l.points; ++m) {
      vmax[static_cast<std::size_t>(k)] =
          std::max(vmax[static_cast<std::size_t>(k)], w[l.z(e, m, v)]);
    }
  }
  return l.dcs->sides(vmax, tol);
}

HomotopyNlp& homotopy_nlp(Transcription& transcription) { return *transcription.handle_->nlp; }

}  // namespace fesd
}  // namespace bflow

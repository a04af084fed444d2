#include "bflow/ocp/ocp.h"

#include <time.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include <IpIpoptApplication.hpp>
#include <IpSolveStatistics.hpp>
#include <IpTNLP.hpp>

#include "bflow/core/errors.h"
#include "bflow/fesd/dcs.h"
#include "bflow/fesd/element.h"
#include "bflow/fesd/ipopt_options.h"

namespace bflow {

const char* to_string(OcpStatus status) {
  switch (status) {
    case OcpStatus::kSolved:
      return "solved";
    case OcpStatus::kComplementarityNotReached:
      return "complementarity_not_reached";
    case OcpStatus::kAcceptableOnly:
      return "acceptable_only";
    case OcpStatus::kNlpFailed:
      return "nlp_failed";
    case OcpStatus::kInfeasible:
      return "infeasible";
  }
  return "unknown";
}

namespace {

constexpr double kInfinity = 1e19;  // IPOPT's default nlp_upper_bound_inf

using fesd::ElementShape;
using fesd::PointDcs;

double cpu_now() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

// The OCP model seen as a step inclusion on [x; u] (u' = 0), so that one PointDcs serves.
class ControlsAsStates final : public StepModel {
 public:
  explicit ControlsAsStates(const OcpModel& model) : model_(model) {}
  int states() const override { return model_.states() + model_.controls(); }
  int switches() const override { return model_.switches(); }
  void switching(const double* y, double* c) const override { model_.switching(y, c); }
  void switching(const JetChunk* y, JetChunk* c) const override { model_.switching(y, c); }
  void switching(const HessianScalar* y, HessianScalar* c) const override {
    model_.switching(y, c);
  }
  void field(const double* y, const double* a, double* ydot) const override { eval(y, a, ydot); }
  void field(const JetChunk* y, const JetChunk* a, JetChunk* ydot) const override {
    eval(y, a, ydot);
  }
  void field(const HessianScalar* y, const HessianScalar* a, HessianScalar* ydot) const override {
    eval(y, a, ydot);
  }
  const SignMatrix* sign_matrix() const override { return model_.sign_matrix(); }
  int modes() const override { return model_.modes(); }
  void mode_fields(const double* y, double* f) const override { modes_of(y, f); }
  void mode_fields(const JetChunk* y, JetChunk* f) const override { modes_of(y, f); }
  void mode_fields(const HessianScalar* y, HessianScalar* f) const override { modes_of(y, f); }

 private:
  template <typename T>
  void eval(const T* y, const T* a, T* ydot) const {
    const int d = model_.states();
    model_.field(y, y + d, a, ydot);
    for (int k = 0; k < model_.controls(); ++k) ydot[d + k] = T(0.0);
  }
  // Each mode's rates of [x; u] (those of u are 0).
  template <typename T>
  void modes_of(const T* y, T* f) const {
    const int d = model_.states(), nu = model_.controls(), nf = model_.modes();
    thread_local std::vector<T> fx;
    fx.resize(static_cast<std::size_t>(nf * d));
    model_.mode_fields(y, y + d, fx.data());
    for (int i = 0; i < nf; ++i) {
      for (int k = 0; k < d; ++k) f[i * (d + nu) + k] = fx[static_cast<std::size_t>(i * d + k)];
      for (int k = 0; k < nu; ++k) f[i * (d + nu) + d + k] = T(0.0);
    }
  }
  const OcpModel& model_;
};

std::string number(double value) { return format_number(value); }

void check_vector(const Eigen::VectorXd& v, int size, const char* name, bool allow_empty = true) {
  if (v.size() == 0 && allow_empty) return;
  if (v.size() != size) {
    throw InvalidArgument(std::string("ocp: ") + name + " has " + std::to_string(v.size()) +
                          " entries, expected " + std::to_string(size));
  }
  for (Eigen::Index k = 0; k < v.size(); ++k) {
    if (std::isnan(v[k])) {
      throw InvalidArgument(std::string("ocp: ") + name + "[" + std::to_string(k) + "] is nan");
    }
  }
}

void check_bounds(const Eigen::VectorXd& lower, const Eigen::VectorXd& upper, int size,
                  const char* lower_name, const char* upper_name) {
  check_vector(lower, size, lower_name);
  check_vector(upper, size, upper_name);
  for (int k = 0; k < size && lower.size() > 0 && upper.size() > 0; ++k) {
    if (lower[k] > upper[k]) {
      throw InvalidArgument(std::string("ocp: ") + lower_name + "[" + std::to_string(k) +
                            "] = " + number(lower[k]) + " > " + upper_name + "[" +
                            std::to_string(k) + "] = " + number(upper[k]));
    }
  }
}

void check_input(const OcpModel& model, const OcpProblem& p, const OcpOptions& o) {
  const int d = model.states(), nu = model.controls();
  check_vector(p.x0, d, "x0", false);
  if (!p.x0.allFinite()) throw InvalidArgument("ocp: x0 is not finite");
  if (!(p.horizon > 0.0) || !std::isfinite(p.horizon)) {
    throw InvalidArgument("ocp: the horizon must be positive and finite, got " + number(p.horizon));
  }
  if (p.time_optimal && (!(p.T_min <= p.T_max) || !(p.T_max > 0.0) || std::isnan(p.T_min))) {
    throw InvalidArgument("ocp: T_min = " + number(p.T_min) + ", T_max = " + number(p.T_max) +
                          " is no interval of positive times");
  }
  check_bounds(p.x_lower, p.x_upper, d, "x_lower", "x_upper");
  if (p.clock_state < -1 || p.clock_state >= d) {
    throw InvalidArgument("ocp: clock_state = " + std::to_string(p.clock_state) +
                          " is no state index (0.." + std::to_string(d - 1) + ") and not -1");
  }
  if (p.clock_state >= 0 && p.time_optimal) {
    throw InvalidArgument("ocp: the stage-wise clock constraint (clock_state = " +
                          std::to_string(p.clock_state) + ") needs a fixed horizon");
  }
  check_bounds(p.u_lower, p.u_upper, nu, "u_lower", "u_upper");
  check_bounds(p.path_lower, p.path_upper, model.path_constraints(), "path_lower", "path_upper");
  check_bounds(p.terminal_lower, p.terminal_upper, model.terminal_constraints(), "terminal_lower",
               "terminal_upper");
  check_vector(p.track_Q, d, "track_Q");
  check_vector(p.track_R, nu, "track_R");
  check_vector(p.track_Q_terminal, d, "track_Q_terminal");
  check_vector(p.u_ref, nu, "u_ref");
  if ((p.track_Q.size() > 0 || p.track_Q_terminal.size() > 0) && !p.x_ref) {
    throw InvalidArgument("ocp: track_Q or track_Q_terminal is given without x_ref");
  }
  if (p.track_R.size() > 0 && p.u_ref.size() == 0) {
    throw InvalidArgument("ocp: track_R is given without u_ref");
  }
  if (p.time_optimal && (p.track_Q.size() > 0 || p.track_Q_terminal.size() > 0)) {
    throw InvalidArgument(
        "ocp: tracking a reference x_ref(t) needs a fixed horizon (time_optimal is set)");
  }
  check_vector(p.guess_x, d, "guess_x");
  if (p.guess_u.size() > 0 &&
      (p.guess_u.rows() != nu || (p.guess_u.cols() != 1 && p.guess_u.cols() != o.stages))) {
    throw InvalidArgument("ocp: guess_u is " + std::to_string(p.guess_u.rows()) + " x " +
                          std::to_string(p.guess_u.cols()) + ", expected " + std::to_string(nu) +
                          " x 1 or " + std::to_string(nu) + " x " + std::to_string(o.stages));
  }
  if (p.guess == OcpGuess::kReference && !p.guess_trajectory) {
    throw InvalidArgument("ocp: the reference guess needs guess_trajectory");
  }
  if (o.stages < 1 || o.elements < 1) {
    throw InvalidArgument("ocp: N = " + std::to_string(o.stages) + " control stages and N_FE = " +
                          std::to_string(o.elements) + " elements per stage; both must be >= 1");
  }
  if (o.collocation_stages < 1 || o.collocation_stages > 9) {
    throw InvalidArgument("ocp: n_s = " + std::to_string(o.collocation_stages) +
                          " collocation stages, expected 1..9");
  }
  if (!(o.sigma_final > 0.0) || !(o.sigma_initial >= o.sigma_final) ||
      !std::isfinite(o.sigma_initial)) {
    throw InvalidArgument("ocp: sigma_initial = " + number(o.sigma_initial) +
                          " and sigma_final = " + number(o.sigma_final) +
                          " must satisfy 0 < sigma_final <= sigma_initial < inf");
  }
  if (!(o.sigma_factor > 0.0 && o.sigma_factor < 1.0)) {
    throw InvalidArgument("ocp: sigma_factor = " + number(o.sigma_factor) + " must lie in (0, 1)");
  }
  if (!(o.complementarity_tolerance > 0.0) || !(o.nlp_tolerance > 0.0) ||
      !(o.equilibration_weight >= 0.0) || o.max_nlp_iterations < 1) {
    throw InvalidArgument(
        "ocp: complementarity_tolerance = " + number(o.complementarity_tolerance) +
        ", nlp_tolerance = " + number(o.nlp_tolerance) +
        ", equilibration_weight = " + number(o.equilibration_weight) +
        ", max_nlp_iterations = " + std::to_string(o.max_nlp_iterations) +
        ": tolerances must be positive, the weight >= 0, iterations >= 1");
  }
  if (!std::isfinite(o.exact_hessian_scale)) {
    throw InvalidArgument("ocp: exact_hessian_scale = " + number(o.exact_hessian_scale) +
                          " must be finite");
  }
}

// Lower or upper bound k of an optional bound vector.
double bound(const Eigen::VectorXd& v, int k, double fallback) {
  return v.size() == 0 ? fallback : std::clamp(v[k], -kInfinity, kInfinity);
}

// Where the unknowns of the whole OCP live:
//   [T | stage 0: u_0 (nu), N_FE element blocks | stage 1: ... ]
// An element's local vector (bflow/fesd/element.h) reads x_n and the pairs' v from the previous
// element (from x0 for the first), u of its stage and T.
struct OcpLayout : ElementShape {
  int stages = 0, per_stage = 0, elements = 0;
  OcpLayout(const PointDcs& point, int states, int switches, int controls,
            const ButcherTableau& tableau, int n, int n_fe)
      : ElementShape(point, states, switches, tableau, controls, true),
        stages(n),
        per_stage(n_fe),
        elements(n * n_fe) {}
  static constexpr int kT = 0;
  int stage_base(int k) const { return 1 + k * (nu + per_stage * block); }
  int u(int k, int j) const { return stage_base(k) + j; }
  int var(int e, int offset) const {
    return stage_base(e / per_stage) + nu + (e % per_stage) * block + offset;
  }
  int z(int e, int m, int k) const { return var(e, off_z + m * nz + k); }
  int x_end(int e, int i) const { return var(e, off_x + i); }
  int variables() const { return stage_base(stages); }
  int global(int e, int k) const {
    if (k < d) return e == 0 ? -1 : x_end(e - 1, k);
    if (k < d + npairs) {
      return e == 0 ? -1 : z(e - 1, points - 1, dcs->pairs()[static_cast<std::size_t>(k - d)].v);
    }
    if (k < d + npairs + nu) return u(e / per_stage, k - d - npairs);
    if (k == d + npairs + nu) return kT;
    return var(e, k - own());
  }
};

// The OCP as one IPOPT problem at relaxation sigma.
class OcpNlp final : public Ipopt::TNLP {
 public:
  // A function of a few unknowns that enters the objective.
  enum class TermKind { kLagrange, kMayer, kEquilibration };
  struct Term {
    TermKind kind;
    int stage;
    std::vector<int> globals;
    std::vector<double> constants;
  };

  OcpNlp(const OcpModel& model, const OcpProblem& problem, const OcpOptions& options,
         const ButcherTableau& tab, const OcpLayout& layout)
      : model_(model), p_(problem), o_(options), tab_(tab), l_(layout) {
    const int d = l_.d, nu = l_.nu;
    Eigen::VectorXd y0 = Eigen::VectorXd::Zero(d + nu);
    y0.head(d) = p_.x0;
    v_start_.resize(l_.npairs);
    l_.dcs->start(y0.data(), v_start_.data());  // (17)
    h0_ = 1.0 / l_.elements;
    // Element inputs.
    element_globals_.resize(static_cast<std::size_t>(l_.elements));
    for (int e = 0; e < l_.elements; ++e) {
      std::vector<int>& g = element_globals_[static_cast<std::size_t>(e)];
      for (int k = 0; k < l_.local; ++k) g.push_back(l_.global(e, k));
    }
    // Tracking references per stage (the middle of the stage).
    if (p_.x_ref) {
      for (int k = 0; k < l_.stages; ++k) {
        Eigen::VectorXd r = p_.x_ref((k + 0.5) * p_.horizon / l_.stages);
        check_vector(r, d, "x_ref(t)", false);
        x_ref_.push_back(r);
      }
      x_ref_end_ = p_.x_ref(p_.horizon);
      check_vector(x_ref_end_, d, "x_ref(T)", false);
    }
    tracking_ = p_.track_Q.size() > 0 || p_.track_R.size() > 0;
    // Objective terms.
    if (model_.has_lagrange() || tracking_) {
      for (int e = 0; e < l_.elements; ++e) {
        Term t{TermKind::kLagrange, e / l_.per_stage, {}, {}};
        t.globals.push_back(OcpLayout::kT);
        t.globals.push_back(l_.var(e, 0));
        for (int k = 0; k < l_.s * d; ++k) t.globals.push_back(l_.var(e, 1 + k));
        for (int j = 0; j < nu; ++j) t.globals.push_back(l_.u(t.stage, j));
        t.constants.assign(t.globals.size(), 0.0);
        terms_.push_back(std::move(t));
      }
    }
    if (model_.has_mayer() || p_.track_Q_terminal.size() > 0) {
      Term t{TermKind::kMayer, l_.stages - 1, {}, {}};
      for (int i = 0; i < d; ++i) t.globals.push_back(l_.x_end(l_.elements - 1, i));
      t.constants.assign(t.globals.size(), 0.0);
      terms_.push_back(std::move(t));
    }
    if (!o_.standard && o_.equilibration_weight > 0.0) {
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
        terms_.push_back(std::move(t));
      }
    }
    // Constraint rows.
    rows_elements_ = l_.elements * l_.rows_per_element();
    rows_sums_ = o_.standard ? 0 : l_.stages;
    npath_ = model_.path_constraints();
    nterm_ = model_.terminal_constraints();
    rows_path_ = (l_.elements + 1) * npath_;
    constraints_ = rows_elements_ + rows_sums_ + rows_path_ + nterm_;
    // Jacobian structure: each element row lists the inputs it reads (element_jacobian_pattern).
    jac_pattern_ = fesd::element_jacobian_pattern(l_);
    for (int e = 0; e < l_.elements; ++e) {
      const std::vector<int>& g = element_globals_[static_cast<std::size_t>(e)];
      for (int r = 0; r < l_.rows_per_element(); ++r) {
        for (int c : jac_pattern_[static_cast<std::size_t>(r)]) {
          const int col = g[static_cast<std::size_t>(c)];
          if (col < 0) continue;
          jac_rows_.push_back(e * l_.rows_per_element() + r);
          jac_cols_.push_back(col);
        }
      }
    }
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
      for (int i = 0; i < d; ++i) {
        jac_rows_.push_back(rows_elements_ + rows_sums_ + rows_path_ + r);
        jac_cols_.push_back(l_.x_end(l_.elements - 1, i));
      }
    }
    if (o_.exact_hessian) {
      pieces_ = fesd::element_hessian_pieces(l_);
      for (const std::vector<int>& g : element_globals_) {
        for (const std::vector<int>& piece : pieces_) {
          std::vector<int> globals;
          for (int k : piece) globals.push_back(g[static_cast<std::size_t>(k)]);
          hessian_.add_block(globals);
        }
      }
      for (const Term& t : terms_) hessian_.add_block(t.globals);
      for (int b = 0; b <= l_.elements && npath_ > 0; ++b) hessian_.add_block(path_globals(b));
      if (nterm_ > 0) hessian_.add_block(terminal_globals());
    }
  }

  int constraints() const { return constraints_ + static_cast<int>(equal_.size()); }

  // The active set read from w: which member of each complementarity pair is zero on every
  // element (a member is fixed at its zero value through its bounds), plus equal lengths of
  // neighbouring elements of a stage with the same sides. Solving the NLP with it (polish) gives
  // an exact FESD solution (every product zero) with the exact step equilibration, without the
  // relaxation and without the equilibration penalty in the objective.
  void enter_polish(const std::vector<std::vector<int>>& sides) {
    polish_ = true;
    fixed_.clear();
    equal_.clear();
    const Eigen::VectorXd& w = w_;
    const PointDcs& dcs = *l_.dcs;
    const int P = l_.points;
    std::vector<bool> u_fixed_prev(static_cast<std::size_t>(l_.npairs), false);
    for (int e = 0; e < l_.elements; ++e) {
      std::vector<bool> u_fixed(static_cast<std::size_t>(l_.npairs), false);
      for (int k = 0; k < l_.npairs; ++k) {
        const fesd::Pair& pair = dcs.pairs()[static_cast<std::size_t>(k)];
        if (o_.standard) {
          for (int m = 0; m < P; ++m) {
            const double um = PointDcs::member_u(pair, &w[l_.z(e, m, 0)]);
            const double vm = w[l_.z(e, m, pair.v)];
            if (um <= vm) {
              fixed_.push_back({l_.z(e, m, pair.u), PointDcs::u_zero(pair)});
            } else {
              fixed_.push_back({l_.z(e, m, pair.v), 0.0});
            }
          }
          continue;
        }
        double su = 0.0, sv = 0.0;
        for (int m = 0; m < P; ++m) {
          su += PointDcs::member_u(pair, &w[l_.z(e, m, 0)]);
          sv += w[l_.z(e, m, pair.v)];
        }
        const double v0 = e == 0 ? v_start_[k] : w[l_.z(e - 1, P - 1, pair.v)];
        const bool fix_u = su <= sv + v0 || (e == 0 && v0 > 0.0);
        if (fix_u) {
          u_fixed[static_cast<std::size_t>(k)] = true;
          for (int m = 0; m < P; ++m)
            fixed_.push_back({l_.z(e, m, pair.u), PointDcs::u_zero(pair)});
          // Leaving a sliding arc: the selection is continuous there.
          if (e > 0 && !u_fixed_prev[static_cast<std::size_t>(k)] &&
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
      if (!o_.standard && e % l_.per_stage != 0 &&
          sides[static_cast<std::size_t>(e)] == sides[static_cast<std::size_t>(e - 1)]) {
        equal_.push_back(e);
      }
    }
    for (const auto& [index, value] : fixed_) w_[index] = value;
    const int base = constraints_;
    polish_jac_.clear();
    for (std::size_t r = 0; r < equal_.size(); ++r) {
      polish_jac_.push_back({base + static_cast<int>(r), l_.var(equal_[r], 0)});
      polish_jac_.push_back({base + static_cast<int>(r), l_.var(equal_[r] - 1, 0)});
    }
  }
  void leave_polish() {
    polish_ = false;
    fixed_.clear();
    equal_.clear();
    polish_jac_.clear();
  }
  std::size_t jacobian_nonzeros() const { return jac_rows_.size(); }
  std::size_t hessian_nonzeros() const { return hessian_.size(); }
  void set_sigma(double sigma) { sigma_ = sigma; }
  void set_solution(const Eigen::VectorXd& w) { w_ = w; }
  const Eigen::VectorXd& solution() const { return w_; }
  void save() { saved_ = {w_, z_l_, z_u_, lambda_}; }
  void restore() {
    w_ = saved_[0];
    z_l_ = saved_[1];
    z_u_ = saved_[2];
    lambda_ = saved_[3];
  }
  Ipopt::SolverReturn last_status() const { return status_; }

  // Inputs of element e at w.
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

  // The OCP's own cost at w (T, Lagrange and Mayer; no equilibration or penalty).
  double cost(const double* w) const {
    double value = p_.time_optimal ? w[OcpLayout::kT] : 0.0;
    std::vector<double> in;
    for (const Term& t : terms_) {
      if (t.kind == TermKind::kEquilibration) continue;
      gather(t, w, in);
      value += term_value(t, in.data());
    }
    return value;
  }

  // Largest aggregated complementarity product at w.
  double complementarity(const double* w) const {
    double worst = 0.0;
    std::vector<double> in, out(static_cast<std::size_t>(l_.rows_per_element()));
    for (int e = 0; e < l_.elements; ++e) {
      element_inputs(w, e, in);
      fesd::element_residual(tab_, l_, o_.standard, in.data(), out.data());
      for (int r = l_.equalities; r < l_.rows_per_element(); ++r) {
        worst = std::max(worst, std::abs(out[static_cast<std::size_t>(r)]));
      }
    }
    return worst;
  }

  // The initial point (see OcpGuess).
  void initial_guess(const Eigen::MatrixXd& u_guess, const FesdResult* sim) {
    const int d = l_.d, nu = l_.nu;
    w_.setZero(l_.variables());
    w_[OcpLayout::kT] = p_.horizon;
    const double stage_length = p_.horizon / l_.stages;
    Eigen::VectorXd y(d + nu), z(l_.nz);
    for (int k = 0; k < l_.stages; ++k) {
      const Eigen::VectorXd uk = u_guess.col(u_guess.cols() == 1 ? 0 : k);
      for (int j = 0; j < nu; ++j) w_[l_.u(k, j)] = uk[j];
      for (int n = 0; n < l_.per_stage; ++n) {
        const int e = k * l_.per_stage + n;
        double h = h0_;
        Eigen::VectorXd xa, xb;
        if (sim != nullptr) {
          xa = sim->states.col(e);
          xb = sim->states.col(e + 1);
          h = sim->step_sizes[static_cast<std::size_t>(e)] / p_.horizon;
        } else if (p_.guess == OcpGuess::kReference) {
          const double ta = k * stage_length + n * stage_length / l_.per_stage;
          xa = p_.guess_trajectory(ta);
          xb = p_.guess_trajectory(ta + stage_length / l_.per_stage);
          check_vector(xa, d, "guess_trajectory(t)", false);
          check_vector(xb, d, "guess_trajectory(t)", false);
        } else {
          xa = xb = p_.guess_x.size() > 0 ? p_.guess_x : p_.x0;
        }
        w_[l_.var(e, 0)] = h;
        y.tail(nu) = uk;
        for (int m = 0; m < l_.points; ++m) {
          const double c = m < l_.s ? tab_.c(m) : 1.0;
          y.head(d) = (1.0 - c) * xa + c * xb;
          if (m < l_.s) w_.segment(l_.var(e, 1 + m * d), d) = y.head(d);
          l_.dcs->initial(y.data(), z.data());
          w_.segment(l_.z(e, m, 0), l_.nz) = z;
        }
        w_.segment(l_.var(e, l_.off_x), d) = xb;
      }
    }
  }

  // --- Ipopt::TNLP ---
  bool get_nlp_info(Ipopt::Index& n, Ipopt::Index& m, Ipopt::Index& nnz_jac, Ipopt::Index& nnz_hess,
                    IndexStyleEnum& style) override {
    n = l_.variables();
    m = constraints();
    nnz_jac = static_cast<Ipopt::Index>(jac_rows_.size() + polish_jac_.size());
    nnz_hess = static_cast<Ipopt::Index>(hessian_.size());
    style = C_STYLE;
    return true;
  }

  bool get_bounds_info(Ipopt::Index n, Ipopt::Number* x_l, Ipopt::Number* x_u, Ipopt::Index,
                       Ipopt::Number* g_l, Ipopt::Number* g_u) override {
    std::fill(x_l, x_l + n, -kInfinity);
    std::fill(x_u, x_u + n, kInfinity);
    if (p_.time_optimal) {
      x_l[OcpLayout::kT] = std::max(p_.T_min, 1e-9 * p_.horizon);
      x_u[OcpLayout::kT] = std::min(p_.T_max, kInfinity);
    } else {
      x_l[OcpLayout::kT] = x_u[OcpLayout::kT] = p_.horizon;
    }
    for (int k = 0; k < l_.stages; ++k) {
      for (int j = 0; j < l_.nu; ++j) {
        x_l[l_.u(k, j)] = bound(p_.u_lower, j, -kInfinity);
        x_u[l_.u(k, j)] = bound(p_.u_upper, j, kInfinity);
      }
    }
    for (int e = 0; e < l_.elements; ++e) {
      x_l[l_.var(e, 0)] = o_.standard ? h0_ : 0.0;
      x_u[l_.var(e, 0)] = o_.standard ? h0_ : 2.0 * h0_;
      for (int i = 0; i < l_.d; ++i) {
        x_l[l_.x_end(e, i)] = bound(p_.x_lower, i, -kInfinity);
        x_u[l_.x_end(e, i)] = bound(p_.x_upper, i, kInfinity);
      }
      if (p_.clock_state >= 0 && (e + 1) % l_.per_stage == 0) {
        const double clock = (e + 1) / l_.per_stage * p_.horizon / l_.stages;
        x_l[l_.x_end(e, p_.clock_state)] = x_u[l_.x_end(e, p_.clock_state)] = clock;
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
        g_u[row] = equality                                                  ? 0.0
                   : (o_.relaxation == OcpRelaxation::kScholtes && !polish_) ? sigma_
                                                                             : kInfinity;
      }
    }
    for (int k = 0; k < rows_sums_; ++k) {
      g_l[rows_elements_ + k] = g_u[rows_elements_ + k] = 1.0 / l_.stages;
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
    return true;
  }

  bool get_starting_point(Ipopt::Index n, bool init_x, Ipopt::Number* x, bool init_z,
                          Ipopt::Number* z_l, Ipopt::Number* z_u, Ipopt::Index m, bool init_lambda,
                          Ipopt::Number* lambda) override {
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

  bool eval_f(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Number& value) override {
    value = p_.time_optimal ? x[OcpLayout::kT] : 0.0;
    std::vector<double> in;
    for (const Term& t : terms_) {
      if (polish_ && t.kind == TermKind::kEquilibration) continue;
      gather(t, x, in);
      value += term_value(t, in.data());
    }
    if (penalty()) {
      std::vector<double> out(static_cast<std::size_t>(l_.rows_per_element()));
      for (int e = 0; e < l_.elements; ++e) {
        element_inputs(x, e, in);
        fesd::element_residual(tab_, l_, o_.standard, in.data(), out.data());
        for (int r = l_.equalities; r < l_.rows_per_element(); ++r) {
          value += out[static_cast<std::size_t>(r)] / sigma_;
        }
      }
    }
    return true;
  }

  bool eval_grad_f(Ipopt::Index n, const Ipopt::Number* x, bool, Ipopt::Number* grad) override {
    std::fill(grad, grad + n, 0.0);
    if (p_.time_optimal) grad[OcpLayout::kT] = 1.0;
    std::vector<double> in;
    for (const Term& t : terms_) {
      if (polish_ && t.kind == TermKind::kEquilibration) continue;
      gather(t, x, in);
      fesd::add_gradient(
          t.globals, in, 1.0, [&](const JetChunk* v) { return term_value(t, v); }, grad);
    }
    if (penalty()) {
      std::vector<JetChunk> out(static_cast<std::size_t>(l_.rows_per_element()));
      for (int e = 0; e < l_.elements; ++e) {
        element_inputs(x, e, in);
        fesd::add_gradient(
            element_globals_[static_cast<std::size_t>(e)], in, 1.0 / sigma_,
            [&](const JetChunk* v) {
              fesd::element_residual(tab_, l_, o_.standard, v, out.data());
              JetChunk sum(0.0);
              for (int r = l_.equalities; r < l_.rows_per_element(); ++r)
                sum += out[static_cast<std::size_t>(r)];
              return sum;
            },
            grad);
      }
    }
    return true;
  }

  bool eval_g(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Index, Ipopt::Number* g) override {
    std::vector<double> in;
    for (int e = 0; e < l_.elements; ++e) {
      element_inputs(x, e, in);
      fesd::element_residual(tab_, l_, o_.standard, in.data(), g + e * l_.rows_per_element());
    }
    for (int k = 0; k < rows_sums_; ++k) {
      double sum = 0.0;
      for (int n = 0; n < l_.per_stage; ++n) sum += x[l_.var(k * l_.per_stage + n, 0)];
      g[rows_elements_ + k] = sum;
    }
    for (int b = 0; b <= l_.elements && npath_ > 0; ++b) {
      path_inputs(x, b, in);
      model_.path(in.data(), in.data() + l_.d, g + rows_elements_ + rows_sums_ + b * npath_);
    }
    if (nterm_ > 0) {
      terminal_inputs(x, in);
      model_.terminal(in.data(), g + rows_elements_ + rows_sums_ + rows_path_);
    }
    for (std::size_t r = 0; r < equal_.size(); ++r) {
      g[constraints_ + static_cast<int>(r)] = x[l_.var(equal_[r], 0)] - x[l_.var(equal_[r] - 1, 0)];
    }
    return true;
  }

  bool eval_jac_g(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Index, Ipopt::Index nele,
                  Ipopt::Index* rows, Ipopt::Index* cols, Ipopt::Number* values) override {
    if (values == nullptr) {
      const Ipopt::Index own = static_cast<Ipopt::Index>(jac_rows_.size());
      for (Ipopt::Index k = 0; k < own; ++k) {
        rows[k] = jac_rows_[static_cast<std::size_t>(k)];
        cols[k] = jac_cols_[static_cast<std::size_t>(k)];
      }
      for (Ipopt::Index k = own; k < nele; ++k) {
        rows[k] = polish_jac_[static_cast<std::size_t>(k - own)].first;
        cols[k] = polish_jac_[static_cast<std::size_t>(k - own)].second;
      }
      return true;
    }
    Ipopt::Index k = 0;
    std::vector<double> base;
    const int rpe = l_.rows_per_element();
    Eigen::MatrixXd jac;
    for (int e = 0; e < l_.elements; ++e) {
      element_inputs(x, e, base);
      fesd::dense_jacobian(base, rpe, jac, [&](const JetChunk* in, JetChunk* out) {
        fesd::element_residual(tab_, l_, o_.standard, in, out);
      });
      const std::vector<int>& g = element_globals_[static_cast<std::size_t>(e)];
      for (int r = 0; r < rpe; ++r) {
        for (int c : jac_pattern_[static_cast<std::size_t>(r)]) {
          if (g[static_cast<std::size_t>(c)] >= 0) values[k++] = jac(r, c);
        }
      }
    }
    for (int s = 0; s < rows_sums_ * l_.per_stage; ++s) values[k++] = 1.0;
    for (int b = 0; b <= l_.elements && npath_ > 0; ++b) {
      path_inputs(x, b, base);
      fesd::dense_jacobian(base, npath_, jac, [&](const JetChunk* in, JetChunk* out) {
        model_.path(in, in + l_.d, out);
      });
      const std::vector<int> g = path_globals(b);
      for (int r = 0; r < npath_; ++r) {
        for (std::size_t c = 0; c < g.size(); ++c) {
          if (g[c] >= 0) values[k++] = jac(r, static_cast<Eigen::Index>(c));
        }
      }
    }
    if (nterm_ > 0) {
      terminal_inputs(x, base);
      fesd::dense_jacobian(base, nterm_, jac,
                           [&](const JetChunk* in, JetChunk* out) { model_.terminal(in, out); });
      for (int r = 0; r < nterm_; ++r) {
        for (int i = 0; i < l_.d; ++i) values[k++] = jac(r, i);
      }
    }
    for (std::size_t r = 0; r < equal_.size(); ++r) {
      values[k++] = 1.0;
      values[k++] = -1.0;
    }
    BFLOW_ASSERT(k == nele);
    return true;
  }

  bool eval_h(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Number obj_factor, Ipopt::Index,
              const Ipopt::Number* lambda, bool, Ipopt::Index nele, Ipopt::Index* rows,
              Ipopt::Index* cols, Ipopt::Number* values) override {
    if (values == nullptr) {
      for (Ipopt::Index k = 0; k < nele; ++k) {
        rows[k] = hessian_.rows()[static_cast<std::size_t>(k)];
        cols[k] = hessian_.cols()[static_cast<std::size_t>(k)];
      }
      return true;
    }
    std::fill(values, values + nele, 0.0);
    std::vector<double> base, weights(static_cast<std::size_t>(l_.rows_per_element()));
    for (int e = 0; e < l_.elements; ++e) {
      element_inputs(x, e, base);
      const double* lam = lambda + e * l_.rows_per_element();
      std::copy(lam, lam + l_.rows_per_element(), weights.begin());
      if (penalty()) {
        for (int r = l_.equalities; r < l_.rows_per_element(); ++r)
          weights[static_cast<std::size_t>(r)] += obj_factor / sigma_;
      }
      fesd::add_element_hessian(tab_, l_, o_.standard, pieces_,
                                element_globals_[static_cast<std::size_t>(e)], base, weights.data(),
                                hessian_, values);
    }
    for (const Term& t : terms_) {
      if (polish_ && t.kind == TermKind::kEquilibration) continue;
      gather(t, x, base);
      hessian_.add(
          t.globals, base, 1, &obj_factor,
          [&](const auto* in, auto* out) { out[0] = term_value(t, in); }, values);
    }
    for (int b = 0; b <= l_.elements && npath_ > 0; ++b) {
      path_inputs(x, b, base);
      hessian_.add(
          path_globals(b), base, npath_, lambda + rows_elements_ + rows_sums_ + b * npath_,
          [&](const auto* in, auto* out) { model_.path(in, in + l_.d, out); }, values);
    }
    if (nterm_ > 0) {
      terminal_inputs(x, base);
      hessian_.add(
          terminal_globals(), base, nterm_, lambda + rows_elements_ + rows_sums_ + rows_path_,
          [&](const auto* in, auto* out) { model_.terminal(in, out); }, values);
    }
    if (o_.exact_hessian_scale != 1.0) {
      for (Ipopt::Index k = 0; k < nele; ++k) values[k] *= o_.exact_hessian_scale;
    }
    return true;
  }

  void finalize_solution(Ipopt::SolverReturn status, Ipopt::Index n, const Ipopt::Number* x,
                         const Ipopt::Number* z_l, const Ipopt::Number* z_u, Ipopt::Index m,
                         const Ipopt::Number*, const Ipopt::Number* lambda, Ipopt::Number,
                         const Ipopt::IpoptData*, Ipopt::IpoptCalculatedQuantities*) override {
    status_ = status;
    w_ = Eigen::Map<const Eigen::VectorXd>(x, n);
    z_l_ = Eigen::Map<const Eigen::VectorXd>(z_l, n);
    z_u_ = Eigen::Map<const Eigen::VectorXd>(z_u, n);
    lambda_ = Eigen::Map<const Eigen::VectorXd>(lambda, m);
  }

 private:
  bool penalty() const { return o_.relaxation == OcpRelaxation::kL1Penalty && !polish_; }

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

  // The value of an objective term from its inputs.
  template <typename T>
  T term_value(const Term& t, const T* in) const {
    const int d = l_.d, nu = l_.nu;
    switch (t.kind) {
      case TermKind::kLagrange: {
        const T& horizon = in[0];
        const T& h = in[1];
        const T* stage = in + 2;
        const T* u = in + 2 + l_.s * d;
        T sum(0.0);
        for (int m = 0; m < l_.s; ++m) {
          T value = model_.lagrange(stage + m * d, u);
          if (p_.track_Q.size() > 0) {
            const Eigen::VectorXd& r = x_ref_[static_cast<std::size_t>(t.stage)];
            for (int i = 0; i < d; ++i) {
              const T e = stage[m * d + i] - r[i];
              value += p_.track_Q[i] * e * e;
            }
          }
          if (p_.track_R.size() > 0) {
            for (int j = 0; j < nu; ++j) {
              const T e = u[j] - p_.u_ref[j];
              value += p_.track_R[j] * e * e;
            }
          }
          sum += tab_.b(m) * value;
        }
        return horizon * h * sum;
      }
      case TermKind::kMayer: {
        T value = model_.mayer(in);
        for (Eigen::Index i = 0; i < p_.track_Q_terminal.size(); ++i) {
          const T e = in[i] - x_ref_end_[i];
          value += p_.track_Q_terminal[i] * e * e;
        }
        return value;
      }
      case TermKind::kEquilibration:
        return std::min(1.0, sigma_) * o_.equilibration_weight *
               fesd::equilibration_term(l_, h0_, in);
    }
    return T(0.0);
  }

  const OcpModel& model_;
  const OcpProblem& p_;
  const OcpOptions& o_;
  const ButcherTableau& tab_;
  const OcpLayout& l_;
  Eigen::VectorXd v_start_;
  double h0_ = 1.0;
  double sigma_ = 1.0;
  bool tracking_ = false;
  std::vector<Eigen::VectorXd> x_ref_;
  Eigen::VectorXd x_ref_end_;
  std::vector<std::vector<int>> element_globals_;
  std::vector<Term> terms_;
  int rows_elements_ = 0, rows_sums_ = 0, rows_path_ = 0, npath_ = 0, nterm_ = 0;
  int constraints_ = 0;
  std::vector<Ipopt::Index> jac_rows_, jac_cols_;
  fesd::HessianBlocks hessian_;
  std::vector<std::vector<int>> pieces_;       // an element's Hessian pieces (local indices)
  std::vector<std::vector<int>> jac_pattern_;  // per element row: the local inputs it reads
  bool polish_ = false;
  std::vector<std::pair<int, double>> fixed_;
  std::vector<int> equal_;
  std::vector<std::pair<int, int>> polish_jac_;
  Eigen::VectorXd w_, z_l_, z_u_, lambda_;
  std::array<Eigen::VectorXd, 4> saved_;
  Ipopt::SolverReturn status_ = Ipopt::SUCCESS;
};

const char* ipopt_status_name(Ipopt::ApplicationReturnStatus status) {
  switch (status) {
    case Ipopt::Solve_Succeeded:
      return "Solve_Succeeded";
    case Ipopt::Solved_To_Acceptable_Level:
      return "Solved_To_Acceptable_Level";
    case Ipopt::Infeasible_Problem_Detected:
      return "Infeasible_Problem_Detected";
    case Ipopt::Search_Direction_Becomes_Too_Small:
      return "Search_Direction_Becomes_Too_Small";
    case Ipopt::Diverging_Iterates:
      return "Diverging_Iterates";
    case Ipopt::User_Requested_Stop:
      return "User_Requested_Stop";
    case Ipopt::Feasible_Point_Found:
      return "Feasible_Point_Found";
    case Ipopt::Maximum_Iterations_Exceeded:
      return "Maximum_Iterations_Exceeded";
    case Ipopt::Restoration_Failed:
      return "Restoration_Failed";
    case Ipopt::Error_In_Step_Computation:
      return "Error_In_Step_Computation";
    case Ipopt::Maximum_CpuTime_Exceeded:
      return "Maximum_CpuTime_Exceeded";
    case Ipopt::Not_Enough_Degrees_Of_Freedom:
      return "Not_Enough_Degrees_Of_Freedom";
    case Ipopt::Invalid_Problem_Definition:
      return "Invalid_Problem_Definition";
    case Ipopt::Invalid_Option:
      return "Invalid_Option";
    case Ipopt::Invalid_Number_Detected:
      return "Invalid_Number_Detected";
    default:
      return "IPOPT_error";
  }
}

}  // namespace

HeldControlModel::HeldControlModel(const OcpModel& model, Eigen::VectorXd u)
    : model_(model), u_(std::move(u)) {
  if (u_.size() != model_.controls()) {
    throw InvalidArgument("HeldControlModel: u has " + std::to_string(u_.size()) +
                          " entries, the model " + std::to_string(model_.controls()) + " controls");
  }
}

namespace {
template <typename T>
void held_field(const OcpModel& model, const Eigen::VectorXd& u, const T* x, const T* a, T* xdot) {
  thread_local std::vector<T> uu;
  uu.resize(static_cast<std::size_t>(u.size()));
  for (Eigen::Index j = 0; j < u.size(); ++j) uu[static_cast<std::size_t>(j)] = T(u[j]);
  model.field(x, uu.data(), a, xdot);
}
}  // namespace

void HeldControlModel::field(const double* x, const double* a, double* xdot) const {
  held_field(model_, u_, x, a, xdot);
}
void HeldControlModel::field(const JetChunk* x, const JetChunk* a, JetChunk* xdot) const {
  held_field(model_, u_, x, a, xdot);
}
void HeldControlModel::field(const HessianScalar* x, const HessianScalar* a,
                             HessianScalar* xdot) const {
  held_field(model_, u_, x, a, xdot);
}
namespace {
template <typename T>
void held_modes(const OcpModel& model, const Eigen::VectorXd& u, const T* x, T* f) {
  thread_local std::vector<T> uu;
  uu.resize(static_cast<std::size_t>(u.size()));
  for (Eigen::Index k = 0; k < u.size(); ++k) uu[static_cast<std::size_t>(k)] = T(u[k]);
  model.mode_fields(x, uu.data(), f);
}
}  // namespace
void HeldControlModel::mode_fields(const double* x, double* f) const {
  held_modes(model_, u_, x, f);
}
void HeldControlModel::mode_fields(const JetChunk* x, JetChunk* f) const {
  held_modes(model_, u_, x, f);
}
void HeldControlModel::mode_fields(const HessianScalar* x, HessianScalar* f) const {
  held_modes(model_, u_, x, f);
}

FesdResult simulate_controls(const OcpModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                             double horizon, const Eigen::Ref<const Eigen::MatrixXd>& u,
                             FesdOptions options) {
  if (u.rows() != model.controls() || u.cols() < 1) {
    throw InvalidArgument("simulate_controls: u is " + std::to_string(u.rows()) + " x " +
                          std::to_string(u.cols()) + ", expected " +
                          std::to_string(model.controls()) + " x N with N >= 1");
  }
  if (!(horizon > 0.0) || !std::isfinite(horizon)) {
    throw InvalidArgument("simulate_controls: the horizon must be positive and finite, got " +
                          number(horizon));
  }
  options.sensitivities = false;
  const int n = static_cast<int>(u.cols());
  const double length = horizon / n;
  FesdResult all;
  all.grid.push_back(0.0);
  std::vector<Eigen::VectorXd> states{x0};
  Eigen::VectorXd x = x0;
  for (int k = 0; k < n; ++k) {
    const HeldControlModel held(model, u.col(k));
    FesdResult r = fesd_simulate(held, x, length, options);
    const double t0 = k * length;
    for (std::size_t i = 1; i < r.grid.size(); ++i) {
      all.grid.push_back(t0 + r.grid[i]);
      states.push_back(r.states.col(static_cast<Eigen::Index>(i)));
    }
    all.step_sizes.insert(all.step_sizes.end(), r.step_sizes.begin(), r.step_sizes.end());
    for (double t : r.switch_times) all.switch_times.push_back(t0 + t);
    // A switch at the stage boundary: the sides change from the previous stage's last element.
    if (!all.active_sets.empty() && !r.active_sets.empty() &&
        r.active_sets.front() != all.active_sets.back()) {
      all.switch_times.push_back(t0);
      std::sort(all.switch_times.begin(), all.switch_times.end());
    }
    all.active_sets.insert(all.active_sets.end(), r.active_sets.begin(), r.active_sets.end());
    all.max_complementarity = std::max(all.max_complementarity, r.max_complementarity);
    all.halved_steps += r.halved_steps;
    all.newton_steps += r.newton_steps;
    all.newton_switch_steps += r.newton_switch_steps;
    all.acceptable_only_steps += r.acceptable_only_steps;
    all.acceptable_only = all.acceptable_only || r.acceptable_only;
    all.nlp_iterations.insert(all.nlp_iterations.end(), r.nlp_iterations.begin(),
                              r.nlp_iterations.end());
    if (!r.message.empty()) {
      all.message += (all.message.empty() ? "" : "; ") + std::string("stage ") + std::to_string(k) +
                     ": " + r.message;
    }
    x = r.x_end;
    if (!r.ok()) {
      all.status = r.status;
      break;
    }
  }
  all.x_end = x;
  all.states.resize(x0.size(), static_cast<Eigen::Index>(states.size()));
  for (std::size_t i = 0; i < states.size(); ++i)
    all.states.col(static_cast<Eigen::Index>(i)) = states[i];
  return all;
}

std::string OcpProblemSize::excess() const {
  if (elements > kFesdMaxIndex) {
    return std::to_string(elements) + " finite elements, above IPOPT's limit of " +
           std::to_string(kFesdMaxIndex);
  }
  const std::pair<const char*, std::int64_t> counts[] = {{"NLP unknowns", unknowns},
                                                         {"constraints", constraints},
                                                         {"Jacobian nonzeros", jacobian_nonzeros},
                                                         {"Hessian nonzeros", hessian_nonzeros}};
  for (const auto& [what, count] : counts) {
    if (count > kFesdMaxIndex) {
      return std::to_string(count) + " " + what + ", above IPOPT's limit of " +
             std::to_string(kFesdMaxIndex);
    }
  }
  if (bytes > kFesdMaxMemoryBytes) {
    char text[32];
    std::snprintf(text, sizeof text, "%.2g", bytes);
    return std::to_string(unknowns) + " NLP unknowns, needing about " + text +
           " bytes, above the limit of 4 GiB = " +
           std::to_string(static_cast<std::int64_t>(kFesdMaxMemoryBytes)) + " bytes";
  }
  return "";
}

OcpProblemSize ocp_problem_size(const OcpModel& model, const OcpOptions& options) {
  OcpProblemSize size;
  size.elements = std::int64_t{options.stages} * options.elements;
  if (size.elements > kFesdMaxIndex || size.elements < 1) return size;
  FesdOptions f;
  f.scheme = options.scheme;
  f.stages = options.collocation_stages;
  f.elements = static_cast<int>(size.elements);
  f.standard = options.standard;
  f.formulation = options.formulation;
  f.lifting_depth = options.lifting_depth;
  f.exact_hessian = options.exact_hessian;
  f.newton = false;
  f.sensitivities = false;
  const HeldControlModel held(model, Eigen::VectorXd::Zero(model.controls()));
  const FesdProblemSize elements = fesd_problem_size(held, f);
  size.unknowns = elements.unknowns + std::int64_t{options.stages} * model.controls() + 1;
  size.constraints = elements.constraints;
  size.jacobian_nonzeros = elements.jacobian_nonzeros;
  size.hessian_nonzeros = elements.hessian_nonzeros;
  size.bytes = elements.step_bytes;
  return size;
}

OcpResult ocp_solve(const OcpModel& model, const OcpProblem& problem, const OcpOptions& options) {
  check_input(model, problem, options);
  const int d = model.states(), nu = model.controls();
  if (const std::string excess = ocp_problem_size(model, options).excess(); !excess.empty()) {
    throw InvalidArgument("ocp: N = " + std::to_string(options.stages) + " stages of N_FE = " +
                          std::to_string(options.elements) + " elements give " + excess);
  }
  const ControlsAsStates step_model(model);
  FesdOptions shape;
  shape.scheme = options.scheme;
  shape.stages = options.collocation_stages;
  shape.elements = options.elements;
  shape.formulation = options.formulation;
  shape.lifting_depth = options.lifting_depth;
  shape.newton = false;
  shape.sensitivities = false;

  const double cpu_start = cpu_now();
  const ButcherTableau tab = collocation_tableau(options.scheme, options.collocation_stages);
  const PointDcs dcs(step_model, options.formulation, options.lifting_depth);
  const OcpLayout l(dcs, d, model.switches(), nu, tab, options.stages, options.elements);
  OcpResult result;

  // Controls of the guess: given, or 0 clamped into the bounds.
  Eigen::MatrixXd u_guess = problem.guess_u;
  if (u_guess.size() == 0) {
    u_guess = Eigen::MatrixXd::Zero(nu, 1);
    for (int j = 0; j < nu; ++j) {
      u_guess(j, 0) = std::clamp(0.0, bound(problem.u_lower, j, -kInfinity),
                                 bound(problem.u_upper, j, kInfinity));
    }
  }
  Ipopt::SmartPtr<OcpNlp> nlp = new OcpNlp(model, problem, options, tab, l);
  FesdResult simulation;
  bool simulated = false;
  if (problem.guess == OcpGuess::kSimulation) {
    Eigen::MatrixXd per_stage(nu, options.stages);
    for (int k = 0; k < options.stages; ++k)
      per_stage.col(k) = u_guess.col(u_guess.cols() == 1 ? 0 : k);
    FesdOptions sim = shape;
    sim.steps = 1;
    sim.newton = true;
    simulation = simulate_controls(model, problem.x0, problem.horizon, per_stage, sim);
    simulated = simulation.ok() && static_cast<int>(simulation.step_sizes.size()) == l.elements;
    if (!simulated) {
      result.notes.push_back("the simulated guess " +
                             std::string(simulation.ok() ? "halved a step (its grid does not match)"
                                                         : "failed: " + simulation.message) +
                             "; the constant guess was used");
    }
  }
  nlp->initial_guess(u_guess, simulated ? &simulation : nullptr);
  result.unknowns = l.variables();
  result.constraints = nlp->constraints();
  result.jacobian_nonzeros = static_cast<int>(nlp->jacobian_nonzeros());
  result.hessian_nonzeros = static_cast<int>(nlp->hessian_nonzeros());

  Ipopt::SmartPtr<Ipopt::IpoptApplication> app = IpoptApplicationFactory();
  app->RethrowNonIpoptException(false);
  fesd::set_ipopt_defaults(*app, options.print_level, options.exact_hessian,
                           options.max_nlp_iterations);
  fesd::apply_ipopt_options(*app, options, "ocp");
  if (app->Initialize() != Ipopt::Solve_Succeeded) {
    throw InvalidArgument("ocp: IPOPT failed to initialise");
  }

  // One NLP at the options set on `app`: solved, recorded in result.homotopy and reported.
  const auto run_nlp = [&](double at_sigma, bool polish,
                           Ipopt::ApplicationReturnStatus& status) -> const OcpHomotopyStep& {
    const double nlp_start = cpu_now();
    status = app->OptimizeTNLP(nlp);
    OcpHomotopyStep step;
    step.index = static_cast<int>(result.homotopy.size());
    step.sigma = at_sigma;
    step.polish = polish;
    step.iterations = Ipopt::IsValid(app->Statistics()) ? app->Statistics()->IterationCount() : 0;
    step.cpu_seconds = cpu_now() - nlp_start;
    step.ipopt_status = ipopt_status_name(status);
    step.objective = nlp->cost(nlp->solution().data());
    step.complementarity = nlp->complementarity(nlp->solution().data());
    result.ipopt_iterations += step.iterations;
    result.homotopy.push_back(std::move(step));
    if (options.progress) options.progress(result.homotopy.back());
    return result.homotopy.back();
  };
  double sigma = options.sigma_initial, last_sigma = sigma;
  bool first = true, any_solved = false;
  int retries = 0;
  Ipopt::ApplicationReturnStatus last_status = Ipopt::Solve_Succeeded;
  while (true) {
    nlp->set_sigma(sigma);
    const bool final_nlp = sigma <= options.sigma_final;
    const double tol =
        final_nlp ? options.nlp_tolerance : std::max(options.nlp_tolerance, 1e-2 * sigma);
    app->Options()->SetNumericValue("tol", tol);
    app->Options()->SetNumericValue("acceptable_tol", std::max(1e-6, 1e3 * tol));
    // An acceptable point may violate the constraints by acceptable_constr_viol_tol (IPOPT's
    // default 1e-2): at small sigma that lets products far above sigma pass, and the homotopy
    // stalls (measured on the monoped: sigma = 1e-3 "solved" in 2 iterations with products of
    // 1e-2). The violation allowed follows sigma.
    app->Options()->SetNumericValue("acceptable_constr_viol_tol",
                                    std::min(1e-2, std::max(tol, 0.1 * sigma)));
    app->Options()->SetIntegerValue("acceptable_iter", 15);
    const bool warm = !first && options.warm_start;
    app->Options()->SetStringValue("warm_start_init_point", warm ? "yes" : "no");
    if (!first) {
      app->Options()->SetNumericValue("mu_init", std::max(1e-11, 1e-2 * sigma));
      app->Options()->SetNumericValue("warm_start_bound_push", 1e-9);
      app->Options()->SetNumericValue("warm_start_mult_bound_push", 1e-9);
      app->Options()->SetNumericValue("warm_start_slack_bound_push", 1e-9);
    } else {
      app->Options()->SetNumericValue("mu_init", 0.1);
    }
    fesd::apply_ipopt_options(*app, options, "ocp");
    Ipopt::ApplicationReturnStatus status;
    const OcpHomotopyStep step = run_nlp(sigma, false, status);
    const bool solved = status == Ipopt::Solve_Succeeded ||
                        status == Ipopt::Solved_To_Acceptable_Level ||
                        status == Ipopt::Feasible_Point_Found;
    if (!solved && any_solved && retries < 6) {
      // Too large a step in sigma: back to the last solution, half the step (in log sigma).
      ++retries;
      nlp->restore();
      sigma = std::sqrt(sigma * last_sigma);
      continue;
    }
    if (!solved) {
      result.status = status == Ipopt::Infeasible_Problem_Detected ? OcpStatus::kInfeasible
                                                                   : OcpStatus::kNlpFailed;
      result.message = "IPOPT returned " + std::string(step.ipopt_status) +
                       " at sigma = " + number(sigma) + " (complementarity residual " +
                       number(step.complementarity) + ")";
      if (any_solved) {
        nlp->restore();
        result.message += "; the result is the solution at sigma = " + number(last_sigma);
      }
      break;
    }
    any_solved = true;
    first = false;
    nlp->save();
    last_sigma = sigma;
    last_status = status;
    if (final_nlp) break;
    double next = options.sigma_factor * sigma;
    if (options.superlinear) next = std::min(next, std::pow(sigma, 1.5));
    // Round-off must not leave one more NLP just above sigma_final.
    if (next < options.sigma_final * (1.0 + 1e-9)) next = options.sigma_final;
    sigma = std::max(next, options.sigma_final);
  }

  const double active_tol = std::clamp(std::sqrt(options.sigma_final), 1e-9, 1e-4);
  const auto sides_of = [&](const Eigen::VectorXd& w, int e) {
    std::vector<double> vmax(static_cast<std::size_t>(l.npairs), 0.0);
    for (int k = 0; k < l.npairs; ++k) {
      const int v = dcs.pairs()[static_cast<std::size_t>(k)].v;
      for (int m = 0; m < l.points; ++m) {
        vmax[static_cast<std::size_t>(k)] =
            std::max(vmax[static_cast<std::size_t>(k)], w[l.z(e, m, v)]);
      }
    }
    return dcs.sides(vmax, active_tol);
  };
  const bool homotopy_done = any_solved && last_sigma <= options.sigma_final;
  bool polished = false;
  if (homotopy_done && options.polish) {
    // The active set of the last NLP, fixed: an exact FESD solution without relaxation.
    std::vector<std::vector<int>> sides;
    for (int e = 0; e < l.elements; ++e) sides.push_back(sides_of(nlp->solution(), e));
    const double before = nlp->cost(nlp->solution().data());
    nlp->enter_polish(sides);
    app->Options()->SetNumericValue("tol", options.nlp_tolerance);
    app->Options()->SetNumericValue("acceptable_tol", options.nlp_tolerance);
    app->Options()->SetStringValue("warm_start_init_point", "no");
    app->Options()->SetNumericValue("mu_init", 1e-9);
    app->Options()->SetNumericValue("bound_push", 1e-12);
    app->Options()->SetNumericValue("bound_frac", 1e-12);
    fesd::apply_ipopt_options(*app, options, "ocp");
    Ipopt::ApplicationReturnStatus status;
    const OcpHomotopyStep step = run_nlp(0.0, true, status);
    const double slack = 1e-6 * (1.0 + std::abs(before));
    // A polish with as many equations as free unknowns (every control pinned, e.g. by a clock
    // constraint) is a square system, which IPOPT reports as Feasible_Point_Found.
    if ((status == Ipopt::Solve_Succeeded || status == Ipopt::Feasible_Point_Found) &&
        step.complementarity <= options.complementarity_tolerance &&
        step.objective <= before + slack) {
      polished = true;
      result.notes.push_back("polished: the active set of sigma = " + number(last_sigma) +
                             " fixed, cost " + number(before) + " -> " + number(step.objective));
    } else {
      nlp->restore();
      result.notes.push_back(
          "the polish with the active set fixed was not kept (IPOPT " + step.ipopt_status +
          ", complementarity " + number(step.complementarity) + ", cost " + number(before) +
          " -> " + number(step.objective) +
          "); the result is the relaxed solution at sigma = " + number(last_sigma));
    }
    nlp->leave_polish();
    // The IPOPT defaults again for a later solve.
    app->Options()->SetNumericValue("bound_push", 1e-2);
    app->Options()->SetNumericValue("bound_frac", 1e-2);
  }
  result.polished = polished;

  // The result from the last solved NLP (or the last iterate when none was solved).
  const Eigen::VectorXd& w = nlp->solution();
  result.max_complementarity = nlp->complementarity(w.data());
  if (homotopy_done) {
    if (!polished && last_status == Ipopt::Solved_To_Acceptable_Level) {
      result.status = OcpStatus::kAcceptableOnly;
      result.message = "IPOPT solved the last NLP (sigma = " + number(last_sigma) +
                       ") only to its acceptable level";
    } else if (!(result.max_complementarity <= options.complementarity_tolerance)) {
      result.status = OcpStatus::kComplementarityNotReached;
      result.message = "the complementarity residual " + number(result.max_complementarity) +
                       " is above the tolerance " + number(options.complementarity_tolerance);
    } else {
      result.status = OcpStatus::kSolved;
    }
  }
  result.objective = nlp->cost(w.data());
  result.T = w[OcpLayout::kT];
  const int n_stages = options.stages;
  result.stage_times.resize(static_cast<std::size_t>(n_stages + 1));
  for (int k = 0; k <= n_stages; ++k)
    result.stage_times[static_cast<std::size_t>(k)] = k * result.T / n_stages;
  result.u.resize(nu, n_stages);
  for (int k = 0; k < n_stages; ++k) {
    for (int j = 0; j < nu; ++j) result.u(j, k) = w[l.u(k, j)];
  }
  result.x_stages.resize(d, n_stages + 1);
  result.x_stages.col(0) = problem.x0;
  result.x_grid.resize(d, l.elements + 1);
  result.x_grid.col(0) = problem.x0;
  result.grid.push_back(0.0);
  double t = 0.0;
  std::vector<int> previous;
  for (int e = 0; e < l.elements; ++e) {
    const double h = result.T * w[l.var(e, 0)];
    t += h;
    const bool stage_end = (e + 1) % l.per_stage == 0;
    result.grid.push_back(
        stage_end ? result.stage_times[static_cast<std::size_t>((e + 1) / l.per_stage)] : t);
    if (stage_end) t = result.grid.back();
    result.step_sizes.push_back(h);
    result.x_grid.col(e + 1) = w.segment(l.x_end(e, 0), d);
    if (stage_end) result.x_stages.col((e + 1) / l.per_stage) = w.segment(l.x_end(e, 0), d);
    std::vector<int> sides = sides_of(w, e);
    // An element of (numerically) zero length, which FESD allows at a switch, has no active
    // set of its own: the switch is counted once, from the neighbours' sides.
    const bool empty = h <= 1e-9 * result.T / l.elements;
    if (!empty) {
      if (!previous.empty() && sides != previous) {
        result.switch_times.push_back(result.grid[result.grid.size() - 2]);
      }
      previous = sides;
    }
    result.active_sets.push_back(std::move(sides));
  }
  result.cpu_seconds = cpu_now() - cpu_start;
  result.cpu_per_iteration =
      result.ipopt_iterations > 0 ? result.cpu_seconds / result.ipopt_iterations : 0.0;
  return result;
}

}  // namespace bflow

#include "bflow/ocp/ocp.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "bflow/core/errors.h"
#include "bflow/fesd/dcs.h"
#include "bflow/fesd/element.h"
#include "bflow/fesd/linear_solver.h"
#include "bflow/fesd/transcription.h"

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
    case OcpStatus::kBudgetExhausted:
      return "budget_exhausted";
    case OcpStatus::kCancelled:
      return "cancelled";
  }
  return "unknown";
}

namespace {

constexpr double kInfinity = 1e19;  // IPOPT's default nlp_upper_bound_inf

using fesd::ElementShape;
using fesd::PointDcs;

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

// What the entries of a vector may be: any number but NaN (bounds, where infinity means
// "unbounded"; its direction is checked by check_bounds), finite, or finite and >= 0 (weights).
enum class Entries { kNotNan, kFinite, kWeights };

void check_vector(const Eigen::VectorXd& v, int size, const char* name, bool allow_empty = true,
                  Entries entries = Entries::kFinite) {
  if (v.size() == 0 && allow_empty) return;
  if (v.size() != size) {
    throw InvalidArgument(std::string("ocp: ") + name + " has " + std::to_string(v.size()) +
                          " entries, expected " + std::to_string(size));
  }
  for (Eigen::Index k = 0; k < v.size(); ++k) {
    const bool bad = std::isnan(v[k]) || (entries != Entries::kNotNan && !std::isfinite(v[k])) ||
                     (entries == Entries::kWeights && v[k] < 0.0);
    if (bad) {
      throw InvalidArgument(std::string("ocp: ") + name + "[" + std::to_string(k) +
                            "] = " + number(v[k]) + " must be " +
                            (entries == Entries::kNotNan   ? "a number"
                             : entries == Entries::kFinite ? "finite"
                                                           : "finite and >= 0"));
    }
  }
}

void check_bounds(const Eigen::VectorXd& lower, const Eigen::VectorXd& upper, int size,
                  const char* lower_name, const char* upper_name) {
  check_vector(lower, size, lower_name, true, Entries::kNotNan);
  check_vector(upper, size, upper_name, true, Entries::kNotNan);
  for (Eigen::Index k = 0; k < lower.size(); ++k) {
    if (lower[k] == std::numeric_limits<double>::infinity()) {
      throw InvalidArgument(std::string("ocp: ") + lower_name + "[" + std::to_string(k) +
                            "] = inf: a lower bound may be -inf (unbounded), not +inf");
    }
  }
  for (Eigen::Index k = 0; k < upper.size(); ++k) {
    if (upper[k] == -std::numeric_limits<double>::infinity()) {
      throw InvalidArgument(std::string("ocp: ") + upper_name + "[" + std::to_string(k) +
                            "] = -inf: an upper bound may be inf (unbounded), not -inf");
    }
  }
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
  if (!(p.horizon > 0.0) || !std::isfinite(p.horizon)) {
    throw InvalidArgument("ocp: the horizon must be positive and finite, got " + number(p.horizon));
  }
  if (p.time_optimal &&
      (!(p.T_min <= p.T_max) || !(p.T_max > 0.0) || !std::isfinite(p.T_min) || !(p.T_min >= 0.0))) {
    throw InvalidArgument("ocp: T_min = " + number(p.T_min) + ", T_max = " + number(p.T_max) +
                          " is no interval of positive times (T_min finite and >= 0, T_max "
                          "above it, inf for none)");
  }
  if (!p.time_optimal && (p.T_min != 0.0 || p.T_max != std::numeric_limits<double>::infinity())) {
    throw InvalidArgument("ocp: T_min = " + number(p.T_min) + ", T_max = " + number(p.T_max) +
                          " bound a free horizon, but time_optimal is not set (the horizon " +
                          number(p.horizon) + " is fixed)");
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
  if (!(p.clock_tolerance >= 0.0) || !std::isfinite(p.clock_tolerance)) {
    throw InvalidArgument("ocp: clock_tolerance = " + number(p.clock_tolerance) +
                          " must be finite and >= 0");
  }
  if (p.clock_tolerance > 0.0 && p.clock_state < 0) {
    throw InvalidArgument("ocp: clock_tolerance = " + number(p.clock_tolerance) +
                          " is given without a clock_state");
  }
  check_bounds(p.u_lower, p.u_upper, nu, "u_lower", "u_upper");
  if (p.track_time_scale < -1 || p.track_time_scale >= nu) {
    throw InvalidArgument("ocp: track_time_scale = " + std::to_string(p.track_time_scale) +
                          " is no control index (0.." + std::to_string(nu - 1) + ") and not -1");
  }
  check_bounds(p.path_lower, p.path_upper, model.path_constraints(), "path_lower", "path_upper");
  check_bounds(p.terminal_lower, p.terminal_upper, model.terminal_constraints(), "terminal_lower",
               "terminal_upper");
  check_vector(p.track_Q, d, "track_Q", true, Entries::kWeights);
  check_vector(p.track_R, nu, "track_R", true, Entries::kWeights);
  check_vector(p.track_Q_terminal, d, "track_Q_terminal", true, Entries::kWeights);
  check_vector(p.u_ref, nu, "u_ref");
  const bool tracking =
      p.track_Q.size() > 0 || p.track_R.size() > 0 || p.track_Q_terminal.size() > 0;
  if (p.track_time_scale >= 0 && p.track_Q.size() == 0 && p.track_R.size() == 0) {
    throw InvalidArgument("ocp: track_time_scale = " + std::to_string(p.track_time_scale) +
                          " scales the stage tracking, but neither track_Q nor track_R is given");
  }
  if (o.tracking == OcpTracking::kStageEnds && !tracking) {
    throw InvalidArgument(
        "ocp: tracking at the stage ends is chosen, but no track_Q, track_R or track_Q_terminal "
        "is given");
  }
  if (p.x_bounds_at_stage_points && p.x_lower.size() == 0 && p.x_upper.size() == 0) {
    throw InvalidArgument(
        "ocp: x_bounds_at_stage_points is set, but there are no x bounds (x_lower, x_upper)");
  }
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
  for (Eigen::Index k = 0; k < p.guess_u.size(); ++k) {
    const double v = p.guess_u.data()[k];
    if (!std::isfinite(v)) {
      throw InvalidArgument("ocp: guess_u(" + std::to_string(k % std::max<Eigen::Index>(nu, 1)) +
                            ", " + std::to_string(k / std::max<Eigen::Index>(nu, 1)) +
                            ") = " + number(v) + " must be finite");
    }
  }
  if (p.guess == OcpGuess::kReference && !p.guess_trajectory) {
    throw InvalidArgument("ocp: the reference guess needs guess_trajectory");
  }
  if (p.guess != OcpGuess::kReference && p.guess_trajectory) {
    throw InvalidArgument(
        "ocp: guess_trajectory is given, but the guess is not the reference guess");
  }
  if (p.guess != OcpGuess::kSimulation && p.guess_policy) {
    throw InvalidArgument("ocp: guess_policy is given, but the guess is not the simulated guess");
  }
  if (o.stages < 1 || o.elements < 1) {
    throw InvalidArgument("ocp: N = " + std::to_string(o.stages) + " control stages and N_FE = " +
                          std::to_string(o.elements) + " elements per stage; both must be >= 1");
  }
  if (o.collocation_stages < 1 || o.collocation_stages > 9) {
    throw InvalidArgument("ocp: n_s = " + std::to_string(o.collocation_stages) +
                          " collocation stages, expected 1..9");
  }
  if (!(o.homotopy.sigma_final > 0.0) || !(o.homotopy.sigma_initial >= o.homotopy.sigma_final) ||
      !std::isfinite(o.homotopy.sigma_initial)) {
    throw InvalidArgument("ocp: sigma_initial = " + number(o.homotopy.sigma_initial) +
                          " and sigma_final = " + number(o.homotopy.sigma_final) +
                          " must satisfy 0 < sigma_final <= sigma_initial < inf");
  }
  if (!(o.homotopy.early_polish_sigma >= 0.0) || !std::isfinite(o.homotopy.early_polish_sigma)) {
    throw InvalidArgument("ocp: early_polish_sigma = " + number(o.homotopy.early_polish_sigma) +
                          " must be >= 0 and finite (0: only the final polish)");
  }
  if (!(o.homotopy.monotone_mu_down_to >= 0.0)) {
    throw InvalidArgument("ocp: monotone_mu_down_to = " + number(o.homotopy.monotone_mu_down_to) +
                          " must be >= 0 (infinity: the adaptive mu strategy for every NLP)");
  }
  if (!(o.homotopy.sigma_factor > 0.0 && o.homotopy.sigma_factor < 1.0)) {
    throw InvalidArgument("ocp: sigma_factor = " + number(o.homotopy.sigma_factor) +
                          " must lie in (0, 1)");
  }
  if (!(o.homotopy.complementarity_tolerance > 0.0) || !(o.homotopy.nlp_tolerance > 0.0) ||
      !(o.equilibration_weight >= 0.0) || o.homotopy.max_nlp_iterations < 1) {
    throw InvalidArgument(
        "ocp: complementarity_tolerance = " + number(o.homotopy.complementarity_tolerance) +
        ", nlp_tolerance = " + number(o.homotopy.nlp_tolerance) +
        ", equilibration_weight = " + number(o.equilibration_weight) +
        ", max_nlp_iterations = " + std::to_string(o.homotopy.max_nlp_iterations) +
        ": tolerances must be positive, the weight >= 0, iterations >= 1");
  }
  if (!(o.step_deviation_weight >= 0.0 && std::isfinite(o.step_deviation_weight)) ||
      !(o.homotopy.acceptable_tolerance >= 0.0 && std::isfinite(o.homotopy.acceptable_tolerance)) ||
      o.homotopy.acceptable_iterations < 0 || o.homotopy.max_total_iterations < 0 ||
      !(o.homotopy.later_mu_init >= 0.0 && std::isfinite(o.homotopy.later_mu_init)) ||
      !(o.homotopy.intermediate_tolerance_factor >= 0.0 &&
        std::isfinite(o.homotopy.intermediate_tolerance_factor))) {
    throw InvalidArgument(
        "ocp: step_deviation_weight = " + number(o.step_deviation_weight) +
        ", acceptable_tolerance = " + number(o.homotopy.acceptable_tolerance) +
        ", acceptable_iterations = " + std::to_string(o.homotopy.acceptable_iterations) +
        ", max_total_iterations = " + std::to_string(o.homotopy.max_total_iterations) +
        ", later_mu_init = " + number(o.homotopy.later_mu_init) +
        ", intermediate_tolerance_factor = " + number(o.homotopy.intermediate_tolerance_factor) +
        ": each must be finite and >= 0");
  }
  if (o.tracking == OcpTracking::kStageEnds && p.time_optimal && p.track_R.size() > 0) {
    throw InvalidArgument(
        "ocp: tracking at the stage ends weighs by the fixed stage length T / N (time_optimal "
        "is set)");
  }
  if (!std::isfinite(o.homotopy.sigma_final) ||
      !std::isfinite(o.homotopy.complementarity_tolerance) ||
      !std::isfinite(o.homotopy.nlp_tolerance) || !std::isfinite(o.equilibration_weight)) {
    throw InvalidArgument(
        "ocp: sigma_final = " + number(o.homotopy.sigma_final) +
        ", complementarity_tolerance = " + number(o.homotopy.complementarity_tolerance) +
        ", nlp_tolerance = " + number(o.homotopy.nlp_tolerance) +
        ", equilibration_weight = " + number(o.equilibration_weight) + ": each must be finite");
  }
  // Options that only act on FESD's free element lengths and cross complementarity.
  if (o.standard && o.cross_complementarity != CrossComplementarity::kElementSums) {
    throw InvalidArgument(
        std::string("ocp: cross complementarity ") + to_string(o.cross_complementarity) +
        " belongs to FESD, but standard time-stepping is asked for (one product per point and "
        "pair, no cross complementarity)");
  }
  if (o.standard && (o.equilibration_weight > 0.0 || o.step_deviation_weight > 0.0)) {
    throw InvalidArgument("ocp: equilibration_weight = " + number(o.equilibration_weight) +
                          ", step_deviation_weight = " + number(o.step_deviation_weight) +
                          " weigh the element lengths, which standard time-stepping fixes");
  }
  // Before the simulated guess: HomotopySolver checks it again, for every solver it builds.
  check_solver_options(o.solver, o.exact_hessian, "ocp");
}

// Lower or upper bound k of an optional bound vector.
double bound(const Eigen::VectorXd& v, int k, double fallback) {
  return v.size() == 0 ? fallback : std::clamp(v[k], -kInfinity, kInfinity);
}

using OcpLayout = fesd::TranscriptionLayout;

// The OCP's costs and constraints as seen by the transcription: the Lagrange term plus the
// tracking of x_ref and u_ref (by quadrature with x_ref at each stage's middle, or at the
// stage ends), the Mayer term plus the terminal tracking, the path and terminal constraints.
class OcpTerms final : public fesd::TranscriptionTerms {
 public:
  OcpTerms(const OcpModel& model, const OcpProblem& problem, int stages, OcpTracking tracking)
      : model_(model),
        p_(problem),
        at_ends_(tracking == OcpTracking::kStageEnds),
        stage_length_(problem.horizon / stages) {
    const int d = model_.states();
    if (p_.x_ref) {
      for (int k = 0; k < stages; ++k) {
        Eigen::VectorXd r = p_.x_ref((k + (at_ends_ ? 1.0 : 0.5)) * p_.horizon / stages);
        check_vector(
            r, d,
            ("x_ref(" + number((k + (at_ends_ ? 1.0 : 0.5)) * p_.horizon / stages) + ")").c_str(),
            false);
        x_ref_.push_back(r);
      }
      x_ref_end_ = p_.x_ref(p_.horizon);
      check_vector(x_ref_end_, d, "x_ref(T)", false);
    }
  }
  bool tracks() const { return p_.track_Q.size() > 0 || p_.track_R.size() > 0; }
  bool has_stage_cost() const override { return model_.has_lagrange() || (tracks() && !at_ends_); }
  bool has_stage_end_cost() const override { return tracks() && at_ends_; }
  bool has_terminal_cost() const override {
    return model_.has_mayer() || p_.track_Q_terminal.size() > 0;
  }
  int path_constraints() const override { return model_.path_constraints(); }
  int terminal_constraints() const override { return model_.terminal_constraints(); }

#define BFLOW_OCP_TERMS(T)                                                         \
  T stage_cost(int stage, const T* x, const T* u) const override {                 \
    return stage_value(stage, x, u);                                               \
  }                                                                                \
  T stage_end_cost(int stage, const T* x, const T* u) const override {             \
    return stage_length_ * tracking_value(stage, x, u);                            \
  }                                                                                \
  T terminal_cost(const T* x) const override { return terminal_value(x); }         \
  void path(const T* x, const T* u, T* g) const override { model_.path(x, u, g); } \
  void terminal(const T* x, T* r) const override { model_.terminal(x, r); }
  BFLOW_OCP_TERMS(double)
  BFLOW_OCP_TERMS(JetChunk)
  BFLOW_OCP_TERMS(HessianScalar)
#undef BFLOW_OCP_TERMS

 private:
  template <typename T>
  T stage_value(int stage, const T* x, const T* u) const {
    T value = model_.lagrange(x, u);
    if (!at_ends_) value += tracking_value(stage, x, u);
    return value;
  }
  template <typename T>
  T tracking_value(int stage, const T* x, const T* u) const {
    T value(0.0);
    if (p_.track_Q.size() > 0) {
      const Eigen::VectorXd& r = x_ref_[static_cast<std::size_t>(stage)];
      for (Eigen::Index i = 0; i < r.size(); ++i) {
        const T e = x[i] - r[i];
        value += p_.track_Q[i] * e * e;
      }
    }
    for (Eigen::Index j = 0; j < p_.track_R.size(); ++j) {
      const T e = u[j] - p_.u_ref[j];
      value += p_.track_R[j] * e * e;
    }
    if (p_.track_time_scale >= 0) value *= u[p_.track_time_scale];
    return value;
  }
  template <typename T>
  T terminal_value(const T* x) const {
    T value = model_.mayer(x);
    for (Eigen::Index i = 0; i < p_.track_Q_terminal.size(); ++i) {
      const T e = x[i] - x_ref_end_[i];
      value += p_.track_Q_terminal[i] * e * e;
    }
    return value;
  }

  const OcpModel& model_;
  const OcpProblem& p_;
  bool at_ends_ = false;
  double stage_length_ = 0.0;
  std::vector<Eigen::VectorXd> x_ref_;
  Eigen::VectorXd x_ref_end_;
};

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
  const Eigen::MatrixXd held = u;
  return simulate_policy(
      model, x0, horizon, static_cast<int>(u.cols()),
      [&held](int k, const Eigen::VectorXd&) { return Eigen::VectorXd(held.col(k)); }, options);
}

FesdResult simulate_policy(const OcpModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                           double horizon, int stages, const OcpPolicy& policy, FesdOptions options,
                           const Eigen::VectorXd& u_lower, const Eigen::VectorXd& u_upper,
                           Eigen::MatrixXd* controls, int* clamped) {
  const int nu = model.controls();
  if (stages < 1) {
    throw InvalidArgument("simulate_policy: the number of stages must be >= 1, got " +
                          std::to_string(stages));
  }
  if (!(horizon > 0.0) || !std::isfinite(horizon)) {
    throw InvalidArgument("simulate_policy: the horizon must be positive and finite, got " +
                          number(horizon));
  }
  if (!policy) throw InvalidArgument("simulate_policy: the policy is empty");
  for (const auto& [bounds, what] :
       {std::make_pair(&u_lower, "u_lower"), std::make_pair(&u_upper, "u_upper")}) {
    if (bounds->size() != 0 && bounds->size() != nu) {
      throw InvalidArgument("simulate_policy: " + std::string(what) + " has " +
                            std::to_string(bounds->size()) + " entries, expected " +
                            std::to_string(nu));
    }
  }
  for (int j = 0; j < nu; ++j) {
    const double lo = u_lower.size() > 0 ? u_lower[j] : -kInfinity;
    const double hi = u_upper.size() > 0 ? u_upper[j] : kInfinity;
    if (std::isnan(lo) || std::isnan(hi) || lo > hi) {
      throw InvalidArgument("simulate_policy: u_lower[" + std::to_string(j) + "] = " + number(lo) +
                            ", u_upper[" + std::to_string(j) + "] = " + number(hi) +
                            " is no interval");
    }
  }
  options.sensitivities = false;
  const double length = horizon / stages;
  FesdResult all;
  all.grid.push_back(0.0);
  std::vector<Eigen::VectorXd> states{x0};
  Eigen::VectorXd x = x0;
  if (controls != nullptr) controls->setZero(nu, stages);
  if (clamped != nullptr) *clamped = 0;
  for (int k = 0; k < stages; ++k) {
    Eigen::VectorXd uk = policy(k, x);
    if (uk.size() != nu || !uk.allFinite()) {
      throw InvalidArgument("simulate_policy: the policy gave " +
                            std::string(uk.size() != nu ? std::to_string(uk.size()) + " controls"
                                                        : "a value that is not finite") +
                            " at stage " + std::to_string(k) + ", expected " + std::to_string(nu) +
                            " finite controls");
    }
    bool clamp = false;
    for (int j = 0; j < nu; ++j) {
      const double v =
          std::clamp(uk[j], bound(u_lower, j, -kInfinity), bound(u_upper, j, kInfinity));
      clamp = clamp || v != uk[j];
      uk[j] = v;
    }
    if (clamp && clamped != nullptr) ++*clamped;
    if (controls != nullptr) controls->col(k) = uk;
    const HeldControlModel held(model, uk);
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
  const FesdProblemSize elements = fesd_problem_size(held, f, /*end_apart=*/false);
  // T, and the elastic slack.
  size.unknowns = elements.unknowns + std::int64_t{options.stages} * model.controls() + 1 +
                  (options.homotopy.relaxation == OcpRelaxation::kElastic ? 1 : 0);
  size.constraints = elements.constraints;
  size.jacobian_nonzeros = elements.jacobian_nonzeros;
  if (!options.standard && options.cross_complementarity == CrossComplementarity::kPointPairs) {
    // Every pair's P (P + 1) point products in place of its one aggregated row, two entries each.
    const std::int64_t extra =
        size.elements * elements.point_pairs * (elements.points * (elements.points + 1) - 1);
    size.constraints += extra;
    size.jacobian_nonzeros += 2 * extra;
  }
  if (!options.standard && options.cross_complementarity == CrossComplementarity::kPointSums) {
    // Every pair's P rows, each one u and the P + 1 v's, in place of its one aggregated row.
    const std::int64_t extra = size.elements * elements.point_pairs * (elements.points - 1);
    size.constraints += extra;
    size.jacobian_nonzeros += (elements.points + 2) * extra;
  }
  size.hessian_nonzeros = elements.hessian_nonzeros;
  size.bytes = elements.step_bytes;
  return size;
}

namespace {

// The transcription's problem data and the options that shape its rows and costs.
fesd::TranscriptionSetup transcription_setup(const OcpProblem& problem, const OcpOptions& options) {
  fesd::TranscriptionSetup setup;
  setup.x0 = problem.x0;
  setup.horizon = problem.horizon;
  setup.time_optimal = problem.time_optimal;
  setup.T_min = problem.T_min;
  setup.T_max = problem.T_max;
  setup.x_lower = problem.x_lower;
  setup.x_upper = problem.x_upper;
  setup.u_lower = problem.u_lower;
  setup.u_upper = problem.u_upper;
  setup.path_lower = problem.path_lower;
  setup.path_upper = problem.path_upper;
  setup.terminal_lower = problem.terminal_lower;
  setup.terminal_upper = problem.terminal_upper;
  setup.clock_state = problem.clock_state;
  setup.clock_tolerance = problem.clock_tolerance;
  setup.x_bounds_at_stage_points = problem.x_bounds_at_stage_points;
  setup.standard = options.standard;
  setup.relaxation =
      options.homotopy.relaxation == OcpRelaxation::kL1Penalty ? fesd::Relaxation::kL1Penalty
      : options.homotopy.relaxation == OcpRelaxation::kElastic ? fesd::Relaxation::kElastic
                                                               : fesd::Relaxation::kScholtes;
  setup.equilibration_weight = options.equilibration_weight;
  setup.equilibration_fades = true;
  setup.step_deviation_weight = options.step_deviation_weight;
  setup.algebraic_guess = options.algebraic_guess;
  setup.exact_hessian = options.exact_hessian;
  setup.exact_hessian_scale = options.solver.exact_hessian_scale;
  setup.derivative_programs = options.solver.derivative_programs;
  setup.probe_sparsity = options.probe_sparsity;
  return setup;
}

// The initial guess set on `nlp`: the controls given (or 0 clamped into the bounds) and the states
// of a simulation of them (OcpGuess::kSimulation, notes when it cannot serve), of the reference
// trajectory or constant. @throws InvalidArgument for a guess where the model is not finite.
void set_initial_guess(const OcpModel& model, const OcpProblem& problem, const OcpOptions& options,
                       const OcpLayout& l, fesd::Transcription& nlp, OcpResult& result) {
  const int d = model.states(), nu = model.controls();
  // Controls of the guess: given, or 0 clamped into the bounds.
  Eigen::MatrixXd u_guess = problem.guess_u;
  if (u_guess.size() == 0) {
    u_guess = Eigen::MatrixXd::Zero(nu, 1);
    for (int j = 0; j < nu; ++j) {
      u_guess(j, 0) = std::clamp(0.0, bound(problem.u_lower, j, -kInfinity),
                                 bound(problem.u_upper, j, kInfinity));
    }
  }
  FesdResult simulation;
  bool simulated = false;
  if (problem.guess == OcpGuess::kSimulation) {
    Eigen::MatrixXd per_stage(nu, options.stages);
    for (int k = 0; k < options.stages; ++k)
      per_stage.col(k) = u_guess.col(u_guess.cols() == 1 ? 0 : k);
    FesdOptions sim;
    sim.scheme = options.scheme;
    sim.stages = options.collocation_stages;
    sim.elements = options.elements;
    sim.formulation = options.formulation;
    sim.lifting_depth = options.lifting_depth;
    sim.sensitivities = false;
    sim.steps = 1;
    sim.newton = true;
    sim.solver = options.solver;
    sim.solver.print_level = 0;
    sim.solver.ipopt_string_options.clear();
    sim.solver.ipopt_numeric_options.clear();
    sim.solver.ipopt_integer_options.clear();
    sim.solver.exact_hessian_scale = 1.0;
    sim.cancelled = options.cancelled;
    if (problem.guess_policy) {
      int clamped = 0;
      simulation =
          simulate_policy(model, problem.x0, problem.horizon, options.stages, problem.guess_policy,
                          sim, problem.u_lower, problem.u_upper, &per_stage, &clamped);
      u_guess = per_stage;
      if (clamped > 0) {
        result.notes.push_back("the guess policy's controls were clamped into the bounds on " +
                               std::to_string(clamped) + " of " + std::to_string(options.stages) +
                               " stages");
      }
    } else {
      simulation = simulate_controls(model, problem.x0, problem.horizon, per_stage, sim);
    }
    simulated = simulation.ok() && static_cast<int>(simulation.step_sizes.size()) == l.elements;
    if (!simulated) {
      result.notes.push_back("the simulated guess " +
                             std::string(simulation.ok() ? "halved a step (its grid does not match)"
                                                         : "failed: " + simulation.message) +
                             "; the constant guess was used");
    }
  }
  // Each element's start and end states and the relative element lengths of the guess.
  fesd::Transcription::ElementEnds ends;
  std::vector<double> lengths;
  if (simulated) {
    ends = [&](int e) {
      return std::make_pair(Eigen::VectorXd(simulation.states.col(e)),
                            Eigen::VectorXd(simulation.states.col(e + 1)));
    };
    for (double h : simulation.step_sizes) lengths.push_back(h / problem.horizon);
  } else if (problem.guess == OcpGuess::kReference) {
    ends = [&](int e) {
      const double stage_length = problem.horizon / l.stages;
      const double ta =
          e / l.per_stage * stage_length + e % l.per_stage * stage_length / l.per_stage;
      Eigen::VectorXd xa = problem.guess_trajectory(ta);
      Eigen::VectorXd xb = problem.guess_trajectory(ta + stage_length / l.per_stage);
      check_vector(xa, d, "guess_trajectory(t)", false);
      check_vector(xb, d, "guess_trajectory(t)", false);
      return std::make_pair(std::move(xa), std::move(xb));
    };
  } else {
    const Eigen::VectorXd x = problem.guess_x.size() > 0 ? problem.guess_x : problem.x0;
    ends = [x](int) { return std::make_pair(x, x); };
  }
  nlp.set_guess(u_guess, ends, lengths);
  // IPOPT cannot start where the problem's functions are not finite (a guess whose model values
  // overflow, e.g. u = 1e308), and it does not say so: refused here, naming where.
  if (const std::string bad = nlp.non_finite_at(nlp.solution()); !bad.empty()) {
    const char* kind = simulated                               ? "simulated"
                       : problem.guess == OcpGuess::kReference ? "reference"
                                                               : "constant";
    throw InvalidArgument(std::string("ocp: at the initial guess (") + kind +
                          "; guess_x, guess_u, x0) " + bad +
                          ": the model cannot be evaluated there; give a guess where it is finite");
  }
}

// The homotopy's rules from OcpOptions::homotopy: the sigma schedule, the NLPs' tolerances and
// acceptable levels, the warm starts, the budget and the early polish.
fesd::HomotopyRules ocp_homotopy_rules(const OcpOptions& options) {
  fesd::HomotopyRules rules = fesd::homotopy_schedule(options);
  rules.warm_start = options.homotopy.warm_start;
  rules.warm_start_multipliers = options.homotopy.warm_start_multipliers;
  rules.first_from_zero_multipliers = options.homotopy.first_from_zero_multipliers;
  rules.max_total_iterations = options.homotopy.max_total_iterations;
  rules.continue_after_failure = options.homotopy.continue_after_failure;
  rules.mu_init_min = 1e-11;
  rules.acceptable_tol_min = 1e-6;
  rules.acceptable_tol_factor = 1e3;
  // An acceptable point may violate the constraints by acceptable_constr_viol_tol (IPOPT's
  // default 1e-2): at small sigma that lets products far above sigma pass, and the homotopy
  // stalls (measured on the monoped: sigma = 1e-3 "solved" in 2 iterations with products of
  // 1e-2). The violation allowed follows sigma.
  rules.acceptable_violation_min = 0.0;
  rules.acceptable_violation_sigma = 0.1;
  rules.acceptable_violation_max = 1e-2;
  rules.acceptable_compl_inf_tol = 1e-2;  // IPOPT's default
  rules.acceptable_iter = options.homotopy.acceptable_iterations;
  if (options.homotopy.acceptable_tolerance > 0.0) {
    // A fixed acceptable level, with IPOPT's default constraint violation for it.
    rules.acceptable_tol_min = options.homotopy.acceptable_tolerance;
    rules.acceptable_tol_factor = 0.0;
    rules.acceptable_violation_min = rules.acceptable_violation_max = 1e-2;
  }
  rules.later_mu_init = options.homotopy.later_mu_init;
  rules.monotone_mu_down_to = options.homotopy.monotone_mu_down_to;
  rules.intermediate_tolerance_factor = options.homotopy.intermediate_tolerance_factor;
  if (options.homotopy.stop_at_complementarity)
    rules.stop_complementarity = options.homotopy.complementarity_tolerance;
  if (options.homotopy.polish) rules.early_polish_sigma = options.homotopy.early_polish_sigma;
  return rules;
}

// The status and message of a homotopy that did not end (cancelled, out of budget, infeasible or
// failed).
void report_unfinished(const fesd::HomotopyOutcome& outcome, const OcpOptions& options,
                       OcpResult& result) {
  result.status = outcome.cancelled          ? OcpStatus::kCancelled
                  : outcome.budget_exhausted ? OcpStatus::kBudgetExhausted
                  : outcome.infeasible       ? OcpStatus::kInfeasible
                                             : OcpStatus::kNlpFailed;
  result.message =
      outcome.cancelled ? "cancelled (OcpOptions::cancelled) during the NLP at sigma = " +
                              number(outcome.failed_sigma)
      : outcome.budget_exhausted
          ? "the budget of " + std::to_string(options.homotopy.max_total_iterations) +
                " IPOPT iterations (max_total_iterations) ran out " +
                (outcome.budget_exhausted_before
                     ? "before the NLP at sigma = " + number(outcome.failed_sigma) +
                           ", the NLPs and early polishes before it having used it up"
                     : "in the NLP at sigma = " + number(outcome.failed_sigma)) +
                " (complementarity residual " + number(outcome.failed_complementarity) + ")"
          : "IPOPT returned " + outcome.failed_status +
                " at sigma = " + number(outcome.failed_sigma) + " (complementarity residual " +
                number(outcome.failed_complementarity) + ")";
  if (outcome.any_solved) {
    result.message += "; the result is the solution at sigma = " + number(outcome.last_sigma);
  } else if (outcome.cancelled) {
    result.message += "; no NLP was solved: the result is that NLP's last iterate";
  }
}

// The notes of what the homotopy decided: structures widened, NLPs handed on unsolved, an early
// stop, polishes tried and not kept, an early polish kept.
void report_homotopy_notes(const fesd::HomotopyOutcome& outcome, const OcpOptions& options,
                           OcpResult& result) {
  for (const fesd::HomotopyStep& step : outcome.steps) {
    if (!step.structure_widened) continue;
    result.notes.push_back("at sigma = " + number(step.sigma) +
                           " a derivative outside the probed sparsity was nonzero (the model "
                           "branches on values): every candidate entry was declared from there "
                           "on and that NLP solved again");
  }
  for (const double sigma : outcome.continued) {
    result.notes.push_back("the NLP at sigma = " + number(sigma) +
                           " was not solved; its last iterate started the next sigma");
  }
  if (outcome.stopped_early) {
    result.notes.push_back("the homotopy stopped at sigma = " + number(outcome.last_sigma) +
                           ": its complementarity residual is within the tolerance " +
                           number(options.homotopy.complementarity_tolerance));
  }
  for (const double sigma : outcome.polishes_not_kept) {
    result.notes.push_back("the polish with the active set of sigma = " + number(sigma) +
                           " was not kept; the homotopy went on");
  }
  if (outcome.polished_early) {
    result.notes.push_back("polished at sigma = " + number(outcome.last_sigma) +
                           ": the active set fixed there gave an exact solution within the "
                           "relaxation's reach, so the homotopy stopped (early_polish_sigma " +
                           number(options.homotopy.early_polish_sigma) + ")");
  }
}

// The final polish with the last NLP's active set fixed, and its note; whether it was kept.
bool final_polish(fesd::HomotopySolver& solver, fesd::Transcription& nlp,
                  const fesd::HomotopyOutcome& outcome, double active_tol,
                  const OcpOptions& options,
                  const std::function<void(const OcpHomotopyStep&)>& on_step, OcpResult& result) {
  // The active set of the last NLP, fixed: an exact FESD solution without relaxation.
  const fesd::PolishOutcome p = solver.polish(nlp, active_tol, options.homotopy.nlp_tolerance,
                                              options.homotopy.complementarity_tolerance,
                                              static_cast<int>(result.homotopy.size()), on_step);
  if (p.step.structure_widened) {
    result.notes.push_back(
        "in the polish a derivative outside the probed sparsity was nonzero (the model "
        "branches on values): every candidate entry was declared and the polish solved again");
  }
  if (p.kept) {
    result.notes.push_back("polished: the active set of sigma = " + number(outcome.last_sigma) +
                           " fixed, cost " + number(p.cost_before) + " -> " +
                           number(p.step.objective));
  } else {
    result.notes.push_back(
        "the polish with the active set fixed was not kept (IPOPT " + p.step.ipopt_status +
        ", complementarity " + number(p.step.complementarity) + ", cost " + number(p.cost_before) +
        " -> " + number(p.step.objective) +
        "); the result is the relaxed solution at sigma = " + number(outcome.last_sigma));
  }
  return p.kept;
}

// How IPOPT stopped on the last solved NLP (the polish when kept), and the result's status when
// the homotopy ended: solved, only to IPOPT's acceptable level, or short of the complementarity
// tolerance.
void report_status(const fesd::HomotopyOutcome& outcome, bool polished, const OcpOptions& options,
                   OcpResult& result) {
  const OcpHomotopyStep* last = nullptr;
  for (const OcpHomotopyStep& step : result.homotopy) {
    if (step.polish ? polished : step.sigma == outcome.last_sigma) last = &step;
  }
  if (outcome.polished_early && outcome.result_step >= 0 &&
      outcome.result_step < static_cast<int>(result.homotopy.size())) {
    last = &result.homotopy[static_cast<std::size_t>(outcome.result_step)];
  }
  if (last != nullptr) {
    result.ipopt_status = last->ipopt_status;
    result.kkt_error = last->kkt_error;
  }
  if (outcome.done) {
    // An acceptable stop still solves the NLP when its KKT error is within nlp_tolerance
    // (acceptable_tolerance <= nlp_tolerance, nosnoc's setup).
    if (!polished && outcome.acceptable_only &&
        !(result.kkt_error <= options.homotopy.nlp_tolerance)) {
      result.status = OcpStatus::kAcceptableOnly;
      result.message = "IPOPT solved the last NLP (sigma = " + number(outcome.last_sigma) +
                       ") only to its acceptable level (KKT error " + number(result.kkt_error) +
                       " above nlp_tolerance " + number(options.homotopy.nlp_tolerance) + ")";
    } else if (!(result.max_complementarity <= options.homotopy.complementarity_tolerance)) {
      result.status = OcpStatus::kComplementarityNotReached;
      result.message = "the complementarity residual " + number(result.max_complementarity) +
                       " is above the tolerance " +
                       number(options.homotopy.complementarity_tolerance);
    } else {
      result.status = OcpStatus::kSolved;
    }
  }
}

// The solution's trajectory from the NLP's point w: T, the stage times, controls and states, the
// element grid and lengths, the active sets (sides within active_tol) and the switch times.
void read_solution(const fesd::Transcription& nlp, const Eigen::VectorXd& w, const OcpLayout& l,
                   const OcpProblem& problem, const OcpOptions& options, double active_tol,
                   OcpResult& result) {
  const int d = l.d, nu = l.nu;
  result.objective = nlp.cost(w);
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
    std::vector<int> sides = nlp.sides(w, e, active_tol);
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
}

}  // namespace

OcpResult ocp_solve(const OcpModel& model, const OcpProblem& problem, const OcpOptions& options) {
  check_input(model, problem, options);
  const int d = model.states(), nu = model.controls();
  if (const std::string excess = ocp_problem_size(model, options).excess(); !excess.empty()) {
    throw InvalidArgument("ocp: N = " + std::to_string(options.stages) + " stages of N_FE = " +
                          std::to_string(options.elements) + " elements give " + excess);
  }
  const ControlsAsStates step_model(model);

  const double cpu_start = fesd::process_cpu_seconds();
  const ButcherTableau tab = collocation_tableau(options.scheme, options.collocation_stages);
  const PointDcs dcs(step_model, options.formulation, options.lifting_depth);
  OcpLayout layout(dcs, d, model.switches(), nu, tab, options.stages, options.elements,
                   /*time_scaled=*/true, /*end_apart=*/false, options.collocation_form);
  // Standard time-stepping has one product per point and pair, whatever the cross rows.
  if (!options.standard) layout.cross = options.cross_complementarity;
  const OcpLayout& l = layout;
  OcpResult result;

  const fesd::TranscriptionSetup setup = transcription_setup(problem, options);
  const OcpTerms terms(model, problem, options.stages, options.tracking);

  fesd::Transcription nlp(tab, l, setup, &terms);
  set_initial_guess(model, problem, options, l, nlp, result);
  // The elastic slack is IPOPT's last unknown.
  result.unknowns =
      l.variables() + (options.homotopy.relaxation == OcpRelaxation::kElastic ? 1 : 0);
  result.constraints = nlp.constraints();

  fesd::HomotopySolver solver(fesd::ipopt_settings(options, "ocp"));
  result.ipopt = ipopt_description();
  result.linear_solver =
      linear_solver_description(solver.linear_solver(), solver.linear_solver_library());
  result.blas = blas_description(options.solver.blas_threads);
  const fesd::HomotopyRules rules = ocp_homotopy_rules(options);
  const auto on_step = [&](const OcpHomotopyStep& step) {
    result.ipopt_iterations += step.iterations;
    result.homotopy.push_back(step);
    result.homotopy.back().index = static_cast<int>(result.homotopy.size()) - 1;
    if (options.progress) options.progress(result.homotopy.back());
  };
  const fesd::HomotopyOutcome outcome = solver.run(nlp, rules, on_step);
  if (!outcome.done) report_unfinished(outcome, options, result);
  report_homotopy_notes(outcome, options, result);
  // The active set is read at the last sigma (sigma_final unless the homotopy stopped earlier).
  const double active_tol = std::clamp(
      std::sqrt(outcome.done ? outcome.last_sigma : options.homotopy.sigma_final), 1e-9, 1e-4);
  bool polished = outcome.polished_early;
  if (outcome.done && options.homotopy.polish && !outcome.polished_early) {
    polished = final_polish(solver, nlp, outcome, active_tol, options, on_step, result);
  }
  result.polished = polished;

  // The result from the last solved NLP (or the last iterate when none was solved).
  const Eigen::VectorXd& w = nlp.solution();
  result.max_complementarity = nlp.complementarity(w);
  // The last solved NLP (the polish when kept): how IPOPT stopped and its KKT error.
  report_status(outcome, polished, options, result);
  read_solution(nlp, w, l, problem, options, active_tol, result);
  result.cpu_seconds = fesd::process_cpu_seconds() - cpu_start;
  // The structure the last NLP was given (probe_sparsity: widened after a miss).
  result.jacobian_nonzeros = static_cast<int>(nlp.jacobian_nonzeros());
  result.hessian_nonzeros = static_cast<int>(nlp.hessian_nonzeros());
  result.derivatives =
      fesd::describe_derivatives(options.solver.derivative_programs, nlp.derivative_counts());
  result.cpu_per_iteration =
      result.ipopt_iterations > 0 ? result.cpu_seconds / result.ipopt_iterations : 0.0;
  return result;
}

}  // namespace bflow

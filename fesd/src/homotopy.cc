// The sigma homotopy of transcription.h (HomotopySolver): the relaxed NLPs from sigma_initial
// down to sigma_final with their tolerances, warm starts and retries, the early and final
// polish with the active set fixed, the iteration budget and cancellation. It sees the
// transcription's NLP through HomotopyNlp (homotopy_nlp.h) and IPOPT through IpoptSession
// (ipopt_adapter.h).
#include <algorithm>
#include <cctype>
#include <cmath>
#include <functional>
#include <limits>
#include <string>
#include <tuple>
#include <vector>

#include "bflow/core/errors.h"
#include "bflow/fesd/linear_solver.h"
#include "bflow/fesd/transcription.h"
#include "homotopy_nlp.h"
#include "ipopt_adapter.h"

namespace bflow {
namespace fesd {

struct HomotopySolver::Impl {
  IpoptSettings settings;
  std::string linear_solver;  // the one in use: settings' or the caller's string option
  std::string library;        // the file IPOPT loads it from ("" when linked)
  IpoptSession session;

  // The caller's value of an option of IPOPT's (applied after bflow's), else `ours`; strings
  // in lower case, as IPOPT reads them.
  std::string caller_string(const std::string& name, const std::string& ours) const {
    std::string value = ours;
    for (const auto& [n, v] : settings.solver.ipopt_string_options) {
      if (n == name) value = v;
    }
    std::transform(value.begin(), value.end(), value.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return value;
  }
  double caller_numeric(const std::string& name, double ours) const {
    double value = ours;
    for (const auto& [n, v] : settings.solver.ipopt_numeric_options) {
      if (n == name) value = v;
    }
    return value;
  }

  void apply_caller_options() {
    session.apply(settings.solver.ipopt_string_options, settings.solver.ipopt_numeric_options,
                  settings.solver.ipopt_integer_options, settings.who);
  }

  // One NLP at the options set on the session. IPOPT and MUMPS run under the process's lock,
  // one NLP at a time (ipopt_mutex, linear_solver.h).
  HomotopyStep solve(HomotopyNlp& nlp, double sigma, bool polish, int index, NlpStatus& status) {
    apply_caller_options();
    const double start = process_cpu_seconds();
    nlp.set_cancel(settings.cancelled ? &settings.cancelled : nullptr);
    const ScopedMumpsAmalgamation fronts(settings.solver.mumps_amalgamation &&
                                         linear_solver == "mumps");
    const ScopedBlasThreads blas(settings.solver.blas_threads);
    if (settings.solver.keep_freed_memory) keep_freed_memory();
    nlp.keep_start();
    nlp.clear_missed();
    IpoptSession::Outcome run = session.optimize(nlp);
    status = run.status;
    int earlier_iterations = 0;
    bool widened = false;
    if (status != NlpStatus::kInvalidOption && status != NlpStatus::kUserStop &&
        nlp.structure_missed() && !nlp.full_structure()) {
      // An entry left out of the structure was not zero: the derivatives IPOPT used were
      // wrong, so the NLP again from its start with every candidate declared.
      earlier_iterations = run.iterations;
      widened = true;
      nlp.widen_structure();
      nlp.back_to_start();
      nlp.clear_missed();
      // The two solves share the NLP's max_iter (what is left of a budget, or the cap per NLP):
      // the second gets what the first left, so that the NLP never takes more than was given.
      int max_iter = 0;
      const bool capped = session.get_integer("max_iter", max_iter);
      if (capped) session.set_integer("max_iter", std::max(0, max_iter - earlier_iterations));
      run = session.optimize(nlp);
      status = run.status;
      if (capped) session.set_integer("max_iter", max_iter);
    }
    if (status == NlpStatus::kInvalidOption) {
      // Not an outcome of the NLP: no NLP of this solver can run.
      const std::string what = settings.who + ": IPOPT refused its options (Invalid_Option) " +
                               "with linear solver \"" + linear_solver +
                               "\"; print_level 5 shows IPOPT's reason";
      if (linear_solver != "mumps") throw LinearSolverUnavailable(what);
      throw InvalidArgument(what);
    }
    HomotopyStep step;
    step.index = index;
    step.sigma = sigma;
    step.polish = polish;
    step.iterations = earlier_iterations + run.iterations;
    step.structure_widened = widened;
    step.cpu_seconds = process_cpu_seconds() - start;
    step.ipopt_status = nlp_status_name(status);
    if (status != NlpStatus::kSolved && status != NlpStatus::kAcceptable)
      step.worst_rows = nlp.worst_rows(3);
    step.objective = nlp.cost(nlp.solution().data());
    step.complementarity = nlp.complementarity(nlp.solution().data());
    step.kkt_error = nlp.kkt_error();
    step.constraint_violation = nlp.constraint_violation();
    std::tie(step.product_multipliers, step.largest_product_multiplier) = nlp.product_multipliers();
    return step;
  }
};

HomotopySolver::HomotopySolver(const IpoptSettings& settings) : impl_(new Impl) {
  impl_->settings = settings;
  // Before IPOPT sees it: a solver missing from its library makes IPOPT return Invalid_Option
  // at the first NLP, or end the process (HSL_MA97).
  impl_->linear_solver = settings.solver.linear_solver;
  for (const auto& [name, value] : settings.solver.ipopt_string_options) {
    if (name == "linear_solver") impl_->linear_solver = value;
  }
  check_blas_threads(settings.solver.blas_threads, settings.who);
  impl_->library = check_linear_solver(impl_->linear_solver, settings.solver.linear_solver_library,
                                       settings.who);
  impl_->session.set_defaults(settings.solver.print_level, settings.exact_hessian,
                              settings.max_iterations, impl_->linear_solver, impl_->library);
  impl_->apply_caller_options();
  impl_->session.initialize(settings.who);
}
HomotopySolver::~HomotopySolver() = default;

HomotopyOutcome HomotopySolver::run(Transcription& transcription, const HomotopyRules& rules,
                                    const std::function<void(const HomotopyStep&)>& on_step) {
  HomotopyNlp& nlp = homotopy_nlp(transcription);
  IpoptSession& o = impl_->session;
  HomotopyOutcome out;
  double sigma = rules.sigma_initial, last_sigma = sigma;
  bool first = true, finishing = false;
  int retries = 0;
  double last_objective = std::numeric_limits<double>::quiet_NaN();
  std::vector<std::vector<int>> polished_sides;  // the active set of the last early polish
  while (true) {
    nlp.set_sigma(sigma);
    if (rules.max_total_iterations > 0) {
      const int left = rules.max_total_iterations - out.iterations;
      if (left <= 0) {
        out.budget_exhausted = true;
        out.budget_exhausted_before = true;
        out.failed_status =
            "no iterations left of the budget of " + std::to_string(rules.max_total_iterations);
        out.failed_sigma = sigma;
        out.failed_complementarity = nlp.complementarity(nlp.solution().data());
        // (After an NLP handed on unsolved, back to the last solved one.)
        if (out.any_solved) nlp.restore();
        return out;
      }
      o.set_integer("max_iter", std::min(impl_->settings.max_iterations, left));
    } else {
      o.set_integer("max_iter", impl_->settings.max_iterations);
    }
    const bool final_nlp = sigma <= rules.sigma_final || finishing;
    // Intermediate problems only need to be solved to the accuracy sigma allows.
    const double tol =
        final_nlp ? rules.nlp_tolerance
                  : std::max(rules.nlp_tolerance, rules.intermediate_tolerance_factor * sigma);
    o.set_numeric("tol", tol);
    o.set_numeric("acceptable_tol",
                  std::max(rules.acceptable_tol_min, rules.acceptable_tol_factor * tol));
    o.set_numeric("acceptable_constr_viol_tol",
                  std::min(rules.acceptable_violation_max,
                           std::max({tol, rules.acceptable_violation_min,
                                     rules.acceptable_violation_sigma * sigma})));
    o.set_numeric("acceptable_compl_inf_tol", rules.acceptable_compl_inf_tol);
    o.set_integer("acceptable_iter", rules.acceptable_iter);
    const bool zero_start = first && rules.first_from_zero_multipliers;
    // The warm start of a relaxed NLP keeps the previous products, about 1/sigma_factor times
    // the new sigma, with their multipliers, and the point 1e-9 off its bounds: the adaptive
    // strategy reads mu from that tiny complementarity (1e-11 at its first iteration on the
    // turbo car), and the iterates then creep off the new relaxation's bounds. The monotone
    // strategy starts at mu_init, the NLP's own tolerance (docs/ocp.md, Warm starts and
    // IPOPT's mu strategy). Not the re-solve at nlp_tolerance of a solved NLP (finishing), whose
    // tolerance is far below 1e-2 sigma. (sigma_initial times powers of the factor lands within
    // round-off of a round threshold.)
    const bool monotone = !first && !finishing && rules.warm_start &&
                          rules.warm_start_multipliers &&
                          sigma >= rules.monotone_mu_down_to * (1.0 - 1e-9);
    o.set_string("mu_strategy", monotone ? "monotone" : "adaptive");
    double mu_init = 0.1;
    o.set_string("warm_start_init_point",
                 (!first && rules.warm_start) || zero_start ? "yes" : "no");
    if (zero_start) {
      // nosnoc's start: IPOPT's warm start from the guess with every multiplier 0.
      o.set_numeric("mu_init", mu_init);
      o.set_numeric("warm_start_bound_push", 1e-3);
      o.set_numeric("warm_start_mult_bound_push", 1e-3);
      o.set_numeric("warm_start_slack_bound_push", 1e-3);
      nlp.forget_multipliers();
    } else if (!first) {
      mu_init = rules.later_mu_init > 0.0 ? rules.later_mu_init
                                          : std::max(rules.mu_init_min, 1e-2 * sigma);
      o.set_numeric("mu_init", mu_init);
      // With the multipliers the point stays at its bounds; without, IPOPT's pushes (1e-3).
      const double push = rules.warm_start_multipliers ? 1e-9 : 1e-3;
      o.set_numeric("warm_start_bound_push", push);
      o.set_numeric("warm_start_mult_bound_push", push);
      o.set_numeric("warm_start_slack_bound_push", push);
      if (rules.warm_start && !rules.warm_start_multipliers) nlp.forget_multipliers();
    } else {
      o.set_numeric("mu_init", mu_init);
    }
    NlpStatus status;
    HomotopyStep step = impl_->solve(nlp, sigma, false, static_cast<int>(out.steps.size()), status);
    step.mu_strategy = impl_->caller_string("mu_strategy", monotone ? "monotone" : "adaptive");
    step.mu_init = impl_->caller_numeric("mu_init", mu_init);
    out.iterations += step.iterations;
    out.steps.push_back(step);
    if (on_step) on_step(step);
    if (status == NlpStatus::kUserStop) {
      out.cancelled = true;
      out.failed_status = step.ipopt_status;
      out.failed_sigma = sigma;
      out.failed_complementarity = step.complementarity;
      if (out.any_solved) nlp.restore();
      return out;
    }
    // A square problem (every unknown pinned) is reported as Feasible_Point_Found.
    const bool solved = status == NlpStatus::kSolved || status == NlpStatus::kAcceptable ||
                        status == NlpStatus::kFeasiblePointFound;
    const bool out_of_budget =
        !solved && rules.max_total_iterations > 0 && out.iterations >= rules.max_total_iterations;
    const auto next_sigma = [&rules](double current) {
      double next = rules.sigma_factor * current;
      if (rules.superlinear) next = std::min(next, std::pow(current, 1.5));
      // Round-off must not leave one more NLP just above sigma_final.
      if (next < rules.sigma_final * (1.0 + 1e-9)) next = rules.sigma_final;
      return std::max(next, rules.sigma_final);
    };
    if (!solved && !out_of_budget && rules.continue_after_failure && !final_nlp && !finishing &&
        status != NlpStatus::kInvalidNumber) {
      // nosnoc's rule: the failed NLP's last iterate starts the next, smaller sigma.
      out.continued.push_back(sigma);
      first = false;
      sigma = next_sigma(sigma);
      continue;
    }
    // (A failed re-solve at nlp_tolerance is not retried: its sigma is the last solved one.)
    if (!solved && !out_of_budget && !rules.continue_after_failure && out.any_solved &&
        !finishing && retries < rules.max_retries) {
      // Too large a step in sigma: back to the last solution, half the step (in log sigma).
      ++retries;
      nlp.restore();
      sigma = std::sqrt(sigma * last_sigma);
      continue;
    }
    if (!solved) {
      out.infeasible = status == NlpStatus::kInfeasible;
      out.budget_exhausted = out_of_budget;
      out.failed_status = out_of_budget ? step.ipopt_status + " (the budget of " +
                                              std::to_string(rules.max_total_iterations) +
                                              " iterations used up)"
                                        : step.ipopt_status;
      out.failed_sigma = sigma;
      out.failed_complementarity = step.complementarity;
      if (out.any_solved) nlp.restore();
      return out;
    }
    out.any_solved = true;
    first = false;
    nlp.save();
    out.last_sigma = last_sigma = sigma;
    out.acceptable_only = status == NlpStatus::kAcceptable;
    const double cost_moved = std::abs(step.objective - last_objective);
    last_objective = step.objective;
    // (sigma_initial times powers of the factor lands within round-off of a round threshold.)
    if (rules.early_polish_sigma > 0.0 && sigma <= rules.early_polish_sigma * (1.0 + 1e-9) &&
        !final_nlp && !finishing) {
      // The active set the relaxation has settled on, fixed: when its exact solution is about
      // as good as the relaxed one, the smaller sigmas would only confirm it.
      const double active_tol = std::clamp(std::sqrt(sigma), 1e-9, 1e-4);
      std::vector<std::vector<int>> sides;
      for (int e = 0; e < nlp.layout().elements; ++e)
        sides.push_back(transcription.sides(nlp.solution(), e, active_tol));
      // An early polish is part of the homotopy: it gets what is left of the budget, if any.
      const int left = rules.max_total_iterations > 0 ? rules.max_total_iterations - out.iterations
                                                      : impl_->settings.max_iterations;
      if (sides != polished_sides && left > 0) {
        polished_sides = sides;
        const double slack = std::max(1e-6 * (1.0 + std::abs(step.objective)),
                                      std::isfinite(cost_moved) ? cost_moved : 0.0);
        // Only an exact FESD solution ends the homotopy early (every product zero): where the
        // active set read this far up is not consistent, the polish leaves small products, and
        // the smaller sigmas are still needed.
        const PolishOutcome p = polish(transcription, active_tol, rules.nlp_tolerance, 0.0,
                                       static_cast<int>(out.steps.size()), on_step, slack, left);
        out.iterations += p.step.iterations;
        out.steps.push_back(p.step);
        if (p.kept) {
          // Once more from the polished point, as the final polish starts from the solution at
          // sigma_final: a polish from a relaxed point this far up ends as exactly as IPOPT's
          // tolerance asks, one from an exact FESD solution as exactly as round-off allows.
          const double again_tol = std::clamp(std::sqrt(rules.sigma_final), 1e-9, 1e-4);
          const int still_left = rules.max_total_iterations > 0
                                     ? rules.max_total_iterations - out.iterations
                                     : impl_->settings.max_iterations;
          out.result_step = static_cast<int>(out.steps.size()) - 1;
          if (still_left > 0) {
            const PolishOutcome q =
                polish(transcription, again_tol, rules.nlp_tolerance, 0.0,
                       static_cast<int>(out.steps.size()), on_step, -1.0, still_left);
            out.iterations += q.step.iterations;
            out.steps.push_back(q.step);
            out.result_step = static_cast<int>(out.steps.size()) - (q.kept ? 1 : 2);
          }
          out.done = true;
          out.polished_early = true;
          out.acceptable_only = false;
          return out;
        }
        out.polishes_not_kept.push_back(sigma);
      }
    }
    const bool within =
        rules.stop_complementarity > 0.0 && step.complementarity <= rules.stop_complementarity;
    if (final_nlp || (within && tol <= rules.nlp_tolerance)) {
      out.done = true;
      out.stopped_early = sigma > rules.sigma_final;
      return out;
    }
    if (within) {
      // Solved only to the accuracy sigma allows: once more at nlp_tolerance.
      finishing = true;
      continue;
    }
    sigma = next_sigma(sigma);
  }
}

PolishOutcome HomotopySolver::polish(Transcription& transcription, double active_tol,
                                     double nlp_tolerance, double complementarity_tolerance,
                                     int index,
                                     const std::function<void(const HomotopyStep&)>& on_step,
                                     double cost_slack, int max_iterations) {
  HomotopyNlp& nlp = homotopy_nlp(transcription);
  const TranscriptionLayout& l = nlp.layout();
  IpoptSession& o = impl_->session;
  std::vector<std::vector<int>> sides;
  for (int e = 0; e < l.elements; ++e)
    sides.push_back(transcription.sides(nlp.solution(), e, active_tol));
  PolishOutcome out;
  out.cost_before = nlp.cost(nlp.solution().data());
  nlp.save();
  nlp.enter_polish(sides);
  o.set_numeric("tol", nlp_tolerance);
  o.set_numeric("acceptable_tol", nlp_tolerance);
  o.set_integer("max_iter", max_iterations > 0
                                ? std::min(max_iterations, impl_->settings.max_iterations)
                                : impl_->settings.max_iterations);
  o.set_string("warm_start_init_point", "no");
  o.set_string("mu_strategy", "adaptive");
  o.set_numeric("mu_init", 1e-9);
  o.set_numeric("bound_push", 1e-12);
  o.set_numeric("bound_frac", 1e-12);
  NlpStatus status;
  out.step = impl_->solve(nlp, 0.0, true, index, status);
  out.step.mu_init = impl_->caller_numeric("mu_init", 1e-9);
  out.step.mu_strategy = impl_->caller_string("mu_strategy", "adaptive");
  if (on_step) on_step(out.step);
  const double slack = cost_slack >= 0.0 ? cost_slack : 1e-6 * (1.0 + std::abs(out.cost_before));
  // A polish with as many equations as free unknowns (every control pinned, e.g. by a clock
  // constraint) is a square system, which IPOPT reports as Feasible_Point_Found.
  out.kept = (status == NlpStatus::kSolved || status == NlpStatus::kFeasiblePointFound) &&
             out.step.complementarity <= complementarity_tolerance &&
             out.step.objective <= out.cost_before + slack;
  if (!out.kept) nlp.restore();
  nlp.leave_polish();
  // The IPOPT defaults again for a later solve.
  o.set_numeric("bound_push", 1e-2);
  o.set_numeric("bound_frac", 1e-2);
  return out;
}

const std::string& HomotopySolver::linear_solver() const { return impl_->linear_solver; }
const std::string& HomotopySolver::linear_solver_library() const { return impl_->library; }

}  // namespace fesd
}  // namespace bflow

// What IPOPT's derivative checker (derivative_test = second-order, print_level >= 5) printed,
// judged by one stated criterion whichever IPOPT printed it.
//
// IPOPT's TNLPAdapter::CheckDerivatives evaluates everything at the NLP's starting point moved
// to a random point (fixed seed) of the box of radius point_perturbation_radius (default 10)
// around it, clipped to the variable bounds, so the point is generic: off every switching
// surface, no complementarity member at zero. The second-order part does not use IPOPT's
// multipliers: it compares the Hessian of the objective (obj_factor 1, every lambda 0) and then
// of each constraint i alone (obj_factor 0, lambda = e_i) with forward differences of the
// gradient and of row i of the Jacobian, entry by entry, and prints each entry as
//   "*             obj_hess[    3,    7] = exact v  ~ approx  [ rel]"
//   "*    12-th constr_hess[    3,    7] = exact v  ~ approx  [ rel]"
// (C-style indices; '*' where IPOPT's own criterion flags it). IPOPT 3.11 flags
// |approx - exact| / max(|approx|, 1) >= derivative_test_tol (1e-4); IPOPT 3.14.19 divides by
// max(|approx|, 1e-4) instead, which flags the forward difference's own truncation error
// (about |H| 1e-8) on entries of 1e-4 and below. The parser reads exact and approx from each
// line and flags an entry by the first criterion, kTolerance against max(|approx|, 1): an
// entry IPOPT 3.14 prints unflagged passes both, so the printed lines hold every entry this
// criterion flags. A Hessian scaled by 1 + 1e-3 is reported exactly at the entries of
// magnitude above about 0.1, so a negative control's flagged lines show which Hessians the
// check compared with nonzero entries.
#ifndef BFLOW_TESTS_SUPPORT_DERIVATIVE_CHECKER_H_
#define BFLOW_TESTS_SUPPORT_DERIVATIVE_CHECKER_H_

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <set>
#include <sstream>
#include <string>

#include <gtest/gtest.h>

namespace bflow::testing {

/** The relative error an entry is flagged at: |approx - exact| / max(|approx|, 1). */
inline constexpr double kTolerance = 1e-4;

struct CheckerOutput {
  bool second_order_started = false;  ///< "Starting derivative checker for second derivatives"
  bool no_errors = false;             ///< no entry flagged by kTolerance
  bool errors = false;                ///< some entry flagged by kTolerance
  int flagged_objective = 0;          ///< flagged obj_hess entries
  int flagged_constraint = 0;         ///< flagged constr_hess entries
  int flagged_first_order = 0;        ///< flagged grad_f or jac_g entries
  std::set<int> constraint_rows;      ///< constraints with a flagged constr_hess entry
  std::set<int> variables;            ///< unknowns in a flagged obj_hess or constr_hess entry
  /** The largest relative error printed for a second derivative: of the flagged entries, or of
      all entries with derivative_test_print_all = yes. */
  double worst_second_order = 0.0;
  std::string first_flagged;  ///< the first few flagged lines, for a failure message
};

inline CheckerOutput parse_checker_output(const std::string& text) {
  CheckerOutput out;
  out.second_order_started =
      text.find("Starting derivative checker for second derivatives") != std::string::npos;
  std::istringstream lines(text);
  std::string line;
  int flagged_entries = 0;
  while (std::getline(lines, line)) {
    if (line.size() < 2 || (line[0] != '*' && line[0] != ' ')) continue;
    // "... = exact [v]  ~ approx  [ rel]": the numbers after '=' and '~'.
    const auto equals = line.find("] = ");
    const auto tilde = line.find(" ~ ");
    if (equals == std::string::npos || tilde == std::string::npos) continue;
    const double exact = std::atof(line.c_str() + equals + 4);
    const double approx = std::atof(line.c_str() + tilde + 3);
    const double rel = std::abs(approx - exact) / std::max(std::abs(approx), 1.0);
    const bool flagged = rel >= kTolerance;
    if (flagged) ++flagged_entries;
    if (flagged && std::count(out.first_flagged.begin(), out.first_flagged.end(), '\n') < 12) {
      out.first_flagged += line + "\n";
    }
    const auto objective = line.find("obj_hess[");
    const auto constraint = line.find("-th constr_hess[");
    if (objective == std::string::npos && constraint == std::string::npos) {
      if (flagged && (line.find("grad_f[") != std::string::npos ||
                      line.find("jac_g [") != std::string::npos)) {
        ++out.flagged_first_order;
      }
      continue;
    }
    out.worst_second_order = std::max(out.worst_second_order, rel);
    if (!flagged) continue;
    const auto indices = line.find('[');
    int first = -1, second = -1;
    std::sscanf(line.c_str() + indices, "[%d,%d]", &first, &second);
    out.variables.insert(first);
    out.variables.insert(second);
    if (objective != std::string::npos) {
      ++out.flagged_objective;
    } else {
      ++out.flagged_constraint;
      out.constraint_rows.insert(std::atoi(line.substr(1, constraint - 1).c_str()));
    }
  }
  out.errors = flagged_entries > 0;
  out.no_errors = out.second_order_started && flagged_entries == 0;
  return out;
}

// The checker ran its second-order part and flagged nothing.
inline void expect_checker_passes(const CheckerOutput& out, const std::string& what) {
  EXPECT_TRUE(out.second_order_started) << what;
  EXPECT_TRUE(out.no_errors) << what;
  EXPECT_FALSE(out.errors) << what << ": " << out.flagged_objective << " obj_hess and "
                           << out.flagged_constraint << " constr_hess entries flagged, first:\n"
                           << out.first_flagged;
}

// A negative control (only the Hessian perturbed): errors reported, no first derivative flagged.
inline void expect_checker_reports(const CheckerOutput& out, const std::string& what) {
  EXPECT_TRUE(out.second_order_started) << what;
  EXPECT_TRUE(out.errors) << what;
  EXPECT_FALSE(out.no_errors) << what;
  EXPECT_EQ(out.flagged_first_order, 0) << what << ": only the Hessian was scaled\n"
                                        << out.first_flagged;
}

}  // namespace bflow::testing

#endif  // BFLOW_TESTS_SUPPORT_DERIVATIVE_CHECKER_H_

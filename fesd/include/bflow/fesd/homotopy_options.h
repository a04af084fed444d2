// The relaxation homotopy's schedule: the sigma of its NLPs and how far IPOPT solves each, the
// part FESD simulation (FesdOptions::homotopy) and optimal control (OcpOptions::homotopy, which
// adds its warm starts, acceptable levels and polish) share. The options of a run come in three
// groups, as nosnoc keeps problem and solver options apart: the discretisation and the problem
// (FesdOptions and OcpOptions themselves), the homotopy (this), and IPOPT with its linear solver
// (SolverOptions, solver_options.h).
#ifndef BFLOW_FESD_HOMOTOPY_OPTIONS_H_
#define BFLOW_FESD_HOMOTOPY_OPTIONS_H_

namespace bflow {

/** The defaults are FESD simulation's; OcpHomotopyOptions (ocp.h) sets its own. */
struct HomotopyOptions {
  double sigma_initial = 1.0;    ///< the first NLP's relaxation, > 0
  double sigma_final = 1e-12;    ///< the last NLP's, in (0, sigma_initial]
  double sigma_factor = 0.1;     ///< linear update sigma <- factor sigma, in (0, 1)
  bool superlinear = true;       ///< sigma <- min(factor sigma, sigma^1.5)
  double nlp_tolerance = 1e-13;  ///< IPOPT's tol for the last NLP
  int max_nlp_iterations = 500;  ///< IPOPT's max_iter for each NLP
};

}  // namespace bflow

#endif  // BFLOW_FESD_HOMOTOPY_OPTIONS_H_

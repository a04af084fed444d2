// What the sigma homotopy (homotopy.cc) asks of a transcription's NLP (transcription.cc): the
// NLP IPOPT solves (NlpProblem, ipopt_adapter.h) plus its relaxation, its saved points, its
// polish and its measures. Private to fesd/.
#ifndef BFLOW_FESD_SRC_HOMOTOPY_NLP_H_
#define BFLOW_FESD_SRC_HOMOTOPY_NLP_H_

#include <Eigen/Core>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "bflow/fesd/transcription.h"
#include "ipopt_adapter.h"

namespace bflow {
namespace fesd {

class HomotopyNlp : public NlpProblem {
 public:
  virtual const TranscriptionLayout& layout() const = 0;
  /** The relaxation's sigma of the NLPs solved from now on. */
  virtual void set_sigma(double sigma) = 0;
  virtual const Eigen::VectorXd& solution() const = 0;
  /** The caller's cost and the largest complementarity product at w. */
  virtual double cost(const double* w) const = 0;
  virtual double complementarity(const double* w) const = 0;
  /** IPOPT's KKT error and constraint violation at the end of the last NLP. */
  virtual double kkt_error() const = 0;
  virtual double constraint_violation() const = 0;
  /** The rows the current point violates most, named (at most `count`). */
  virtual std::string worst_rows(int count) = 0;
  /** The sum and the largest of the relaxed rows' multipliers (Scholtes), else zeros. */
  virtual std::pair<double, double> product_multipliers() const = 0;
  /** "" when every function and derivative is finite at w, else the first that is not. */
  virtual std::string non_finite_at(const double* w) = 0;

  /** The last solved point with its multipliers, kept (save) and gone back to (restore). */
  virtual void save() = 0;
  virtual void restore() = 0;
  /** The starting point of the NLP about to be solved, kept (keep_start) so that it can be
      solved again from there (back_to_start). */
  virtual void keep_start() = 0;
  virtual void back_to_start() = 0;
  /** Every multiplier 0: a warm start from the primal point only. */
  virtual void forget_multipliers() = 0;

  /** A derivative outside the declared structure was met since clear_missed(). */
  virtual bool structure_missed() const = 0;
  virtual void clear_missed() = 0;
  virtual bool full_structure() const = 0;
  /** Every candidate entry declared from now on. */
  virtual void widen_structure() = 0;

  /** The active set (each element's sides) fixed, until leave_polish(). */
  virtual void enter_polish(const std::vector<std::vector<int>>& sides) = 0;
  virtual void leave_polish() = 0;
  /** Polled after every IPOPT iteration: true stops the NLP. */
  virtual void set_cancel(const std::function<bool()>* cancelled) = 0;
};

/** The NLP of a transcription. */
HomotopyNlp& homotopy_nlp(Transcription& transcription);

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_SRC_HOMOTOPY_NLP_H_

// HessianProgram: the second derivatives of a block function (a piece of an element, a cost, a
// constraint) as a short program of scalar operations, derived once from a traced evaluation of
// the same templated code and run at every later point.
//
// HessianJet (hessian_jet.h) carries every pair of its lanes through every operation: a product
// costs O(n^2) whatever the operands, and the entries that are identically zero (the second
// derivatives of a field that is linear in most of its inputs) are computed as zeros each time.
// A program is what the function's Hessian is symbolically: the evaluation is traced once
// (HessianJet values with a tape, hessian_jet.h), its expression graph is differentiated twice
// (forward over forward, with constant folding and common subexpressions merged), and what is
// left is the list of operations that compute the weighted Lagrangian's nonzero second
// derivatives, its gradient and value. The multipliers, the length factor and every input are
// the program's inputs, so one program serves every later evaluation of its block.
//
// What makes it exact where HessianJet is: the derivative rules are HessianJet's functions' own
// (the same first and second derivatives, in another order of operations: results agree to
// rounding), and a branch the traced evaluation took (a comparison, abs, fmax, floor, ...) is
// a guard the program checks at every run; a run whose guard fails reports it, and the caller
// traces again at that point (HessianBlocks does). A program is checked against HessianJet at
// the point it was traced (HessianBlocks: entries apart by more than 1e-8 of their scale keep
// the block on HessianJet), so that an operation the tape does not see (a model reading a
// value's .a and computing with doubles) costs speed, never exactness.
#ifndef BFLOW_FESD_HESSIAN_TAPE_H_
#define BFLOW_FESD_HESSIAN_TAPE_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include "bflow/fesd/hessian_jet.h"

namespace bflow {
namespace fesd {

/** Whether a program's numbers a[0..count) are those of the evaluation it replaces, b: apart by
    at most 1e-8 of their scale (the largest finite magnitude, at least 1), infinities equal,
    NaN only with NaN. A dropped dependence or a number kept from another point is off by
    the size of a derivative; rounding, by about 1e-16 of it. */
inline bool programs_agree(const double* a, const double* b, int count) {
  double scale = 1.0;
  for (int k = 0; k < count; ++k) {
    if (std::isfinite(a[k])) scale = std::max(scale, std::abs(a[k]));
    if (std::isfinite(b[k])) scale = std::max(scale, std::abs(b[k]));
  }
  for (int k = 0; k < count; ++k) {
    if (std::isnan(a[k]) || std::isnan(b[k])) {
      if (std::isnan(a[k]) != std::isnan(b[k])) return false;
      continue;
    }
    if (std::isinf(a[k]) || std::isinf(b[k])) {
      if (a[k] != b[k]) return false;
      continue;
    }
    if (std::abs(a[k] - b[k]) > 1e-8 * scale) return false;
  }
  return true;
}

class HessianProgram {
 public:
  /** What the program computes, for inputs in[0..inputs) and lanes on in[lanes[i]]:
      S = sum_{r < scaled} w_r f_r, Q = sum_{r >= scaled} w_r f_r and L = P S + Q with P an
      input (the product of add_scaled's factors): the lower triangle of d2 L / d lane_i
      d lane_j (by rows, HessianJet::at), dS / d lane_i (with `gradient`) and S. */
  struct Shape {
    int inputs = 0;
    std::vector<int> lanes;
    int outputs = 0;
    int scaled = 0;
    bool gradient = false;
  };

  /** Traces eval(in, out) (HessianJet in, HessianJet out) at `base` and derives the program.
      eval must be a function of `in` alone: any other number it reads is kept as a constant. */
  template <typename Eval>
  static std::unique_ptr<HessianProgram> trace(const Shape& shape, const double* base, Eval& eval);

  enum class Outcome {
    kDone,
    kGuardFailed,  ///< the evaluation branches otherwise here than where it was traced
    kNotFinite,    ///< a result is infinite or NaN
  };
  /** Runs the program at inputs `in`, weights `w` (the outputs'), factor product `product`:
      hessian[at(i, j)] for j <= i < lanes, gradient[i] (with Shape::gradient) and the value
      S. The results are written, and to be used, only with kDone. */
  Outcome run(const double* in, const double* w, double product, double* hessian, double* gradient,
              double* value);

  const Shape& shape() const { return shape_; }
  /** Operations a run executes (constants and inputs not counted) and guards it checks. */
  std::size_t operations() const { return code_.size(); }
  std::size_t guards() const { return guards_.size(); }

  // The recorder of a trace (HessianTape, hessian_jet.h); holds the expression graph.
  class Graph;
  // A program's operation: register dst = op(register x[, register y]) (c: kPowC's exponent,
  // kCPow's base), and a guard: test(register x[, register y]) must be `outcome`.
  struct Instruction {
    HessianTape::Op op;
    std::int32_t dst, x, y;
    double c;
  };
  struct Guard {
    HessianTape::Test test;
    std::int32_t x, y;
    bool outcome;
  };

 private:
  friend class JacobianProgram;
  static std::unique_ptr<HessianProgram> derive(Graph& graph, const Shape& shape,
                                                const std::vector<int>& outputs);
  // Runs `code` on the registers r and checks `guards`: false when one fails.
  static bool execute(const std::vector<Instruction>& code, const std::vector<Guard>& guards,
                      double* r);

  Shape shape_;
  std::vector<Instruction> code_;
  std::vector<Guard> guards_;
  std::vector<double> registers_;  // constants preset; inputs and results written by run
  std::vector<std::int32_t> input_registers_;   // in[k] -> register (-1: not read)
  std::vector<std::int32_t> weight_registers_;  // w[r] -> register (-1: not read)
  std::int32_t product_register_ = -1;
  std::vector<std::int32_t> hessian_registers_, gradient_registers_;
  std::int32_t value_register_ = -1;
};

// First derivatives the same way: entries (row r, input c) of the Jacobian of eval(in, out) at
// any point, from one trace (element_residual's rows of an element: Transcription's
// jacobian_values), each entry that is identically zero or constant costing nothing per run.
class JacobianProgram {
 public:
  /** Traces eval at `base` (inputs in[0..inputs), outputs out[0..outputs)) for the entries
      d out[entries[k].first] / d in[entries[k].second]. eval must read its inputs alone. */
  template <typename Eval>
  static std::unique_ptr<JacobianProgram> trace(int inputs, int outputs,
                                                const std::vector<std::pair<int, int>>& entries,
                                                const double* base, Eval& eval);
  /** values[k] = entry k at `in`; kDone, kGuardFailed (to be traced again here) or kNotFinite
      (values written, one of them infinite or NaN). */
  HessianProgram::Outcome run(const double* in, double* values);
  std::size_t operations() const { return code_.size(); }
  std::size_t entries() const { return value_registers_.size(); }

 private:
  friend class HessianProgram;
  using Instruction = HessianProgram::Instruction;
  using Guard = HessianProgram::Guard;
  static std::unique_ptr<JacobianProgram> derive(HessianProgram::Graph& graph, int inputs,
                                                 const std::vector<int>& outputs,
                                                 const std::vector<std::pair<int, int>>& entries);
  std::vector<Instruction> code_;
  std::vector<Guard> guards_;
  std::vector<double> registers_;
  std::vector<std::int32_t> input_registers_;
  std::vector<std::int32_t> value_registers_;
};

// The graph a trace records into; a HessianTape so that HessianJet's operations reach it.
class HessianProgram::Graph final : public HessianTape {
 public:
  Graph();
  ~Graph();
  int input(int k);
  int constant(double value) override;
  int unary(Op op, int x, double c) override;
  int binary(Op op, int x, int y) override;
  void guard(Test test, int x, int y, bool outcome) override;

  struct Impl;
  std::unique_ptr<Impl> impl;
};

template <typename Eval>
std::unique_ptr<HessianProgram> HessianProgram::trace(const Shape& shape, const double* base,
                                                      Eval& eval) {
  Graph graph;
  std::vector<HessianJet> in(static_cast<std::size_t>(shape.inputs));
  std::vector<HessianJet> out(static_cast<std::size_t>(shape.outputs));
  for (int k = 0; k < shape.inputs; ++k)
    in[static_cast<std::size_t>(k)] = HessianJet::traced(&graph, graph.input(k), base[k]);
  eval(static_cast<const HessianJet*>(in.data()), out.data());
  std::vector<int> nodes(static_cast<std::size_t>(shape.outputs));
  for (int r = 0; r < shape.outputs; ++r) {
    const HessianJet& o = out[static_cast<std::size_t>(r)];
    // An untraced output is a constant (it depends on no input).
    nodes[static_cast<std::size_t>(r)] = o.tape == &graph ? o.node : graph.constant(o.a);
  }
  return derive(graph, shape, nodes);
}

template <typename Eval>
std::unique_ptr<JacobianProgram> JacobianProgram::trace(
    int inputs, int outputs, const std::vector<std::pair<int, int>>& entries, const double* base,
    Eval& eval) {
  HessianProgram::Graph graph;
  std::vector<HessianJet> in(static_cast<std::size_t>(inputs));
  std::vector<HessianJet> out(static_cast<std::size_t>(outputs));
  for (int k = 0; k < inputs; ++k)
    in[static_cast<std::size_t>(k)] = HessianJet::traced(&graph, graph.input(k), base[k]);
  eval(static_cast<const HessianJet*>(in.data()), out.data());
  std::vector<int> nodes(static_cast<std::size_t>(outputs));
  for (int r = 0; r < outputs; ++r) {
    const HessianJet& o = out[static_cast<std::size_t>(r)];
    nodes[static_cast<std::size_t>(r)] = o.tape == &graph ? o.node : graph.constant(o.a);
  }
  return derive(graph, inputs, nodes, entries);
}

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_HESSIAN_TAPE_H_

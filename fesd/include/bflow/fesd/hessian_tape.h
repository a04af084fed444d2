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

#include <cstdint>
#include <memory>
#include <vector>

#include "bflow/fesd/hessian_jet.h"

namespace bflow {
namespace fesd {

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

 private:
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
  static std::unique_ptr<HessianProgram> derive(Graph& graph, const Shape& shape,
                                                const std::vector<int>& outputs);

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

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_HESSIAN_TAPE_H_

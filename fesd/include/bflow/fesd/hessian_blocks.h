// The sparse lower triangle of a Lagrangian's Hessian assembled from small dense blocks, each
// the second derivatives of a function of a few unknowns (fesd element pieces, equilibration
// terms, an OCP's costs and constraints).
#ifndef BFLOW_FESD_HESSIAN_BLOCKS_H_
#define BFLOW_FESD_HESSIAN_BLOCKS_H_

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <map>
#include <memory>
#include <utility>
#include <vector>

#include "bflow/ad/tangent_jet.h"
#include "bflow/core/errors.h"
#include "bflow/fesd/hessian_tape.h"
#include "bflow/fesd/step_model.h"

namespace bflow {
namespace fesd {

// The lower triangle of a Lagrangian's Hessian assembled from blocks: each block is a function of
// a few unknowns (`globals`, -1 for a constant), and its second derivatives come from
// HessianJet (hessian_jet.h), one lane per unknown.
//
// HessianJet makes a value pay only for the leading lanes it depends on, so the order of the
// lanes matters: one pass of Jet chunks whose derivative lanes are NaN first finds the unknowns
// the weighted outputs depend on along the code path taken (NaN survives every product, even by
// a zero partial), and those get the leading lanes. The others come after them: they still have
// lanes, so that a dependence the NaN pass cannot see (Ceres's pow(f, g) at f = 0 returns a Jet
// without f's lanes) costs time, never exactness. The monoped's field piece depends on 13 of its
// 16 unknowns (not on its horizontal position, its height or the clock).
//
// An evaluation of the whole Hessian repeats the same calls of add in the same order (every
// element's pieces, then the costs and constraints). Between begin_evaluation() and
// end_evaluation() each call's plan (its lane order and the position in `values` of every pair
// of lanes) is kept at its place in that sequence and used again by the same call of the next
// evaluation (the same globals), so that an evaluation repeats neither the NaN pass nor the
// search for the positions. A lane order read at another point stays exact (every free unknown
// keeps a lane; it is only the order), and the positions depend on the globals alone.
//
// A kept plan of one group (up to kLanes unknowns) also keeps its block's second derivatives as
// a program (hessian_tape.h): traced at the plan's first evaluation, run at the later ones
// (traced again where a branch of the model goes the other way), and checked against HessianJet
// at its 1st, 2nd, 4th, 8th, ... run, a block that disagrees staying on HessianJet. `eval` must
// therefore compute its outputs from its inputs alone: a multiplier or any number that changes
// between evaluations is a weight or an input, never a captured constant.
class HessianBlocks {
 public:
  // Registers every pair of the block's unknowns (call for every block before values are added).
  void add_block(const std::vector<int>& globals) {
    for (int a : globals) {
      for (int b : globals) {
        if (a >= b) register_pair(a, b);
      }
    }
  }
  // Registers the listed pairs of unknowns (either order; pairs with a constant are skipped).
  void add_pairs(const std::vector<std::pair<int, int>>& pairs) {
    for (const auto& [x, y] : pairs) register_pair(std::max(x, y), std::min(x, y));
  }
  // Forgets every registered pair (and the misses).
  void clear() {
    plans_.clear();
    position_.clear();
    rows_.clear();
    cols_.clear();
    index_ready_ = false;
    missed_ = 0;
    traces_ = 0;
    jet_only_ = 0;
  }
  // Nonzero second derivatives `add` found at pairs that were not registered, and left out,
  // since the last clear_missed(): the registered structure is too small for them.
  long missed() const { return missed_; }
  // Blocks traced into programs (hessian_tape.h) since the last clear(), the first time and
  // again where a guard failed, and those whose program disagreed with HessianJet where it
  // was traced (kept on HessianJet).
  long traces() const { return traces_; }
  long jet_only_blocks() const { return jet_only_; }
  // Whether the blocks of a kept plan run as programs (the default) or on HessianJet at every
  // evaluation (SolverOptions::derivative_programs).
  void set_programs(bool on) { programs_ = on; }
  void clear_missed() { missed_ = 0; }
  // One evaluation of the whole Hessian: the calls of add between these two use and keep the
  // plans of the previous evaluation's calls at the same places (see above).
  void begin_evaluation() {
    planning_ = true;
    call_ = 0;
  }
  void end_evaluation() { planning_ = false; }
  std::size_t size() const { return rows_.size(); }
  const std::vector<int>& rows() const { return rows_; }
  const std::vector<int>& cols() const { return cols_; }

  // Adds the Hessian of sum_r weights[r] f_r(in) (f = `eval`, `outputs` values) at `base` into
  // the lower-triangle values. `eval(in, out)` is called with JetChunk and with HessianScalar
  // (a generic lambda). Outputs of weight 0 are left out.
  template <typename Eval>
  void add(const std::vector<int>& globals, const std::vector<double>& base, int outputs,
           const double* weights, Eval eval, double* values) {
    add_scaled(globals, base, 0, outputs, weights, eval, values);
  }

  // As add, for the function s g(in) + q(in) with s the product of the last `factors` entries of
  // `in` (at most 2: an element's length h, or h and the horizon T), g = sum_{r < scaled}
  // weights[r] f_r(in) and q = sum_{r >= scaled} weights[r] f_r(in) (scaled < 0: every output),
  // where `eval` gives the f_r of the other entries (it must not read the factors). The lanes of
  // HessianJet then cover the other entries only, and the factors' second derivatives follow in
  // closed form: s g'' + q'' among the other entries, (s / s_a) g' between factor a and them, g
  // between the two factors (a factor's own second derivative is 0).
  template <typename Eval>
  void add_scaled(const std::vector<int>& globals, const std::vector<double>& base, int factors,
                  int outputs, const double* weights, Eval eval, double* values, int scaled = -1) {
    BFLOW_ASSERT(factors >= 0 && factors <= 2 && factors <= static_cast<int>(globals.size()));
    if (scaled < 0 || scaled > outputs) scaled = outputs;
    if (!index_ready_) build_index();
    Plan* plan = next_plan();
    const bool fresh = plan == nullptr || plan->globals != globals;
    if (plan != nullptr && fresh) {
      plan->globals = globals;
      plan->deps = lane_order(globals, base, factors, outputs, weights, eval);
      plan->positions.clear();
      plan->distinct = distinct(globals, plan->deps, factors);
    }
    const std::vector<int>& deps =
        plan != nullptr ? plan->deps : lane_order(globals, base, factors, outputs, weights, eval);
    if (plan != nullptr && fresh) {
      plan->program.reset();
      plan->jet_only = false;
    }
    Positions positions{plan != nullptr ? &plan->positions : nullptr, fresh, 0,
                        plan != nullptr && plan->distinct, plan};
    Scale scale;
    scale.count = factors;
    scale.outputs = scaled;
    const std::size_t first_factor = globals.size() - static_cast<std::size_t>(factors);
    double factor[2] = {1.0, 1.0};
    for (int a = 0; a < factors; ++a) {
      scale.globals[a] = globals[first_factor + static_cast<std::size_t>(a)];
      factor[a] = base[first_factor + static_cast<std::size_t>(a)];
    }
    scale.product = factors == 2 ? factor[0] * factor[1] : factor[0];
    scale.others[0] = factor[1];
    scale.others[1] = factor[0];
    const int count = static_cast<int>(deps.size());
    double g = 0.0;
    constexpr int kLanes = HessianScalar::kLanes;
    if (count == 0) {
      if (factors == 2) g = constant_value(globals, base, outputs, scaled, weights, eval);
    } else if (count <= kLanes) {
      pass(globals, base, outputs, weights, eval, deps, 0, count, count, 0, true, true, scale, g,
           positions, values);
    } else {
      // More unknowns than lanes: groups of half the lanes, two at a time. Pair (0, 1) gives the
      // diagonal block of group 0, every pair (0, B) that of group B, every pair its cross
      // block.
      constexpr int kGroup = kLanes / 2;
      const int groups = (count + kGroup - 1) / kGroup;
      for (int ga = 0; ga < groups; ++ga) {
        for (int gb = ga + 1; gb < groups; ++gb) {
          pass(globals, base, outputs, weights, eval, deps, ga * kGroup,
               std::min(kGroup, count - ga * kGroup), gb * kGroup,
               std::min(kGroup, count - gb * kGroup), ga == 0 && gb == 1, ga == 0, scale, g,
               positions, values);
        }
      }
    }
    // d2 (s_0 s_1 g) / ds_0 ds_1 = g.
    if (factors == 2) put(scale.globals[0], scale.globals[1], g, false, positions, values);
  }

  // Adds constant second derivatives: terms[t] at the pair of locals pairs[t] = (a, b) of
  // `globals` (the Hessian's entry itself: the mixed derivative for a != b, the diagonal one for
  // a == b; a pair with a constant, -1, is left out). For functions whose second derivatives are
  // known without AD, such as products of two affine members (the complementarity rows), which
  // HessianJet would take in passes over every pair of their unknowns. Plans as add: the same
  // call of the next evaluation reuses the positions.
  void add_constant(const std::vector<int>& globals, const std::vector<std::pair<int, int>>& pairs,
                    const std::vector<double>& terms, double* values) {
    if (!index_ready_) build_index();
    Plan* plan = next_plan();
    const bool fresh =
        plan == nullptr || plan->globals != globals || plan->positions.size() != pairs.size();
    if (plan != nullptr && fresh) {
      plan->globals = globals;
      plan->deps.clear();
      plan->positions.clear();
    }
    for (std::size_t t = 0; t < pairs.size(); ++t) {
      const int ga = globals[static_cast<std::size_t>(pairs[t].first)];
      const int gb = globals[static_cast<std::size_t>(pairs[t].second)];
      long at = -1;
      if (plan != nullptr && !fresh) {
        at = plan->positions[t];
      } else if (ga >= 0 && gb >= 0) {
        at = find(std::max(ga, gb), std::min(ga, gb));
      }
      if (plan != nullptr && fresh) plan->positions.push_back(at);
      if (terms[t] == 0.0 || ga < 0 || gb < 0) continue;
      if (at < 0) {
        ++missed_;
      } else {
        values[at] += terms[t];
      }
    }
  }

 private:
  // A call's plan: its globals, lane order and, pass after pass, the position of every pair of
  // lanes it adds (-1: not registered).
  struct Plan {
    std::vector<int> globals;
    std::vector<int> deps;
    std::vector<long> positions;
    bool distinct = false;  // no two lanes or factors name one unknown
    // The block's second derivatives as a program (hessian_tape.h), traced at the first
    // evaluation and again where a guard fails; jet_only: the program disagreed with HessianJet
    // at the point it was traced (the block stays on HessianJet).
    std::unique_ptr<HessianProgram> program;
    long runs = 0;  // the program's runs since it was traced
    bool jet_only = false;
  };
  // The plan of the next call in this evaluation's sequence; null outside begin_evaluation()
  // and end_evaluation().
  Plan* next_plan() {
    if (!planning_) return nullptr;
    if (call_ >= plans_.size()) plans_.resize(call_ + 1);
    return &plans_[call_++];
  }
  // Where a call's passes read (fresh: write) their positions.
  struct Positions {
    std::vector<long>* list;  // null: no plan, every position searched
    bool fresh;
    std::size_t next;
    bool distinct;  // the plan's lanes and factors name distinct unknowns
    Plan* plan;     // the call's plan (null: none)
  };
  // Whether the unknowns of the lanes (deps) and of the factors are distinct.
  static bool distinct(const std::vector<int>& globals, const std::vector<int>& deps, int factors) {
    thread_local std::vector<int> named;
    named.clear();
    for (int k : deps) named.push_back(globals[static_cast<std::size_t>(k)]);
    for (std::size_t k = globals.size() - static_cast<std::size_t>(factors); k < globals.size();
         ++k) {
      if (globals[k] >= 0) named.push_back(globals[k]);
    }
    std::sort(named.begin(), named.end());
    return std::adjacent_find(named.begin(), named.end()) == named.end();
  }
  // Adds `value` at a planned position (-1: not registered, a miss unless the value is 0).
  void add_at(long at, double value, double* values) {
    if (value == 0.0) return;
    if (at < 0) {
      ++missed_;
    } else {
      values[at] += value;
    }
  }

  // The free entries of `globals` (local indices), those that some output of nonzero weight
  // visibly depends on first.
  template <typename Eval>
  const std::vector<int>& lane_order(const std::vector<int>& globals,
                                     const std::vector<double>& base, int factors, int outputs,
                                     const double* weights, Eval& eval) {
    thread_local std::vector<int> deps, free, rest;
    thread_local std::vector<JetChunk> in, out;
    deps.clear();
    free.clear();
    rest.clear();
    const std::size_t own = globals.size() - static_cast<std::size_t>(factors);
    for (std::size_t k = 0; k < own; ++k) {
      if (globals[k] >= 0) free.push_back(static_cast<int>(k));
    }
    in.resize(globals.size());
    out.resize(static_cast<std::size_t>(outputs));
    const int count = static_cast<int>(free.size());
    const double nan = std::numeric_limits<double>::quiet_NaN();
    for (int first = 0; first < count; first += kTangentChunk) {
      for (std::size_t k = 0; k < globals.size(); ++k) in[k] = JetChunk(base[k]);
      const int width = std::min(kTangentChunk, count - first);
      for (int c = 0; c < width; ++c) {
        in[static_cast<std::size_t>(free[static_cast<std::size_t>(first + c)])].v[c] = nan;
      }
      eval(static_cast<const JetChunk*>(in.data()), out.data());
      for (int c = 0; c < width; ++c) {
        bool seen = false;
        for (int r = 0; r < outputs && !seen; ++r) {
          seen = weights[r] != 0.0 && std::isnan(out[static_cast<std::size_t>(r)].v[c]);
        }
        (seen ? deps : rest).push_back(free[static_cast<std::size_t>(first + c)]);
      }
    }
    deps.insert(deps.end(), rest.begin(), rest.end());
    return deps;
  }

  // The factors of add_scaled: their unknowns (-1: a constant), product s and, per factor, the
  // product of the others (s / s_a without a division).
  struct Scale {
    int count = 0;
    int globals[2] = {-1, -1};
    double product = 1.0;
    double others[2] = {1.0, 1.0};
    int outputs = 0;  // the outputs the factors multiply (the first ones)
  };

  // Adds `value` at the pair of unknowns (gi, gj) (either order; `twice` when two lanes of one
  // unknown make it a diagonal entry counted once per lane pair). A pair with a constant is left
  // out and takes no position. With a plan the position comes from it (fresh: is found and
  // kept); without, it is searched for nonzero values only.
  void put(int gi, int gj, double value, bool twice, Positions& positions, double* values) {
    if (gi < 0 || gj < 0) return;
    long at;
    if (positions.list == nullptr) {
      if (value == 0.0) return;
      at = find(std::max(gi, gj), std::min(gi, gj));
    } else if (positions.fresh) {
      at = find(std::max(gi, gj), std::min(gi, gj));
      positions.list->push_back(at);
    } else {
      at = (*positions.list)[positions.next++];
    }
    add_at(at, twice && gi == gj ? 2.0 * value : value, values);
  }

  // sum_r weights[r] f_r at `base` (no lanes: every entry constant).
  template <typename Eval>
  double constant_value(const std::vector<int>& globals, const std::vector<double>& base,
                        int outputs, int scaled, const double* weights, Eval& eval) {
    thread_local std::vector<HessianScalar> in, out;
    in.resize(globals.size());
    out.resize(static_cast<std::size_t>(outputs));
    for (std::size_t k = 0; k < globals.size(); ++k) set_constant(in[k], base[k]);
    eval(static_cast<const HessianScalar*>(in.data()), out.data());
    double g = 0.0;
    for (int r = 0; r < scaled; ++r) {
      if (weights[r] != 0.0) g += weights[r] * out[static_cast<std::size_t>(r)].a;
    }
    return g;
  }
  static void set_constant(HessianScalar& x, double value) {
    x.a = value;
    x.n = 0;
    x.tape = nullptr;
    x.node = -1;
  }

  // One HessianJet evaluation with lanes [0, na) on deps[first_a ...] and [na, na + nb) on
  // deps[first_b ...] (nb = 0: one group). Adds the cross block, and the diagonal blocks of the
  // first and second group where asked, each times the factors' product; with the diagonal
  // block of a group, the factors' cross entries with its lanes; with the first group's
  // diagonal block, g's value into `g`.
  template <typename Eval>
  void pass(const std::vector<int>& globals, const std::vector<double>& base, int outputs,
            const double* weights, Eval& eval, const std::vector<int>& deps, int first_a, int na,
            int first_b, int nb, bool diagonal_a, bool diagonal_b, const Scale& scale, double& g,
            Positions& positions, double* values) {
    const int lanes = na + nb;
    // lane -> local index
    int local[HessianScalar::kLanes];
    for (int i = 0; i < na; ++i) local[i] = deps[static_cast<std::size_t>(first_a + i)];
    for (int j = 0; j < nb; ++j) {
      local[na + j] = deps[static_cast<std::size_t>(first_b + j)];
    }
    // The weighted sums' Hessian (lower triangle over the lanes), s times that of the scaled
    // outputs plus that of the others; the scaled outputs' gradient and value.
    double sum[HessianScalar::kEntries];
    double grad[HessianScalar::kLanes];
    double value = 0.0;
    const int entries = HessianScalar::at(lanes, 0);
    if (!(nb == 0 && positions.plan != nullptr &&
          program_sums(globals, base, outputs, weights, eval, local, lanes, scale, *positions.plan,
                       sum, grad, value))) {
      jet_sums(globals, base, outputs, weights, eval, local, lanes, scale, sum, grad, value);
    }
    if (diagonal_a) g = value;
    if (nb == 0 && positions.list != nullptr && !positions.fresh && positions.distinct) {
      // One group on a kept plan: its positions in the order of the loops below, the lower
      // triangle by rows (the order of `sum`), then each free factor's lanes.
      const long* at = positions.list->data() + positions.next;
      for (int k = 0; k < entries; ++k) add_at(at[k], sum[k], values);
      at += entries;
      for (int f = 0; f < scale.count; ++f) {
        if (scale.globals[f] < 0) continue;
        for (int i = 0; i < lanes; ++i) add_at(at[i], scale.others[f] * grad[i], values);
        at += lanes;
      }
      positions.next = static_cast<std::size_t>(at - positions.list->data());
      return;
    }
    for (int i = 0; i < lanes; ++i) {
      const bool in_a = i < na;
      const int gi = globals[static_cast<std::size_t>(local[i])];
      for (int j = 0; j <= i; ++j) {
        const bool j_in_a = j < na;
        // Block of (i, j): both in a, both in b, or across.
        if (in_a && j_in_a && !diagonal_a) continue;
        if (!in_a && !j_in_a && !diagonal_b) continue;
        const int gj = globals[static_cast<std::size_t>(local[j])];
        // Two locals may name one unknown (never in FESD's blocks, but allowed): each pair of
        // lanes is one term of the chain rule, the diagonal counted once per lane pair.
        put(gi, gj, sum[HessianScalar::at(i, j)], i != j, positions, values);
      }
    }
    for (int f = 0; f < scale.count; ++f) {
      for (int i = 0; i < lanes; ++i) {
        if (!(i < na ? diagonal_a : diagonal_b)) continue;
        put(scale.globals[f], globals[static_cast<std::size_t>(local[i])],
            scale.others[f] * grad[i], true, positions, values);
      }
    }
  }

  // One HessianJet evaluation with lanes on in[local[0 .. lanes)]: the weighted sums' Hessian
  // (sum = s H(scaled outputs) + H(the others)), the scaled outputs' gradient (with factors)
  // and value.
  template <typename Eval>
  static void jet_sums(const std::vector<int>& globals, const std::vector<double>& base,
                       int outputs, const double* weights, Eval& eval, const int* local, int lanes,
                       const Scale& scale, double* sum, double* grad, double& value) {
    thread_local std::vector<HessianScalar> in, out;
    in.resize(globals.size());
    out.resize(static_cast<std::size_t>(outputs));
    for (std::size_t k = 0; k < globals.size(); ++k) set_constant(in[k], base[k]);
    for (int i = 0; i < lanes; ++i) {
      HessianScalar& x = in[static_cast<std::size_t>(local[i])];
      x.n = i + 1;
      for (int k = 0; k <= i; ++k) x.v[k] = 0.0;
      for (int k = 0; k < HessianScalar::at(i + 1, 0); ++k) x.h[k] = 0.0;
      x.v[i] = 1.0;
    }
    eval(static_cast<const HessianScalar*>(in.data()), out.data());
    double plain[HessianScalar::kEntries];
    const int entries = HessianScalar::at(lanes, 0);
    for (int k = 0; k < entries; ++k) sum[k] = 0.0;
    for (int i = 0; i < lanes; ++i) grad[i] = 0.0;
    value = 0.0;
    bool any_plain = false;
    for (int r = 0; r < outputs; ++r) {
      const double w = weights[r];
      if (w == 0.0) continue;
      const HessianScalar& o = out[static_cast<std::size_t>(r)];
      const int n = std::min(o.n, lanes);
      const int e = HessianScalar::at(n, 0);
      if (r >= scale.outputs) {
        if (!any_plain) {
          for (int k = 0; k < entries; ++k) plain[k] = 0.0;
          any_plain = true;
        }
        for (int k = 0; k < e; ++k) plain[k] += w * o.h[k];
        continue;
      }
      value += w * o.a;
      for (int k = 0; k < e; ++k) sum[k] += w * o.h[k];
      if (scale.count > 0) {
        for (int i = 0; i < n; ++i) grad[i] += w * o.v[i];
      }
    }
    for (int k = 0; k < entries; ++k) sum[k] *= scale.product;
    if (any_plain) {
      for (int k = 0; k < entries; ++k) sum[k] += plain[k];
    }
  }

  // jet_sums' results from the plan's program (hessian_tape.h): traced at the plan's first
  // call and again where a guard fails; checked against jet_sums at its 1st, 2nd, 4th, 8th,
  // ... run (entries apart by more than 1e-8 of their scale leave the plan on HessianJet for
  // good). False: use jet_sums (also for a call whose numbers the program finds not finite).
  template <typename Eval>
  bool program_sums(const std::vector<int>& globals, const std::vector<double>& base, int outputs,
                    const double* weights, Eval& eval, const int* local, int lanes,
                    const Scale& scale, Plan& plan, double* sum, double* grad, double& value) {
    if (plan.jet_only || !programs_) return false;
    const bool gradient = scale.count > 0;
    const auto matches = [&](const HessianProgram& p) {
      const HessianProgram::Shape& sh = p.shape();
      return sh.outputs == outputs && sh.scaled == scale.outputs && sh.gradient == gradient &&
             static_cast<int>(sh.lanes.size()) == lanes;
    };
    for (int attempt = 0; attempt < 2; ++attempt) {
      if (plan.program == nullptr || !matches(*plan.program)) {
        HessianProgram::Shape shape;
        shape.inputs = static_cast<int>(globals.size());
        shape.lanes.assign(local, local + lanes);
        shape.outputs = outputs;
        shape.scaled = scale.outputs;
        shape.gradient = gradient;
        plan.program = HessianProgram::trace(shape, base.data(), eval);
        plan.runs = 0;
        ++traces_;
      }
      const HessianProgram::Outcome outcome =
          plan.program->run(base.data(), weights, scale.product, sum, grad, &value);
      if (outcome == HessianProgram::Outcome::kGuardFailed) {
        plan.program.reset();  // the branch differs here: trace again
        continue;
      }
      // A number that is not finite: HessianJet leaves the outputs of weight 0 out (their
      // infinite derivatives with them), the program multiplies them by 0.
      if (outcome == HessianProgram::Outcome::kNotFinite) return false;
      // Checked against HessianJet at its 1st, 2nd, 4th, 8th, ... run.
      ++plan.runs;
      if ((plan.runs & (plan.runs - 1)) != 0) return true;
      double jet_sum[HessianScalar::kEntries], jet_grad[HessianScalar::kLanes], jet_value = 0.0;
      jet_sums(globals, base, outputs, weights, eval, local, lanes, scale, jet_sum, jet_grad,
               jet_value);
      if (programs_agree(sum, jet_sum, HessianScalar::at(lanes, 0)) &&
          (!gradient || programs_agree(grad, jet_grad, lanes)) &&
          programs_agree(&value, &jet_value, 1)) {
        return true;
      }
      plan.program.reset();
      plan.jet_only = true;
      ++jet_only_;
      return false;
    }
    return false;
  }
  // Row-wise sorted columns and positions (a std::map lookup per entry was a few per cent of an
  // IPOPT iteration).
  void build_index() {
    int rows = 0;
    for (int a : rows_) rows = std::max(rows, a + 1);
    row_begin_.assign(static_cast<std::size_t>(rows) + 1, 0);
    for (int a : rows_) ++row_begin_[static_cast<std::size_t>(a) + 1];
    for (std::size_t a = 0; a < static_cast<std::size_t>(rows); ++a)
      row_begin_[a + 1] += row_begin_[a];
    index_cols_.resize(rows_.size());
    index_positions_.resize(rows_.size());
    for (const auto& [key, pos] : position_) {  // ordered by (row, column)
      const auto at = static_cast<std::size_t>(row_begin_[static_cast<std::size_t>(key.first)]++);
      index_cols_[at] = key.second;
      index_positions_[at] = pos;
    }
    for (std::size_t a = static_cast<std::size_t>(rows); a > 0; --a)
      row_begin_[a] = row_begin_[a - 1];
    row_begin_[0] = 0;
    index_ready_ = true;
  }
  // Registers the pair (a, b), a >= b, once; a pair with a constant (index < 0) is skipped.
  void register_pair(int a, int b) {
    if (b < 0) return;
    if (position_.emplace(std::make_pair(a, b), static_cast<int>(position_.size())).second) {
      rows_.push_back(a);
      cols_.push_back(b);
      index_ready_ = false;
      plans_.clear();  // a pair a plan found missing may be there now
    }
  }
  // The position of the pair (a, b), a >= b, or -1 when it is not registered.
  long find(int a, int b) const {
    if (static_cast<std::size_t>(a) + 1 >= row_begin_.size()) return -1;
    const auto first = index_cols_.begin() + row_begin_[static_cast<std::size_t>(a)];
    const auto last = index_cols_.begin() + row_begin_[static_cast<std::size_t>(a) + 1];
    const auto it = std::lower_bound(first, last, b);
    if (it == last || *it != b) return -1;
    return index_positions_[static_cast<std::size_t>(it - index_cols_.begin())];
  }

  std::vector<Plan> plans_;
  std::size_t call_ = 0;
  bool planning_ = false;
  std::map<std::pair<int, int>, int> position_;
  std::vector<int> rows_, cols_;
  bool index_ready_ = false;
  std::vector<int> row_begin_, index_cols_, index_positions_;
  long missed_ = 0;
  long traces_ = 0, jet_only_ = 0;
  bool programs_ = true;
};

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_HESSIAN_BLOCKS_H_

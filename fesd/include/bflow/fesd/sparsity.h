// The sparsity an NLP hands IPOPT: which entries of a block's Jacobian and Hessian can be
// nonzero, found by evaluating the block at random points.
//
// Every nonzero IPOPT is told about is an entry of its KKT matrix, factorised at every
// iteration, so a structure declared larger than the derivatives are costs time in every
// factorisation and back-solve. What a block reads is known by construction (element.h lists
// the inputs of each row and the unknowns of each Hessian piece), but not what a model does with
// them: the braking block's field (v, u - sign v) is linear, so its pieces' second derivatives
// are only the products with the element length, while every pair of a piece's unknowns is a
// candidate.
//
// The probes evaluate the derivatives (Jets, HessianJet) at kProbePoints points drawn from a
// fixed seed, half with entries of both signs in [-2, 2] and half positive in [0.25, 2], with
// random weights on the outputs (so that two outputs cannot cancel), and keep the entries that
// are nonzero at some point. An entry that is structurally nonzero vanishes at a random point
// only on a set of measure zero, except where the model branches on values: a branch none of the
// points takes is not seen. A point whose derivatives are not finite (a square root of a
// negative value) is left out; when no point is left, every candidate is kept. The transcription
// therefore checks, at every evaluation, that the entries left out are zero, and on a miss
// declares the full structure and solves the NLP again (Transcription, HomotopyStep).
#ifndef BFLOW_FESD_SPARSITY_H_
#define BFLOW_FESD_SPARSITY_H_

#include <cmath>
#include <cstdint>
#include <random>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/fesd/element.h"
#include "bflow/fesd/hessian_blocks.h"

namespace bflow {
namespace fesd {

constexpr int kProbePoints = 4;

/** The inputs of probe point `point` (of kProbePoints) for a block of `count` inputs. */
inline std::vector<double> probe_point(int count, int point, std::mt19937& rng) {
  std::uniform_real_distribution<double> both(-2.0, 2.0), positive(0.25, 2.0);
  std::vector<double> x(static_cast<std::size_t>(count));
  for (double& v : x) v = point % 2 == 0 ? both(rng) : positive(rng);
  return x;
}

/** Per row of f (`rows` outputs of `count` inputs, JetChunk in and out), the candidate inputs
    (`candidates[r]`, local indices) whose derivative is nonzero at some probe point. */
template <typename F>
std::vector<std::vector<int>> probe_jacobian_pattern(
    int count, int rows, const std::vector<std::vector<int>>& candidates, F f) {
  std::mt19937 rng(20261128u);
  std::vector<std::vector<char>> seen(static_cast<std::size_t>(rows),
                                      std::vector<char>(static_cast<std::size_t>(count), 0));
  int valid = 0;
  Eigen::MatrixXd jac;
  for (int point = 0; point < kProbePoints; ++point) {
    dense_jacobian(probe_point(count, point, rng), rows, jac, f);
    if (!jac.allFinite()) continue;
    ++valid;
    for (int r = 0; r < rows; ++r) {
      for (int c = 0; c < count; ++c) {
        if (jac(r, c) != 0.0) seen[static_cast<std::size_t>(r)][static_cast<std::size_t>(c)] = 1;
      }
    }
  }
  if (valid == 0) return candidates;
  std::vector<std::vector<int>> pattern(static_cast<std::size_t>(rows));
  for (int r = 0; r < rows; ++r) {
    for (int c : candidates[static_cast<std::size_t>(r)]) {
      if (seen[static_cast<std::size_t>(r)][static_cast<std::size_t>(c)]) {
        pattern[static_cast<std::size_t>(r)].push_back(c);
      }
    }
  }
  return pattern;
}

/** The pairs (a, b), a >= b, of local inputs whose second derivative is nonzero at some probe
    point. `blocks` are the candidates (each a list of local inputs whose every pair may be
    nonzero); `add(probe, base, weights, values)` adds the Hessian of sum_r weights[r] f_r at
    `base` (`count` inputs) into `values` through `probe`, whose unknowns are the local inputs
    (HessianBlocks::add with globals 0..count-1); `outputs` weights are drawn per point. */
template <typename Add>
std::vector<std::pair<int, int>> probe_hessian_pattern(int count, int outputs,
                                                       const std::vector<std::vector<int>>& blocks,
                                                       Add add) {
  HessianBlocks probe;
  for (const std::vector<int>& block : blocks) probe.add_block(block);
  std::mt19937 rng(20261128u);
  std::uniform_real_distribution<double> weight(1.0, 2.0);
  std::vector<char> seen(probe.size(), 0);
  std::vector<double> values, weights(static_cast<std::size_t>(outputs));
  int valid = 0;
  for (int point = 0; point < kProbePoints; ++point) {
    const std::vector<double> base = probe_point(count, point, rng);
    for (double& w : weights) w = weight(rng);
    values.assign(probe.size(), 0.0);
    add(probe, base, weights.data(), values.data());
    bool finite = true;
    for (double v : values) finite = finite && std::isfinite(v);
    if (!finite) continue;
    ++valid;
    for (std::size_t k = 0; k < values.size(); ++k) {
      if (values[k] != 0.0) seen[k] = 1;
    }
  }
  std::vector<std::pair<int, int>> pairs;
  for (std::size_t k = 0; k < probe.size(); ++k) {
    if (valid == 0 || seen[k]) pairs.emplace_back(probe.rows()[k], probe.cols()[k]);
  }
  return pairs;
}

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_SPARSITY_H_

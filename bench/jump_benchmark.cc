// Cost of the B-derivative at a point where n switching surfaces meet in R^d ([B] Sections 2.3
// and 6), three ways:
//
//   BM_JumpApply/<n>/<d>      JumpMap::apply (Algorithm 2.1): O(n^2 d) per tangent, no
//                             allocation. A table source for n <= 9; a lazily evaluated
//                             HashedLimits source for n in {16, 32, 64}, where most of the n + 1
//                             words each apply() visits are evaluated afresh (O(n d) each).
//   BM_JumpEnumerate/<n>/<d>  The baseline Algorithm 2.1 replaces: build all n! saltation
//                             matrices M_sigma (O(n d^2) each), find the cone holding the
//                             tangent, apply its matrix. O(n! n d^2) per tangent.
//   BM_JumpApplyBlock/<n>/<d> JumpMap::apply_block on 64 tangents at once: for n = 1 the
//                             block path (two passes over the block), else a walk per column.
//   BM_JumpPieces/<n>/<d>     JumpMap::pieces(): all n! pieces with shared prefixes.
//
// Run: scripts/bench (Release build; JSON in bench/results/jump_benchmark.json; prints the
// medians of the target rows). docs/benchmarks.md has the measured numbers.
//
// Every random case comes from tests/support/random_jump.h with a seed fixed by (n, d), so
// the numbers are comparable between runs and machines.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <random>
#include <utility>
#include <vector>

#include <benchmark/benchmark.h>
#include <Eigen/Core>

#include "bflow/core/jump_map.h"
#include "bflow/core/signs.h"
#include "support/random_jump.h"

namespace {

using bflow::JumpMap;
using bflow::Signs;

// Tangents per case: apply() cycles through them so the crossing order changes from one call
// to the next (a single repeated tangent would let the branch predictor learn the order).
constexpr int kTangentPool = 64;
// Largest n with a table source in BM_JumpApply; above it the limits are evaluated lazily.
constexpr int kLargestTableCase = 9;
// BM_JumpEnumerate skips sizes whose n! n d^2 exceeds this (one evaluation would take
// minutes).
constexpr double kEnumerateFlopCap = 3e10;
// Enumeration and Algorithm 2.1 must agree to this relative error.
constexpr double kAgreement = 1e-9;

std::mt19937_64 case_rng(std::int64_t n, std::int64_t d) {
  return std::mt19937_64(0xB10Full * 1000003ull + static_cast<std::uint64_t>(n * 1000 + d));
}

double factorial(int n) {
  double f = 1;
  for (int k = 2; k <= n; ++k) f *= k;
  return f;
}

Eigen::MatrixXd tangent_pool(std::mt19937_64& rng, int d) {
  Eigen::MatrixXd pool(d, kTangentPool);
  for (int k = 0; k < kTangentPool; ++k) pool.col(k) = bflow::testing::gaussian_vector(rng, d);
  return pool;
}

// A JumpMap with table limits (n <= kMaxTableSurfaces).
JumpMap table_map(std::mt19937_64& rng, int n, int d) {
  const Eigen::MatrixXd eta = bflow::testing::random_normals(rng, n, d, false);
  return JumpMap(eta, bflow::testing::random_limits(rng, eta, {}));
}

// HashedLimits that counts its evaluations, so the benchmark can report how many words each
// apply() evaluated afresh (the rest came from the JumpMap's cache).
class CountedLimits {
 public:
  CountedLimits(bflow::testing::HashedLimits limits, std::int64_t* evaluations)
      : limits_(std::move(limits)), evaluations_(evaluations) {}
  void operator()(Signs b, Eigen::Ref<Eigen::VectorXd> out) const {
    ++*evaluations_;
    limits_(b, out);
  }

 private:
  bflow::testing::HashedLimits limits_;
  std::int64_t* evaluations_;
};

[[noreturn]] void fail(const char* what, int n, int d, double value) {
  std::fprintf(stderr, "jump_benchmark: %s (n = %d, d = %d): %.3e\n", what, n, d, value);
  std::abort();
}

// ---------------------------------------------------------------------------------------------
// BM_JumpApply

void BM_JumpApply(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int d = static_cast<int>(state.range(1));
  std::mt19937_64 rng = case_rng(n, d);
  std::int64_t evaluations = 0;
  std::unique_ptr<JumpMap> map;
  if (n <= kLargestTableCase) {
    map = std::make_unique<JumpMap>(table_map(rng, n, d));
  } else {
    const Eigen::MatrixXd eta = bflow::testing::random_normals(rng, n, d, false);
    map = std::make_unique<JumpMap>(
        eta, CountedLimits(bflow::testing::HashedLimits(rng, eta), &evaluations));
  }
  const Eigen::MatrixXd tangents = tangent_pool(rng, d);
  Eigen::VectorXd out(d);
  // Untimed first pass: checks every word the loop meets for transversality. A lazy map's
  // cache cannot hold them all, so the loop still evaluates most afresh (see fresh_words).
  for (int k = 0; k < kTangentPool; ++k) map->apply(tangents.col(k), out);
  evaluations = 0;

  int k = 0;
  for (auto _ : state) {
    map->apply(tangents.col(k), out);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
    k = (k + 1) % kTangentPool;
  }
  state.SetComplexityN(std::int64_t{n} * n * d);
  state.SetItemsProcessed(state.iterations());
  if (n > kLargestTableCase) {
    state.counters["fresh_words"] =
        benchmark::Counter(static_cast<double>(evaluations), benchmark::Counter::kAvgIterations);
  }
}

void apply_args(benchmark::internal::Benchmark* b) {
  for (int n = 2; n <= kLargestTableCase; ++n) {
    for (int d : {n, 16, 64}) b->Args({n, d});
    // The biped's size (d = 6): the C++ side of the Python call overhead
    // (bench/python/overhead.py).
    if (n == 2) b->Args({2, 6});
  }
  for (int n : {16, 32, 64}) {
    for (int d : {64, 256}) b->Args({n, d});
  }
}

BENCHMARK(BM_JumpApply)
    ->Apply(apply_args)
    ->Unit(benchmark::kMicrosecond)
    ->Complexity(benchmark::oN);

// ---------------------------------------------------------------------------------------------
// BM_JumpEnumerate

// Evaluates B(dx) by enumeration: every M_sigma is built (no early exit, so the cost is that
// of building the whole representation), and the one whose cone holds dx is applied.
//
// Cone test. Walk the sampled system of [B] Figure 2.1(b) in the order sigma: starting from
// c = eta dx, surface sigma(k) is reached after tau_k = -c_j / (eta_j . Gamma(b_k)), where b_k
// has the surfaces sigma(0..k-1) on their + side, and then c += tau_k eta Gamma(b_k). The
// crossing times T_k = tau_0 + ... + tau_k are non-decreasing (tau_k >= 0 for k >= 1) exactly
// when dx lies in the closed cone of sigma: if they are, the piecewise-linear path that moves
// along Gamma(b_k) on [T_{k-1}, T_k] is a trajectory of the sampled system, because each
// eta_i . x(t) is strictly increasing (eta_i . Gamma(b) > 0 for every b) and vanishes at the
// crossing time of i, so it is < 0 before and > 0 after: the path is on the side b_k
// prescribes throughout. The sampled flow is unique, so Algorithm 2.1 follows the same order
// (up to ties, where B is continuous). Conversely the true trajectory crosses in its own order
// at non-decreasing times. Rounding can make a near-tie fail the test by an ulp, so we keep
// the order with the largest min_k tau_k (>= 0 exactly for the cone holding dx; a generic dx
// lies in one cone's interior, where every other order has some tau_k < 0).
class Enumeration {
 public:
  explicit Enumeration(const JumpMap& map)
      : map_(map),
        n_(map.surfaces()),
        eta_gamma_(n_, Eigen::Index{1} << n_),
        sigma_(static_cast<std::size_t>(n_)),
        c0_(n_),
        c_(n_) {}

  void apply(const Eigen::Ref<const Eigen::VectorXd>& dx, Eigen::Ref<Eigen::VectorXd> out) {
    // eta . Gamma(b) for every word: part of the representation, so timed.
    for (Eigen::Index w = 0; w < eta_gamma_.cols(); ++w) {
      eta_gamma_.col(w) = map_.transversality(Signs(n_, static_cast<std::uint64_t>(w)));
    }
    c0_.noalias() = map_.normals() * dx;
    for (int j = 0; j < n_; ++j) sigma_[static_cast<std::size_t>(j)] = j;
    double best_margin = -std::numeric_limits<double>::infinity();
    do {
      Eigen::MatrixXd m = map_.saltation(sigma_);
      const double margin = cone_margin();
      if (margin > best_margin) {
        best_margin = margin;
        best_ = std::move(m);
      }
    } while (std::next_permutation(sigma_.begin(), sigma_.end()));
    out.noalias() = best_ * dx;
  }

 private:
  // min_{k >= 1} tau_k along sigma_ (+inf for n = 1): >= 0 iff dx is in sigma_'s cone.
  double cone_margin() {
    c_ = c0_;
    double margin = std::numeric_limits<double>::infinity();
    std::uint64_t bits = 0;
    for (int k = 0; k < n_; ++k) {
      const int j = sigma_[static_cast<std::size_t>(k)];
      const double* g = eta_gamma_.col(static_cast<Eigen::Index>(bits)).data();
      const double tau = -c_[j] / g[j];
      if (k > 0) margin = std::min(margin, tau);
      for (int i = 0; i < n_; ++i) {
        if (!((bits >> i) & 1u)) c_[i] += tau * g[i];
      }
      bits |= std::uint64_t{1} << j;
    }
    return margin;
  }

  const JumpMap& map_;
  int n_;
  Eigen::MatrixXd eta_gamma_;  // n x 2^n
  std::vector<int> sigma_;
  Eigen::VectorXd c0_;
  Eigen::VectorXd c_;
  Eigen::MatrixXd best_;
};

void BM_JumpEnumerate(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int d = static_cast<int>(state.range(1));
  std::mt19937_64 rng = case_rng(n, d);
  const JumpMap map = table_map(rng, n, d);
  const Eigen::MatrixXd tangents = tangent_pool(rng, d);
  Enumeration enumeration(map);
  Eigen::VectorXd out(d);

  int k = 0;
  int last = 0;
  for (auto _ : state) {
    enumeration.apply(tangents.col(k), out);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
    last = k;
    k = (k + 1) % kTangentPool;
  }

  // Untimed: the last evaluation must agree with Algorithm 2.1.
  const Eigen::VectorXd expected = map.apply(tangents.col(last));
  const double error = (out - expected).norm() / expected.norm();
  if (!(error <= kAgreement))
    fail("enumeration disagrees with apply(), relative error", n, d, error);

  state.SetComplexityN(static_cast<std::int64_t>(factorial(n)) * n * d * d);
  state.SetItemsProcessed(state.iterations());
  state.counters["orders"] = factorial(n);
}

void enumerate_args(benchmark::internal::Benchmark* b) {
  for (int n = 2; n <= kLargestTableCase; ++n) {
    for (int d : {n, 16, 64}) {
      if (factorial(n) * n * d * d <= kEnumerateFlopCap) b->Args({n, d});
    }
  }
}

// Sizes of a second or more run a single iteration per repetition by themselves (the runner
// stops as soon as min_time is reached); Iterations()/MinTime() would change the names.
BENCHMARK(BM_JumpEnumerate)
    ->Apply(enumerate_args)
    ->Unit(benchmark::kMicrosecond)
    ->Complexity(benchmark::oN);

// ---------------------------------------------------------------------------------------------
// BM_JumpApplyBlock

// JumpMap::apply_block on the d x 64 tangent pool at once (table source): for n = 1 the block
// path (eta X and two rank-one updates), otherwise a walk per column.
void BM_JumpApplyBlock(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int d = static_cast<int>(state.range(1));
  std::mt19937_64 rng = case_rng(n, d);
  const JumpMap map = table_map(rng, n, d);
  const Eigen::MatrixXd tangents = tangent_pool(rng, d);
  Eigen::MatrixXd out(d, kTangentPool);
  for (auto _ : state) {
    map.apply_block(tangents, out);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * kTangentPool);
}

void apply_block_args(benchmark::internal::Benchmark* b) {
  for (int n : {1, 2, 4}) {
    for (int d : {6, 64}) b->Args({n, d});
  }
}

BENCHMARK(BM_JumpApplyBlock)->Apply(apply_block_args);

// ---------------------------------------------------------------------------------------------
// BM_JumpPieces

void BM_JumpPieces(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int d = static_cast<int>(state.range(1));
  std::mt19937_64 rng = case_rng(n, d);
  const JumpMap map = table_map(rng, n, d);
  std::size_t count = 0;
  for (auto _ : state) {
    // Freeing the n! matrices is timed too: the caller pays for it.
    const bflow::Pieces pieces = map.pieces();
    benchmark::DoNotOptimize(pieces.matrix(0).data());
    count = pieces.size();
  }
  if (static_cast<double>(count) != factorial(n)) {
    fail("pieces() returned the wrong count", n, d, static_cast<double>(count));
  }
  // About e n! rank-1 updates of d x d matrices (a tree of shared prefixes).
  state.SetComplexityN(static_cast<std::int64_t>(factorial(n)) * d * d);
  state.counters["pieces"] = static_cast<double>(count);
}

void pieces_args(benchmark::internal::Benchmark* b) {
  // n = 9, d = 16 returns 9! matrices of 16 x 16, about 750 MB; nothing bigger.
  for (int n = 2; n <= kLargestTableCase; ++n) {
    for (int d : {n, 16}) b->Args({n, d});
  }
}

BENCHMARK(BM_JumpPieces)
    ->Apply(pieces_args)
    ->Unit(benchmark::kMillisecond)
    ->Complexity(benchmark::oN);

// BM_JumpVisitPieces: the same enumeration through for_each_piece(), which stores nothing:
// the difference to BM_JumpPieces is the cost of keeping n! d x d matrices in memory.
void BM_JumpVisitPieces(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int d = static_cast<int>(state.range(1));
  std::mt19937_64 rng = case_rng(n, d);
  const JumpMap map = table_map(rng, n, d);
  double trace = 0;
  for (auto _ : state) {
    map.for_each_piece([&](const std::vector<int>&, const Eigen::Ref<const Eigen::MatrixXd>& m) {
      trace += m(0, 0);
    });
    benchmark::DoNotOptimize(trace);
  }
  state.SetComplexityN(static_cast<std::int64_t>(factorial(n)) * d * d);
}

BENCHMARK(BM_JumpVisitPieces)
    ->Apply(pieces_args)
    ->Unit(benchmark::kMillisecond)
    ->Complexity(benchmark::oN);

}  // namespace

BENCHMARK_MAIN();

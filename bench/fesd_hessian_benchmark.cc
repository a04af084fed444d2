// The exact Hessian of one FESD field piece (element.h: -h sum_i w_i f_i([X; u], z) at one stage
// point) of the hopping monoped's OCP (monoped_ocp.h), by the AD bflow uses (HessianJet over the
// unknowns the piece depends on, hessian_blocks.h) against the nested forward AD it used before
// (Eigen's AutoDiffScalar in itself, 8 x 8 directions per evaluation, every pair of chunks of the
// piece's unknowns, h included).
//
//   BM_FieldDouble/<formulation>           one evaluation of the piece in double (the unit)
//   BM_FieldNestedAutoDiff/<formulation>   the earlier nested AutoDiffScalar
//   BM_FieldHessianJet/<formulation>       HessianBlocks::add: the NaN dependency pass, then
//                                          HessianJet over the dependent unknowns
//   BM_FieldHessianJetAllLanes/<formulation>  HessianJet over every unknown (no dependency pass)
//
// step: the Heaviside step formulation (three regions; unknowns X 9, u 3, alpha 3, h);
// stewart: the field sum_i theta_i f_i over the eight base sets (X 9, u 3, theta 8, h).
// The monoped's OCP has 2 N_FE N such pieces (Radau IIA 2), 360 at N = 60.
//
//   build/bench/fesd_hessian_benchmark   (JSON: bench/results/fesd_hessian_benchmark.json)
#include <benchmark/benchmark.h>

#include <random>
#include <type_traits>
#include <vector>

#include <Eigen/Core>
#include <unsupported/Eigen/AutoDiff>

#include "bflow/examples/monoped_ocp.h"
#include "bflow/fesd/hessian_blocks.h"

namespace {

using bflow::HessianJet;

template <bflow::TimeFreezingRegions kRegions>
struct Piece {
  using Model = decltype(bflow::examples::monoped_model<kRegions>());
  static constexpr bool kStewart = kRegions == bflow::TimeFreezingRegions::kBaseSets;
  static constexpr int d = Model::kStates, nu = Model::kControls;
  static constexpr int nz = kStewart ? Model::kModes : Model::kSwitches;
  static constexpr int size = d + nu + nz + 1;  // [X, u, z, h]
  Model model = bflow::examples::monoped_model<kRegions>();
  std::vector<double> base = std::vector<double>(size);
  std::vector<double> w = std::vector<double>(d);

  Piece() {
    std::mt19937 gen(1);
    std::uniform_real_distribution<double> uniform(-0.5, 0.5);
    for (double& b : base) b = uniform(gen);
    base[1] = 0.3;          // height
    base[d + 2] = 2.0;      // speed of time
    base[size - 1] = 0.02;  // h
    for (int k = 0; k < nz; ++k) base[d + nu + k] = kStewart ? 1.0 / nz : 0.5;
    for (double& x : w) x = uniform(gen);
  }
  // -h sum_i w_i f_i from [X, u, z, h].
  template <typename T>
  T operator()(const T* y) const {
    T f[d];
    if constexpr (kStewart) {
      T modes[Model::kModes * d];
      model.mode_fields(y, y + d, modes);
      for (int i = 0; i < d; ++i) {
        f[i] = T(0.0);
        for (int j = 0; j < nz; ++j) f[i] += y[d + nu + j] * modes[j * d + i];
      }
    } else {
      model.field(y, y + d, y + d + nu, f);
    }
    T s(0.0);
    for (int i = 0; i < d; ++i) s += w[static_cast<std::size_t>(i)] * f[i];
    return -y[size - 1] * s;
  }
};

template <bflow::TimeFreezingRegions kRegions>
void BM_FieldDouble(benchmark::State& state) {
  Piece<kRegions> p;
  double sink = 0.0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(p.base.data());
    sink += p(p.base.data());
  }
  benchmark::DoNotOptimize(sink);
}

// The nested forward AD of commit f792220: chunks of 8 directions inside and outside, every pair
// (a <= b) of chunks of the piece's unknowns.
template <bflow::TimeFreezingRegions kRegions>
void BM_FieldNestedAutoDiff(benchmark::State& state) {
  constexpr int kChunk = 8;
  using Inner = Eigen::AutoDiffScalar<Eigen::Matrix<double, kChunk, 1>>;
  using Outer = Eigen::AutoDiffScalar<Eigen::Matrix<Inner, kChunk, 1>>;
  Piece<kRegions> p;
  const int n = Piece<kRegions>::size;
  std::vector<Outer> in(static_cast<std::size_t>(n));
  double sink = 0.0;
  for (auto _ : state) {
    for (int first_a = 0; first_a < n; first_a += kChunk) {
      for (int first_b = first_a; first_b < n; first_b += kChunk) {
        for (int k = 0; k < n; ++k) in[static_cast<std::size_t>(k)] = Outer(Inner(p.base[k]));
        for (int i = 0; i < kChunk && first_a + i < n; ++i) {
          in[static_cast<std::size_t>(first_a + i)].value().derivatives()[i] = 1.0;
        }
        for (int j = 0; j < kChunk && first_b + j < n; ++j) {
          in[static_cast<std::size_t>(first_b + j)].derivatives()[j] = Inner(1.0);
        }
        const Outer r = p(in.data());
        sink += r.derivatives()[0].derivatives()[0];
      }
    }
  }
  benchmark::DoNotOptimize(sink);
}

template <bflow::TimeFreezingRegions kRegions>
void BM_FieldHessianJet(benchmark::State& state) {
  Piece<kRegions> p;
  const int n = Piece<kRegions>::size;
  std::vector<int> globals(static_cast<std::size_t>(n));
  for (int k = 0; k < n; ++k) globals[static_cast<std::size_t>(k)] = k;
  bflow::fesd::HessianBlocks blocks;
  blocks.add_block(globals);
  std::vector<double> values(blocks.size());
  const double one = 1.0;
  for (auto _ : state) {
    blocks.add(
        globals, p.base, 1, &one, [&](const auto* in, auto* out) { out[0] = p(in); },
        values.data());
  }
  benchmark::DoNotOptimize(values.data());
  state.counters["unknowns"] = n;
}

template <bflow::TimeFreezingRegions kRegions>
void BM_FieldHessianJetAllLanes(benchmark::State& state) {
  Piece<kRegions> p;
  const int n = Piece<kRegions>::size;
  if (n > HessianJet::kLanes) {
    state.SkipWithError("more unknowns than lanes: HessianBlocks pairs groups of them");
    return;
  }
  std::vector<HessianJet> in(static_cast<std::size_t>(n));
  double sink = 0.0;
  for (auto _ : state) {
    for (int k = 0; k < n; ++k)
      in[static_cast<std::size_t>(k)] = HessianJet::variable(p.base[k], k);
    sink += p(in.data()).h[1];
  }
  benchmark::DoNotOptimize(sink);
}

}  // namespace

using bflow::TimeFreezingRegions;
BENCHMARK_TEMPLATE(BM_FieldDouble, TimeFreezingRegions::kUnions)->Name("BM_FieldDouble/step");
BENCHMARK_TEMPLATE(BM_FieldNestedAutoDiff, TimeFreezingRegions::kUnions)
    ->Name("BM_FieldNestedAutoDiff/step");
BENCHMARK_TEMPLATE(BM_FieldHessianJet, TimeFreezingRegions::kUnions)
    ->Name("BM_FieldHessianJet/step");
BENCHMARK_TEMPLATE(BM_FieldHessianJetAllLanes, TimeFreezingRegions::kUnions)
    ->Name("BM_FieldHessianJetAllLanes/step");
BENCHMARK_TEMPLATE(BM_FieldDouble, TimeFreezingRegions::kBaseSets)->Name("BM_FieldDouble/stewart");
BENCHMARK_TEMPLATE(BM_FieldNestedAutoDiff, TimeFreezingRegions::kBaseSets)
    ->Name("BM_FieldNestedAutoDiff/stewart");
BENCHMARK_TEMPLATE(BM_FieldHessianJet, TimeFreezingRegions::kBaseSets)
    ->Name("BM_FieldHessianJet/stewart");
BENCHMARK_MAIN();

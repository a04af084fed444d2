// Cost of periodic orbits through simultaneous events (bflow/orbits/periodic_orbit.h) against
// n, the number of surfaces crossed at once.
//
// The corner orbit (examples/corner_orbit.h, CornerOrbit::with_surfaces(n), n = 1..6): states
// (p, q, w, z_1..z_m), d = 3 + m, m = max(0, n - 2); the unit circle with period T = 1, through the
// corner where its n surfaces meet once per period (and crossing each once more, alone). Section
// CornerOrbitSection (theta = 5 pi / 4), guess r = 1.05, w = 0, z = 0 on it:
// x = (-1.05/sqrt 2, -1.05/sqrt 2, 0, 0, ...). Default OrbitOptions (rtol 1e-10, atol 1e-12).
//
//   BM_FindOrbit/<n>     find_periodic_orbit() with options.stability = false: Newton alone.
//                        Counters: newton_iterations; per_newton_iteration (seconds, the row's
//                        CPU time / newton_iterations); pieces = return_map.pieces().size() (n! if
//                        the corner is one event, the single-surface events adding none).
//   BM_ReturnMap/<n>     one bflow::return_map() at the converged fixed point: one period's
//                        simulation with the flow's B-derivative (Algorithm 2.1 at the corner).
//   BM_Pieces/<n>        orbit.return_map.pieces() on the converged orbit: all of the return
//                        map's linear pieces (what the bracket starts from). Counters: pieces,
//                        states (d).
//   BM_GrowthBracket/<n> growth_rate_bracket(orbit.return_map, orbit.tangent_basis, options) on
//                        the converged orbit (found once, outside the timed loop). Counters:
//                        pieces (bracket.pieces: distinct pieces on the section), upper_length,
//                        lower, upper, and rate = max(exp(-2 k T), exp(-a T), exp(-a_z T)),
//                        the closed-form growth rate the bracket must hold.
//   BM_Biped             the hopping biped (core/biped.h: mode-damping, kappa 1000, beta 4,
//                        thrust 10, thrust_speed 0.1; d = 6, both feet land and lift off
//                        together), section CoordinateSection{4, 0.0, -1.0} (the apex), guess
//                        (0, 0.8, 0, 0, 0, 0): find_periodic_orbit() with the bracket. Counters:
//                        newton_iterations, lower, upper, pieces, period and the event
//                        counters below.
//
// Every row on an orbit also reports what the period's events were: events, largest_event (the most
// surfaces grouped into one event; n when the corner is one event) and notices (near-simultaneous
// crossings left ungrouped); BM_FindOrbit adds decisions (Newton steps cut because the return map
// failed at a longer one, PeriodicOrbit::decisions).
//
// A Newton run that does not converge, or a call that throws, is a benchmark error quoting the
// message, never a row of numbers.
//
// Run (Release build, about a minute; JSON in bench/results/orbit_benchmark.json):
//   build/bench/orbit_benchmark --benchmark_min_time=0.1 --benchmark_repetitions=5
//       --benchmark_report_aggregates_only=true
//       --benchmark_out=bench/results/orbit_benchmark.json --benchmark_out_format=json
// docs/benchmarks.md (Periodic orbits) has the measured numbers.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <exception>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <benchmark/benchmark.h>
#include <Eigen/Core>

#include "bflow/core/biped.h"
#include "bflow/examples/corner_orbit.h"
#include "bflow/integrators/model_adapter.h"
#include "bflow/orbits/periodic_orbit.h"

namespace {

using bflow::OrbitOptions;
using bflow::PeriodicOrbit;
using bflow::SegmentModel;
using bflow::examples::CornerOrbit;
using bflow::examples::CornerOrbitSection;

constexpr int kLargestCorner = 6;
constexpr double kGuessRadius = 1.05;

// r = kGuessRadius on the section, w = 0 and z = 0.
Eigen::VectorXd corner_guess(int n) {
  Eigen::VectorXd x = Eigen::VectorXd::Zero(CornerOrbit::with_surfaces(n).states());
  x[0] = x[1] = -kGuessRadius / std::sqrt(2.0);
  return x;
}

// One adapter per n, kept for the whole run (the timed loops only read them).
const SegmentModel& corner_model(int n) {
  using Adapter = bflow::ModelAdapter<CornerOrbit>;
  static std::map<int, std::unique_ptr<Adapter>> models;
  auto& model = models[n];
  if (!model) model = std::make_unique<Adapter>(bflow::adapt(CornerOrbit::with_surfaces(n)));
  return *model;
}

OrbitOptions fixed_point_options() {
  OrbitOptions options;
  options.stability = false;
  return options;
}

// The converged orbit of n, found once (Google Benchmark calls a benchmark function several
// times while it sizes the loop). A throw is kept as a non-converged orbit quoting it.
const PeriodicOrbit& corner_orbit(int n) {
  static std::map<int, PeriodicOrbit> orbits;
  auto found = orbits.find(n);
  if (found == orbits.end()) {
    PeriodicOrbit orbit;
    try {
      orbit = bflow::find_periodic_orbit(corner_model(n), CornerOrbitSection{}, corner_guess(n),
                                         fixed_point_options());
    } catch (const std::exception& e) {
      orbit.converged = false;
      orbit.message = std::string("threw: ") + e.what();
    }
    found = orbits.emplace(n, std::move(orbit)).first;
  }
  return found->second;
}

bool require_converged(benchmark::State& state, const PeriodicOrbit& orbit) {
  if (orbit.converged) return true;
  state.SkipWithError(("find_periodic_orbit did not converge: " + orbit.message).c_str());
  return false;
}

void skip_with(benchmark::State& state, const char* what, const std::exception& e) {
  state.SkipWithError((std::string(what) + " threw: " + e.what()).c_str());
}

// What the period's events were (see the file comment).
void event_counters(benchmark::State& state, const std::vector<bflow::EventRecord>& events,
                    const std::vector<bflow::FlowNotice>& notices) {
  int largest = 0;
  for (const bflow::EventRecord& event : events) largest = std::max(largest, event.group_size());
  state.counters["events"] = static_cast<double>(events.size());
  state.counters["largest_event"] = largest;
  state.counters["notices"] = static_cast<double>(notices.size());
}

// Seconds per unit of `count`: the row's CPU time divided by count.
benchmark::Counter per(double count) {
  return benchmark::Counter(
      count, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

void BM_FindOrbit(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const SegmentModel& model = corner_model(n);
  const OrbitOptions options = fixed_point_options();
  const Eigen::VectorXd guess = corner_guess(n);
  PeriodicOrbit orbit;
  try {
    for (auto _ : state) {
      orbit = bflow::find_periodic_orbit(model, CornerOrbitSection{}, guess, options);
    }
  } catch (const std::exception& e) {
    skip_with(state, "find_periodic_orbit", e);
    return;
  }
  if (!require_converged(state, orbit)) return;
  state.counters["newton_iterations"] = orbit.newton_iterations;
  state.counters["per_newton_iteration"] = per(orbit.newton_iterations);
  event_counters(state, orbit.events, orbit.notices);
  state.counters["decisions"] = static_cast<double>(orbit.decisions.size());
  try {
    state.counters["pieces"] = static_cast<double>(orbit.return_map.pieces().size());
  } catch (const std::exception& e) {
    skip_with(state, "return_map.pieces()", e);
  }
}

void BM_ReturnMap(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const PeriodicOrbit& orbit = corner_orbit(n);
  if (!require_converged(state, orbit)) return;
  const SegmentModel& model = corner_model(n);
  const OrbitOptions options = fixed_point_options();
  bflow::ReturnMap map;
  try {
    for (auto _ : state) {
      map = bflow::return_map(model, CornerOrbitSection{}, orbit.x, options);
    }
  } catch (const std::exception& e) {
    skip_with(state, "return_map", e);
    return;
  }
  event_counters(state, map.events, map.notices);
  state.counters["return_time"] = map.time;
}

void BM_Pieces(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const PeriodicOrbit& orbit = corner_orbit(n);
  if (!require_converged(state, orbit)) return;
  std::size_t pieces = 0;
  try {
    for (auto _ : state) {
      pieces = orbit.return_map.pieces().size();
      benchmark::DoNotOptimize(pieces);
    }
  } catch (const std::exception& e) {
    skip_with(state, "return_map.pieces()", e);
    return;
  }
  state.counters["pieces"] = static_cast<double>(pieces);
  state.counters["states"] = static_cast<double>(orbit.x.size());
}

void BM_GrowthBracket(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const PeriodicOrbit& orbit = corner_orbit(n);
  if (!require_converged(state, orbit)) return;
  const OrbitOptions options;  // the bracket's defaults
  bflow::GrowthBracket bracket;
  try {
    for (auto _ : state) {
      bracket = bflow::growth_rate_bracket(orbit.return_map, orbit.tangent_basis, options);
    }
  } catch (const std::exception& e) {
    skip_with(state, "growth_rate_bracket", e);
    return;
  }
  const CornerOrbit m = CornerOrbit::with_surfaces(n);
  event_counters(state, orbit.events, orbit.notices);
  state.counters["pieces"] = bracket.pieces;
  state.counters["upper_length"] = bracket.upper_length;
  state.counters["lower"] = bracket.lower;
  state.counters["upper"] = bracket.upper;
  double rate = std::max(std::exp(-2.0 * m.k * m.period()), std::exp(-m.a * m.period()));
  if (m.extra_states() > 0) rate = std::max(rate, std::exp(-m.a_z * m.period()));
  state.counters["rate"] = rate;
}

bflow::BipedParams hopper() {
  bflow::BipedParams p;
  p.variant = bflow::BipedVariant::kModeDamping;
  p.kappa = 1000.0;
  p.beta = 4.0;
  p.thrust = 10.0;
  p.thrust_speed = 0.1;
  return p;
}

void BM_Biped(benchmark::State& state) {
  Eigen::VectorXd guess(6);
  guess << 0.0, 0.8, 0.0, 0.0, 0.0, 0.0;
  const bflow::CoordinateSection apex{4, 0.0, -1.0};
  const OrbitOptions options;  // with the bracket
  PeriodicOrbit orbit;
  try {
    orbit = bflow::visit_biped(hopper(), [&](const auto& scene) {
      const auto model = bflow::adapt(scene);
      PeriodicOrbit last;
      for (auto _ : state) {
        last = bflow::find_periodic_orbit(model, apex, guess, options);
      }
      return last;
    });
  } catch (const std::exception& e) {
    skip_with(state, "find_periodic_orbit", e);
    return;
  }
  if (!require_converged(state, orbit)) return;
  state.counters["newton_iterations"] = orbit.newton_iterations;
  state.counters["lower"] = orbit.growth_rate_lower;
  state.counters["upper"] = orbit.growth_rate_upper;
  state.counters["pieces"] = orbit.bracket.pieces;
  state.counters["period"] = orbit.period;
  event_counters(state, orbit.events, orbit.notices);
}

BENCHMARK(BM_FindOrbit)->DenseRange(1, kLargestCorner)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReturnMap)->DenseRange(1, kLargestCorner)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Pieces)->DenseRange(1, kLargestCorner)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_GrowthBracket)->DenseRange(1, kLargestCorner)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Biped)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();

// Cost of the flow's B-derivative against the plain simulation and finite differences, and the
// cost each scene effect adds.
//
// The flow benchmarks integrate the mode-damping biped of [B] Section 3.2.4 (bflow/core/biped.h,
// default parameters) from (0, 1, 0, 0, 0, 0) to t = 0.6: free fall, both feet touch the ground
// together at t = 0.3968 (one event of two surfaces, where the derivative has two pieces),
// then both stay in contact. d = 6. Tolerances rtol = 10^-e, atol = 1e-3 rtol.
//
//   BM_FlowSimulate/<e>     simulate(): the state only, no tangents
//   BM_FlowDirectional/<e>  simulate() with one direction (Jet<double, 1>)
//   BM_FlowFull/<e>         flow_derivative(): all d = 6 directions (one Jet<double, 6> chunk)
//                           and the jump map, reusable for any direction; the default error
//                           control (the tangents in the norm, as in BM_FlowDirectional)
//   BM_FlowOneSidedFd/<e>   d + 1 simulations: phi(x0) and phi(x0 + a e_i), a = sqrt(rtol)
//   BM_FlowCentralFd/<e>    2d + 1 simulations: phi(x0) and phi(x0 +- a e_i), a = rtol^(1/3)
//   BM_FlowFullStateOnly/<e>  BM_FlowFull with the state alone in dopri5's error norm
//   BM_FlowGrouping/<policy>/<simulate|derivative>  default options on an oscillator crossing
//                           two axes a quarter turn apart (38 single-surface events, none
//                           near-simultaneous) with grouping auto, window and none: what the
//                           automatic window costs where it changes nothing (target <= 5 %)
//
// The targets compare medians of the same e: Directional <= 2x Simulate, Full <= 4x Simulate,
// CentralFd >= 3x Full (scripts/accuracy --benchmark prints the ratios). The default names
// are the dopri5 backend; "/cvodes-bdf" and "/cvodes-adams" rows follow when that backend is
// built (a backend whose make_integrator() throws is skipped with a note on stderr).
// Finite differences run with Grouping::kNone, as bflow::fd does, so that a perturbed run
// resolves the two touchdowns however close they are.
//
// Effect costs (scenes of bflow/core/scene.h):
//
//   BM_SceneField/<scene>      one F_b(x) with doubles through the SegmentModel interface (the
//                              call an integrator makes), contacts on (b = all +, state
//                              penetrating) or off (b = all -, same state)
//   BM_SceneFieldJet8/<scene>  the same with Jet<double, 8> (what one tangent chunk costs);
//                              both also for the mode-damping biped, feet off and on
//   BM_SceneSimulate/<scene>   simulate() of a body thrown upwards under gravity for 2 s, with
//                              no contact (kSurfaces = 0: surfaces() is empty, no event check runs)
//                              and with 1 or 2 contacts whose ground is 1000 below (never
//                              reached: same field, same steps, so the difference is the
//                              event checks). Counter `per_step` = time per accepted step.
//                              "*_field_no_events": the contact scene's field (contacts off)
//                              behind a model with no surfaces, to split the added cost into
//                              the field's share and the event checks' share.
//
// Run: scripts/accuracy --benchmark (Release build in build-accuracy/, JSON in
// bench/results/flow_benchmark.json); docs/accuracy.md has the measured numbers.
#include <cmath>
#include <cstdio>
#include <exception>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <benchmark/benchmark.h>
#include <Eigen/Core>

#include "bflow/core/biped.h"
#include "bflow/core/scene.h"
#include "bflow/core/signs.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "bflow/integrators/segment.h"

namespace {

using bflow::Backend;
using bflow::FlowOptions;
using bflow::FlowResult;
using bflow::SegmentModel;

constexpr double kFinalTime = 0.6;
constexpr int kStates = 6;
// Rtol exponents: 1e-10 carries the targets, 1e-6 is for context.
constexpr int kExponents[] = {6, 10};

const SegmentModel& biped() {
  static const auto model = bflow::adapt(bflow::make_biped_mode_damping(bflow::BipedParams{}));
  return model;
}

Eigen::VectorXd biped_x0() { return bflow::biped_initial_state(); }

// A direction that crosses the two-piece cone structure off its boundary (theta component).
Eigen::VectorXd biped_direction() {
  Eigen::VectorXd dx(kStates);
  dx << 0.3, -0.5, 0.8, 0.1, -0.2, 0.4;
  return dx.normalized();
}

FlowOptions options_for(int exponent, Backend backend) {
  FlowOptions options;
  options.backend = backend;
  options.integrator.rtol = std::pow(10.0, -exponent);
  options.integrator.atol = 1e-3 * options.integrator.rtol;
  return options;
}

FlowOptions fd_options(int exponent, Backend backend) {
  FlowOptions options = options_for(exponent, backend);
  options.grouping = bflow::Grouping::kNone;
  return options;
}

// Counters shared by the flow benchmarks: the work of one nominal simulation.
void flow_counters(benchmark::State& state, const FlowResult& r, int simulations) {
  state.counters["steps"] = static_cast<double>(r.steps);
  state.counters["events"] = static_cast<double>(r.events.size());
  state.counters["simulations"] = simulations;
}

bool require_ok(benchmark::State& state, const FlowResult& r) {
  if (r.ok()) return true;
  state.SkipWithError(("simulation failed: " + r.message).c_str());
  return false;
}

// ---------------------------------------------------------------------------------------------
// Flow derivative against simulation and finite differences

void BM_FlowSimulate(benchmark::State& state, Backend backend, int exponent) {
  const FlowOptions options = options_for(exponent, backend);
  const Eigen::VectorXd x0 = biped_x0();
  FlowResult r;
  for (auto _ : state) {
    r = bflow::simulate(biped(), x0, kFinalTime, options);
    benchmark::DoNotOptimize(r.x.data());
  }
  if (require_ok(state, r)) flow_counters(state, r, 1);
}

void BM_FlowDirectional(benchmark::State& state, Backend backend, int exponent) {
  const FlowOptions options = options_for(exponent, backend);
  const Eigen::VectorXd x0 = biped_x0();
  const Eigen::MatrixXd dx = biped_direction();
  FlowResult r;
  for (auto _ : state) {
    r = bflow::simulate(biped(), x0, kFinalTime, dx, options);
    benchmark::DoNotOptimize(r.v.data());
  }
  if (require_ok(state, r)) flow_counters(state, r, 1);
}

void full_derivative(benchmark::State& state, Backend backend, int exponent, bool state_only) {
  FlowOptions options = options_for(exponent, backend);
  options.integrator.tangents_in_error_norm = !state_only;
  const Eigen::VectorXd x0 = biped_x0();
  FlowResult r;
  for (auto _ : state) {
    const bflow::FlowDerivative derivative =
        bflow::flow_derivative(biped(), x0, kFinalTime, options, &r);
    benchmark::DoNotOptimize(derivative.transitions().back().data());
  }
  flow_counters(state, r, 1);
}

void BM_FlowFull(benchmark::State& state, Backend backend, int exponent) {
  full_derivative(state, backend, exponent, false);
}
// For context: the state alone in dopri5's error norm: fewer steps on this symmetric trajectory,
// and a derivative whose error rtol does not bound (bench/accuracy.cc, docs/accuracy.md).
void BM_FlowFullStateOnly(benchmark::State& state, Backend backend, int exponent) {
  full_derivative(state, backend, exponent, true);
}

// One-sided (central = false) or central differences in all d coordinate directions, plus the
// nominal run (the state itself): d + 1 or 2d + 1 simulations.
void finite_differences(benchmark::State& state, Backend backend, int exponent, bool central) {
  const FlowOptions options = fd_options(exponent, backend);
  const double rtol = options.integrator.rtol;
  const double alpha = central ? std::cbrt(rtol) : std::sqrt(rtol);
  const Eigen::VectorXd x0 = biped_x0();
  Eigen::MatrixXd jacobian(kStates, kStates);
  FlowResult nominal;
  for (auto _ : state) {
    nominal = bflow::simulate(biped(), x0, kFinalTime, options);
    for (int i = 0; i < kStates; ++i) {
      Eigen::VectorXd moved = x0;
      moved[i] += alpha;
      const FlowResult plus = bflow::simulate(biped(), moved, kFinalTime, options);
      if (central) {
        moved[i] = x0[i] - alpha;
        const FlowResult minus = bflow::simulate(biped(), moved, kFinalTime, options);
        jacobian.col(i) = (plus.x - minus.x) / (2 * alpha);
      } else {
        jacobian.col(i) = (plus.x - nominal.x) / alpha;
      }
    }
    benchmark::DoNotOptimize(jacobian.data());
  }
  if (require_ok(state, nominal)) {
    flow_counters(state, nominal, central ? 2 * kStates + 1 : kStates + 1);
  }
}

void BM_FlowOneSidedFd(benchmark::State& state, Backend backend, int exponent) {
  finite_differences(state, backend, exponent, false);
}
void BM_FlowCentralFd(benchmark::State& state, Backend backend, int exponent) {
  finite_differences(state, backend, exponent, true);
}

// ---------------------------------------------------------------------------------------------
// What grouping costs on events with no near-simultaneity

// x' = a_b y, y' = -c_b x with a, c switching across both axes: an orbit around the origin
// crossing one axis at a time, a quarter turn apart (far outside any grouping window), 38 events
// in t = 50.
struct QuadrantOscillator {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 2;
  template <typename T>
  void field(const T* x, bflow::Signs b, T* xdot) const {
    xdot[0] = (b.plus(0) ? 1.5 : 1.0) * x[1];
    xdot[1] = -(b.plus(1) ? 1.3 : 1.0) * x[0];
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = x[0];
    h[1] = x[1];
  }
};

constexpr double kOscillatorTime = 50.0;

void BM_FlowGrouping(benchmark::State& state, bflow::Grouping grouping, bool derivative) {
  static const auto model = bflow::adapt(QuadrantOscillator{});
  FlowOptions options;  // the defaults, as a user runs it
  options.grouping = grouping;
  const Eigen::Vector2d x0(1.0, 0.5);
  FlowResult r;
  for (auto _ : state) {
    if (derivative) {
      const bflow::FlowDerivative d =
          bflow::flow_derivative(model, x0, kOscillatorTime, options, &r);
      benchmark::DoNotOptimize(d.transitions().back().data());
    } else {
      r = bflow::simulate(model, x0, kOscillatorTime, options);
      benchmark::DoNotOptimize(r.x.data());
    }
  }
  if (require_ok(state, r)) {
    flow_counters(state, r, 1);
    state.counters["notices"] = static_cast<double>(r.notices.size());
  }
}

void register_grouping_benchmarks() {
  const std::pair<const char*, bflow::Grouping> policies[] = {
      {"auto", bflow::Grouping::kAutomatic},
      {"window", bflow::Grouping::kFixedWindow},
      {"none", bflow::Grouping::kNone},
  };
  for (bool derivative : {false, true}) {
    for (const auto& [name, grouping] : policies) {
      const std::string full =
          std::string("BM_FlowGrouping/") + name + (derivative ? "/derivative" : "/simulate");
      benchmark::RegisterBenchmark(full.c_str(), BM_FlowGrouping, grouping, derivative)
          ->Unit(benchmark::kMicrosecond);
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Effect costs

using bflow::FlatGround;
using bflow::Gravity;
using bflow::PlanarBody;
using GroundContact = bflow::SoftContact<FlatGround>;
using BodyScene = bflow::Scene<PlanarBody>;
using GravityScene = bflow::Scene<PlanarBody, Gravity>;
using OneContactScene = bflow::Scene<PlanarBody, Gravity, GroundContact>;
using TwoContactScene = bflow::Scene<PlanarBody, Gravity, GroundContact, GroundContact>;

constexpr PlanarBody kBody{2.0, 0.5};
constexpr Gravity kGravity{9.8};

GroundContact ground_contact(double height) {
  return GroundContact{FlatGround{height}, 100.0, 3.0};
}

// 0.1 below the ground at 0 (and 0.05 below the second ground), falling: both contacts act.
Eigen::VectorXd penetrating_state() {
  Eigen::VectorXd x(kStates);
  x << 0.1, -0.1, 0.2, 0.3, -0.7, 0.4;
  return x;
}

template <typename T>
void time_field(benchmark::State& state, const SegmentModel& model, bflow::Signs b) {
  const Eigen::VectorXd x0 = penetrating_state();
  std::vector<T> x(kStates), xdot(kStates);
  for (int i = 0; i < kStates; ++i) {
    x[static_cast<std::size_t>(i)] = T(x0[i]);
    if constexpr (!std::is_same_v<T, double>) {
      x[static_cast<std::size_t>(i)].v[i % T::DIMENSION] = 1.0;
    }
  }
  for (auto _ : state) {
    benchmark::DoNotOptimize(x.data());
    model.field(x.data(), b, xdot.data());
    benchmark::DoNotOptimize(xdot.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations());
}

template <typename T>
void register_field_benchmarks(const char* family) {
  static const auto body = bflow::adapt(BodyScene(kBody));
  static const auto gravity = bflow::adapt(GravityScene(kBody, kGravity));
  static const auto one = bflow::adapt(OneContactScene(kBody, kGravity, ground_contact(0.0)));
  static const auto two =
      bflow::adapt(TwoContactScene(kBody, kGravity, ground_contact(0.0), ground_contact(-0.05)));
  struct Case {
    const char* name;
    const SegmentModel* model;
    bflow::Signs b;
  };
  const Case cases[] = {
      {"body", &body, bflow::Signs(0)},
      {"body+gravity", &gravity, bflow::Signs(0)},
      {"body+gravity+contact_off", &one, bflow::Signs::parse("-")},
      {"body+gravity+contact_on", &one, bflow::Signs::parse("+")},
      {"body+gravity+2contacts_off", &two, bflow::Signs::parse("--")},
      {"body+gravity+2contacts_on", &two, bflow::Signs::parse("++")},
      // The scene of the flow benchmarks, for the ratio of a Jet<8> to a double evaluation.
      {"biped_feet_off", &biped(), bflow::Signs::parse("--")},
      {"biped_feet_on", &biped(), bflow::Signs::parse("++")},
  };
  for (const Case& c : cases) {
    benchmark::RegisterBenchmark(
        (std::string(family) + "/" + c.name).c_str(),
        [c](benchmark::State& state) { time_field<T>(state, *c.model, c.b); })
        ->Unit(benchmark::kNanosecond);
  }
}

// Thrown upwards from the origin, for 2 s: the parabola never comes near ground 1000 below.
// dopri5 integrates a parabola exactly, so the step is capped at 0.01: 200 steps in every
// variant, and the time per step compares like with like.
void time_scene_simulation(benchmark::State& state, const SegmentModel& model) {
  Eigen::VectorXd x0(kStates);
  x0 << 0.0, 0.0, 0.0, 1.0, 5.0, 0.5;
  FlowOptions options = options_for(10, Backend::kDopri5);
  options.integrator.max_step = 0.01;
  FlowResult r;
  for (auto _ : state) {
    r = bflow::simulate(model, x0, 2.0, options);
    benchmark::DoNotOptimize(r.x.data());
  }
  if (!require_ok(state, r)) return;
  state.counters["steps"] = static_cast<double>(r.steps);
  state.counters["field_evaluations"] = static_cast<double>(r.field_evaluations);
  state.counters["per_step"] = benchmark::Counter(
      static_cast<double>(r.steps),
      benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

// The field of `inner` with every contact off, seen as a model without surfaces: the field's
// cost without the event checks (one more virtual call per evaluation than `inner`).
class WithoutSurfaces final : public SegmentModel {
 public:
  explicit WithoutSurfaces(const SegmentModel& inner)
      : inner_(inner), off_(bflow::Signs::all_minus(inner.surfaces())) {}
  int states() const override { return inner_.states(); }
  int surfaces() const override { return 0; }
  void field(const double* x, bflow::Signs, double* xdot) const override {
    inner_.field(x, off_, xdot);
  }
  void field(const bflow::Jet1* x, bflow::Signs, bflow::Jet1* xdot) const override {
    inner_.field(x, off_, xdot);
  }
  void field(const bflow::Jet2* x, bflow::Signs, bflow::Jet2* xdot) const override {
    inner_.field(x, off_, xdot);
  }
  void field(const bflow::Jet4* x, bflow::Signs, bflow::Jet4* xdot) const override {
    inner_.field(x, off_, xdot);
  }
  void field(const bflow::Jet6* x, bflow::Signs, bflow::Jet6* xdot) const override {
    inner_.field(x, off_, xdot);
  }
  void field(const bflow::JetChunk* x, bflow::Signs, bflow::JetChunk* xdot) const override {
    inner_.field(x, off_, xdot);
  }
  void field(const bflow::Jet12* x, bflow::Signs, bflow::Jet12* xdot) const override {
    inner_.field(x, off_, xdot);
  }
  void field(const bflow::Jet16* x, bflow::Signs, bflow::Jet16* xdot) const override {
    inner_.field(x, off_, xdot);
  }
  void field_tangents(const Eigen::Ref<const Eigen::VectorXd>& x, bflow::Signs,
                      const Eigen::Ref<const Eigen::MatrixXd>& v, Eigen::Ref<Eigen::VectorXd> f,
                      Eigen::Ref<Eigen::MatrixXd> fv) const override {
    inner_.field_tangents(x, off_, v, f, fv);
  }
  void surface_values(const double*, double*) const override {}
  Eigen::MatrixXd surface_normals(const Eigen::Ref<const Eigen::VectorXd>&) const override {
    return Eigen::MatrixXd(0, inner_.states());
  }

 private:
  const SegmentModel& inner_;
  bflow::Signs off_;
};

void register_scene_simulations() {
  static const auto free_body = bflow::adapt(GravityScene(kBody, kGravity));
  static const auto one = bflow::adapt(OneContactScene(kBody, kGravity, ground_contact(-1000.0)));
  static const auto two = bflow::adapt(
      TwoContactScene(kBody, kGravity, ground_contact(-1000.0), ground_contact(-1001.0)));
  static const WithoutSurfaces one_without_surfaces(one);
  static const WithoutSurfaces two_without_surfaces(two);
  struct Case {
    const char* name;
    const SegmentModel* model;
  };
  const Case cases[] = {
      {"free", &free_body},          {"contact_field_no_events", &one_without_surfaces},
      {"unreached_contact", &one},   {"2contacts_field_no_events", &two_without_surfaces},
      {"2unreached_contacts", &two},
  };
  for (const Case& c : cases) {
    benchmark::RegisterBenchmark(
        (std::string("BM_SceneSimulate/") + c.name).c_str(),
        [c](benchmark::State& state) { time_scene_simulation(state, *c.model); })
        ->Unit(benchmark::kMicrosecond);
  }
}

// ---------------------------------------------------------------------------------------------
// Registration

using FlowBenchmark = void (*)(benchmark::State&, Backend, int);

void register_flow_benchmarks(Backend backend) {
  const std::string suffix =
      backend == Backend::kDopri5 ? "" : std::string("/") + bflow::to_string(backend);
  const std::pair<const char*, FlowBenchmark> families[] = {
      {"BM_FlowSimulate", BM_FlowSimulate},   {"BM_FlowDirectional", BM_FlowDirectional},
      {"BM_FlowFull", BM_FlowFull},           {"BM_FlowOneSidedFd", BM_FlowOneSidedFd},
      {"BM_FlowCentralFd", BM_FlowCentralFd}, {"BM_FlowFullStateOnly", BM_FlowFullStateOnly},
  };
  for (const auto& [name, function] : families) {
    // The state-only row is for context, on the default backend only.
    if (function == BM_FlowFullStateOnly && backend != Backend::kDopri5) continue;
    for (int exponent : kExponents) {
      const std::string full = std::string(name) + "/" + std::to_string(exponent) + suffix;
      benchmark::RegisterBenchmark(full.c_str(), function, backend, exponent)
          ->Unit(benchmark::kMicrosecond);
    }
  }
}

// A backend that is not built throws from make_integrator(): say so and leave it out.
bool backend_available(Backend backend) {
  try {
    bflow::make_integrator(backend);
    return true;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "flow_benchmark: skipping %s: %s\n", bflow::to_string(backend), e.what());
    return false;
  }
}

}  // namespace

int main(int argc, char** argv) {
  for (Backend backend : {Backend::kDopri5, Backend::kCvodesBdf, Backend::kCvodesAdams}) {
    if (backend_available(backend)) register_flow_benchmarks(backend);
  }
  register_field_benchmarks<double>("BM_SceneField");
  register_field_benchmarks<bflow::JetChunk>("BM_SceneFieldJet8");
  register_scene_simulations();
  register_grouping_benchmarks();

  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}

// bflow's side of the sensitivity comparison of scripts/peers (bench/peers/peer_flow.py,
// docs/peers.md): one problem from a given start, x(T) and the B-derivative of the flow, at one
// backend and tolerance. Prints one JSON object on stdout.
//
//   peer_flow --problem chain --x0 0.1,0.2,... --t 10 --backend dopri5 --rtol 1e-8 --atol 1e-10
//
// Problems (the peers state the same fields in Python, bench/peers/flow_problems.py):
//   chain   six pendulums coupled by springs, d = 12, no surface (a smooth flow):
//           q_i'' = -sin q_i + k (q_{i+1} - 2 q_i + q_{i-1}), k = 0.5, free ends
//   ball    a ball on a damped spring ground, d = 2, one surface h = -y (side + = contact):
//           y' = v, v' = -g + [contact] (-k y - c v), g = 9.81, k = 400, c = 4 (the field jumps
//           by (0, -c v) at the surface: a saltation matrix that is not the identity)
//   biped   the mode-damping biped of bflow/core/biped.h with its defaults, d = 6, two surfaces
//   three   examples::ThreeSurfaces, d = 5, three surfaces
//
// What is timed: the run the peers do, x(T) and the derivative in `--directions` (default the d
// unit vectors: the full Jacobian dx(T)/dx0), by bflow::simulate with those tangents, with the
// options given (the rest at their defaults: automatic grouping, bflow's default error
// control); after one untimed run (as every peer gets), repeated until --min-cpu seconds of
// process CPU time have passed, the mean per run reported. The JSON: the problem and settings,
// status, x(T), the images of the directions (d x k, "images" as k rows), the events (time,
// surfaces, group size), steps, field evaluations, cpu_s per run and runs.
//
//   peer_flow --reference --problem three --x0 crossing --t 1.5 [--directions ...]
//
// The reference instead (no bflow engine code: examples::ReferenceFlow, long double, fixed-step
// sixth-order Runge-Kutta with bisected crossings, --reference-step its step): x(T), every
// crossing, and the image of each direction by (8 D(a/4) - 6 D(a/2) + D(a)) / 3,
// D(a) = (phi(x0 + a v) - phi(x0)) / a, a = 5e-5, with the crossing order of the a/4 run; and
// its own accuracy, the largest relative change of the images when its step or a is halved.
// For `three`, --x0 crossing starts at phi_{-1}(rho) under F_{---} (ReferenceFlow::backward),
// rounded to double: the start every tool is given.
#include <algorithm>
#include <cstdio>
#include <exception>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bflow/core/biped.h"
#include "bflow/core/errors.h"
#include "bflow/core/model.h"
#include "bflow/core/signs.h"
#include "bflow/examples/reference_flow.h"
#include "bflow/examples/three_surfaces.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"
#include "peer_common.h"

namespace {

using bflow_bench::process_cpu_seconds;
using bflow_bench::vector_json;
using nlohmann::ordered_json;

// Six pendulums coupled by springs (free ends): a smooth, nonlinear flow without surfaces.
struct PendulumChain {
  static constexpr int kPendulums = 6;
  static constexpr int kStates = 2 * kPendulums;
  static constexpr int kSurfaces = 0;
  double coupling = 0.5;
  template <typename T>
  void field(const T* x, bflow::Signs, T* xdot) const {
    using std::sin;
    const T* q = x;
    const T* p = x + kPendulums;
    for (int i = 0; i < kPendulums; ++i) {
      const T& left = q[i > 0 ? i - 1 : i];
      const T& right = q[i + 1 < kPendulums ? i + 1 : i];
      xdot[i] = p[i];
      xdot[kPendulums + i] = -sin(q[i]) + T(coupling) * (left - T(2.0) * q[i] + right);
    }
  }
  template <typename T>
  void surfaces(const T*, T*) const {}
};

// A ball on a damped spring ground; side + of the surface h = -y is contact.
struct DampedBall {
  static constexpr int kStates = 2;
  static constexpr int kSurfaces = 1;
  double g = 9.81, stiffness = 400.0, damping = 4.0;
  template <typename T>
  void field(const T* x, bflow::Signs b, T* xdot) const {
    xdot[0] = x[1];
    xdot[1] = b.plus(0) ? T(-g) - T(stiffness) * x[0] - T(damping) * x[1] : T(-g);
  }
  template <typename T>
  void surfaces(const T* x, T* h) const {
    h[0] = -x[0];
  }
};

// "a,b,c" -> numbers; "a,b;c,d" -> rows.
std::vector<std::vector<double>> parse_rows(const std::string& text, const char* flag) {
  std::vector<std::vector<double>> rows;
  std::stringstream rows_in(text);
  std::string row;
  while (std::getline(rows_in, row, ';')) {
    std::vector<double> values;
    std::stringstream in(row);
    std::string item;
    while (std::getline(in, item, ',')) {
      std::size_t used = 0;
      double value = 0.0;
      try {
        value = std::stod(item, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used == 0 || item.find_first_not_of(" \t", used) != std::string::npos) {
        throw bflow::InvalidArgument(std::string(flag) + ": \"" + item + "\" is not a number");
      }
      values.push_back(value);
    }
    rows.push_back(values);
  }
  return rows;
}

struct Flags {
  std::string problem, backend = "dopri5", x0, directions;
  double t = 0.0, rtol = 1e-8, atol = -1.0, min_cpu = 0.2;
  bool reference = false;
  double reference_step = 1.0 / 512;
};

template <typename Model>
Eigen::VectorXd read_x0(const Flags& f, const Model& model) {
  const int d = bflow::model_states(model);
  const std::vector<std::vector<double>> x0_rows = parse_rows(f.x0, "--x0");
  if (x0_rows.size() != 1 || static_cast<int>(x0_rows[0].size()) != d) {
    throw bflow::InvalidArgument("--x0: " + std::to_string(d) + " numbers expected for " +
                                 f.problem + ", got \"" + f.x0 + "\"");
  }
  return Eigen::Map<const Eigen::VectorXd>(x0_rows[0].data(), d);
}

Eigen::MatrixXd read_directions(const Flags& f, int d) {
  Eigen::MatrixXd directions = Eigen::MatrixXd::Identity(d, d);
  if (!f.directions.empty()) {
    const std::vector<std::vector<double>> rows = parse_rows(f.directions, "--directions");
    directions.resize(d, static_cast<Eigen::Index>(rows.size()));
    for (std::size_t k = 0; k < rows.size(); ++k) {
      if (static_cast<int>(rows[k].size()) != d) {
        throw bflow::InvalidArgument("--directions: direction " + std::to_string(k) + " has " +
                                     std::to_string(rows[k].size()) + " numbers, expected " +
                                     std::to_string(d));
      }
      directions.col(static_cast<Eigen::Index>(k)) =
          Eigen::Map<const Eigen::VectorXd>(rows[k].data(), d);
    }
  }
  return directions;
}

template <typename Model>
ordered_json run(const Flags& f, const Model& model) {
  const auto adapted = bflow::adapt(model);
  const int d = bflow::model_states(model);
  const Eigen::VectorXd x0 = read_x0(f, model);
  const Eigen::MatrixXd directions = read_directions(f, d);
  bflow::FlowOptions options;
  options.backend = bflow::parse_backend(f.backend);
  options.integrator.rtol = f.rtol;
  if (f.atol > 0.0) options.integrator.atol = f.atol;

  // The untimed first run: the peers' harness gives each tool one (imports, allocations).
  bflow::FlowResult r = bflow::simulate(adapted, x0, f.t, directions, options);
  int runs = 0;
  const double start = process_cpu_seconds();
  double elapsed = 0.0;
  do {
    r = bflow::simulate(adapted, x0, f.t, directions, options);
    ++runs;
    elapsed = process_cpu_seconds() - start;
  } while (elapsed < f.min_cpu && r.ok());

  ordered_json j;
  j["problem"] = f.problem;
  j["d"] = d;
  j["t"] = f.t;
  j["backend"] = bflow::to_string(r.backend);  // for --backend auto, the one it chose
  j["rtol"] = f.rtol;
  j["atol"] = options.integrator.absolute_tolerance();
  j["status"] = r.ok() ? "solved" : bflow::to_string(r.status);
  j["message"] = r.message;
  j["cpu_s"] = elapsed / runs;
  j["runs"] = runs;
  j["steps"] = r.steps;
  j["field_evaluations"] = r.field_evaluations;
  j["x"] = vector_json(r.x);
  j["images"] = ordered_json::array();
  for (Eigen::Index k = 0; k < r.v.cols(); ++k) j["images"].push_back(vector_json(r.v.col(k)));
  j["events"] = ordered_json::array();
  for (const bflow::EventRecord& e : r.events) {
    j["events"].push_back({{"t", e.t}, {"surfaces", e.surfaces}, {"spread", e.spread}});
  }
  j["notices"] = r.notices.size();
  return j;
}

// The independent reference (see the top of the file).
template <typename Model>
ordered_json reference(const Flags& f, const Model& model) {
  using LVector = Eigen::Matrix<long double, Eigen::Dynamic, 1>;
  using Reference = bflow::examples::ReferenceFlow<Model>;
  constexpr long double kAlpha = 5e-5L;
  const int d = bflow::model_states(model);
  const double cpu_start = process_cpu_seconds();
  const Reference ref(model, static_cast<long double>(f.reference_step));
  const Reference fine(model, static_cast<long double>(f.reference_step) / 2);
  ordered_json j;
  Eigen::VectorXd x0;
  if (f.x0 == "crossing") {
    if (f.problem != "three") {
      throw bflow::InvalidArgument("--x0 crossing: only for three, not " + f.problem);
    }
    const LVector rho = bflow::examples::ThreeSurfaces::crossing_point().cast<long double>();
    const LVector back =
        ref.backward(rho, static_cast<long double>(bflow::examples::ThreeSurfaces::kCrossingTime),
                     bflow::Signs(3));
    x0 = back.cast<double>();
    j["x0_long_double"] = ordered_json::array();
    for (Eigen::Index i = 0; i < back.size(); ++i) {
      char text[64];
      std::snprintf(text, sizeof text, "%.21Lg", back[i]);
      j["x0_long_double"].push_back(text);
    }
  } else {
    x0 = read_x0(f, model);
  }
  const Eigen::MatrixXd directions = read_directions(f, d);
  const LVector start = x0.cast<long double>();
  const long double t = f.t;
  // (8 D(a/4) - 6 D(a/2) + D(a)) / 3 from the flows of `flow`, and the a/4 run's crossings.
  const auto richardson2 = [&](const Reference& flow, const LVector& base, const LVector& v,
                               long double a, std::vector<int>* order) {
    const LVector d1 = (flow.flow(start + a * v, t).x - base) / a;
    const LVector d2 = (flow.flow(start + (a / 2) * v, t).x - base) / (a / 2);
    const auto quarter = flow.flow(start + (a / 4) * v, t);
    const LVector d4 = (quarter.x - base) / (a / 4);
    if (order != nullptr) {
      for (const auto& c : quarter.crossings) order->push_back(c.surface);
    }
    return LVector((8.0L * d4 - 6.0L * d2 + d1) / 3.0L);
  };
  const auto nominal = ref.flow(start, t);
  const LVector base_fine = fine.flow(start, t).x;
  j["problem"] = f.problem;
  j["x0"] = vector_json(x0);
  j["x"] = vector_json(nominal.x.template cast<double>());
  j["x_step_change"] = static_cast<double>((base_fine - nominal.x).cwiseAbs().maxCoeff() /
                                           std::max(1.0L, nominal.x.cwiseAbs().maxCoeff()));
  j["events"] = ordered_json::array();
  for (const auto& c : nominal.crossings) {
    j["events"].push_back({static_cast<double>(c.t), c.surface});
  }
  j["images"] = ordered_json::array();
  j["orders"] = ordered_json::array();
  double step_change = 0.0, alpha_change = 0.0;
  for (Eigen::Index k = 0; k < directions.cols(); ++k) {
    const LVector v = directions.col(k).cast<long double>();
    std::vector<int> order;
    const LVector r = richardson2(ref, nominal.x, v, kAlpha, &order);
    const LVector r_step = richardson2(fine, base_fine, v, kAlpha, nullptr);
    const LVector r_alpha = richardson2(ref, nominal.x, v, kAlpha / 2, nullptr);
    const long double scale = std::max(1.0L, r.cwiseAbs().maxCoeff());
    step_change =
        std::max(step_change, static_cast<double>((r_step - r).cwiseAbs().maxCoeff() / scale));
    alpha_change =
        std::max(alpha_change, static_cast<double>((r_alpha - r).cwiseAbs().maxCoeff() / scale));
    j["images"].push_back(vector_json(r.template cast<double>()));
    j["orders"].push_back(order);
  }
  j["step_change"] = step_change;
  j["alpha_change"] = alpha_change;
  j["step"] = f.reference_step;
  j["alpha"] = static_cast<double>(kAlpha);
  j["cpu_s"] = process_cpu_seconds() - cpu_start;
  return j;
}

template <typename Model>
ordered_json run_or_reference(const Flags& f, const Model& model) {
  return f.reference ? reference(f, model) : run(f, model);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"bflow's side of scripts/peers flow: x(T) and the B-derivative of one problem"};
  Flags f;
  app.add_option("--problem", f.problem, "chain, ball, biped or three")
      ->required()
      ->check(CLI::IsMember({"chain", "ball", "biped", "three"}));
  app.add_option("--x0", f.x0, "the start, d numbers separated by commas")->required();
  app.add_option("--t", f.t, "final time, > 0")->required();
  app.add_option("--backend", f.backend,
                 "auto (the default's choice), dopri5, dop853, cvodes-adams or cvodes-bdf");
  app.add_option("--rtol", f.rtol, "relative tolerance");
  app.add_option("--atol", f.atol, "absolute tolerance (default 1e-2 rtol)");
  app.add_option("--directions", f.directions,
                 "directions, d numbers each, separated by ';' (default: the unit vectors)");
  app.add_option("--min-cpu", f.min_cpu, "repeat the run until this much CPU time (s)");
  app.add_flag("--reference", f.reference,
               "the independent long double reference (examples::ReferenceFlow) instead");
  app.add_option("--reference-step", f.reference_step, "the reference's step (default 2^-9)")
      ->check(CLI::PositiveNumber);
  CLI11_PARSE(app, argc, argv);
  try {
    if (!(f.t > 0.0)) throw bflow::InvalidArgument("--t must be > 0, got " + std::to_string(f.t));
    ordered_json j;
    if (f.problem == "chain") {
      j = run_or_reference(f, PendulumChain{});
    } else if (f.problem == "ball") {
      j = run_or_reference(f, DampedBall{});
    } else if (f.problem == "biped") {
      j = run_or_reference(f, bflow::make_biped_mode_damping(bflow::BipedParams{}));
    } else {
      j = run_or_reference(f, bflow::examples::ThreeSurfaces{});
    }
    std::cout << j.dump() << "\n";
  } catch (const std::exception& e) {
    std::fprintf(stderr, "peer_flow: %s\n", e.what());
    return 2;
  }
  return 0;
}

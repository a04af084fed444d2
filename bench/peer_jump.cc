// The jump alone, bflow's side of a comparison with other tools (scripts/peers, bench/peers/
// flow_jump.py, docs/peers.md): JumpMap::apply (Algorithm 2.1 of [B]) on a case the Python side
// wrote, timed per call and per tangent of a block. Prints one JSON object on stdout.
//
//   peer_jump --case case.json --repeat 3
//
// The case (JSON): n, d; "normals", n rows of d numbers (eta_j, oriented so that
// eta_j . Gamma(b) > 0); "limits", 2^n columns of d numbers, column b.bits() being Gamma(b)
// (bit j set: side + of surface j, signs.h); "tangents", k rows of d numbers.
//
// Untimed first: every tangent through apply() and through apply_block() (the largest difference
// between the two is reported; it should be 0). Then, each --repeat times (the median kept, every
// run listed):
//   apply        one call per tangent, cycling through the k tangents (so the crossing order
//                changes from one call to the next), calls enough for >= 0.2 s;
//   apply_block  the whole d x k block in one call, repeated to >= 0.2 s;
//   construct    the JumpMap from the normals and the table, repeated to >= 0.2 s.
// Times are process CPU time (clock_gettime(CLOCK_PROCESS_CPUTIME_ID)), in ns per tangent (per
// construction). The JSON also holds B of the first min(k, 100) tangents, for the agreement with
// the other tools.
//
// Bad input (an unreadable file, missing or mis-sized arrays, normals or limits the JumpMap
// refuses) is a message naming the value on stderr and exit code 2.
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bflow/core/errors.h"
#include "bflow/core/jump_map.h"
#include "peer_common.h"

namespace {

using bflow_bench::process_cpu_seconds;
using nlohmann::json;
using nlohmann::ordered_json;

// Each timed run lasts at least this long (CPU seconds).
constexpr double kMinRunSeconds = 0.2;
// Images of this many tangents go into the JSON.
constexpr Eigen::Index kImagesReported = 100;

// Bad input: reported with exit code 2.
struct CaseError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

const json& field(const json& j, const char* name) {
  if (!j.is_object() || !j.contains(name)) {
    throw CaseError(std::string("the case has no \"") + name + "\"");
  }
  return j.at(name);
}

int positive_int(const json& j, const char* name) {
  const json& v = field(j, name);
  if (!v.is_number_integer() || v.get<long long>() < 1 || v.get<long long>() > 1000000) {
    throw CaseError(std::string("\"") + name + "\" must be an integer in [1, 1000000], got " +
                    v.dump());
  }
  return v.get<int>();
}

// rows x cols numbers given as `rows` arrays of `cols` numbers; `transpose` stores array r as
// column r.
Eigen::MatrixXd read_matrix(const json& j, const char* name, Eigen::Index rows, Eigen::Index cols,
                            bool transpose) {
  const json& a = field(j, name);
  const Eigen::Index outer = transpose ? cols : rows;
  const Eigen::Index inner = transpose ? rows : cols;
  if (!a.is_array() || static_cast<Eigen::Index>(a.size()) != outer) {
    throw CaseError(std::string("\"") + name + "\" must be an array of " + std::to_string(outer) +
                    " arrays, got " +
                    (a.is_array() ? std::to_string(a.size()) + " entries" : a.type_name()));
  }
  Eigen::MatrixXd m(rows, cols);
  for (Eigen::Index r = 0; r < outer; ++r) {
    const json& v = a[static_cast<std::size_t>(r)];
    if (!v.is_array() || static_cast<Eigen::Index>(v.size()) != inner) {
      throw CaseError(std::string("\"") + name + "\"[" + std::to_string(r) + "] must hold " +
                      std::to_string(inner) + " numbers, got " +
                      (v.is_array() ? std::to_string(v.size()) : std::string(v.type_name())));
    }
    for (Eigen::Index c = 0; c < inner; ++c) {
      const json& x = v[static_cast<std::size_t>(c)];
      if (!x.is_number()) {
        throw CaseError(std::string("\"") + name + "\"[" + std::to_string(r) + "][" +
                        std::to_string(c) + "] is not a number: " + x.dump());
      }
      (transpose ? m(c, r) : m(r, c)) = x.get<double>();
    }
  }
  return m;
}

struct Case {
  int n = 0, d = 0;
  Eigen::MatrixXd normals;   // n x d
  Eigen::MatrixXd limits;    // d x 2^n
  Eigen::MatrixXd tangents;  // d x k, one tangent per column
};

Case read_case(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw CaseError("cannot open the case file \"" + path + "\"");
  json j;
  try {
    in >> j;
  } catch (const json::exception& e) {
    throw CaseError("\"" + path + "\" is not JSON: " + e.what());
  }
  Case c;
  c.n = positive_int(j, "n");
  c.d = positive_int(j, "d");
  if (c.n > 24) throw CaseError("\"n\" = " + std::to_string(c.n) + " is above 24 (2^n columns)");
  const json& tangents = field(j, "tangents");
  if (!tangents.is_array() || tangents.empty()) {
    throw CaseError("\"tangents\" must be a non-empty array of arrays of d = " +
                    std::to_string(c.d) + " numbers");
  }
  const auto k = static_cast<Eigen::Index>(tangents.size());
  c.normals = read_matrix(j, "normals", c.n, c.d, false);
  c.limits = read_matrix(j, "limits", c.d, Eigen::Index{1} << c.n, true);
  c.tangents = read_matrix(j, "tangents", c.d, k, true);
  return c;
}

// Runs `body(calls)` with calls doubled from 1 until one run takes kMinRunSeconds, then `repeat`
// timed runs of that many calls. Returns the CPU seconds per call of each run.
template <typename Body>
std::vector<double> time_runs(int repeat, const Body& body, long* calls_out) {
  long calls = 1;
  for (;;) {
    const double start = process_cpu_seconds();
    body(calls);
    if (process_cpu_seconds() - start >= kMinRunSeconds) break;
    calls *= 2;
  }
  std::vector<double> per_call;
  for (int r = 0; r < repeat; ++r) {
    const double start = process_cpu_seconds();
    body(calls);
    per_call.push_back((process_cpu_seconds() - start) / static_cast<double>(calls));
  }
  *calls_out = calls;
  return per_call;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

// Nanoseconds per tangent (per construction when tangents_per_call is 0) of each run, and
// their median.
ordered_json timing_json(const std::vector<double>& seconds_per_call, double tangents_per_call,
                         long calls) {
  const std::string unit = tangents_per_call > 0.0 ? "ns_per_tangent" : "ns_per_call";
  ordered_json j;
  std::vector<double> ns;
  for (double s : seconds_per_call) ns.push_back(1e9 * s / std::max(tangents_per_call, 1.0));
  j[unit] = median(ns);
  j["runs_" + unit] = ns;
  j["calls_per_run"] = calls;
  j["cpu_s_per_run"] = median(seconds_per_call) * static_cast<double>(calls);
  return j;
}

}  // namespace

int main(int argc, char** argv) {
  std::string case_path;
  int repeat = 3;
  CLI::App app(
      "The jump alone: JumpMap::apply (Algorithm 2.1) and apply_block on a case written by "
      "bench/peers/flow_jump.py, timed in process CPU time; prints one JSON object.");
  app.add_option("--case", case_path, "the case (JSON: n, d, normals, limits, tangents)")
      ->required();
  app.add_option("--repeat", repeat, "timed runs of each measurement, the median kept")
      ->check(CLI::Range(1, 100));
  CLI11_PARSE(app, argc, argv);

  ordered_json out;
  try {
    const Case c = read_case(case_path);
    const Eigen::Index k = c.tangents.cols();
    const bflow::JumpMap jump(c.normals, c.limits);

    // Untimed: apply() on every tangent against apply_block() on the whole block.
    Eigen::MatrixXd images(c.d, k);
    for (Eigen::Index t = 0; t < k; ++t) jump.apply(c.tangents.col(t), images.col(t));
    const Eigen::MatrixXd block = jump.apply_block(c.tangents);
    // Relative to the largest image entry: for one surface apply_block sums eta . x in another
    // order than apply() (a block product), a few ulps apart.
    const double block_vs_apply =
        (block - images).cwiseAbs().maxCoeff() / std::max(1.0, images.cwiseAbs().maxCoeff());
    if (!images.allFinite()) throw CaseError("an image is not finite");

    Eigen::VectorXd image(c.d);
    long apply_calls = 0;
    const std::vector<double> apply_s = time_runs(
        repeat,
        [&](long calls) {
          Eigen::Index t = 0;
          for (long i = 0; i < calls; ++i) {
            jump.apply(c.tangents.col(t), image);
            if (++t == k) t = 0;
          }
        },
        &apply_calls);
    Eigen::MatrixXd block_out(c.d, k);
    long block_calls = 0;
    const std::vector<double> block_s = time_runs(
        repeat,
        [&](long calls) {
          for (long i = 0; i < calls; ++i) jump.apply_block(c.tangents, block_out);
        },
        &block_calls);

    // The JumpMap's construction (eta . Gamma(b) for every column, the rank and transversality
    // checks), which the timings above leave out.
    long construct_calls = 0;
    int sink = 0;
    const std::vector<double> construct_s = time_runs(
        repeat,
        [&](long calls) {
          for (long i = 0; i < calls; ++i) sink += bflow::JumpMap(c.normals, c.limits).dim();
        },
        &construct_calls);

    out["tool"] = "bflow";
    out["n"] = c.n;
    out["d"] = c.d;
    out["k"] = k;
    out["repeat"] = repeat;
    out["apply"] = timing_json(apply_s, 1.0, apply_calls);
    out["apply_block"] = timing_json(block_s, static_cast<double>(k), block_calls);
    out["construct"] = timing_json(construct_s, 0.0, construct_calls);
    out["block_vs_apply_max_rel_diff"] = block_vs_apply;
    // Keeps the timed results observable.
    out["checksum"] = image.sum() + block_out.sum() + sink;
    ordered_json list = ordered_json::array();
    for (Eigen::Index t = 0; t < std::min(k, kImagesReported); ++t) {
      list.push_back(std::vector<double>(images.col(t).data(), images.col(t).data() + c.d));
    }
    out["images"] = list;
  } catch (const CaseError& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 2;
  } catch (const bflow::InvalidArgument& e) {
    std::fprintf(stderr, "error: %s: %s\n", case_path.c_str(), e.what());
    return 2;
  }
  out["status"] = "ok";
  std::cout << out.dump() << "\n";
  return 0;
}

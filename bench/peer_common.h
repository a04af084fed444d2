// What bflow's problem programs of scripts/peers (peer_problems.cc, peer_flow.cc, peer_jump.cc)
// share: the process CPU clock they time with and vectors as JSON arrays.
#ifndef BFLOW_BENCH_PEER_COMMON_H_
#define BFLOW_BENCH_PEER_COMMON_H_

#include <time.h>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

namespace bflow_bench {

/** Process CPU time (user + system, every thread), in seconds. */
inline double process_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

/** The entries of v as a JSON array of numbers. */
inline nlohmann::ordered_json vector_json(const Eigen::Ref<const Eigen::VectorXd>& v) {
  nlohmann::ordered_json j = nlohmann::ordered_json::array();
  for (Eigen::Index i = 0; i < v.size(); ++i) j.push_back(v[i]);
  return j;
}

}  // namespace bflow_bench

#endif  // BFLOW_BENCH_PEER_COMMON_H_

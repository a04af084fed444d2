// FlowNotice: a decision the flow engine took for the user, or could not take, that changes how a
// result should be read. Notices never change the numbers; they say where the numbers deserve a
// second look.
//
//   bflow::FlowResult r = bflow::simulate(model, x0, t);
//   for (const bflow::FlowNotice& n : r.notices) std::cerr << "warning: " << n.message << '\n';
//
// Kinds.
//  * kNearSimultaneous: crossings of different surfaces that were NOT grouped into one event
//    (their located times are further apart than the grouping window) but closer than the
//    near-simultaneity band (FlowOptions::near_simultaneity_band times the automatic window).
//    The derivative treats them as separate crossings, which is right for perturbations that
//    shift the crossing times by less than `gap`; larger perturbations meet the other crossing
//    order. Tighten rtol to confirm that the gap is real, or group them (FlowOptions::grouping).
//  * kNearGrazing: a surface passed at a distance g_min > 0 within the band in which the
//    integrator's error could hide a crossing; whether it is crossed is undecided at this
//    tolerance.
#ifndef BFLOW_CORE_FLOW_NOTICE_H_
#define BFLOW_CORE_FLOW_NOTICE_H_

#include <string>
#include <vector>

namespace bflow {

struct FlowNotice {
  enum class Kind { kNearSimultaneous, kNearGrazing };
  Kind kind = Kind::kNearSimultaneous;
  /** The surfaces concerned (model indices). */
  std::vector<int> surfaces;
  /** kNearSimultaneous: the two crossing times; kNearGrazing: the time of closest approach. */
  std::vector<double> times;
  /** kNearSimultaneous: the time between the crossings; kNearGrazing: the closest distance g. */
  double gap = 0.0;
  /** The band that `gap` fell inside (a time, or a distance for kNearGrazing). */
  double band = 0.0;
  /** One line for a person, quoting the values. */
  std::string message;
};

/** "near-simultaneous" or "near-grazing". */
inline const char* to_string(FlowNotice::Kind kind) {
  return kind == FlowNotice::Kind::kNearSimultaneous ? "near-simultaneous" : "near-grazing";
}

}  // namespace bflow

#endif  // BFLOW_CORE_FLOW_NOTICE_H_

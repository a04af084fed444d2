// The state ScopedMumpsAmalgamation (linear_solver.h) sets for the dmumps_c interposer
// (mumps_fronts.cc, in builds with a MUMPS before 5.8). Private to fesd/.
#ifndef BFLOW_FESD_SRC_MUMPS_FRONTS_H_
#define BFLOW_FESD_SRC_MUMPS_FRONTS_H_

namespace bflow {
namespace fesd {

/** Whether this thread's analyses are to amalgamate small fronts (KEEP(197) = 1). */
bool mumps_amalgamation_wanted();
/** Counts one analysis the interposer set KEEP(197) for (mumps_amalgamated_analyses). */
void count_mumps_amalgamation();

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_SRC_MUMPS_FRONTS_H_

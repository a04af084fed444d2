// IPOPT calls MUMPS through dmumps_c, and a build with a MUMPS before 5.8 (Debian's 5.5.1 under
// IPOPT 3.11.9, the fallback) defines dmumps_c itself so that it can set what IPOPT 3.11 has no
// option for and that MUMPS 5.8 sets by default, the amalgamation of small fronts (linear_solver.h,
// ScopedMumpsAmalgamation): this definition, in the executable or the shared object that links
// bflow's static libraries, comes before Debian's libdmumps_seq in the dynamic linker's lookup
// and forwards every call to it. cmake/BflowIpopt.cmake leaves this file out of other builds.
#include <dlfcn.h>
#include <dmumps_c.h>

#include <cstdio>
#include <cstdlib>
#include <mutex>

#include "bflow/fesd/linear_solver.h"
#include "mumps_fronts.h"

namespace bflow {
namespace {

using DmumpsC = void (*)(DMUMPS_STRUC_C*);

DmumpsC next_dmumps_c() {
  static const DmumpsC next = reinterpret_cast<DmumpsC>(dlsym(RTLD_NEXT, "dmumps_c"));
  return next;
}

// KEEP(197) is MUMPS 5.5's switch for the amalgamation of small fronts (on by default from a
// later release); older versions may use the entry for something else.
bool takes_keep_197(const DMUMPS_STRUC_C& id) {
  int major = 0, minor = 0;
  if (std::sscanf(id.version_number, "%d.%d", &major, &minor) != 2) return false;
  return major > 5 || (major == 5 && minor >= 5);
}

}  // namespace
}  // namespace bflow

extern "C" void dmumps_c(DMUMPS_STRUC_C* id) {
  const bflow::DmumpsC next = bflow::next_dmumps_c();
  if (next == nullptr) {
    // Only a program that links this file without MUMPS gets here, and nothing can be solved.
    std::fputs("bflow: dmumps_c called, but no MUMPS library is loaded\n", stderr);
    std::abort();
  }
  // MUMPS's module variables are shared by its instances (bflow::ipopt_mutex).
  const std::lock_guard<std::recursive_mutex> lock(bflow::ipopt_mutex());
  const bool analysis = id->job == 1 || id->job == 4 || id->job == 6;
  if (analysis && bflow::fesd::mumps_amalgamation_wanted() && bflow::takes_keep_197(*id)) {
    id->keep[196] = 1;
    bflow::fesd::count_mumps_amalgamation();
  }
  next(id);
}

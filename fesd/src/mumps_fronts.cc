// IPOPT 3.11 calls MUMPS through dmumps_c, and bflow defines dmumps_c itself so that it can set
// what IPOPT has no option for (linear_solver.h, ScopedMumpsAmalgamation): this definition, in
// the executable or the shared object that links bflow's static libraries, comes before
// Debian's libdmumps_seq in the dynamic linker's lookup and forwards every call to it.
#include <dlfcn.h>
#include <dmumps_c.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <mutex>

#include "bflow/fesd/linear_solver.h"

namespace bflow {
namespace {

thread_local bool amalgamate = false;
std::atomic<long> amalgamated{0};

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

ScopedMumpsAmalgamation::ScopedMumpsAmalgamation(bool on) : previous_(amalgamate) {
  amalgamate = on;
}
ScopedMumpsAmalgamation::~ScopedMumpsAmalgamation() { amalgamate = previous_; }

long mumps_amalgamated_analyses() { return amalgamated.load(); }

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
  if (analysis && bflow::amalgamate && bflow::takes_keep_197(*id)) {
    id->keep[196] = 1;
    ++bflow::amalgamated;
  }
  next(id);
}

#include "bflow/fesd/linear_solver.h"

#include <dlfcn.h>

#include <mutex>
#include <string>

#include "bflow/core/text.h"

namespace bflow {
namespace {

struct SolverInfo {
  const char* name;
  const char* library;   // "" when linked into IPOPT
  const char* provider;  // whose library it is, for the message
  const char* title;     // the solver's own name
  // The first routine IPOPT 3.11's loader looks up for the solver (HSLLoader.c, PardisoLoader.c):
  // a file built without the solver lacks it.
  const char* routine;
};

constexpr SolverInfo kSolvers[] = {
    {"mumps", "", "", "MUMPS", ""},
    {"ma27", "libhsl.so", "HSL's", "MA27", "ma27ad"},
    {"ma57", "libhsl.so", "HSL's", "MA57", "ma57ad"},
    {"ma77", "libhsl.so", "HSL's", "HSL_MA77", "ma77_default_control_d"},
    {"ma86", "libhsl.so", "HSL's", "HSL_MA86", "ma86_default_control_d"},
    {"ma97", "libhsl.so", "HSL's", "HSL_MA97", "ma97_default_control_d"},
    {"pardiso", "libpardiso.so", "PARDISO's", "PARDISO", "pardiso"},
};
static_assert(sizeof(kSolvers) / sizeof(kSolvers[0]) ==
                  sizeof(kLinearSolvers) / sizeof(kLinearSolvers[0]),
              "every name of kLinearSolvers needs its library and routine here");

const SolverInfo& solver_info(const std::string& name, const std::string& who) {
  for (const SolverInfo& s : kSolvers) {
    if (name == s.name) return s;
  }
  throw InvalidArgument(who + ": unknown linear solver " + quote(name) + "; use " +
                        linear_solver_list());
}

}  // namespace

std::recursive_mutex& ipopt_mutex() {
  // Never destroyed: a thread may still solve while the process exits.
  static std::recursive_mutex* const mutex = new std::recursive_mutex;
  return *mutex;
}

std::string linear_solver_list() {
  std::string list;
  const std::size_t n = sizeof(kLinearSolvers) / sizeof(kLinearSolvers[0]);
  for (std::size_t i = 0; i < n; ++i) {
    list += (i == 0 ? "" : i + 1 == n ? " or " : ", ") + std::string(kLinearSolvers[i]);
  }
  return list;
}

std::string linear_solver_library(const std::string& name, const std::string& who) {
  return solver_info(name, who).library;
}

std::string linear_solver_load_error(const std::string& name, const std::string& library) {
  const SolverInfo& s = solver_info(name, "linear_solver_load_error");
  if (*s.routine == '\0') return "";
  const std::lock_guard<std::recursive_mutex> lock(ipopt_mutex());
  dlerror();  // clear an earlier error
  void* handle = dlopen(library.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (handle == nullptr) {
    const char* why = dlerror();
    return why != nullptr ? why : library + ": dlopen failed without a reason";
  }
  // IPOPT tries the name as it is and with the trailing underscore of gfortran's Fortran
  // routines; the C interfaces of HSL_MA77/86/97 have none.
  const std::string routine = s.routine;
  const bool found = dlsym(handle, routine.c_str()) != nullptr ||
                     dlsym(handle, (routine + "_").c_str()) != nullptr;
  dlclose(handle);
  if (found) return "";
  return library + " has no routine " + routine + " (nor " + routine + "_): it was built without " +
         s.title;
}

void check_linear_solver(const std::string& name, const std::string& who) {
  const SolverInfo& s = solver_info(name, who);
  if (*s.library == '\0') return;
  const std::string why = linear_solver_load_error(name, s.library);
  if (why.empty()) return;
  const bool hsl = std::string(s.library) == "libhsl.so";
  throw LinearSolverUnavailable(
      who + ": linear solver " + quote(name) + " needs " + s.provider + " " + s.library +
      ", which cannot be loaded (" + why + "); " +
      (hsl ? "get Coin-HSL (https://licences.stfc.ac.uk/product/coin-hsl), build libhsl.so and "
           : "") +
      "put the directory holding " + s.library +
      " on LD_LIBRARY_PATH (docs/ocp.md, \"Linear solvers: MUMPS and HSL\"), or use mumps");
}

}  // namespace bflow

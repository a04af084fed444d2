#include "bflow/fesd/linear_solver.h"

#include <dlfcn.h>

#include <atomic>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#include "bflow/core/text.h"
#include "ipopt_adapter.h"
#include "mumps_fronts.h"

namespace bflow {
namespace {

enum class Source { kLinked, kHsl, kPardiso };

struct SolverInfo {
  const char* name;
  Source source;
  const char* title;  // the solver's own name
  // The first routine IPOPT's loader looks up for the solver (HSLLoader.c, PardisoLoader.c):
  // a file built without the solver lacks it.
  const char* routine;
};

constexpr SolverInfo kSolvers[] = {
    {"mumps", Source::kLinked, "MUMPS", ""},
    {"spral", Source::kLinked, "SPRAL", ""},
    {"ma27", Source::kHsl, "MA27", "ma27ad"},
    {"ma57", Source::kHsl, "MA57", "ma57ad"},
    {"ma77", Source::kHsl, "HSL_MA77", "ma77_default_control_d"},
    {"ma86", Source::kHsl, "HSL_MA86", "ma86_default_control_d"},
    {"ma97", Source::kHsl, "HSL_MA97", "ma97_default_control_d"},
    {"pardiso", Source::kPardiso, "PARDISO", "pardiso"},
    {"pardisomkl", Source::kLinked, "MKL's PARDISO", ""},
};
static_assert(sizeof(kSolvers) / sizeof(kSolvers[0]) ==
                  sizeof(kLinearSolvers) / sizeof(kLinearSolvers[0]),
              "every name of kLinearSolvers needs its source and routine here");

const SolverInfo& solver_info(const std::string& name, const std::string& who) {
  for (const SolverInfo& s : kSolvers) {
    if (name == s.name) return s;
  }
  throw InvalidArgument(who + ": unknown linear solver " + quote(name) + "; use " +
                        linear_solver_list());
}

std::vector<std::string> default_libraries(const SolverInfo& s) {
  if (s.source == Source::kHsl) {
    if (fesd::ipopt_names_solver_libraries()) return {"libcoinhsl.so", "libhsl.so"};
    return {"libhsl.so"};
  }
  if (s.source == Source::kPardiso) return {"libpardiso.so"};
  return {};
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
  std::string out;
  for (const std::string& file : default_libraries(solver_info(name, who))) {
    out += (out.empty() ? "" : " ") + file;
  }
  return out;
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

std::string check_linear_solver(const std::string& name, const std::string& library,
                                const std::string& who) {
  const SolverInfo& s = solver_info(name, who);
  if (s.source == Source::kLinked) {
    if (!library.empty()) {
      throw InvalidArgument(who + ": linear solver " + quote(name) + " is linked into IPOPT; " +
                            "it takes no library (" + quote(library) + ")");
    }
    if (!fesd::ipopt_takes_linear_solver(name)) {
      throw LinearSolverUnavailable(
          who + ": linear solver " + quote(name) + " (" + s.title + ") is not in this build's " +
          ipopt_description() +
          (name == "spral" ? "; configure with -DBFLOW_IPOPT=wheel (IPOPT 3.14 with SPRAL, "
                             "scripts/install-deps)"
                           : "; it needs an IPOPT built with Intel MKL") +
          ", or use mumps");
    }
    return "";
  }
  if (!library.empty() && !fesd::ipopt_names_solver_libraries()) {
    throw InvalidArgument(who + ": this build's " + ipopt_description() +
                          " loads its linear solvers from fixed names (libhsl.so, "
                          "libpardiso.so) and cannot load " +
                          quote(library) + "; configure with -DBFLOW_IPOPT=wheel for IPOPT 3.14");
  }
  const std::vector<std::string> files =
      library.empty() ? default_libraries(s) : std::vector<std::string>{library};
  std::string why;
  for (const std::string& file : files) {
    const std::string error = linear_solver_load_error(name, file);
    if (error.empty()) return file;
    if (why.empty()) why = error;
  }
  const bool hsl = s.source == Source::kHsl;
  std::string named = files[0];
  for (std::size_t k = 1; k < files.size(); ++k) named += " (or " + files[k] + ")";
  const std::string get =
      hsl ? "get Coin-HSL (https://licences.stfc.ac.uk/product/coin-hsl) and " : "";
  const std::string hint =
      !library.empty()
          ? "name a library that holds " + std::string(s.title)
          : get + "put the directory holding " + files[0] + " on LD_LIBRARY_PATH" +
                (fesd::ipopt_names_solver_libraries()
                     ? " or name the file (linear_solver_library, --linear-solver-library)"
                     : "");
  throw LinearSolverUnavailable(who + ": linear solver " + quote(name) + " needs " +
                                (hsl ? "HSL's " : "PARDISO's ") + named +
                                ", which cannot be loaded (" + why + "); " + hint +
                                " (docs/ocp.md, \"Linear solvers\"), or use mumps");
}

std::string check_linear_solver(const std::string& name, const std::string& who) {
  return check_linear_solver(name, "", who);
}

std::string ipopt_description() { return std::string("IPOPT ") + fesd::ipopt_version(); }

std::string linear_solver_description(const std::string& name, const std::string& library) {
  if (name == "mumps") {
    const std::string version = fesd::mumps_version();
    return version.empty() ? "mumps" : "mumps " + version;
  }
  if (!library.empty()) return name + " (" + library + ")";
  return name + " (" + ipopt_description() + "'s)";
}

// --- MUMPS's small fronts (linear_solver.h; the interposer is mumps_fronts.cc) ---

namespace {
thread_local bool amalgamate = false;
std::atomic<long> amalgamated{0};
}  // namespace

ScopedMumpsAmalgamation::ScopedMumpsAmalgamation(bool on) : previous_(amalgamate) {
  amalgamate = on;
}
ScopedMumpsAmalgamation::~ScopedMumpsAmalgamation() { amalgamate = previous_; }

long mumps_amalgamated_analyses() { return amalgamated.load(); }

namespace fesd {
bool mumps_amalgamation_wanted() { return amalgamate; }
void count_mumps_amalgamation() { ++amalgamated; }
}  // namespace fesd

}  // namespace bflow

#include "bflow/fesd/linear_solver.h"

#include <dlfcn.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <atomic>
#include <cmath>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#include "bflow/core/text.h"
#include "ipopt_adapter.h"
#include "mumps_fronts.h"

// A sanitizer's allocator replaces malloc: its settings are not glibc's (keep_freed_memory).
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define BFLOW_OWN_ALLOCATOR 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(memory_sanitizer) || \
    __has_feature(thread_sanitizer)
#define BFLOW_OWN_ALLOCATOR 1
#endif
#endif

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

// --- The BLAS under MUMPS (linear_solver.h) ---

namespace {

struct OpenBlas {
  void (*set)(int) = nullptr;
  int (*get)() = nullptr;
};

std::string base_name(const std::string& path) {
  const std::size_t slash = path.rfind('/');
  return slash == std::string::npos ? path : path.substr(slash + 1);
}

// The library that defines `symbol` at `address` and the same symbol `name` in it, or null.
void* symbol_in_same_library(void* address, const char* name) {
  Dl_info where{};
  if (address == nullptr || dladdr(address, &where) == 0 || where.dli_fname == nullptr)
    return nullptr;
  // RTLD_NOLOAD: a handle to the library already loaded (never a new load); kept open, so the
  // pointers stay valid.
  void* handle = dlopen(where.dli_fname, RTLD_LAZY | RTLD_NOLOAD);
  if (handle == nullptr) return nullptr;
  void* found = dlsym(handle, name);
  Dl_info other{};
  // dlsym on a handle also searches the library's dependencies: only the library's own.
  if (found == nullptr || dladdr(found, &other) == 0 || other.dli_fbase != where.dli_fbase) {
    return nullptr;
  }
  return found;
}

struct BlasState {
  BlasInfo info;
  OpenBlas openblas;
};

BlasState find_blas() {
  BlasState state;
  void* dgemm = dlsym(RTLD_DEFAULT, "dgemm_");
  if (dgemm == nullptr) {
    // A library loaded with RTLD_LOCAL (a Python extension): IPOPT's own dependencies.
    void* ipopt = dlopen(fesd::ipopt_library_file(), RTLD_LAZY | RTLD_NOLOAD);
    if (ipopt != nullptr) dgemm = dlsym(ipopt, "dgemm_");
  }
  Dl_info where{};
  if (dgemm == nullptr || dladdr(dgemm, &where) == 0 || where.dli_fname == nullptr) return state;
  state.info.file = base_name(where.dli_fname);
  state.openblas.set =
      reinterpret_cast<void (*)(int)>(symbol_in_same_library(dgemm, "openblas_set_num_threads"));
  state.openblas.get =
      reinterpret_cast<int (*)()>(symbol_in_same_library(dgemm, "openblas_get_num_threads"));
  const auto config =
      reinterpret_cast<char* (*)()>(symbol_in_same_library(dgemm, "openblas_get_config"));
  if (state.openblas.set == nullptr || state.openblas.get == nullptr) {
    state.openblas = OpenBlas{};
    return state;
  }
  state.info.threads_settable = true;
  state.info.version = "OpenBLAS";
  if (config != nullptr) {
    // "OpenBLAS 0.3.28 DYNAMIC_ARCH NO_AFFINITY Haswell MAX_THREADS=64": its first two words.
    std::istringstream words(config());
    std::string name, version;
    if (words >> name >> version) state.info.version = name + " " + version;
  }
  return state;
}

const BlasState& blas_state() {
  static const BlasState state = find_blas();
  return state;
}

}  // namespace

const BlasInfo& blas_info() { return blas_state().info; }

void check_blas_threads(int threads, const std::string& who) {
  if (threads < 0) {
    throw InvalidArgument(who + ": blas_threads = " + std::to_string(threads) +
                          " must be >= 0 (0: OpenBLAS's own count)");
  }
}

void check_solver_options(const SolverOptions& s, bool exact_hessian, const std::string& who) {
  if (s.print_level < 0 || s.print_level > 12) {
    throw InvalidArgument(who + ": print_level = " + std::to_string(s.print_level) +
                          " is not one of IPOPT's levels 0..12");
  }
  if (!std::isfinite(s.exact_hessian_scale) || (s.exact_hessian_scale != 1.0 && !exact_hessian)) {
    throw InvalidArgument(who + ": exact_hessian_scale = " + format_number(s.exact_hessian_scale) +
                          (std::isfinite(s.exact_hessian_scale)
                               ? " scales the exact Hessian, but exact_hessian is off"
                               : " must be finite"));
  }
  check_blas_threads(s.blas_threads, who);
  check_linear_solver(s.linear_solver, s.linear_solver_library, who);
}

bool keep_freed_memory() {
#if defined(__GLIBC__) && !defined(BFLOW_OWN_ALLOCATOR)
  static const bool kept = [] {
    return mallopt(M_MMAP_MAX, 0) == 1 && mallopt(M_TRIM_THRESHOLD, 512 << 20) == 1;
  }();
  return kept;
#else
  return false;
#endif
}

int blas_threads() {
  const OpenBlas& b = blas_state().openblas;
  return b.get != nullptr ? b.get() : 0;
}

ScopedBlasThreads::ScopedBlasThreads(int threads) {
  const OpenBlas& b = blas_state().openblas;
  if (threads <= 0 || b.set == nullptr) return;
  previous_ = b.get();
  if (previous_ != threads) b.set(threads);
}

ScopedBlasThreads::~ScopedBlasThreads() {
  const OpenBlas& b = blas_state().openblas;
  if (previous_ > 0 && b.get() != previous_) b.set(previous_);
}

std::string blas_description(int threads) {
  const BlasInfo& info = blas_info();
  if (info.file.empty()) return "";
  if (!info.threads_settable) return info.file;
  const int count = threads > 0 ? threads : blas_threads();
  return info.version + ", " + std::to_string(count) + (count == 1 ? " thread" : " threads") +
         (threads > 0 ? "" : " (its own count)") + " (" + info.file + ")";
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

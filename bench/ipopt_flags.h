// IPOPT options from a benchmark's command line, and IPOPT's own counts read back from its log
// (bench/monoped_benchmark.cc, bench/ocp_benchmark.cc, scripts/kkt_study).
//
//   --ipopt-int=name=value   --ipopt-num=name=value   --ipopt-str=name=value   (repeatable)
//
// take_ipopt_flags() removes them from argv (before benchmark::Initialize) and apply_to() appends
// them to OcpOptions::solver.ipopt_*_options, which ocp_solve applies after its own options, so
// they win. A malformed flag prints an error naming it and exits with status 2.
//
// IpoptLog sends IPOPT's output to a temporary file (output_file, file_print_level 6,
// print_timing_statistics yes) and reads back, summed over every NLP the solve ran:
//   trial_factorizations  the k of every "Number of trial factorizations performed: k" line
//                         (PDFullSpaceSolver: the factorizations of one search direction,
//                         inertia corrections included)
//   factorizations        MUMPS's numeric factorizations: its "Number of doubles for MUMPS to
//                         hold factorization (INFO(9))" lines, one per factorization (also the
//                         ones of the initial multipliers and of pivtol raises)
//   factorization         CPU seconds in them. IPOPT 3.11.9's MUMPS interface leaves the timer
//                         LinearSystemFactorization at 0 (only MA27/MA57 start it), so this is
//                         StdAugSystemSolverMultiSolve minus LinearSystemBackSolve,
//                         LinearSystemSymbolicFactorization, LinearSystemScaling and
//                         LinearSystemStructureConverter (checked against MUMPS's own calls
//                         with bench/tools/mumps_timer.c)
//   symbolic, hessian ("Lagrangian Hessian" of the function evaluations), functions
//                         (all "Function Evaluations": objective, constraints, their
//                         derivatives and the Hessian), overall (OverallAlgorithm): CPU seconds
//                         of those timing-statistics lines
//   variables, equalities, inequalities, jacobian_nonzeros (equality + inequality),
//   hessian_nonzeros      the NLP as IPOPT sees it (fixed variables removed), from the first
//                         NLP's problem statistics
// Every time read is IPOPT's user time plus its "sys:" time (process CPU time).
// The file is deleted when the IpoptLog is destroyed (unless BFLOW_KEEP_IPOPT_LOG=1).
#pragma once

#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include "bflow/ocp/ocp.h"

namespace bflow_bench {

struct IpoptFlags {
  std::vector<std::pair<std::string, std::string>> strings;
  std::vector<std::pair<std::string, double>> numbers;
  std::vector<std::pair<std::string, int>> integers;

  bool empty() const { return strings.empty() && numbers.empty() && integers.empty(); }

  void apply_to(bflow::OcpOptions& o) const {
    o.solver.ipopt_string_options.insert(o.solver.ipopt_string_options.end(), strings.begin(),
                                         strings.end());
    o.solver.ipopt_numeric_options.insert(o.solver.ipopt_numeric_options.end(), numbers.begin(),
                                          numbers.end());
    o.solver.ipopt_integer_options.insert(o.solver.ipopt_integer_options.end(), integers.begin(),
                                          integers.end());
  }

  // "name=value, ..." for a benchmark's context.
  std::string describe() const {
    std::string s;
    const auto add = [&s](const std::string& name, const std::string& value) {
      if (!s.empty()) s += ", ";
      s += name + "=" + value;
    };
    for (const auto& [n, v] : strings) add(n, v);
    for (const auto& [n, v] : numbers) {
      char buf[64];
      std::snprintf(buf, sizeof buf, "%g", v);
      add(n, buf);
    }
    for (const auto& [n, v] : integers) add(n, std::to_string(v));
    return s;
  }
};

[[noreturn]] inline void bad_ipopt_flag(const std::string& arg, const std::string& why) {
  std::fprintf(stderr, "error: malformed IPOPT option flag '%s': %s\n", arg.c_str(), why.c_str());
  std::exit(2);
}

// Removes every --ipopt-int/--ipopt-num/--ipopt-str=name=value from argv (argc updated).
inline IpoptFlags take_ipopt_flags(int& argc, char** argv) {
  IpoptFlags flags;
  int kept = 1;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    std::string kind;
    for (const char* k : {"int", "num", "str"}) {
      const std::string prefix = std::string("--ipopt-") + k;
      if (arg.compare(0, prefix.size(), prefix) == 0) kind = k;
    }
    if (kind.empty() && arg.compare(0, 7, "--ipopt") == 0) {
      bad_ipopt_flag(arg, "expected --ipopt-int=, --ipopt-num= or --ipopt-str=name=value");
    }
    if (kind.empty()) {
      argv[kept++] = argv[i];
      continue;
    }
    const std::string prefix = "--ipopt-" + kind + "=";
    if (arg.compare(0, prefix.size(), prefix) != 0) {
      bad_ipopt_flag(arg, "expected " + prefix + "name=value");
    }
    const std::string body = arg.substr(prefix.size());
    const std::size_t eq = body.find('=');
    if (eq == std::string::npos || eq == 0 || eq + 1 == body.size()) {
      bad_ipopt_flag(arg, "expected " + prefix + "name=value with a name and a value");
    }
    const std::string name = body.substr(0, eq), value = body.substr(eq + 1);
    if (kind == "str") {
      flags.strings.emplace_back(name, value);
    } else if (kind == "num") {
      char* end = nullptr;
      errno = 0;
      const double v = std::strtod(value.c_str(), &end);
      if (end != value.c_str() + value.size() || errno != 0) {
        bad_ipopt_flag(arg, "'" + value + "' is not a number");
      }
      flags.numbers.emplace_back(name, v);
    } else {
      char* end = nullptr;
      errno = 0;
      const long v = std::strtol(value.c_str(), &end, 10);
      if (end != value.c_str() + value.size() || errno != 0 || v < -2147483647L ||
          v > 2147483647L) {
        bad_ipopt_flag(arg, "'" + value + "' is not an integer");
      }
      flags.integers.emplace_back(name, static_cast<int>(v));
    }
  }
  argv[kept] = nullptr;
  argc = kept;
  return flags;
}

// What IPOPT's log says about one solve (sums over its NLPs).
struct IpoptCounts {
  int nlps = 0;                   // timing-statistics blocks seen
  long trial_factorizations = 0;  // summed "Number of trial factorizations performed"
  long factorizations = 0;        // MUMPS numeric factorizations (INFO(9) lines)
  double factorization = 0.0;     // CPU seconds, see above
  double multi_solve = 0.0, back_solve = 0.0, scaling = 0.0, converter = 0.0;
  double symbolic = 0.0, hessian = 0.0, functions = 0.0, overall = 0.0;  // CPU seconds
  long variables = -1, equalities = -1, inequalities = -1;               // -1: not in the log
  long jacobian_nonzeros = -1, hessian_nonzeros = -1;
};

// The split of an IPOPT solve's CPU (`cpu` seconds over `iterations` IPOPT iterations) from its
// log: KKT factorisations per iteration (IPOPT's trial factorisations, and every MUMPS numeric
// factorisation), seconds per factorisation, the Hessian and the rest per iteration.
template <typename State>
void split_counters(State& state, const IpoptCounts& c, int iterations, double cpu) {
  if (iterations <= 0) return;
  const double it = iterations;
  state.counters["factorizations_per_iteration"] = static_cast<double>(c.trial_factorizations) / it;
  state.counters["mumps_factorizations_per_iteration"] = static_cast<double>(c.factorizations) / it;
  state.counters["seconds_per_factorization"] =
      c.factorizations > 0 ? c.factorization / static_cast<double>(c.factorizations) : 0.0;
  state.counters["hessian_seconds_per_iteration"] = c.hessian / it;
  state.counters["rest_seconds_per_iteration"] = (cpu - c.factorization - c.hessian) / it;
}

class IpoptLog {
 public:
  IpoptLog() {
    char name[] = "/tmp/bflow_ipopt_XXXXXX";
    const int fd = mkstemp(name);
    if (fd < 0) {
      std::perror("mkstemp");
      std::exit(1);
    }
    close(fd);
    path_ = name;
  }
  // BFLOW_KEEP_IPOPT_LOG=1 in the environment keeps the file (its path goes to stderr).
  ~IpoptLog() {
    const char* keep = std::getenv("BFLOW_KEEP_IPOPT_LOG");
    if (keep != nullptr && std::string(keep) == "1") {
      std::fprintf(stderr, "IPOPT log kept: %s\n", path_.c_str());
    } else {
      std::remove(path_.c_str());
    }
  }
  IpoptLog(const IpoptLog&) = delete;
  IpoptLog& operator=(const IpoptLog&) = delete;

  const std::string& path() const { return path_; }

  // Put before the command-line flags, so that those still win.
  void apply_to(bflow::OcpOptions& o) const {
    o.solver.ipopt_string_options.emplace_back("output_file", path_);
    o.solver.ipopt_integer_options.emplace_back("file_print_level", 6);
    o.solver.ipopt_string_options.emplace_back("print_timing_statistics", "yes");
  }

  IpoptCounts read() const {
    IpoptCounts c;
    std::ifstream in(path_);
    std::string line;
    const auto trimmed = [](const std::string& s) {
      const std::size_t a = s.find_first_not_of(' ');
      return a == std::string::npos ? std::string() : s.substr(a);
    };
    // "Name....: user (sys: sys wall: wall)": user + sys, the process CPU time (IPOPT 3.11.9
    // reports user time first; MUMPS's allocations make sys time a tenth of a factorization).
    const auto after_colon = [](const std::string& s) {
      const std::size_t colon = s.find(':');
      if (colon == std::string::npos) return 0.0;
      double t = std::strtod(s.c_str() + colon + 1, nullptr);
      const std::size_t sys = s.find("(sys:", colon);
      if (sys != std::string::npos) t += std::strtod(s.c_str() + sys + 5, nullptr);
      return t;
    };
    const auto starts = [](const std::string& s, const char* p) {
      return s.compare(0, std::char_traits<char>::length(p), p) == 0;
    };
    // "Name....: count" of the first NLP's problem statistics.
    const auto first_count = [](long& field, const std::string& s) {
      if (field < 0) field = std::strtol(s.c_str() + s.find(':') + 1, nullptr, 10);
    };
    long jacobian_equalities = -1, jacobian_inequalities = -1;
    while (std::getline(in, line)) {
      const std::string t = trimmed(line);
      if (starts(t, "Total number of variables.")) {
        first_count(c.variables, t);
      } else if (starts(t, "Total number of equality constraints.")) {
        first_count(c.equalities, t);
      } else if (starts(t, "Total number of inequality constraints.")) {
        first_count(c.inequalities, t);
      } else if (starts(t, "Number of nonzeros in equality constraint Jacobian.")) {
        first_count(jacobian_equalities, t);
      } else if (starts(t, "Number of nonzeros in inequality constraint Jacobian.")) {
        first_count(jacobian_inequalities, t);
      } else if (starts(t, "Number of nonzeros in Lagrangian Hessian.")) {
        first_count(c.hessian_nonzeros, t);
      } else if (starts(t, "Function Evaluations.")) {
        c.functions += after_colon(t);
      } else if (starts(t, "Number of trial factorizations performed:")) {
        c.trial_factorizations += std::strtol(t.c_str() + t.find(':') + 1, nullptr, 10);
      } else if (starts(t, "Number of doubles for MUMPS to hold factorization")) {
        ++c.factorizations;
      } else if (starts(t, "StdAugSystemSolverMultiSolve.")) {
        c.multi_solve += after_colon(t);
      } else if (starts(t, "LinearSystemBackSolve.")) {
        c.back_solve += after_colon(t);
      } else if (starts(t, "LinearSystemScaling.")) {
        c.scaling += after_colon(t);
      } else if (starts(t, "LinearSystemStructureConverter.")) {
        c.converter += after_colon(t);
      } else if (starts(t, "LinearSystemSymbolicFactorization.")) {
        c.symbolic += after_colon(t);
      } else if (starts(t, "Lagrangian Hessian.")) {
        c.hessian += after_colon(t);
      } else if (starts(t, "OverallAlgorithm.")) {
        c.overall += after_colon(t);
        ++c.nlps;
      }
    }
    c.factorization = c.multi_solve - c.back_solve - c.symbolic - c.scaling - c.converter;
    if (jacobian_equalities >= 0 && jacobian_inequalities >= 0) {
      c.jacobian_nonzeros = jacobian_equalities + jacobian_inequalities;
    }
    return c;
  }

 private:
  std::string path_;
};

// The paths of the loaded libraries whose file names contain `name` (e.g. "libblas.so"), from
// /proc/self/maps, comma separated: which BLAS and LAPACK this run really uses.
inline std::string loaded_library(const std::string& name) {
  std::ifstream maps("/proc/self/maps");
  std::string line, found;
  while (std::getline(maps, line)) {
    const std::size_t slash = line.find('/');
    if (slash == std::string::npos) continue;
    const std::string path = line.substr(slash);
    const std::size_t base = path.rfind('/');
    if (path.find(name, base) == std::string::npos) continue;
    if (found.find(path) != std::string::npos) continue;
    if (!found.empty()) found += ",";
    found += path;
  }
  return found.empty() ? "(not loaded)" : found;
}

}  // namespace bflow_bench

#include "demo_util.h"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <system_error>

#include "bflow/core/errors.h"
#include "cli_util.h"

extern char** environ;  // NOLINT: POSIX, for posix_spawnp

namespace bflow::cli {

namespace fs = std::filesystem;

std::string vector_text(const Eigen::Ref<const Eigen::VectorXd>& v) {
  std::string text = "(";
  for (Eigen::Index i = 0; i < v.size(); ++i) {
    const double shown = std::fabs(v[i]) < 5e-7 ? 0.0 : v[i];
    text += formatted("%9.6f", shown) + (i + 1 < v.size() ? ", " : ")");
  }
  return text;
}

std::string order_text(const std::vector<int>& order) {
  std::string text = "(";
  for (std::size_t k = 0; k < order.size(); ++k) {
    text += std::to_string(order[k]) + (k + 1 < order.size() ? "," : ")");
  }
  return text;
}

bool print_checks(std::ostream& out, const std::vector<Check>& checks) {
  out << "\nChecks against independent computations (value against its bound):\n";
  bool all_passed = true;
  for (const Check& check : checks) {
    const bool passed = check.lower_bound ? check.value >= check.bound : check.value <= check.bound;
    all_passed = all_passed && passed;
    const char* relation = check.lower_bound ? (passed ? ">=" : "< ") : (passed ? "<=" : "> ");
    out << formatted("  %-6s %.1e %s %.0e  %s\n", passed ? "ok" : "FAILED", check.value, relation,
                     check.bound, check.what.c_str());
  }
  out << (all_passed ? "All checks passed.\n" : "SOME CHECKS FAILED.\n");
  return all_passed;
}

namespace {

// A directory can exist and still refuse files (permissions, a read-only or virtual file system
// such as /proc); creating one is the only test that holds for every cause. The probe is removed
// at once. @throws DemoError naming the directory and errno's text.
void probe_directory(const fs::path& dir, const std::string& command) {
  const fs::path probe = dir / (".bflow-" + command + "-probe-" + std::to_string(::getpid()));
  const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0) {
    throw DemoError(command + ": cannot write in directory " + quote(dir.string(), 200) + ": " +
                    std::strerror(errno));
  }
  ::close(fd);
  ::unlink(probe.c_str());
}

}  // namespace

void prepare_output_directory(const fs::path& dir, const std::string& command) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir)) {
    throw DemoError(command + ": cannot create directory " + quote(dir.string(), 200) + ": " +
                    (ec ? ec.message() : std::string("a file of that name exists")));
  }
  probe_directory(dir, command);
}

void check_writable_file(const fs::path& path, const std::string& command) {
  check_replaceable_file(path, command);
  const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
  std::error_code ec;
  const fs::file_status status = fs::status(dir, ec);
  if (!fs::is_directory(status)) {
    throw DemoError(command + ": cannot write " + quote(path.string(), 200) + ": " +
                    (fs::exists(status)
                         ? "its directory " + quote(dir.string(), 200) + " is not a directory"
                         : "its directory " + quote(dir.string(), 200) + " does not exist"));
  }
  probe_directory(dir, command);
}

fs::path resolved(const fs::path& path) {
  std::error_code code;
  fs::path p = fs::absolute(path, code);
  for (int links = 0; links < 40 && fs::is_symlink(fs::symlink_status(p, code)); ++links) {
    const fs::path target = fs::read_symlink(p, code);
    if (code) break;
    p = target.is_absolute() ? target : p.parent_path() / target;
  }
  const fs::path canonical = fs::weakly_canonical(p, code);
  return code ? p.lexically_normal() : canonical;
}

bool same_file(const fs::path& a, const fs::path& b) {
  if (resolved(a) == resolved(b)) return true;
  std::error_code code;
  return fs::exists(a, code) && fs::exists(b, code) && fs::equivalent(a, b, code) && !code;
}

namespace {

// A name in the same directory as `path` for a file that is renamed onto it once whole: its
// first part says what it is, the process and a counter make it unique.
fs::path temporary_beside(const fs::path& path, const std::string& extension = ".tmp") {
  static std::atomic<unsigned> counter{0};
  const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
  return dir /
         (".bflow-" + std::to_string(::getpid()) + "-" + std::to_string(counter++) + extension);
}

}  // namespace

void check_replaceable_file(const fs::path& path, const std::string& command) {
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (!fs::exists(status) || fs::is_regular_file(status)) return;
  throw DemoError(command + ": " + quote(path.string(), 200) +
                  " exists and is not a regular file; it is not replaced (remove it or name "
                  "another output)");
}

void write_file(const fs::path& path, const std::string& contents, const std::string& command) {
  check_replaceable_file(path, command);
  const fs::path temporary = temporary_beside(path);
  std::error_code ec;
  errno = 0;
  std::ofstream file(temporary, std::ios::binary | std::ios::trunc);
  if (file) file << contents;
  if (file) file.close();
  if (!file) {
    const std::string why = errno != 0 ? std::strerror(errno) : "an I/O error";
    fs::remove(temporary, ec);
    throw DemoError(command + ": cannot write " + quote(path.string(), 200) + ": " + why);
  }
  fs::rename(temporary, path, ec);
  if (ec) {
    std::error_code ignored;
    fs::remove(temporary, ignored);
    throw DemoError(command + ": cannot write " + quote(path.string(), 200) + ": " + ec.message());
  }
}

void run_gnuplot(const fs::path& dir, const std::string& script, const std::string& png,
                 const std::string& command_name, const std::string& without_plot) {
  const std::string command =
      "gnuplot " + script + " (in directory " + quote(dir.string(), 200) + ")";
  check_replaceable_file(dir / png, command_name);
  // gnuplot draws into a temporary file (the scripts set their output to bflow_output when it
  // is defined), renamed onto the PNG once gnuplot has succeeded: a failed plot leaves the
  // previous PNG, if any, as it was, and a stale plot never passes for a new one.
  const fs::path temporary = temporary_beside(dir / png, ".png");
  const std::string output_name = temporary.filename().string();
  std::error_code ec;
  struct Cleanup {
    fs::path path;
    ~Cleanup() {
      std::error_code ignored;
      if (!path.empty()) fs::remove(path, ignored);
    }
  } cleanup{temporary};
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addchdir_np(&actions, dir.c_str());
  // bflow ignores SIGPIPE (a closed pipe is reported as a failed write); gnuplot gets the
  // default back.
  posix_spawnattr_t attributes;
  posix_spawnattr_init(&attributes);
  sigset_t default_signals;
  sigemptyset(&default_signals);
  sigaddset(&default_signals, SIGPIPE);
  posix_spawnattr_setsigdefault(&attributes, &default_signals);
  posix_spawnattr_setflags(&attributes, POSIX_SPAWN_SETSIGDEF);
  std::string program = "gnuplot";
  std::string option = "-e";
  std::string assignment = "bflow_output='" + output_name + "'";
  std::string script_arg = script;
  char* argv[] = {program.data(), option.data(), assignment.data(), script_arg.data(), nullptr};
  pid_t pid = 0;
  const int spawn_error = posix_spawnp(&pid, program.c_str(), &actions, &attributes, argv, environ);
  posix_spawn_file_actions_destroy(&actions);
  posix_spawnattr_destroy(&attributes);
  if (spawn_error != 0) {
    throw DemoError(command_name + ": cannot run " + command + ": " + std::strerror(spawn_error) +
                    "; install gnuplot (Debian: gnuplot-nox) or " + without_plot);
  }
  int status = 0;
  while (waitpid(pid, &status, 0) < 0) {
    if (errno != EINTR) {
      throw DemoError(command_name + ": waiting for " + command +
                      " failed: " + std::strerror(errno));
    }
  }
  if (WIFSIGNALED(status)) {
    throw DemoError(command_name + ": " + command + " was killed by signal " +
                    std::to_string(WTERMSIG(status)));
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    throw DemoError(command_name + ": " + command + " failed with exit status " +
                    std::to_string(WEXITSTATUS(status)) + " (gnuplot's message is above)");
  }
  const auto size = fs::file_size(temporary, ec);
  if (ec || size == 0) {
    throw DemoError(command_name + ": " + command + " exited normally but did not write " + png);
  }
  fs::rename(temporary, dir / png, ec);
  if (ec) {
    throw DemoError(command_name + ": cannot write " + quote((dir / png).string(), 200) + ": " +
                    ec.message());
  }
  cleanup.path.clear();
}

std::string gnuplot_output(const std::string& png) {
  std::string quoted;
  for (char c : png) quoted += c == '\'' ? std::string("''") : std::string(1, c);
  return "set output (exists('bflow_output') ? bflow_output : '" + quoted + "')\n";
}

void write_samples(std::ostream& out, const std::vector<Sample>& samples) {
  for (const Sample& s : samples) {
    out << formatted("%9.4f", s.angle_deg) << ' ' << format_number(s.dx[0]) << ' '
        << format_number(s.dx[1]) << ' ' << format_number(s.image[0]) << ' '
        << format_number(s.image[1]) << ' ' << s.piece << '\n';
  }
}

}  // namespace bflow::cli

// A harness's scratch directory: every file a fuzzed command line writes goes there, never into
// the repository or the working directory. Created under ${TMPDIR:-/tmp} at the first input,
// emptied before each input (so that no input depends on the ones before), removed when the
// process exits and before a contract violation aborts.
#ifndef BFLOW_TESTS_FUZZ_FUZZ_SCRATCH_H_
#define BFLOW_TESTS_FUZZ_FUZZ_SCRATCH_H_

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <system_error>
#include <vector>

#include "fuzz/fuzz_contract.h"

namespace bflow::fuzz {

class ScratchDir {
 public:
  /** Creates ${TMPDIR:-/tmp}/bflow-fuzz-<name>.XXXXXX; aborts when it cannot. */
  explicit ScratchDir(const std::string& name) {
    const char* tmp = std::getenv("TMPDIR");
    std::string pattern = std::string(tmp != nullptr && *tmp != '\0' ? tmp : "/tmp") +
                          "/bflow-fuzz-" + name + ".XXXXXX";
    std::vector<char> buffer(pattern.begin(), pattern.end());
    buffer.push_back('\0');
    if (::mkdtemp(buffer.data()) == nullptr) {
      std::fprintf(stderr, "fuzz harness: cannot create a directory %s\n", pattern.c_str());
      std::abort();
    }
    path_ = buffer.data();
  }
  ~ScratchDir() { remove(); }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;

  const std::string& path() const { return path_; }

  /** Removes everything in the directory (it stays). */
  void clear() const {
    std::error_code ec;
    for (const auto& entry : std::filesystem::directory_iterator(path_, ec)) {
      std::filesystem::remove_all(entry.path(), ec);
    }
  }

  /** Removes the directory and everything in it. */
  void remove() {
    if (path_.empty()) return;
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
    path_.clear();
  }

  /** `value` as a path inside the directory: its components joined under it without the empty
      ones, "." and "..", so that no fuzzed name leaves it (every other byte is kept). A value
      ending in '/' (or empty) names the directory itself, with the '/'. */
  std::string confine(const std::string& value) const {
    std::string result = path_;
    std::size_t begin = 0;
    while (begin <= value.size()) {
      std::size_t end = value.find('/', begin);
      if (end == std::string::npos) end = value.size();
      const std::string part = value.substr(begin, end - begin);
      if (!part.empty() && part != "." && part != "..") result += "/" + part;
      begin = end + 1;
    }
    if (value.empty() || value.back() == '/') result += '/';
    return result;
  }

  /** Writes `bytes` to `name` in the directory; aborts when it cannot. */
  void write(const std::string& name, const std::string& bytes) const {
    std::ofstream file(path_ + "/" + name, std::ios::binary | std::ios::trunc);
    file << bytes;
    if (!file.flush()) {
      std::fprintf(stderr, "fuzz harness: cannot write %s/%s\n", path_.c_str(), name.c_str());
      std::abort();
    }
  }

 private:
  std::string path_;
};

/** The whole content of the file at `path`; `exists` says whether it could be opened. */
inline std::string read_file(const std::string& path, bool* exists = nullptr) {
  std::ifstream file(path, std::ios::binary);
  if (exists != nullptr) *exists = static_cast<bool>(file);
  return std::string(std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>());
}

/** The process's scratch directory for harness `name`: created at the first call, removed at
    exit and before a contract violation aborts. */
inline ScratchDir& scratch_dir(const std::string& name) {
  static ScratchDir dir(name);
  static const bool hooked = [] {
    before_abort = [] { dir.remove(); };
    return true;
  }();
  (void)hooked;
  return dir;
}

}  // namespace bflow::fuzz

#endif  // BFLOW_TESTS_FUZZ_FUZZ_SCRATCH_H_

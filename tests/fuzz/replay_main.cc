// Replays fuzz inputs without libFuzzer: calls the harness's LLVMFuzzerTestOneInput on every
// file given and on every regular file of every directory given (sorted by name), the way a
// libFuzzer executable runs a list of files. Linked with one harness into <target>_replay, it
// is the ctest fuzz_replay_<target> of every build (tests/fuzz/CMakeLists.txt), so the seed
// corpora are checked where clang's libFuzzer is missing too.
//
// A contract violation aborts in the harness (fuzz_contract.h), a sanitizer report ends the
// process: either fails the test, and the last "replay: FILE" line on stdout names the input.
// Exit code 1 when no input was found (a wrong directory must not pass as an empty corpus).
//
//   build/tests/fuzz/sweep_args_replay tests/fuzz/corpus/sweep_args
//   build/tests/fuzz/ocp_args_replay /tmp/fuzz-findings/ocp_args/crash-1234
#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <system_error>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  std::vector<fs::path> inputs;
  for (int i = 1; i < argc; ++i) {
    const fs::path arg(argv[i]);
    std::error_code ec;
    if (fs::is_directory(arg, ec)) {
      std::vector<fs::path> files;
      for (const auto& entry : fs::directory_iterator(arg, ec)) {
        if (entry.is_regular_file(ec)) files.push_back(entry.path());
      }
      std::sort(files.begin(), files.end());
      inputs.insert(inputs.end(), files.begin(), files.end());
    } else if (fs::is_regular_file(arg, ec)) {
      inputs.push_back(arg);
    } else {
      std::fprintf(stderr, "replay: %s is neither a file nor a directory\n", argv[i]);
      return 1;
    }
  }
  if (inputs.empty()) {
    std::fprintf(stderr, "replay: no input (usage: %s FILE_OR_DIRECTORY...)\n",
                 argc > 0 ? argv[0] : "replay");
    return 1;
  }
  const auto start = std::chrono::steady_clock::now();
  for (const fs::path& input : inputs) {
    std::ifstream file(input, std::ios::binary);
    if (!file) {
      std::fprintf(stderr, "replay: cannot read %s\n", input.c_str());
      return 1;
    }
    const std::string bytes((std::istreambuf_iterator<char>(file)),
                            std::istreambuf_iterator<char>());
    std::printf("replay: %s (%zu bytes)\n", input.c_str(), bytes.size());
    std::fflush(stdout);
    const auto t0 = std::chrono::steady_clock::now();
    // The return value (-1: the harness skipped the input) only tells libFuzzer what to keep.
    LLVMFuzzerTestOneInput(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
    const std::chrono::duration<double> took = std::chrono::steady_clock::now() - t0;
    std::printf("replay:   %.2f s\n", took.count());
  }
  const std::chrono::duration<double> total = std::chrono::steady_clock::now() - start;
  std::printf("replay: %zu inputs in %.1f s, every one within the contract\n", inputs.size(),
              total.count());
  return 0;
}

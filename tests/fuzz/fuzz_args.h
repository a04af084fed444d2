// Command lines from fuzz data: the bytes split into argv words at '\0' and '\n'.
#ifndef BFLOW_TESTS_FUZZ_FUZZ_ARGS_H_
#define BFLOW_TESTS_FUZZ_FUZZ_ARGS_H_

#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>
#include <vector>

#include "cli_commands.h"
#include "fuzz/fuzz_contract.h"

namespace bflow::fuzz {

/** The words of `data` separated by '\0' or '\n' (empty words kept; a final separator does
    not start another word, so a seed file may end with a newline). */
inline std::vector<std::string> split_words(const std::uint8_t* data, std::size_t size) {
  std::vector<std::string> words;
  if (size == 0) return words;
  std::string word;
  for (std::size_t i = 0; i < size; ++i) {
    const char c = static_cast<char>(data[i]);
    if (c == '\0' || c == '\n') {
      words.push_back(word);
      word.clear();
    } else {
      word += c;
    }
  }
  const char last = static_cast<char>(data[size - 1]);
  if (last != '\0' && last != '\n') words.push_back(word);
  return words;
}

/** Whether a word asks for help or the version, which print text with exit code 0: --help,
    --version, and -h, also at the head of a cluster of short options ("-hx0"). */
inline bool asks_for_text(const std::vector<std::string>& words) {
  for (const std::string& w : words) {
    if (w.compare(0, 2, "-h") == 0 || w.compare(0, 6, "--help") == 0 ||
        w.compare(0, 9, "--version") == 0) {
      return true;
    }
  }
  return false;
}

/** Runs "bflow <command> <words...>" in-process (empty stdin) and checks the contract. */
inline void run_and_check(const char* command, const std::vector<std::string>& words,
                          Contract contract) {
  std::vector<const char*> argv = {"bflow", command};
  for (const std::string& w : words) argv.push_back(w.c_str());
  std::istringstream in;
  std::ostringstream out, err;
  const int code = bflow::cli::run_cli(static_cast<int>(argv.size()), argv.data(), in, out, err);
  contract.text_on_success = asks_for_text(words);
  check(code, out.str(), err.str(), contract);
}

}  // namespace bflow::fuzz

#endif  // BFLOW_TESTS_FUZZ_FUZZ_ARGS_H_

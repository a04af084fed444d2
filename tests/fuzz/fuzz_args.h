// Command lines from fuzz data: the bytes split into argv words at '\0' and '\n'.
#ifndef BFLOW_TESTS_FUZZ_FUZZ_ARGS_H_
#define BFLOW_TESTS_FUZZ_FUZZ_ARGS_H_

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "cli_commands.h"
#include "fuzz/fuzz_contract.h"
#include "support/run_command.h"

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

/** Every value given to `option` ("--opt V" or "--opt=V"), in order. */
inline std::vector<std::string> values_of(const std::vector<std::string>& words,
                                          const std::string& option) {
  std::vector<std::string> values;
  for (std::size_t i = 0; i < words.size(); ++i) {
    if (words[i] == option && i + 1 < words.size()) {
      values.push_back(words[i + 1]);
    } else if (words[i].compare(0, option.size() + 1, option + "=") == 0) {
      values.push_back(words[i].substr(option.size() + 1));
    }
  }
  return values;
}

/** Whether `option` is among the words, as "--opt" or "--opt=V". */
inline bool has_option(const std::vector<std::string>& words, const std::string& option) {
  for (const std::string& w : words) {
    if (w == option || w.compare(0, option.size() + 1, option + "=") == 0) return true;
  }
  return false;
}

/** Replaces every value given to `option` ("--opt V" or "--opt=V") by f(value). */
template <typename F>
void map_values(std::vector<std::string>& words, const std::string& option, F f) {
  for (std::size_t i = 0; i < words.size(); ++i) {
    if (words[i] == option && i + 1 < words.size()) {
      words[i + 1] = f(words[i + 1]);
      ++i;
    } else if (words[i].compare(0, option.size() + 1, option + "=") == 0) {
      words[i] = option + "=" + f(words[i].substr(option.size() + 1));
    }
  }
}

using RunResult = bflow::testing::Outcome;

/** Runs "bflow <command> <words...>" in-process (empty stdin). */
inline RunResult run_words(const char* command, const std::vector<std::string>& words) {
  std::vector<std::string> args = {command};
  args.insert(args.end(), words.begin(), words.end());
  return bflow::testing::command_line(args);
}

/** Runs "bflow <command> <words...>" in-process (empty stdin) and checks the contract. */
inline RunResult run_and_check(const char* command, const std::vector<std::string>& words,
                               Contract contract) {
  RunResult r = run_words(command, words);
  contract.text_on_success = asks_for_text(words);
  check(r.code, r.out, r.err, contract);
  return r;
}

}  // namespace bflow::fuzz

#endif  // BFLOW_TESTS_FUZZ_FUZZ_ARGS_H_

// libFuzzer harness: the JSON document of `bflow jump` (bflow::cli::run_jump); the input is the
// document on stdin. Checks the output contract (fuzz_contract.h) on every input.
#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>

#include "cli_commands.h"
#include "fuzz/fuzz_contract.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::istringstream in(std::string(reinterpret_cast<const char*>(data), size));
  std::ostringstream out, err;
  const int code = bflow::cli::run_jump(in, out, err);
  bflow::fuzz::check(code, out.str(), err.str(), bflow::fuzz::Contract{});
  return 0;
}

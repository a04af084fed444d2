// The `bflow` command. Usage: bflow --help; the logic is in bflow_cli (cli_commands.h).
#include <iostream>

#include "cli_commands.h"

int main(int argc, char** argv) {
  return bflow::cli::run_cli(argc, argv, std::cin, std::cout, std::cerr);
}

// The `bflow` command. Usage: bflow --help; the logic is in bflow_cli (cli_commands.h).
#include <cstdio>
#include <exception>
#include <iostream>
#include <memory>

#include "bflow/sweep/mpi.h"

#include "cli_commands.h"
#include "cli_util.h"

int main(int argc, char** argv) {
  // Under an MPI launcher (`mpirun -np K bflow sweep ...`) the ranks share the sweep; otherwise
  // no MPI call is made.
  std::unique_ptr<bflow::MpiSession> mpi;
  try {
    mpi = std::make_unique<bflow::MpiSession>(&argc, &argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return bflow::cli::kExitBadInput;
  }
  bflow::cli::set_mpi_session(mpi.get());
  // std::cout writes through C's stdout, as by default, but through a buffer that keeps the
  // errno of a failed write (a full disk, a closed pipe): by the time the command ends and
  // notices, errno has long been overwritten. std::cerr stays unbuffered (unitbuf) and tied to
  // std::cout, so a diagnostic follows everything printed before it.
  bflow::cli::StdioOutputBuffer stdout_buffer(stdout);
  std::streambuf* const original = std::cout.rdbuf(&stdout_buffer);
  int code = bflow::cli::run_cli(argc, argv, std::cin, std::cout, std::cerr);
  // run_cli() has flushed std::cout into C's stdout; this flushes C's buffer to the file and
  // reports its failure, unless the command already failed with its own line.
  code = bflow::cli::finish_output(std::cout, std::cerr, code);
  std::cout.rdbuf(original);
  return code;
}

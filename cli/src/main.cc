// The `bflow` command. Usage: bflow --help; the logic is in bflow_cli (cli_commands.h).
#include <csignal>
#include <cstdio>
#include <cstring>
#include <exception>
#include <iostream>
#include <memory>

#include "bflow/sweep/mpi.h"

#include "cli_commands.h"
#include "cli_util.h"

int main(int argc, char** argv) {
  // A write to a closed pipe (`bflow flow ... | head`) fails with EPIPE instead of killing the
  // process: the command then ends with exit code 1 and "error: stdout: write failed (Broken
  // pipe)", so that a sweep or an OCP whose output was lost says so (docs/cli.md).
  std::signal(SIGPIPE, SIG_IGN);
  // Under an MPI launcher (`mpirun -np K bflow sweep ...`) the ranks share the sweep; otherwise
  // no MPI call is made. Only the sweep uses MPI: every other command runs as one process
  // whatever launcher variables (PMI_*, OMPI_*) its environment holds.
  std::unique_ptr<bflow::MpiSession> mpi;
  if (argc > 1 && std::strcmp(argv[1], "sweep") == 0) {
    try {
      mpi = std::make_unique<bflow::MpiSession>(&argc, &argv);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "error: %s\n", e.what());
      return bflow::cli::kExitBadInput;
    }
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

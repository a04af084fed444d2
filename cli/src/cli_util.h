// Small helpers shared by the commands: one-line diagnostics and quoting.
#ifndef BFLOW_CLI_CLI_UTIL_H_
#define BFLOW_CLI_CLI_UTIL_H_

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <ostream>
#include <streambuf>
#include <string>

#include "bflow/core/text.h"
#include "bflow/fesd/linear_solver.h"
#include "cli_commands.h"

namespace bflow::cli {

/** `text` with line breaks and other control characters replaced by spaces, and bytes that are
    not UTF-8 by \xNN, so that a diagnostic is always exactly one line of valid UTF-8. */
inline std::string one_line(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (std::size_t i = 0; i < text.size();) {
    char32_t code_point = 0;
    const std::size_t length = utf8_sequence(text, i, code_point);
    if (length == 0) {
      char buffer[16];
      std::snprintf(buffer, sizeof buffer, "\\x%02x", static_cast<unsigned char>(text[i]));
      out += buffer;
      ++i;
      continue;
    }
    if (is_control(code_point)) {
      out += ' ';
    } else {
      out.append(text, i, length);
    }
    i += length;
  }
  return out;
}

/** The longest diagnostic line, in characters (code points), "error: " included. */
inline constexpr std::size_t kMaxErrorChars = 500;

/** Writes "error: <message>\n" to `err`: the only thing a failing command prints there. The
    line is cut to kMaxErrorChars characters ("..." marking the cut) whatever the message holds;
    user text inside it is quoted with quote() at a much smaller bound. */
inline void report_error(std::ostream& err, const std::string& message) {
  const std::string line = one_line(message);
  constexpr std::size_t kKept = kMaxErrorChars - 10;  // "error: " and "..."
  std::size_t end = 0;
  for (std::size_t chars = 0; end < line.size() && chars < kKept; ++chars) {
    char32_t code_point = 0;
    end += std::max<std::size_t>(1, utf8_sequence(line, end, code_point));
  }
  err << "error: " << line.substr(0, end) << (end < line.size() ? "..." : "") << '\n' << std::flush;
}

/** The character (code point) that starts at text[i], quoted, with its code point when it is not
    ASCII: "x", "−" (U+2212), "\xff" (not UTF-8). `length` receives its length in bytes. */
inline std::string quote_character(const std::string& text, std::size_t i, std::size_t& length) {
  char32_t code_point = 0;
  length = utf8_sequence(text, i, code_point);
  if (length == 0) {
    length = 1;
    return quote(text.substr(i, 1));
  }
  std::string result = quote(text.substr(i, length));
  if (code_point >= 0x80) {
    char buffer[16];
    std::snprintf(buffer, sizeof buffer, " (U+%04X)", static_cast<unsigned>(code_point));
    result += buffer;
  }
  return result;
}

/** `message` if it already starts with "<field>:", else "<field>: <message>". Core messages
    (bflow::InvalidArgument) mostly start with the name of the input they reject. */
inline std::string with_field(const std::string& field, const std::string& message) {
  if (message.compare(0, field.size() + 1, field + ":") == 0) return message;
  return field + ": " + message;
}

/** A stream buffer that writes through a C stream (main() puts one under std::cout) and
    remembers the errno of its first failed write or flush, which a later failure of the
    ostream no longer carries. It keeps no buffer of its own: the C stream buffers, so output
    stays in order with anything else written to that C stream. */
class StdioOutputBuffer : public std::streambuf {
 public:
  explicit StdioOutputBuffer(std::FILE* file) : file_(file) {}

  /** True once a write or a flush has failed. */
  bool failed() const { return failed_; }
  /** The errno of the first failure; 0 when none, or when the C library did not set one. */
  int error_number() const { return error_number_; }

 protected:
  int_type overflow(int_type c) override {
    if (traits_type::eq_int_type(c, traits_type::eof())) return traits_type::not_eof(c);
    const char ch = traits_type::to_char_type(c);
    return xsputn(&ch, 1) == 1 ? c : traits_type::eof();
  }

  std::streamsize xsputn(const char* s, std::streamsize n) override {
    if (n <= 0) return 0;
    errno = 0;
    const std::size_t written = std::fwrite(s, 1, static_cast<std::size_t>(n), file_);
    if (written != static_cast<std::size_t>(n)) record_failure();
    return static_cast<std::streamsize>(written);
  }

  int sync() override {
    errno = 0;
    if (std::fflush(file_) == 0) return 0;
    record_failure();
    return -1;
  }

 private:
  void record_failure() {
    if (!failed_) error_number_ = errno;
    failed_ = true;
  }

  std::FILE* file_;
  bool failed_ = false;
  int error_number_ = 0;
};

/** Ends a command: flushes `out` and returns `code`, unless writing `out` failed (now or
    earlier): then, if the command had succeeded (`code` is kExitOk), reports the one line
    "error: stdout: write failed (<errno text>)" on `err` and returns kExitFailure. A command
    that already failed has printed its one error line and keeps its code. Idempotent: every
    entry point and main() call it on the same stream. */
inline int finish_output(std::ostream& out, std::ostream& err, int code) {
  const bool failed_before = out.fail();
  errno = 0;
  if (!failed_before) out.flush();
  const int flush_errno = errno;
  if (!out.fail()) return code;
  if (code != kExitOk) return code;
  int error_number = 0;
  if (const auto* buffer = dynamic_cast<const StdioOutputBuffer*>(out.rdbuf())) {
    error_number = buffer->error_number();
  } else if (!failed_before) {
    error_number = flush_errno;  // the flush that just failed set it, if anything did
  }
  std::string message = "stdout: write failed";
  if (error_number != 0) message += std::string(" (") + std::strerror(error_number) + ")";
  report_error(err, message);
  return kExitFailure;
}

/** The shared solver flags into bflow::FesdOptions or bflow::OcpOptions (linear_solver,
    linear_solver_library, blas_threads), each checked before anything runs. "" when they are
    usable, else the message, which names the flag. */
template <typename Options>
std::string apply_solver_options(const SolverCommandOptions& s, Options& o) {
  if (s.blas_threads < 0) {
    return "--blas-threads: " + std::to_string(s.blas_threads) +
           " must be >= 0 (0: OpenBLAS's own count)";
  }
  try {
    check_linear_solver(s.linear_solver, s.linear_solver_library, "--linear-solver");
  } catch (const InvalidArgument& e) {
    return e.what();  // unknown, or its library missing
  }
  o.solver.linear_solver = s.linear_solver;
  o.solver.linear_solver_library = s.linear_solver_library;
  o.solver.blas_threads = s.blas_threads;
  o.solver.derivative_programs = !s.jet_derivatives;
  return "";
}

}  // namespace bflow::cli

#endif  // BFLOW_CLI_CLI_UTIL_H_

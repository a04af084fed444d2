// Small helpers shared by the commands: one-line diagnostics and quoting.
#ifndef BFLOW_CLI_CLI_UTIL_H_
#define BFLOW_CLI_CLI_UTIL_H_

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <ostream>
#include <streambuf>
#include <string>

#include "cli_commands.h"

namespace bflow::cli {

/** `text` with line breaks and other control characters replaced by spaces, so that a
    diagnostic is always exactly one line. */
inline std::string one_line(std::string text) {
  for (char& c : text) {
    if (static_cast<unsigned char>(c) < 0x20 || c == '\x7f') c = ' ';
  }
  return text;
}

/** Writes "error: <message>\n" to `err`: the only thing a failing command prints there. */
inline void report_error(std::ostream& err, const std::string& message) {
  err << "error: " << one_line(message) << '\n' << std::flush;
}

/** `text` in double quotes, JSON-escaped, cut after `max_chars` characters ("..." marks the
    cut), so that user-supplied names are quoted unambiguously on one line. */
inline std::string quote(const std::string& text, std::size_t max_chars = 60) {
  std::string out = "\"";
  std::size_t shown = 0;
  for (char c : text) {
    if (shown++ == max_chars) {
      out += "...";
      break;
    }
    const auto u = static_cast<unsigned char>(c);
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (u < 0x20 || u == 0x7f) {
      char buffer[8];
      std::snprintf(buffer, sizeof buffer, "\\u%04x", u);
      out += buffer;
    } else {
      out += c;
    }
  }
  return out + "\"";
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

}  // namespace bflow::cli

#endif  // BFLOW_CLI_CLI_UTIL_H_

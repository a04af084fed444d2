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

/** The length (1 to 4) of the well-formed UTF-8 sequence that starts at text[i], with its code
    point in `code_point`; 0 when the bytes there are not one: a stray continuation byte, an
    overlong form, a surrogate, a code point above U+10FFFF or a sequence cut short. */
inline std::size_t utf8_sequence(const std::string& text, std::size_t i, char32_t& code_point) {
  const auto byte = [&](std::size_t k) { return static_cast<unsigned char>(text[k]); };
  const unsigned char lead = byte(i);
  if (lead < 0x80) {
    code_point = lead;
    return 1;
  }
  std::size_t length = 0;
  unsigned char low = 0x80, high = 0xbf;  // the range of the second byte (Unicode Table 3-7)
  if (lead >= 0xc2 && lead <= 0xdf) {
    length = 2;
  } else if (lead >= 0xe0 && lead <= 0xef) {
    length = 3;
    if (lead == 0xe0) low = 0xa0;   // no overlong forms
    if (lead == 0xed) high = 0x9f;  // no surrogates
  } else if (lead >= 0xf0 && lead <= 0xf4) {
    length = 4;
    if (lead == 0xf0) low = 0x90;   // no overlong forms
    if (lead == 0xf4) high = 0x8f;  // nothing above U+10FFFF
  } else {
    return 0;
  }
  if (i + length > text.size()) return 0;
  if (byte(i + 1) < low || byte(i + 1) > high) return 0;
  char32_t value = lead & (0xff >> (length + 1));
  for (std::size_t k = 1; k < length; ++k) {
    if (k > 1 && (byte(i + k) & 0xc0) != 0x80) return 0;
    value = (value << 6) | (byte(i + k) & 0x3f);
  }
  code_point = value;
  return length;
}

/** Whether a code point is a control character (C0, DEL, C1) or a line or paragraph separator:
    what must not reach a one-line diagnostic as is. */
inline bool is_control(char32_t code_point) {
  return code_point < 0x20 || (code_point >= 0x7f && code_point < 0xa0) || code_point == 0x2028 ||
         code_point == 0x2029;
}

/** `text` made printable on one line: valid UTF-8 kept (multi-byte characters included),
    control characters as \u00NN (\u2028, \u2029 for the separators), bytes that are not
    UTF-8 as \xNN; with `quoted`, '"' and '\' escaped by a backslash. At most `max_chars`
    characters (code points; an escaped byte counts as one) are kept, "..." marking a cut, which
    never falls inside a character. */
inline std::string escaped(const std::string& text, std::size_t max_chars, bool quoted) {
  std::string out;
  std::size_t shown = 0;
  for (std::size_t i = 0; i < text.size();) {
    if (shown++ == max_chars) {
      out += "...";
      break;
    }
    char32_t code_point = 0;
    const std::size_t length = utf8_sequence(text, i, code_point);
    char buffer[16];
    if (length == 0) {
      std::snprintf(buffer, sizeof buffer, "\\x%02x", static_cast<unsigned char>(text[i]));
      out += buffer;
      ++i;
      continue;
    }
    if (is_control(code_point)) {
      std::snprintf(buffer, sizeof buffer, "\\u%04x", static_cast<unsigned>(code_point));
      out += buffer;
    } else if (quoted && (code_point == '"' || code_point == '\\')) {
      out += '\\';
      out += static_cast<char>(code_point);
    } else {
      out.append(text, i, length);
    }
    i += length;
  }
  return out;
}

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

/** Writes "error: <message>\n" to `err`: the only thing a failing command prints there. */
inline void report_error(std::ostream& err, const std::string& message) {
  err << "error: " << one_line(message) << '\n' << std::flush;
}

/** `text` in double quotes, '"' and '\' escaped, control characters as \u00NN and bytes that
    are not UTF-8 as \xNN, cut after `max_chars` characters (code points, never inside one;
    "..." marks the cut), so that user-supplied names and values are quoted unambiguously, on
    one line and at a bounded length: "−+" is two characters, "\xff" one. */
inline std::string quote(const std::string& text, std::size_t max_chars = 60) {
  return "\"" + escaped(text, max_chars, true) + "\"";
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

}  // namespace bflow::cli

#endif  // BFLOW_CLI_CLI_UTIL_H_

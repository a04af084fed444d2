// Small helpers shared by the commands: one-line diagnostics and quoting.
#ifndef BFLOW_CLI_CLI_UTIL_H_
#define BFLOW_CLI_CLI_UTIL_H_

#include <cstdio>
#include <ostream>
#include <string>

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

}  // namespace bflow::cli

#endif  // BFLOW_CLI_CLI_UTIL_H_

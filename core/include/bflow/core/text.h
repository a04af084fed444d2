// One-line, bounded quoting of text that comes from a user (names, paths, option values), for
// error messages: every message that echoes user text quotes it with quote(), so that a 5000-
// character value or one with line breaks still gives one short line.
#ifndef BFLOW_CORE_TEXT_H_
#define BFLOW_CORE_TEXT_H_

#include <cstddef>
#include <string>

namespace bflow {

/** The length (1 to 4) of the well-formed UTF-8 sequence that starts at text[i], with its code
    point in `code_point`; 0 when the bytes there are not one: a stray continuation byte, an
    overlong form, a surrogate, a code point above U+10FFFF or a sequence cut short. */
std::size_t utf8_sequence(const std::string& text, std::size_t i, char32_t& code_point);

/** Whether a code point is a control character (C0, DEL, C1) or a line or paragraph separator:
    what must not reach a one-line diagnostic as is. */
bool is_control(char32_t code_point);

/** `text` made printable on one line: valid UTF-8 kept (multi-byte characters included),
    control characters as \u00NN (\u2028, \u2029 for the separators), bytes that are not
    UTF-8 as \xNN; with `quoted`, '"' and '\' escaped by a backslash. At most `max_chars`
    characters (code points; an escaped byte counts as one) are kept, "..." marking a cut, which
    never falls inside a character. */
std::string escaped(const std::string& text, std::size_t max_chars, bool quoted);

/** `text` in double quotes, '"' and '\' escaped, control characters as \u00NN and bytes that
    are not UTF-8 as \xNN, cut after `max_chars` characters (code points, never inside one;
    "..." marks the cut), so that user-supplied names and values are quoted unambiguously, on
    one line and at a bounded length: "−+" is two characters, "\xff" one. */
std::string quote(const std::string& text, std::size_t max_chars = 60);

}  // namespace bflow

#endif  // BFLOW_CORE_TEXT_H_

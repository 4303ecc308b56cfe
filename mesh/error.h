#pragma once

// The one error type of tetcosim. Thrown for bad user input (files, scenes,
// command-line values) at load time; never for trouble inside a step, which
// is reported as a status value instead. The message is complete and meant
// for a person: where (file, line, element), what is wrong, what to do.

#include <span>
#include <stdexcept>
#include <string>
#include <string_view>

namespace tetcosim {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

// "file:line: message" (line <= 0 leaves the line out; empty file leaves the
// file out).
std::string Where(std::string_view file, long line = 0);

// Throws Error("file:line: message").
[[noreturn]] void ThrowAt(std::string_view file, long line, const std::string& message);

// The names a message offers in place of one that is not there, quoted:
// "'a', 'b' and 'c'", the first `max_shown` and how many more ("'a', 'b'
// and 7 more"); empty for no names.
std::string QuotedList(std::span<const std::string_view> names, int max_shown = 12);

}  // namespace tetcosim

#pragma once

// CSV fields for the rollouts' files.

#include <string>
#include <string_view>

namespace tetcosim::app {

// `text` as a CSV field (RFC 4180): as it is, or in double quotes, its own
// doubled, when it holds a comma, a double quote or a line break (a name
// such as "arm, left" would otherwise shift the row's columns).
inline std::string CsvField(std::string_view text) {
  if (text.find_first_of(",\"\r\n") == std::string_view::npos) return std::string(text);
  std::string field = "\"";
  for (const char c : text) {
    if (c == '"') field += '"';
    field += c;
  }
  return field + '"';
}

}  // namespace tetcosim::app

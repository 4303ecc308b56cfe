#include "mesh/error.h"

#include <algorithm>

namespace tetcosim {

std::string Where(std::string_view file, long line) {
  std::string where(file);
  if (line > 0) {
    where.push_back(':');
    where.append(std::to_string(line));
  }
  return where;
}

void ThrowAt(std::string_view file, long line, const std::string& message) {
  std::string where = Where(file, line);
  if (!where.empty()) where.append(": ");
  where.append(message);
  throw Error(where);
}

std::string QuotedList(std::span<const std::string_view> names, int max_shown) {
  const int count = static_cast<int>(names.size());
  const int shown = std::min(count, std::max(1, max_shown));
  std::string list;
  for (int i = 0; i < shown; ++i) {
    if (i > 0) list.append(i + 1 == count ? " and " : ", ");
    list.append("'").append(names[i]).append("'");
  }
  if (shown < count) list.append(" and ").append(std::to_string(count - shown)).append(" more");
  return list;
}

}  // namespace tetcosim

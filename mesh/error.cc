#include "mesh/error.h"

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

}  // namespace tetcosim

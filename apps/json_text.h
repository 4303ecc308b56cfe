#pragma once

// The commands' JSON (summary.json, --json) as text.

#include <string>

namespace tetcosim::app {

// `json` (an nlohmann::json or ordered_json) as text, indented by 2. The
// scene parser makes sure a scene file is UTF-8, as JSON must be; names
// MuJoCo reads from files a scene includes are not checked, and a byte of
// them that is not UTF-8 is written as U+FFFD (nlohmann's dump would throw).
template <typename Json>
std::string JsonText(const Json& json) {
  return json.dump(2, ' ', false, Json::error_handler_t::replace);
}

}  // namespace tetcosim::app

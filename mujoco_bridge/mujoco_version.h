#pragma once

#include <string>

namespace tetcosim {

// The MuJoCo library version tetcosim runs against, e.g. "2.2.2".
std::string MujocoVersion();

}  // namespace tetcosim

#include "mujoco_bridge/mujoco_version.h"

#include <mujoco/mujoco.h>

namespace tetcosim {

std::string MujocoVersion() {
  return mj_versionString();
}

}  // namespace tetcosim

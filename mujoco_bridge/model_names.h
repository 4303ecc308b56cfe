#pragma once

// For errors that name a MuJoCo object the scene does not have: the names it
// does have. Internal to mujoco_bridge (includes MuJoCo).

#include <mujoco/mujoco.h>

#include <string>

namespace tetcosim {

// What the model names among its objects of `type` (mjOBJ_BODY, mjOBJ_GEOM
// or mjOBJ_CAMERA; with body >= 0, that body's geoms only): "the named
// bodies: 'a', 'b' and 'c'" (QuotedList: the first twelve and how many
// more), or "no named body".
std::string NamesOf(const mjModel* m, mjtObj type, int body = -1);

}  // namespace tetcosim

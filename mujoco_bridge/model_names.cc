#include "mujoco_bridge/model_names.h"

#include <string_view>
#include <vector>

#include "mesh/error.h"

namespace tetcosim {

std::string NamesOf(const mjModel* m, mjtObj type, int body) {
  const char* one = type == mjOBJ_BODY ? "body" : type == mjOBJ_GEOM ? "geom" : "camera";
  const char* many = type == mjOBJ_BODY ? "bodies" : type == mjOBJ_GEOM ? "geoms" : "cameras";
  const int count = type == mjOBJ_BODY ? m->nbody : type == mjOBJ_GEOM ? m->ngeom : m->ncam;
  std::vector<std::string_view> names;
  for (int id = 0; id < count; ++id) {
    if (type == mjOBJ_GEOM && body >= 0 && m->geom_bodyid[id] != body) continue;
    const char* name = mj_id2name(m, type, id);
    if (name != nullptr && *name != '\0') names.emplace_back(name);
  }
  if (names.empty()) return std::string("no named ") + one;
  return std::string("the named ") + many + ": " + QuotedList(names);
}

}  // namespace tetcosim

#include "collision/collision_object.h"

#include <cstdio>
#include <string>

#include "collision/penetration_internal.h"
#include "mesh/error.h"

namespace tetcosim {

// (Row by row, in one pass: Eigen's column-wise reduction of a row-major
// matrix walks each column on its own, six passes. Grown in a local and
// copied out: grown in the returned object, which the positions might
// alias as far as the compiler knows, it was kept in memory, 0.5% more
// instructions a solve on the scenes.)
PositionBounds PositionBounds::Of(const Positions& x) {
  PositionBounds grown;
  for (int v = 0; v < x.rows(); ++v) grown.Add(x.row(v).transpose());
  PositionBounds bounds = grown;
  return bounds;
}

void CheckGivenBounds(const CollisionObject& object, int o) {
  // kSampledVertices vertices spread over the numbering, the first and last
  // among them (a box kept from another placement, or of other positions,
  // leaves out some of them)
  const PositionBounds& bounds = *object.frame->bounds;
  const Positions& x = *object.positions;
  const long num_vertices = x.rows();
  for (long i = 0; i <= kSampledVertices && num_vertices > 0; ++i) {
    const long v = SpreadVertex(i, kSampledVertices, num_vertices);
    const Eigen::Vector3d p = x.row(v).transpose();
    const bool finite = p.allFinite();
    const bool inside =
        (bounds.lo.array() <= p.array()).all() && (p.array() <= bounds.hi.array()).all();
    if (finite ? inside : !bounds.finite()) continue;
    char at[96];
    std::snprintf(at, sizeof(at), " (at %g, %g, %g)", p.x(), p.y(), p.z());
    throw Error("penetration solver: object " + std::to_string(o) +
                ": its frame's bounds do not hold its vertex " + std::to_string(v) + at +
                "; give RigidFrame::bounds as PositionBounds::Add of every position as given, "
                "or leave it unset");
  }
}

}  // namespace tetcosim

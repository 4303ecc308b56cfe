#pragma once

// Tetrahedral meshes of simple shapes, centred at the origin. Sizes follow
// MuJoCo's geom conventions (half-extents, radii, half-lengths; metres), so
// that a generated mesh matches the geom of the same size:
//   box      size = (hx, hy, hz)  cells per axis (nx, ny, nz); 5 or 6 tets per cell
//   sphere   size = (r)           resolution 0: the 20-tet icosahedron around a
//                                 centre vertex; each level splits every tet in 8
//   cylinder size = (r, hh)       axis z; resolution = cells across the diameter
//   capsule  size = (r, hl)       axis z; cylinder of half-length hl + two caps
//   torus    size = (R, r)        ring in the xy plane; major radius R > r
// Every generated tetrahedron has positive volume; the boundary is a closed,
// consistently oriented 2-manifold (genus 0, or 1 for the torus).

#include <Eigen/Core>
#include <string>

#include "mesh/tet_mesh.h"

namespace tetcosim {

RawMesh MakeBox(const Eigen::Vector3d& half_size, const Eigen::Vector3i& cells,
                int tets_per_cell = 6);
RawMesh MakeSphere(double radius, int resolution);
RawMesh MakeCylinder(double radius, double half_height, int resolution);
RawMesh MakeCapsule(double radius, double half_length, int resolution);
RawMesh MakeTorus(double major_radius, double minor_radius, int resolution);

// A mesh of the same solid as `solid`, a tetrahedral mesh whose surface is
// star-shaped about `apex` (seen whole from it, as a convex solid's surface
// is from any point inside): one tetrahedron joining each surface triangle
// to the apex, so its surface is the same with as many tetrahedra as it has
// triangles, however fine (a rigid proxy needs a fine surface, not a fine
// inside). Throws Error when a triangle does not face away from the apex.
RawMesh ConeToPoint(const TetMesh& solid, const Eigen::Vector3d& apex);

// The same for a mesh of MakeCylinder or MakeCapsule (axis z), whose
// surface, long or short, is cut at the heights of its side's rings (its
// surface vertices' heights up to half_length) into slabs: each slab's
// surface triangles coned to a point on the axis inside it, and each ring
// between two slabs fanned from the axis (two tetrahedra a ring edge, one
// to each slab's point); a capsule's caps (beyond half_length) are slabs of
// their own. No tetrahedron reaches farther than a slab, however long the
// body. Throws Error when the mesh is not such a body: no rings within
// half_length, a triangle that does not face away from its slab's point,
// or slabs that do not fill the solid (checked by their volume).
RawMesh ConeToAxis(const TetMesh& solid, double half_length);

// True when text looks like a generator spec "shape:key=value:..." with a
// known shape name.
bool IsShapeSpec(const std::string& text);

// Builds a mesh from a spec: "<shape>:size=<a>[,<b>[,<c>]][:res=<n>[,<n>,<n>]][:split=5|6]",
// e.g. "box:size=0.05,0.05,0.05:res=7", "sphere:size=0.1:res=0",
// "torus:size=0.1,0.03:res=3". Throws Error naming the bad part.
RawMesh MakeShape(const std::string& spec);

// The same from separate values (the scene format's shape, size and
// resolution attributes). `where` prefixes error messages.
RawMesh MakeShape(const std::string& shape, const std::vector<double>& size,
                  const std::vector<int>& resolution, int split, const std::string& where);

}  // namespace tetcosim

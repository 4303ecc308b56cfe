#pragma once

// The shapes of MuJoCo geoms as a deformable's vertices meet them: how deep
// a point is inside a geom and the way out, for every geom type MuJoCo
// collides (the geoms without a tetrahedral proxy, see world.h).
//
//   plane, sphere, capsule, box, cylinder: exact signed distance
//   ellipsoid: exact distance to the nearest surface point, found by
//     bisection (Eberly, "Distance from a point to an ellipse, an ellipsoid,
//     or a hyperellipsoid", 2013; see NearestEllipsoidPoint)
//   mesh: its convex hull, as MuJoCo collides a mesh: the depth below the
//     nearest face plane (exact inside a convex polyhedron)
//   height field: terrain, pushed out upward only: the depth below the
//     surface triangle over the point, along that triangle's normal (the
//     grid's cells split as MuJoCo splits them; the sides and base of its
//     prisms are not ways out)

#include <Eigen/Core>
#include <string>
#include <vector>

#include "mesh/tet_mesh.h"

struct mjModel_;

namespace tetcosim {

// A geom's shape in its own frame (geom_xpos, geom_xmat). Sizes and
// elevations are read from the model where they are, at each use, as
// MuJoCo reads them; a mesh's convex hull is taken once, by MakeGeomShape.
struct GeomShape {
  int type = -1;                 // mjtGeom
  const double* size = nullptr;  // geom_size (3); a height field's hfield_size (4)

  // mesh: the faces of its convex hull, n . p <= offset inside (n unit,
  // outward; faces that lie in one plane given once)
  std::vector<Eigen::Vector3d> plane_normal;  // (#planes)
  std::vector<double> plane_offset;           // (#planes, metres)
  double hull_volume = 0.0;                   // m^3
  double mesh_volume = 0.0;  // m^3: what its faces enclose (if they close it), at most the hull's

  // height field: elevation[r * cols + c] (0 to 1, times size[2] in
  // metres) at grid point x = -size[0] + 2 size[0] c / (cols - 1),
  // y = -size[1] + 2 size[1] r / (rows - 1); the base at z = -size[3]
  int rows = 0;
  int cols = 0;
  const float* elevation = nullptr;  // (rows x cols, hfield_data)
};

// The shape of geom `geom` of `m`, valid while `m` is. Throws Error (saying
// what to do) for a mesh without a convex hull (<compiler
// convexhull="false">), which the geom would need to touch deformables, and
// for a height field of fewer than 2 x 2 points; `where` names the geom.
GeomShape MakeGeomShape(const mjModel_* m, int geom, const std::string& where);

// Whether p (geom frame) lies inside the shape; if so, depth (>= 0, metres)
// to its surface and direction, the unit way out (geom frame).
bool GeomPenetration(const GeomShape& shape, const Eigen::Vector3d& p, double& depth,
                     Eigen::Vector3d& direction);

// Where the segment from `outside` to `inside` (geom frame; `inside` a
// point GeomPenetration finds inside) enters the shape: the point
// outside + t (inside - outside), t in [0, 1], and the shape's outward unit
// normal there. The stage 2 crossing of the consistent method
// (collision/shape_depth.h): these shapes are convex, so the segment enters
// once, and that crossing is the nearest to `outside`. False where none is
// found (`inside` on the surface within rounding), and for a plane (whose
// crossings would give its signed distance again: every one lies in it) and
// a height field (pushed up only), whose crossings are not sought.
bool GeomEntry(const GeomShape& shape, const Eigen::Vector3d& outside,
               const Eigen::Vector3d& inside, double& t, Eigen::Vector3d& normal);

// The size of the box of mesh geom `geom`'s vertices along the geom
// frame's axes (MuJoCo's principal axes of the mesh), metres.
Eigen::Vector3d MeshExtent(const mjModel_* m, int geom);

// The narrowest hole geom `geom` of `m` passes through, its second-smallest
// extent (metres): a sphere's or a capsule's diameter, a rod's thickness, a
// plate's width; a mesh's from the box of its vertices in the geom frame
// (MuJoCo's principal axes). Infinity for a plane or a height field. A geom
// narrower than the spacing of a deformable's surface vertices can sink in
// between them, and pass through the body, touching no vertex (world.h).
double GeomPassageWidth(const mjModel_* m, int geom);

// A tetrahedral mesh of mesh geom `geom`'s convex hull (geom frame): a
// tetrahedron from each face of the hull to the mean of its vertices, the
// faces split at the midpoints of their longest edges (which lie on the
// hull) until no edge is longer than max_edge, or there are 20,000 faces
// or more. Throws Error, naming `where`, for a mesh without a hull.
RawMesh ConvexHullTetMesh(const mjModel_* m, int geom, double max_edge, const std::string& where);

// The nearest point of the ellipsoid x^2/a^2 + y^2/b^2 + z^2/c^2 = 1
// (radii = a, b, c > 0) to p, a point inside it or on it, and the outward
// unit normal there. Where two points are nearest (p on a plane of
// symmetry deep inside), the one on the side of the positive axis.
void NearestEllipsoidPoint(const Eigen::Vector3d& radii, const Eigen::Vector3d& p,
                           Eigen::Vector3d& nearest, Eigen::Vector3d& normal);

}  // namespace tetcosim

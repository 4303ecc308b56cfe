#pragma once

// Small geometric predicates and queries used by the penetration solver.
// Plain floating point; the tolerances are explained where they are used.

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace tetcosim {

// A point is inside a tetrahedron when its barycentric coordinates are all
// at least -kBarycentricTolerance: a point on a face shared by two
// tetrahedra is then inside at least one of them despite rounding.
constexpr double kBarycentricTolerance = 1e-12;

// Barycentric coordinates of p in the tetrahedron (a, b, c, d):
// p = l0 a + l1 b + l2 c + l3 d with l0 + l1 + l2 + l3 = 1. Returns false for
// a degenerate tetrahedron (zero volume).
bool TetBarycentric(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                    const Eigen::Vector3d& d, const Eigen::Vector3d& p, Eigen::Vector4d& l);

// Where the segment from q to p crosses the triangle (a, b, c), if it does:
// x = q + t (p - q), t in [0, 1], and the barycentric coordinates (1-u-v, u, v)
// of x in the triangle. Points on triangle edges and vertices count as hits
// (a relative tolerance of 1e-12), so an edge through a shared triangle edge
// hits both triangles rather than slipping between them.
bool SegmentTriangle(const Eigen::Vector3d& q, const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                     const Eigen::Vector3d& b, const Eigen::Vector3d& c, double& t, double& u,
                     double& v);

// The point of the triangle (a, b, c) nearest to p (exact, by Voronoi regions
// of the triangle's vertices, edges and face).
Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                       const Eigen::Vector3d& b, const Eigen::Vector3d& c);

}  // namespace tetcosim

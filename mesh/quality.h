#pragma once

// Element quality of a tetrahedral mesh.

#include "mesh/tet_mesh.h"

namespace tetcosim {

struct MeshQuality {
  double min_dihedral_deg = 0.0;  // smallest dihedral angle over all tets (regular: 70.53)
  double max_dihedral_deg = 0.0;  // largest (regular: 70.53; a sliver approaches 180)
  double min_radius_ratio = 0.0;  // 3 r_in / r_circ: 1 regular, 0 flat
  double mean_radius_ratio = 0.0;
};

// Dihedral angles and radius ratios of one tetrahedron.
void TetDihedralAngles(const Eigen::Vector3d p[4], double angles_deg[6]);
double TetRadiusRatio(const Eigen::Vector3d p[4]);

MeshQuality ComputeQuality(const TetMesh& mesh);

}  // namespace tetcosim

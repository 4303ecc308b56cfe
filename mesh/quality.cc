#include "mesh/quality.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>

namespace tetcosim {

void TetDihedralAngles(const Eigen::Vector3d p[4], double angles_deg[6]) {
  // the dihedral angle at edge (i, j) is pi minus the angle between the
  // outward normals of the two faces that share it: the faces opposite the
  // other two vertices k and l
  static constexpr int kEdges[6][4] = {{0, 1, 2, 3}, {0, 2, 1, 3}, {0, 3, 1, 2},
                                       {1, 2, 0, 3}, {1, 3, 0, 2}, {2, 3, 0, 1}};
  // outward (unnormalised) normal of the face opposite vertex v
  auto normal_opposite = [&](int v) {
    int a = (v + 1) % 4, b = (v + 2) % 4, c = (v + 3) % 4;
    Eigen::Vector3d n = (p[b] - p[a]).cross(p[c] - p[a]);
    if (n.dot(p[v] - p[a]) > 0) n = -n;
    return n.normalized();
  };
  for (int e = 0; e < 6; ++e) {
    Eigen::Vector3d nk = normal_opposite(kEdges[e][2]);
    Eigen::Vector3d nl = normal_opposite(kEdges[e][3]);
    double cosine = std::clamp(-nk.dot(nl), -1.0, 1.0);
    angles_deg[e] = std::acos(cosine) * 180.0 / std::numbers::pi;
  }
}

double TetRadiusRatio(const Eigen::Vector3d p[4]) {
  // r_in = 3 V / (sum of face areas); r_circ from the circumcentre formula
  Eigen::Vector3d a = p[1] - p[0], b = p[2] - p[0], c = p[3] - p[0];
  double six_volume = std::abs(a.cross(b).dot(c));
  double area = 0.0;
  for (int v = 0; v < 4; ++v) {
    const Eigen::Vector3d& x = p[(v + 1) % 4];
    const Eigen::Vector3d& y = p[(v + 2) % 4];
    const Eigen::Vector3d& z = p[(v + 3) % 4];
    area += 0.5 * (y - x).cross(z - x).norm();
  }
  if (six_volume == 0.0 || area == 0.0) return 0.0;
  double r_in = 0.5 * six_volume / area;  // 3 V / A with V = six_volume / 6
  Eigen::Vector3d numerator =
      a.squaredNorm() * b.cross(c) + b.squaredNorm() * c.cross(a) + c.squaredNorm() * a.cross(b);
  double r_circ = numerator.norm() / (2.0 * six_volume);
  return 3.0 * r_in / r_circ;
}

MeshQuality ComputeQuality(const TetMesh& mesh) {
  MeshQuality q;
  q.min_dihedral_deg = 180.0;
  q.min_radius_ratio = 1.0;
  double ratio_sum = 0.0;
  for (int t = 0; t < mesh.num_tets(); ++t) {
    Eigen::Vector3d p[4];
    for (int i = 0; i < 4; ++i) p[i] = mesh.positions().row(mesh.tets()(t, i)).transpose();
    double angles[6];
    TetDihedralAngles(p, angles);
    for (double angle : angles) {
      q.min_dihedral_deg = std::min(q.min_dihedral_deg, angle);
      q.max_dihedral_deg = std::max(q.max_dihedral_deg, angle);
    }
    double ratio = TetRadiusRatio(p);
    q.min_radius_ratio = std::min(q.min_radius_ratio, ratio);
    ratio_sum += ratio;
  }
  q.mean_radius_ratio = mesh.num_tets() > 0 ? ratio_sum / mesh.num_tets() : 0.0;
  return q;
}

}  // namespace tetcosim

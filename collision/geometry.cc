#include "collision/geometry.h"

#include <cmath>

namespace tetcosim {

bool TetBarycentric(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                    const Eigen::Vector3d& d, const Eigen::Vector3d& p, Eigen::Vector4d& l) {
  // solve [b-a c-a d-a] (l1 l2 l3)^T = p - a by Cramer's rule
  Eigen::Vector3d e1 = b - a, e2 = c - a, e3 = d - a, r = p - a;
  double det = e1.dot(e2.cross(e3));
  if (det == 0.0 || !std::isfinite(det)) return false;
  double inv = 1.0 / det;
  l[1] = r.dot(e2.cross(e3)) * inv;
  l[2] = e1.dot(r.cross(e3)) * inv;
  l[3] = e1.dot(e2.cross(r)) * inv;
  l[0] = 1.0 - l[1] - l[2] - l[3];
  return true;
}

bool SegmentTriangle(const Eigen::Vector3d& q, const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                     const Eigen::Vector3d& b, const Eigen::Vector3d& c, double& t, double& u,
                     double& v) {
  // Moller-Trumbore: q + t (p - q) = (1-u-v) a + u b + v c
  constexpr double kTolerance = 1e-12;
  Eigen::Vector3d dir = p - q;
  Eigen::Vector3d e1 = b - a, e2 = c - a;
  Eigen::Vector3d h = dir.cross(e2);
  double det = e1.dot(h);
  double scale = e1.norm() * e2.norm() * dir.norm();
  if (std::abs(det) <= 1e-14 * scale || scale == 0.0) return false;  // parallel or degenerate
  double inv = 1.0 / det;
  Eigen::Vector3d s = q - a;
  u = s.dot(h) * inv;
  if (u < -kTolerance || u > 1.0 + kTolerance) return false;
  Eigen::Vector3d k = s.cross(e1);
  v = dir.dot(k) * inv;
  if (v < -kTolerance || u + v > 1.0 + kTolerance) return false;
  t = e2.dot(k) * inv;
  if (t < -kTolerance || t > 1.0 + kTolerance) return false;
  return true;
}

Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                       const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
  // regions in the order: vertex a, vertex b, edge ab, vertex c, edge ac,
  // edge bc, face (Ericson, Real-Time Collision Detection, 5.1.5)
  Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return a;
  Eigen::Vector3d bp = p - b;
  double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return b;
  double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return a + d1 / (d1 - d3) * ab;
  Eigen::Vector3d cp = p - c;
  double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return c;
  double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return a + d2 / (d2 - d6) * ac;
  double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
  }
  double denom = va + vb + vc;
  if (denom == 0.0) return a;  // degenerate triangle
  double v = vb / denom, w = vc / denom;
  return a + v * ab + w * ac;
}

}  // namespace tetcosim

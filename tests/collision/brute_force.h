#pragma once

// Brute-force oracles for the penetration solver's stages (method.md): every
// vertex against every tetrahedron (stage 1), every intersection edge against
// every surface triangle (stages 2 and 3). The solver's fast paths must give
// what these give.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <string>
#include <tuple>
#include <vector>

#include "collision/geometry.h"
#include "collision/penetration.h"
#include "tests/collision/scene_helpers.h"

namespace tetcosim::testing {

// (object, vertex, penetrated) -> containing tet, by testing every vertex
// against every tetrahedron (the oracle for the spatial hash), but for the
// pairs of objects whose bounding boxes, grown by a millionth of their
// extent, are apart (no vertex of one can then be inside the other: a
// scene of hundreds of bodies, brute force in all else)
inline std::map<std::tuple<int, int, int>, int> BruteForceInside(const TestScene& scene) {
  const int num_objects = static_cast<int>(scene.objects.size());
  std::vector<Eigen::Vector3d> lo(num_objects), hi(num_objects);
  for (int o = 0; o < num_objects; ++o) {
    const PositionBounds bounds = PositionBounds::Of(*scene.objects[o].positions);
    lo[o] = bounds.lo;
    hi[o] = bounds.hi;
    const Eigen::Vector3d margin = Eigen::Vector3d::Constant(1e-6 * (hi[o] - lo[o]).maxCoeff());
    lo[o] -= margin;
    hi[o] += margin;
  }
  std::map<std::tuple<int, int, int>, std::pair<double, int>> best;
  for (int b = 0; b < num_objects; ++b) {
    const CollisionObject& ob = scene.objects[b];
    for (int t = 0; t < ob.mesh->num_tets(); ++t) {
      auto tet = ob.mesh->tets().row(t);
      Eigen::Vector3d c[4];
      for (int i = 0; i < 4; ++i) c[i] = ob.positions->row(tet[i]).transpose();
      for (int a = 0; a < num_objects; ++a) {
        const CollisionObject& oa = scene.objects[a];
        if (a == b && !ob.self_collision) continue;
        if (a != b && oa.rigid && ob.rigid) continue;
        if ((lo[a].array() > hi[b].array()).any() || (lo[b].array() > hi[a].array()).any()) {
          continue;
        }
        for (int v = 0; v < oa.mesh->num_vertices(); ++v) {
          if (a == b && (tet.array() == v).any()) continue;
          Eigen::Vector4d l;
          if (!TetBarycentric(c[0], c[1], c[2], c[3], oa.positions->row(v).transpose(), l)) {
            continue;
          }
          if (l.minCoeff() < -kBarycentricTolerance) continue;
          auto key = std::make_tuple(a, v, b);
          auto it = best.find(key);
          if (it == best.end() || l.minCoeff() > it->second.first) best[key] = {l.minCoeff(), t};
        }
      }
    }
  }
  std::map<std::tuple<int, int, int>, int> out;
  for (const auto& [key, value] : best) out[key] = value.second;
  return out;
}

inline void ExpectSameCollidingPoints(const TestScene& scene, PenetrationOptions options) {
  PenetrationSolver solver(options);
  const auto& results = solver.Solve(scene.objects);
  auto expected = BruteForceInside(scene);
  std::map<std::tuple<int, int, int>, int> found;
  for (const PenetrationResult& r : results) found[{r.object, r.vertex, r.penetrated}] = r.tet;
  EXPECT_EQ(solver.stats().unresolved, 0);
  EXPECT_EQ(found.size(), expected.size());
  EXPECT_EQ(found, expected);
}

// the same at the default cell size, tiny cells (many distinct cells share
// buckets) and huge cells (many vertices per cell)
inline void ExpectSameCollidingPointsAtThreeCellSizes(const TestScene& scene) {
  for (double cell : {0.0, 0.002, 0.2}) {
    SCOPED_TRACE(cell);
    PenetrationOptions options;
    options.cell_size = cell;
    ExpectSameCollidingPoints(scene, options);
  }
}

// Stages 2 and 3 by brute force (method.md): for every colliding point p
// and neighbour q not inside B, the crossing of q -> p with any of B's
// surface triangles nearest q, its smooth normal, and the border point's
// depth and direction from the inverse-squared-distance weights; the
// solver's border points must match, whatever path found the crossings
// (small objects' triangles four at a time, the hashed grid, triangles
// too large to hash).
// (depth_tolerance: absolute, metres; positions far from the origin round
// to coarser steps)
inline void ExpectBorderPointsMatchBruteForce(const TestScene& scene, double cell_size,
                                              double depth_tolerance = 1e-12) {
  PenetrationOptions options;
  options.cell_size = cell_size;
  PenetrationSolver solver(options);
  const std::vector<PenetrationResult> results = solver.Solve(scene.objects);
  std::map<std::tuple<int, int, int>, const PenetrationResult*> colliding;
  for (const PenetrationResult& r : results) colliding[{r.object, r.vertex, r.penetrated}] = &r;
  std::vector<Positions> normals(scene.objects.size());
  for (size_t o = 0; o < scene.objects.size(); ++o) {
    ComputeVertexNormals(*scene.objects[o].positions, scene.objects[o].mesh->surface(), normals[o]);
  }
  const double on_surface = 1e-9 * solver.length_scale();
  int border = 0;
  for (const PenetrationResult& r : results) {
    const TetMesh& mesh_a = *scene.objects[r.object].mesh;
    const TetMesh& mesh_b = *scene.objects[r.penetrated].mesh;
    const Positions& x_a = *scene.objects[r.object].positions;
    const Positions& x_b = *scene.objects[r.penetrated].positions;
    const Triangles& surface = mesh_b.surface();
    const Eigen::Vector3d p = x_a.row(r.vertex).transpose();
    double weight_sum = 0.0, depth_sum = 0.0, nearest_distance = 1e300;
    Eigen::Vector3d normal_sum = Eigen::Vector3d::Zero();
    Eigen::Vector3d nearest_normal = Eigen::Vector3d::Zero();
    for (int n = mesh_a.adjacency_offsets()[r.vertex]; n < mesh_a.adjacency_offsets()[r.vertex + 1];
         ++n) {
      const int q_vertex = mesh_a.adjacency()[n];
      if (colliding.count({r.object, q_vertex, r.penetrated})) continue;
      const Eigen::Vector3d q = x_a.row(q_vertex).transpose();
      double best_t = 1e300, best_u = 0.0, best_v = 0.0;
      int best_f = -1;
      for (int f = 0; f < surface.rows(); ++f) {
        if (r.object == r.penetrated && ((surface.row(f).array() == r.vertex).any() ||
                                         (surface.row(f).array() == q_vertex).any())) {
          continue;  // self-collision: the edge's own triangles do not count
        }
        double t, u, v;
        if (SegmentTriangle(q, p, x_b.row(surface(f, 0)).transpose(),
                            x_b.row(surface(f, 1)).transpose(), x_b.row(surface(f, 2)).transpose(),
                            t, u, v) &&
            t < best_t) {
          best_t = t;
          best_u = u;
          best_v = v;
          best_f = f;
        }
      }
      if (best_f < 0) continue;
      const Eigen::Vector3d point = q + best_t * (p - q);
      Eigen::Vector3d normal =
          ((1.0 - best_u - best_v) * normals[r.penetrated].row(surface(best_f, 0)) +
           best_u * normals[r.penetrated].row(surface(best_f, 1)) +
           best_v * normals[r.penetrated].row(surface(best_f, 2)))
              .transpose();
      ASSERT_GT(normal.norm(), 1e-6);  // (the scenes have no cancelling vertex normals)
      normal.normalize();
      const double distance = (point - p).norm();
      if (distance < nearest_distance) {
        nearest_distance = distance;
        nearest_normal = normal;
      }
      if (distance < on_surface) continue;  // p on B's surface (the guard of stage 3)
      const double w = 1.0 / (distance * distance);
      weight_sum += w;
      depth_sum += w * (point - p).dot(normal);
      normal_sum += w * normal;
    }
    SCOPED_TRACE(::testing::Message()
                 << "object " << r.object << " vertex " << r.vertex << " in " << r.penetrated);
    if (nearest_distance == 1e300) {  // no crossing: not a border point
      EXPECT_NE(r.source, DepthSource::kBorder);
      continue;
    }
    ++border;
    ASSERT_EQ(r.source, DepthSource::kBorder);
    if (nearest_distance < on_surface || weight_sum == 0.0) {
      EXPECT_EQ(r.depth, 0.0);
      EXPECT_LT((r.direction - nearest_normal).norm(), 1e-9);
    } else {
      EXPECT_NEAR(r.depth, std::max(0.0, depth_sum / weight_sum), depth_tolerance);
      // (normals that cancel leave the nearest crossing's)
      const Eigen::Vector3d direction = normal_sum.norm() > 1e-12 * weight_sum
                                            ? Eigen::Vector3d(normal_sum.normalized())
                                            : nearest_normal;
      EXPECT_LT((r.direction - direction).norm(), 1e-9);
    }
  }
  EXPECT_GT(border, 20);  // the scene has border points at all
}

}  // namespace tetcosim::testing

#pragma once

// Shared oracles for tests on tetrahedral meshes.

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <map>
#include <set>
#include <utility>

#include "mesh/tet_mesh.h"

namespace tetcosim::testing {

// Volume enclosed by the surface, by the divergence theorem:
// V = 1/6 sum over triangles of a . (b x c).
inline double EnclosedVolume(const TetMesh& mesh) {
  double volume = 0.0;
  for (Eigen::Index f = 0; f < mesh.surface().rows(); ++f) {
    Eigen::Vector3d a = mesh.positions().row(mesh.surface()(f, 0));
    Eigen::Vector3d b = mesh.positions().row(mesh.surface()(f, 1));
    Eigen::Vector3d c = mesh.positions().row(mesh.surface()(f, 2));
    volume += a.dot(b.cross(c)) / 6.0;
  }
  return volume;
}

// V - E + F of the surface.
inline int SurfaceEulerCharacteristic(const TetMesh& mesh) {
  std::set<std::pair<int, int>> edges;
  std::set<int> vertices;
  for (Eigen::Index f = 0; f < mesh.surface().rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      int a = mesh.surface()(f, k);
      int b = mesh.surface()(f, (k + 1) % 3);
      edges.insert(std::minmax(a, b));
      vertices.insert(a);
    }
  }
  return static_cast<int>(vertices.size()) - static_cast<int>(edges.size()) +
         static_cast<int>(mesh.surface().rows());
}

// Closed and consistently oriented: every directed edge of the surface
// appears exactly once and its reverse exactly once.
inline ::testing::AssertionResult IsClosedOrientedSurface(const TetMesh& mesh) {
  std::map<std::pair<int, int>, int> directed;
  for (Eigen::Index f = 0; f < mesh.surface().rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      ++directed[{mesh.surface()(f, k), mesh.surface()(f, (k + 1) % 3)}];
    }
  }
  for (const auto& [edge, count] : directed) {
    if (count != 1) {
      return ::testing::AssertionFailure() << "directed edge " << edge.first << "->" << edge.second
                                           << " appears " << count << " times";
    }
    if (!directed.contains({edge.second, edge.first})) {
      return ::testing::AssertionFailure()
             << "edge " << edge.first << "->" << edge.second << " has no opposite";
    }
  }
  return ::testing::AssertionSuccess();
}

}  // namespace tetcosim::testing

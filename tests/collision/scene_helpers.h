#pragma once

// Small scenes of tetrahedral objects for collision tests.

#include <Eigen/Geometry>
#include <memory>
#include <vector>

#include "collision/penetration.h"
#include "mesh/generators.h"

namespace tetcosim::testing {

struct TestScene {
  std::vector<std::unique_ptr<TetMesh>> meshes;
  std::vector<std::unique_ptr<Positions>> positions;
  std::vector<CollisionObject> objects;

  // adds a mesh placed by X_WB (rest positions mapped to world)
  int Add(TetMesh mesh, const Eigen::Isometry3d& X_WB = Eigen::Isometry3d::Identity(),
          bool rigid = false, bool self_collision = false) {
    meshes.push_back(std::make_unique<TetMesh>(std::move(mesh)));
    auto x = std::make_unique<Positions>(meshes.back()->positions());
    for (Eigen::Index v = 0; v < x->rows(); ++v) {
      x->row(v) = (X_WB * x->row(v).transpose()).transpose();
    }
    positions.push_back(std::move(x));
    objects.push_back({meshes.back().get(), positions.back().get(), rigid, self_collision});
    return static_cast<int>(objects.size()) - 1;
  }
  int Add(const std::string& spec, const Eigen::Vector3d& translation, bool rigid = false) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.translation() = translation;
    return Add(TetMesh::Build(MakeShape(spec)), X, rigid);
  }
};

inline Eigen::Isometry3d Pose(const Eigen::Vector3d& translation, double angle = 0.0,
                              const Eigen::Vector3d& axis = Eigen::Vector3d::UnitZ()) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  X.translation() = translation;
  return X;
}

}  // namespace tetcosim::testing

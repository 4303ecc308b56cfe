#pragma once

// Small scenes of tetrahedral objects for collision tests.

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <memory>
#include <numbers>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "collision/penetration.h"
#include "mesh/generators.h"
#include "mesh/same_bits.h"

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

// Two tetrahedra on the two sides of a triangle (radius r, apexes h above
// and below): 6 surface triangles, not a multiple of four (the solver keeps
// a small body's triangles in groups of four; the last group's other lanes
// must meet nothing).
inline RawMesh Bipyramid(double r, double h) {
  RawMesh raw;
  raw.positions.resize(5, 3);
  for (int i = 0; i < 3; ++i) {
    const double a = 2.0 * std::numbers::pi * i / 3.0;
    raw.positions.row(i) << r * std::cos(a), r * std::sin(a), 0.0;
  }
  raw.positions.row(3) << 0.0, 0.0, h;
  raw.positions.row(4) << 0.0, 0.0, -h;
  raw.tets.resize(2, 4);
  raw.tets << 0, 1, 2, 3, 0, 2, 1, 4;
  raw.source = "bipyramid";
  return raw;
}

// A pile of small bodies in and around a large one: a large box
// (rigid in odd trials), 14 small bodies (the paper's 20-tet spheres and a
// bipyramid of 6 triangles among them), and a bar folded into itself with
// self-collision.
inline TestScene CrowdedScene(int trial) {
  std::mt19937 rng(11 + trial);
  std::uniform_real_distribution<double> offset(-0.07, 0.07);
  std::uniform_real_distribution<double> angle(0.0, std::numbers::pi);
  const char* shapes[] = {"sphere:size=0.03:res=0", "box:size=0.03,0.02,0.025:res=2",
                          "capsule:size=0.01,0.02:res=2"};
  TestScene scene;
  scene.Add(TetMesh::Build(MakeShape("box:size=0.12,0.12,0.12:res=4")), Pose({0, 0, 0}),
            /*rigid=*/trial % 2 == 1);
  for (int k = 0; k < 14; ++k) {
    Eigen::Vector3d axis(offset(rng), offset(rng), offset(rng) + 0.01);
    scene.Add(TetMesh::Build(k % 4 == 3 ? Bipyramid(0.03, 0.025) : MakeShape(shapes[k % 3])),
              Pose({offset(rng), offset(rng), offset(rng)}, angle(rng), axis),
              /*rigid=*/k % 5 == 4);
  }
  int bar = scene.Add(TetMesh::Build(MakeShape("box:size=0.2,0.02,0.02:res=10,1,1")),
                      Pose({0, 0.01 * trial, 0}), false, /*self_collision=*/true);
  Positions& x = *scene.positions[bar];
  for (Eigen::Index v = 0; v < x.rows(); ++v) {
    if (x(v, 0) > 0.19) x(v, 0) = -0.03;
  }
  return scene;
}

// A layer of side x side paper spheres (radius 2 cm, 20 tetrahedra) 3 cm
// apart, each overlapping its neighbours, jittered by up to 3 mm and turned
// about z (seeded), one in five rigid. At 24 x 24 (576 objects) the broad
// phase cuts it into strips (from 512).
inline TestScene SphereLayer(int side, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.003, 0.003);
  const TetMesh sphere = TetMesh::Build(MakeShape("sphere:size=0.02:res=0"));
  TestScene scene;
  for (int i = 0; i < side; ++i) {
    for (int j = 0; j < side; ++j) {
      const Eigen::Vector3d at(0.03 * i + jitter(rng), 0.03 * j + jitter(rng), jitter(rng));
      scene.Add(sphere, Pose(at, 100 * jitter(rng)), /*rigid=*/(i + j) % 5 == 0);
    }
  }
  return scene;
}

// The same results bit for bit (what: the run compared, for messages).
inline void ExpectSameResults(const std::vector<PenetrationResult>& expected,
                              const std::vector<PenetrationResult>& actual,
                              const std::string& what) {
  ASSERT_EQ(expected.size(), actual.size()) << what;
  for (size_t i = 0; i < actual.size(); ++i) {
    const auto& x = expected[i];
    const auto& y = actual[i];
    EXPECT_EQ(std::tie(x.object, x.vertex, x.penetrated, x.tet),
              std::tie(y.object, y.vertex, y.penetrated, y.tet))
        << what;
    EXPECT_TRUE(SameBits({&x.depth, 1}, {&y.depth, 1})) << what;
    EXPECT_TRUE(SameBits({x.direction.data(), 3}, {y.direction.data(), 3})) << what;
    EXPECT_EQ(x.source, y.source) << what;
  }
}

}  // namespace tetcosim::testing

// Closest features (collision/closest_features.cc): the baseline method
// against brute force, and the fallback for points with no border point.

#include <gtest/gtest.h>

#include <algorithm>

#include "collision/geometry.h"
#include "collision/penetration.h"
#include "tests/collision/scene_helpers.h"

namespace tetcosim {
namespace {

using testing::TestScene;

// The closest features against brute force: a torus and a ball in each
// other (each searched through its box tree), and a coarse box's corner in
// a fine ball (the ball has one query: searched whole).
TEST(ClosestFeature, AcceleratedSearchMatchesBruteForce) {
  for (int trial = 0; trial < 2; ++trial) {
    TestScene scene;
    if (trial == 0) {
      scene.Add("torus:size=0.06,0.025:res=3", {0, 0, 0});
      scene.Add("sphere:size=0.04:res=2", {0.05, 0.01, 0.0});
    } else {
      scene.Add("box:size=0.5,0.5,0.5:res=1", {0, 0, 0});
      scene.Add("sphere:size=0.02:res=3", {0.51, 0.505, 0.503});
    }
    PenetrationOptions options;
    options.method = DepthMethod::kClosest;
    PenetrationSolver solver(options);
    solver.Solve(scene.objects);
    ASSERT_FALSE(solver.results().empty());
    for (const PenetrationResult& r : solver.results()) {
      const CollisionObject& b = scene.objects[r.penetrated];
      Eigen::Vector3d p = scene.objects[r.object].positions->row(r.vertex);
      double best = 1e300;
      for (Eigen::Index f = 0; f < b.mesh->surface().rows(); ++f) {
        Eigen::Vector3d c = ClosestPointOnTriangle(p, b.positions->row(b.mesh->surface()(f, 0)),
                                                   b.positions->row(b.mesh->surface()(f, 1)),
                                                   b.positions->row(b.mesh->surface()(f, 2)));
        best = std::min(best, (c - p).norm());
      }
      EXPECT_NEAR(r.depth, best, 1e-15);
      EXPECT_EQ(r.source, DepthSource::kClosest);
    }
  }
}

TEST(Fallback, EnclosedObjectGetsFlaggedValues) {
  TestScene scene;
  int box = scene.Add("box:size=0.2,0.2,0.2:res=4", {0, 0, 0});
  int inner = scene.Add("sphere:size=0.03:res=1", {0.05, 0.02, -0.01});
  PenetrationSolver solver;
  solver.Solve(scene.objects);
  int fallback = 0;
  for (const PenetrationResult& r : solver.results()) {
    ASSERT_EQ(r.object, inner);
    EXPECT_EQ(r.penetrated, box);
    EXPECT_EQ(r.source, DepthSource::kFallback);
    // the nearest face of the box is +x at 0.2
    Eigen::Vector3d p = scene.positions[inner]->row(r.vertex);
    double nearest = (Eigen::Vector3d::Constant(0.2) - p.cwiseAbs()).minCoeff();
    EXPECT_NEAR(r.depth, nearest, 1e-12);
    ++fallback;
  }
  EXPECT_EQ(fallback, scene.meshes[inner]->num_vertices());
  EXPECT_EQ(solver.stats().fallback, fallback);

  PenetrationOptions no_fallback;
  no_fallback.fallback = false;
  PenetrationSolver strict(no_fallback);
  EXPECT_TRUE(strict.Solve(scene.objects).empty());
  EXPECT_EQ(strict.stats().unresolved, fallback);
}

// The fallback searches all of B's surface, also the triangles already in
// play for another partner: a ball enclosed in a large box just behind its
// +x face, and a small box pushed into that face right in front of the
// ball (so the face's triangles nearest the ball are in B's table for the
// small box's sake, the rest are added for the fallback). The ball's
// points get the distance to the nearest face, solve after solve.
TEST(Fallback, SearchesTheWholeSurface) {
  TestScene scene;
  int box = scene.Add("box:size=0.2,0.2,0.2:res=8", {0, 0, 0});
  int ball = scene.Add("sphere:size=0.03:res=2", {0.15, 0.004, -0.003});
  int poker = scene.Add("box:size=0.05,0.05,0.05:res=2", {0.24, 0.0, 0.0});
  PenetrationSolver solver;
  for (int solve = 0; solve < 2; ++solve) {
    solver.Solve(scene.objects);
    int fallback = 0, poked = 0;
    for (const PenetrationResult& r : solver.results()) {
      if (r.penetrated != box) continue;  // (the box's face inside the small box)
      if (r.object == poker) {
        ++poked;
        continue;
      }
      ASSERT_EQ(r.object, ball);
      EXPECT_EQ(r.source, DepthSource::kFallback);
      const Eigen::Vector3d p = scene.positions[ball]->row(r.vertex);
      EXPECT_NEAR(r.depth, (Eigen::Vector3d::Constant(0.2) - p.cwiseAbs()).minCoeff(), 1e-12);
      ++fallback;
    }
    EXPECT_EQ(fallback, scene.meshes[ball]->num_vertices());
    EXPECT_GT(poked, 0);
  }
}

}  // namespace
}  // namespace tetcosim

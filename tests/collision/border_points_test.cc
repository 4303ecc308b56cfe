// Stages 2 and 3 (collision/border_points.cc): border points, their
// crossings, depths and directions, against brute force.

#include <gtest/gtest.h>

#include "collision/penetration.h"
#include "tests/collision/brute_force.h"
#include "tests/collision/scene_helpers.h"

namespace tetcosim {
namespace {

using testing::CrowdedScene;
using testing::ExpectBorderPointsMatchBruteForce;
using testing::TestScene;

TEST(BorderPoints, MatchBruteForceInCrowdedScenes) {
  for (int trial = 0; trial < 2; ++trial) {
    const TestScene scene = CrowdedScene(trial);
    // default-like cells, tiny cells (the large box's triangles are too
    // large to hash) and huge ones
    for (double cell : {0.01, 0.002, 0.2}) {
      SCOPED_TRACE(::testing::Message() << "trial " << trial << " cell " << cell);
      ExpectBorderPointsMatchBruteForce(scene, cell);
    }
  }
}

// A coarse box (edges of 1 m and longer) with a corner in a finely meshed
// ball (cells of 5 mm): the box's edges from that corner each cover up to
// 10^7 cells, so stage 2 tests the ball's whole triangle hash instead of
// looking the cells up one by one; the border points still match brute
// force, both ways (the ball's vertices inside the box cross its large
// faces).
TEST(BorderPoints, LongEdgesIntoAFineBodyMatchBruteForce) {
  TestScene scene;
  scene.Add("box:size=0.5,0.5,0.5:res=1", {0, 0, 0});
  scene.Add("sphere:size=0.02:res=3", {0.5, 0.5, 0.5});
  ExpectBorderPointsMatchBruteForce(scene, 0.005);
}

}  // namespace
}  // namespace tetcosim

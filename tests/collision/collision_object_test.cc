#include "collision/collision_object.h"

#include <gtest/gtest.h>

#include <limits>
#include <string>
#include <vector>

#include "collision/penetration.h"
#include "mesh/error.h"
#include "tests/collision/scene_helpers.h"

namespace tetcosim {
namespace {

using testing::ExpectSameResults;
using testing::Pose;
using testing::TestScene;

// PositionBounds against the box and finiteness computed coordinate by
// coordinate; given as RigidFrame::bounds, a box of other positions (kept
// from before a move, or of a vertex gone to infinity) is a clear error,
// and bounds of positions that are not all finite leave the object out, as
// the solver's own pass does.
TEST(FramedObjects, GivenBoxIsCheckedAndNonFiniteLeftOut) {
  TestScene scene;
  scene.Add(TetMesh::Build(MakeShape("box:size=0.1,0.1,0.02:res=10,10,2")), Pose({0, 0, 0}),
            /*rigid=*/true);
  scene.Add("sphere:size=0.02:res=2", {0.01, 0.02, 0.03});
  const Positions& x = *scene.positions[0];
  const PositionBounds bounds = PositionBounds::Of(x);
  EXPECT_TRUE(bounds.finite());
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(bounds.lo[k], x.col(k).minCoeff());
    EXPECT_EQ(bounds.hi[k], x.col(k).maxCoeff());
  }
  RigidFrame frame;
  frame.bounds = bounds;
  std::vector<CollisionObject> framed = scene.objects;
  framed[0].frame = &frame;
  PenetrationSolver solver, without;
  ExpectSameResults(without.Solve(scene.objects), solver.Solve(framed), "as given");
  ASSERT_GT(solver.results().size(), 10u);
  // moved, the box not
  *scene.positions[0] = scene.positions[0]->array() + 0.01;
  try {
    solver.Solve(framed);
    ADD_FAILURE() << "a box of other positions was taken";
  } catch (const Error& error) {
    const std::string message = error.what();
    EXPECT_NE(message.find("object 0"), std::string::npos) << message;
    EXPECT_NE(message.find("RigidFrame::bounds"), std::string::npos) << message;
  }
  frame.bounds = PositionBounds::Of(*scene.positions[0]);
  ExpectSameResults(without.Solve(scene.objects), solver.Solve(framed), "moved, box again");
  // the last vertex at infinity: the given box must say so, and the object
  // is left out
  (*scene.positions[0])(x.rows() - 1, 2) = std::numeric_limits<double>::infinity();
  EXPECT_THROW(solver.Solve(framed), Error);
  frame.bounds = PositionBounds::Of(*scene.positions[0]);
  EXPECT_FALSE(frame.bounds->finite());
  ExpectSameResults(without.Solve(scene.objects), solver.Solve(framed), "not finite");
  EXPECT_EQ(solver.stats().non_finite_objects, 1);
  EXPECT_EQ(without.stats().non_finite_objects, 1);
}

}  // namespace
}  // namespace tetcosim

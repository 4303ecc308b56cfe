// A warm World::Step allocates nothing (tests/support/allocation_counter.h
// counts every allocation): the coupled step works in arrays it keeps
// (CoupledStepWorkspace), the rigid system keeps its trees', points' and
// constraints' arrays (RigidSystem::Clear), and arrays sized by a count
// grow with room (mesh/vector_room.h). A step still allocates where a size
// reaches a new high, or where a rigid tree joins or leaves the system
// (the system's size changes): so the scenes are stepped first through
// their settling, to where their contacts hold, and then counted.

#include <gtest/gtest.h>

#include <memory>
#include <string>
#include <vector>

#include "mujoco_bridge/world.h"
#include "tests/mujoco_bridge/lid_scene.h"
#include "tests/mujoco_bridge/temp_dir.h"
#include "tests/support/allocation_counter.h"

namespace tetcosim {
namespace {

// A soft cube resting on a lid whose hinge is damped, the lid held on its
// joint limit by gravity and the cube (as the lids of world_test.cc): a
// constraint on a damped tree, scaled every step (World::ScaleForDamping)
std::string LidOnItsLimit() {
  return LidScene(R"(damping="0.5" range="-90 0" limited="true")", R"(pos="0.05 0 0.245")");
}

struct SteadyScene {
  std::string path;
  int warm_steps;     // through the settling
  int counted_steps;  // then counted
  bool contacts;      // (the strap has none: its attachments)
};

// Each bundled scene that settles: a cube resting on a MuJoCo box (mesh
// contacts both ways), the gripper holding a soft block (a robot's trees
// and MuJoCo's constraints solved with the step), a strap hung from a
// swinging body (attachments carried by its tree) and a block on a height
// field (geom contacts); and the damped lid above. On one and on two
// threads, with either method.
TEST(WorldAllocation, WarmStepsOfSettledScenesAllocateNothing) {
  TempDir dir;
  const std::string bundled = std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/";
  const std::vector<SteadyScene> scenes = {
      {bundled + "cube_on_box.xml", 450, 150, true},
      {bundled + "gripper.xml", 300, 150, true},
      {bundled + "strap.xml", 60, 60, false},
      {bundled + "terrain.xml", 200, 100, true},
      {dir.Write("damped_lid.xml", LidOnItsLimit()), 300, 100, true},
  };
  for (const SteadyScene& scene : scenes) {
    for (const DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
      for (const int threads : {1, 2}) {
        SCOPED_TRACE(scene.path + (method == DepthMethod::kClosest ? ", closest" : "") + ", " +
                     std::to_string(threads) + " threads");
        WorldOptions options;
        options.threads = threads;
        options.method = method;
        std::unique_ptr<World> world = World::Load(scene.path, options);
        for (int k = 0; k < scene.warm_steps; ++k) world->Step();
        ASSERT_EQ(world->metrics().status, StepStatus::kOk);
        const long before = testing::HeapAllocations();
        for (int k = 0; k < scene.counted_steps; ++k) world->Step();
        const long allocations = testing::HeapAllocations() - before;
        ASSERT_EQ(world->metrics().status, StepStatus::kOk);
        EXPECT_EQ(world->metrics().colliding_points > 0, scene.contacts);
        EXPECT_EQ(allocations, 0) << "in " << scene.counted_steps << " steps";
      }
    }
  }
}

}  // namespace
}  // namespace tetcosim

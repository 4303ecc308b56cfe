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

#include "mujoco_bridge/world.h"
#include "tests/support/allocation_counter.h"

namespace tetcosim {
namespace {

struct SteadyScene {
  const char* name;
  int warm_steps;     // through the settling
  int counted_steps;  // then counted
  bool contacts;      // (the strap has none: its attachments)
};

// Each bundled scene that settles: a cube resting on a MuJoCo box (mesh
// contacts both ways), the gripper holding a soft block (a robot's trees
// and MuJoCo's constraints solved with the step), a strap hung from a
// swinging body (attachments carried by its tree) and a block on a height
// field (geom contacts); on one and on two threads, with either method.
TEST(WorldAllocation, WarmStepsOfSettledScenesAllocateNothing) {
  for (const SteadyScene& scene :
       {SteadyScene{"cube_on_box", 450, 150, true}, SteadyScene{"gripper", 300, 150, true},
        SteadyScene{"strap", 60, 60, false}, SteadyScene{"terrain", 200, 100, true}}) {
    for (const DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
      for (const int threads : {1, 2}) {
        SCOPED_TRACE(std::string(scene.name) +
                     (method == DepthMethod::kClosest ? ", closest" : "") + ", " +
                     std::to_string(threads) + " threads");
        WorldOptions options;
        options.threads = threads;
        options.method = method;
        std::unique_ptr<World> world = World::Load(
            std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/" + scene.name + ".xml", options);
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

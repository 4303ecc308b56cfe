// A warm World::Step allocates nothing (tests/support/allocation_counter.h
// counts every allocation): the coupled step works in arrays it keeps
// (CoupledStepWorkspace), the rigid system keeps its trees', points' and
// constraints' arrays (RigidSystem::Clear), and arrays sized by a count
// grow with room (mesh/vector_room.h), also those sized by the system's
// degrees of freedom, which change as rigid trees join and leave it
// (VectorXdWithRoom). A step still allocates where a size reaches a new
// high: so the scenes are stepped first through their settling, to where
// their contacts hold, or through a few periods of their motion, and then
// counted.

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
// (and under RK4, whose matrix for the damping World::TreeMass computes)
std::string LidOnItsLimit(const std::string& option = "") {
  return LidScene(R"(damping="0.5" range="-90 0" limited="true")", R"(pos="0.05 0 0.245")", option);
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
// swinging body (attachments carried by its tree) and soft bodies on a height
// field (geom contacts); and the damped lid above, with Euler and RK4. On one and on two
// threads, with either method.
TEST(WorldAllocation, WarmStepsOfSettledScenesAllocateNothing) {
  TempDir dir;
  const std::string bundled = std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/";
  const std::vector<SteadyScene> scenes = {
      {bundled + "cube_on_box.xml", 450, 150, true},
      {bundled + "gripper.xml", 300, 150, true},
      {bundled + "strap.xml", 60, 60, false},
      {bundled + "terrain.xml", 600, 100, true},
      {dir.Write("damped_lid.xml", LidOnItsLimit()), 300, 100, true},
      {dir.Write("damped_lid_rk4.xml", LidOnItsLimit(R"(integrator="RK4")")), 300, 100, true},
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

// An arm spun by a velocity servo about a vertical axis, whose capsule
// brushes over the top of a soft block glued to the ground once a turn
// (every 1.08 s; MuJoCo's implicit integrator, which takes the servo's
// rate): its tree joins the coupled step as it meets the block and leaves
// it as they part (twice a pass: the capsule hops off the block midway),
// and the system's size changes with it. Before VectorXdWithRoom, each
// join and each leave allocated 14 to 15 times (the coupled step's vectors
// of that size, allocated anew).
TEST(WorldAllocation, ARigidTreeJoiningAndLeavingTheStepAllocatesNothingOnceWarm) {
  TempDir dir;
  const std::string path = dir.Write("sweep.xml", R"(<mujoco>
  <option timestep="0.005" integrator="implicit"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="arm" pos="0 0 0.0715">
      <joint name="spin" type="hinge" axis="0 0 1" damping="0.01"/>
      <geom name="arm" type="capsule" fromto="0 0 0 0.2 0 0" size="0.012" mass="0.2"/>
    </body>
  </worldbody>
  <actuator>
    <velocity name="spin" joint="spin" kv="1"/>
  </actuator>
  <keyframe><key name="start" qpos="3.14" qvel="6" ctrl="6"/></keyframe>
  <deformable>
    <contact friction="0.3"/>
    <tetbody name="block" shape="box" size="0.03 0.03 0.03" resolution="3" pos="0.12 0 0.03"
             density="1000" young="1e5"/>
    <attach tetbody="block" body="world" box="-1 -1 -0.001 1 1 0.001"/>
  </deformable>
</mujoco>)");
  for (const int threads : {1, 2}) {
    SCOPED_TRACE(std::to_string(threads) + " threads");
    WorldOptions options;
    options.threads = threads;
    std::unique_ptr<World> world = World::Load(path, options);
    // (fourteen passes: the capsule's proxy, fine, meets the block at more
    // points in some passes than in others, and the storage grows to the
    // most of them; after four passes it still grew, on two threads)
    for (int k = 0; k < 3000; ++k) world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk);
    const long before = testing::HeapAllocations();
    int joins = 0, leaves = 0;
    size_t trees = world->rigid_system().trees.size();
    for (int k = 0; k < 1300; ++k) {  // (six passes)
      world->Step();
      const size_t now = world->rigid_system().trees.size();
      joins += now > trees;
      leaves += now < trees;
      trees = now;
    }
    const long allocations = testing::HeapAllocations() - before;
    ASSERT_EQ(world->metrics().status, StepStatus::kOk);
    std::printf(
        "%d threads: the arm joined %d times and left %d times in 1300 steps, %ld allocations\n",
        threads, joins, leaves, allocations);
    EXPECT_GE(joins, 6);
    EXPECT_GE(leaves, 6);
    EXPECT_EQ(allocations, 0) << "in 1300 steps, the arm's tree joining " << joins
                              << " times and leaving " << leaves << " times";
  }
}

}  // namespace
}  // namespace tetcosim

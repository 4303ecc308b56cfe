// Bodies moved by mocap (a program sets mocap_pos and mocap_quat each step,
// as a teleoperated hand or a scripted pusher is). MuJoCo 2.2.2 moves such a
// body without giving it a velocity, and tetcosim meets it as MuJoCo's own
// bodies do: it pushes what it moves into (by depth), but its friction and
// damping see it at rest, so a mocap platform slides out from under a soft
// block as it does from under a rigid box; a platform with a free joint
// welded to the mocap body (MuJoCo's way to drive a body) carries both.
// The rollout metrics follow a mocap body where it goes. Labelled
// "scenario".

#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cstdio>
#include <string>

#include "mujoco_bridge/scenario.h"
#include "tests/mujoco_bridge/temp_dir.h"

namespace tetcosim {
namespace {

constexpr double kSpeed = 0.2;  // m/s, the mocap body's

// a soft block 10 cm across and a rigid box beside it, on a platform 1 m
// wide; the platform is the mocap body itself, or a body on a free joint
// welded to it
constexpr char kMocapPlatform[] = R"(
    <body name="platform" mocap="true" pos="0 0 -0.05">
      <geom type="box" size="0.5 0.5 0.05"/>
    </body>)";
constexpr char kWeldedPlatform[] = R"(
    <body name="target" mocap="true" pos="0 0 -0.05"/>
    <body name="platform" pos="0 0 -0.05">
      <freejoint/>
      <geom type="box" size="0.5 0.5 0.05" density="100"/>
    </body>)";
constexpr char kWeld[] = R"(<equality><weld body1="target" body2="platform"/></equality>)";

std::string PlatformScene(bool welded) {
  return std::string(R"(<mujoco>
  <option timestep="0.002"/>
  <worldbody>)") +
         (welded ? kWeldedPlatform : kMocapPlatform) + R"(
    <body name="box" pos="0 0.2 0.05"><freejoint/><geom type="box" size="0.05 0.05 0.05"/></body>
  </worldbody>)" +
         (welded ? kWeld : "") + R"(
  <deformable>
    <tetbody name="block" shape="box" size="0.05 0.05 0.05" resolution="4" pos="0 0 0.05"/>
  </deformable>
</mujoco>)";
}

// Where the block and the box are after the platform has moved for 1.5 s
// at kSpeed, having stood still for 0.5 s while they settled.
struct Carried {
  double target = 0.0;    // m along x, where the mocap body was put last
  double platform = 0.0;  // m along x
  double block = 0.0;     // the block's centre of mass, m along x
  double block_speed = 0.0;
  double box = 0.0;
};

Carried RunPlatform(bool welded) {
  TempDir dir("tetcosim_mocap");
  Scenario scenario(dir.Write("platform.xml", PlatformScene(welded)));
  World& world = scenario.world();
  Carried carried;
  scenario.SetController([&](World& w) {
    carried.target = w.time() < 0.5 ? 0.0 : kSpeed * (w.time() - 0.5);
    w.mj_data()->mocap_pos[0] = carried.target;
  });
  EXPECT_TRUE(scenario.Run(2.0)) << scenario.message();
  const DeformableBody& block = world.deformable(0);
  carried.platform = world.RigidBodyPosition(world.BodyId("platform")).x();
  carried.block = block.CenterOfMass().x();
  carried.block_speed = block.LinearMomentum().x() / block.model().total_mass();
  carried.box = world.RigidBodyPosition(world.BodyId("box")).x();
  std::printf("%s: platform at x = %.4f m, block %.4f m (%.4f m/s), box %.4f m\n",
              welded ? "welded platform" : "mocap platform", carried.platform, carried.block,
              carried.block_speed, carried.box);
  return carried;
}

TEST(Mocap, APlatformMovedByMocapCarriesNothingAsInMuJoCo) {
  const Carried carried = RunPlatform(/*welded=*/false);
  EXPECT_NEAR(carried.target, kSpeed * 1.5, 0.01);
  EXPECT_EQ(carried.platform, carried.target);
  // MuJoCo's own box stays where it was; so does the soft block
  EXPECT_NEAR(carried.box, 0.0, 1e-3);
  EXPECT_NEAR(carried.block, 0.0, 1e-3);
}

TEST(Mocap, APlatformWeldedToAMocapBodyCarriesTheBlock) {
  const Carried carried = RunPlatform(/*welded=*/true);
  // (the weld is soft: the platform trails the mocap body by its speed
  // times about twice the weld's time constant, 0.02 s by default)
  EXPECT_NEAR(carried.platform, carried.target - kSpeed * 0.04, 0.002);
  // the box and the block ride along, at the platform's speed
  EXPECT_NEAR(carried.box, carried.platform, 0.002);
  EXPECT_NEAR(carried.block, carried.platform, 0.002);
  EXPECT_NEAR(carried.block_speed, kSpeed, 0.01 * kSpeed);
}

// A rod moved down by mocap through a soft membrane held at its rim: it
// pushes the membrane ahead (a kinematic body cannot be stopped), and when
// the membrane has stretched as far as the contact can hold, the rod goes
// through it. The metrics count that pass-through: they follow the rod's
// centre where mocap takes it (a body fixed to the world keeps its place).
TEST(Mocap, ARodPushedThroughAMembraneIsCountedAsPassingThrough) {
  TempDir dir("tetcosim_mocap");
  Scenario scenario(dir.Write("membrane.xml", R"(<mujoco>
  <option timestep="0.001" gravity="0 0 0"/>
  <worldbody>
    <body name="left"/>
    <body name="right"/>
    <body name="rod" mocap="true" pos="0 0 0.1">
      <geom name="rod" type="capsule" size="0.01 0.03"/></body>
  </worldbody>
  <deformable>
    <tetbody name="membrane" shape="box" size="0.1 0.1 0.005" resolution="10 10 1"
             young="1e4"/>
    <attach tetbody="membrane" body="left" box="-1 -1 -1 -0.095 1 1"/>
    <attach tetbody="membrane" body="right" box="0.095 -1 -1 1 1 1"/>
  </deformable>
</mujoco>)"));
  World& world = scenario.world();
  scenario.SetController([](World& w) { w.mj_data()->mocap_pos[2] = 0.1 - 1.0 * w.time(); });
  double lowest = 0.0;
  ASSERT_TRUE(scenario.Run(0.5, [&](World& w) {
    lowest = std::min(lowest, w.deformable(0).positions().col(2).minCoeff());
  })) << scenario.message();
  const RolloutSummary summary = scenario.Summarize();
  const double rod = world.RigidBodyPosition(world.BodyId("rod")).z();
  std::printf(
      "rod at z = %.3f m, the membrane's centre at %.4f m (lowest %.4f m); "
      "pass-through pairs %d\n",
      rod, world.deformable(0).CenterOfMass().z(), lowest, summary.pass_through_pairs);
  EXPECT_LT(lowest, -0.02) << "the rod pushed the membrane ahead";
  EXPECT_LT(rod + 0.04, lowest) << "the rod is through";
  ASSERT_EQ(summary.pass_through_pairs, 1);
  ASSERT_EQ(summary.events.size(), 1u);
  EXPECT_EQ(summary.events[0].name_a + " " + summary.events[0].name_b, "membrane rod");
}

}  // namespace
}  // namespace tetcosim

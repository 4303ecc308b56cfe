// Substeps against one step: MuJoCo steps once, after the deformables'
// substeps, so the rigid bodies must end each step where the substeps moved
// them (World::FollowSubstepPaths). A light two-link arm dropped onto a
// stiff deformable slab comes to rest, with 3 substeps, at the pose it
// rests at with one (left where MuJoCo's one update put it, the hand kept
// rocking at 2e-8 J, 3 um deeper). Labelled "scenario" (each drop rests
// in about 0.25 s of simulation, 1.3 s of both on this machine; at most
// 3 s of simulation each).

#include <gtest/gtest.h>

#include <cstdio>
#include <string>

#include "mujoco_bridge/world.h"
#include "tests/mujoco_bridge/stiff_slab_scenes.h"
#include "tests/mujoco_bridge/temp_dir.h"

namespace tetcosim {
namespace {

struct Rest {
  bool at_rest = false;
  double seconds = 0.0;
  double energy = 0.0;
  Eigen::Vector3d elbow, hand;  // the lower link's origin and its hand's centre
};

// steps until the arm's kinetic energy has stayed below 1e-20 J for 0.1 s
// (with the smooth law alone, a hand that lands tilted creeps flat at
// 0.03 rad/s: within 3 s), or 3 s
Rest DropTheArm(int substeps, bool stick) {
  TempDir dir("tetcosim_substeps");
  std::unique_ptr<World> world =
      World::Load(dir.Write("arm.xml", ArmOnAStiffSlab(substeps, stick)));
  const int lower = world->BodyId("lower");
  Rest rest;
  int quiet = 0;
  for (int s = 0; s < 3000 && quiet < 100; ++s) {
    world->Step();
    EXPECT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    quiet = world->RigidKineticEnergy() < 1e-20 ? quiet + 1 : 0;
  }
  rest.at_rest = quiet >= 100;
  rest.seconds = world->time();
  rest.energy = world->RigidKineticEnergy();
  rest.elbow = world->RigidBodyPosition(lower);
  rest.hand = rest.elbow + world->RigidBodyOrientation(lower) * Eigen::Vector3d(0.05, 0, -0.02);
  return rest;
}

void Print(const char* what, const Rest& rest) {
  std::printf("%s: at rest after %.3f s (%.3g J), elbow z %.9f m, hand z %.9f m\n", what,
              rest.seconds, rest.energy, rest.elbow.z(), rest.hand.z());
}

// With the smooth friction law alone the rest pose is unique (friction
// holds nothing still), so both must find it exactly. (Static friction
// holds the arm wherever its hand lands: tilted on an edge, the hand's
// contacts pinned by friction leave the two hinges no freedom, so one
// substep or three rest where each landed.)
TEST(Substeps, ADroppedArmRestsWhereItDoesWithOneSubstep) {
  const Rest one = DropTheArm(1, /*stick=*/false);
  const Rest three = DropTheArm(3, /*stick=*/false);
  Print("one substep", one);
  Print("three substeps", three);
  ASSERT_TRUE(one.at_rest) << one.energy << " J after " << one.seconds << " s";
  EXPECT_TRUE(three.at_rest) << three.energy << " J after " << three.seconds << " s";
  // the same static equilibrium (the contacts' depth is about 1 um): to
  // 1 nm, where the pose MuJoCo's one update leaves was 3 um off
  EXPECT_LT((three.elbow - one.elbow).norm(), 1e-9);
  EXPECT_LT((three.hand - one.hand).norm(), 1e-9);
}

}  // namespace
}  // namespace tetcosim

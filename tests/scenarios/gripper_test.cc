// Scripted scenarios through the public World API, sized to run in seconds.
// Labelled "scenario" (not run again under the sanitizers).

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "mujoco_bridge/world.h"

namespace tetcosim {
namespace {

// close the fingers, lift 10 cm, hold for two seconds: the object comes
// along and does not slip
TEST(Scenarios, GripperLiftsAndHoldsTheObject) {
  std::unique_ptr<World> world =
      World::Load(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/gripper.xml");
  world->SetController([](World& w) {
    double t = w.time();
    double* ctrl = w.controls();
    double close = std::min(1.0, t / 0.3) * 0.028;
    ctrl[1] = close;
    ctrl[2] = close;
    ctrl[0] = t < 0.4 ? 0.0 : std::min(1.0, (t - 0.4) / 0.5) * 0.1;
  });
  const int object = world->DeformableIndex("object");
  const double z0 = world->deformable(object).CenterOfMass().z();
  double z_lifted = 0.0, z_held = 0.0;
  for (int s = 0; s < 3400; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    if (s == 1399) z_lifted = world->deformable(object).CenterOfMass().z();
    if (s == 2399) z_held = world->deformable(object).CenterOfMass().z();
  }
  const double z_end = world->deformable(object).CenterOfMass().z();
  std::printf(
      "object centre of mass: %.6f m at rest, %.6f m lifted, %.6f m after holding 1 s, "
      "%.6f m after 2 s\n",
      z0, z_lifted, z_held, z_end);
  EXPECT_GT(z_lifted - z0, 0.08) << "lifted with the hand";
  EXPECT_LT(std::abs(z_held - z_lifted), 0.005) << "held without slipping";
  // once the grip has settled, static friction holds it still (the smooth
  // law alone let it slide down 0.28 mm in that second, and on)
  EXPECT_LT(std::abs(z_end - z_held), 1e-5) << "no creep";
}

}  // namespace
}  // namespace tetcosim

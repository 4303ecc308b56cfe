// A soft ball thrown at a thin wall, at a time step that carries it past
// the wall's middle before any force acts (the paper's Fig. 1 against a
// MuJoCo geom): the consistent method throws it back the way it came,
// whether the wall is a geom (crossings with its faces,
// collision/shape_depth.h) or a mesh (a proxy), while the closest feature
// (the geom's signed distance) pushes the points past the middle on
// through, and the ball stays stuck in the wall. Labelled "scenario".

#include <gtest/gtest.h>

#include <cstdio>
#include <string>

#include "mujoco_bridge/scenario.h"
#include "tests/mujoco_bridge/temp_dir.h"

namespace tetcosim {
namespace {

// The wall is 2 cm thick (x from -1 to 1 cm); the ball, 3 cm in radius,
// comes at 3 m/s, 2.4 cm a step of 8 ms: its front is 0.5 cm short of the
// wall before the step and 0.9 cm past the wall's middle after it.
std::string Scene(bool proxy) {
  return std::string(R"(<mujoco>
  <option timestep="0.008" gravity="0 0 0"/>
  <worldbody>
    <body name="wall"><geom name="wall" type="box" size="0.01 0.2 0.2"/></body>
  </worldbody>
  <deformable>
    <tetbody name="ball" shape="sphere" size="0.03" resolution="2" pos="-0.045 0.004 0.003"
             vel="3 0 0" young="1e5" density="1000"/>
    )") + (proxy ? "<rigidtet body='wall' geom='wall' resolution='20'/>" : "") +
         R"(
  </deformable>
</mujoco>)";
}

struct Outcome {
  RolloutSummary summary;
  double x = 0.0;   // the ball's centre of mass at the end, m
  double vx = 0.0;  // its velocity, m/s
};

Outcome Throw(bool proxy, DepthMethod method) {
  TempDir dir("tetcosim_thin_wall");
  WorldOptions options;
  options.method = method;
  Scenario scenario(dir.Write("wall.xml", Scene(proxy)), options);
  EXPECT_TRUE(scenario.Run(0.2)) << scenario.message();
  Outcome outcome;
  outcome.summary = scenario.Summarize();
  const DeformableBody& ball = scenario.world().deformable(0);
  outcome.x = ball.CenterOfMass().x();
  outcome.vx = ball.LinearMomentum().x() / ball.model().total_mass();
  std::printf("%s, %s: centre at x = %.4f m, vx = %.3f m/s, residual %.3g mm, sticking %d\n",
              proxy ? "proxy" : "geom", DepthMethodName(method), outcome.x, outcome.vx,
              outcome.summary.residual_max_depth * 1e3, outcome.summary.sticking_pairs);
  return outcome;
}

TEST(ThinWall, ConsistentDepthThrowsTheBallBackTheWayItCame) {
  for (bool proxy : {false, true}) {
    SCOPED_TRACE(proxy ? "proxy" : "geom");
    const Outcome outcome = Throw(proxy, DepthMethod::kConsistent);
    // clear of the wall, on its own side, and moving away
    EXPECT_LT(outcome.x, -0.01 - 0.03);
    EXPECT_LT(outcome.vx, -0.3);
    EXPECT_EQ(outcome.summary.residual_points, 0);
    EXPECT_EQ(outcome.summary.pass_through_pairs, 0);
    EXPECT_EQ(outcome.summary.sticking_pairs, 0);
  }
}

TEST(ThinWall, ClosestFeatureLeavesTheBallStuckInTheWall) {
  for (bool proxy : {false, true}) {
    SCOPED_TRACE(proxy ? "proxy" : "geom");
    const Outcome outcome = Throw(proxy, DepthMethod::kClosest);
    // the baseline's artifact: held inside the wall, at rest
    EXPECT_GT(outcome.x, -0.01 - 0.03);
    EXPECT_EQ(outcome.summary.sticking_pairs, 1);
    EXPECT_GT(outcome.summary.residual_max_depth, 0.005);
  }
}

}  // namespace
}  // namespace tetcosim

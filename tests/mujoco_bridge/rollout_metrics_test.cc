#include "mujoco_bridge/rollout_metrics.h"

#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <cmath>
#include <limits>

#include "mesh/error.h"
#include "mujoco_bridge/scenario.h"
#include "tests/mujoco_bridge/temp_dir.h"

namespace tetcosim {
namespace {

constexpr double kDegrees = 180.0 / 3.14159265358979323846;

// two 10 cm cubes on the x axis, zero gravity; `stiffness` is the contact's
// kappa (Pa/m), tiny to let them pass through each other
std::string TwoCubes(double gap, double speed, const std::string& stiffness) {
  char text[1024];
  std::snprintf(text, sizeof(text), R"(<mujoco>
  <option timestep="0.002" gravity="0 0 0"/>
  <deformable>
    <contact stiffness="%s"/>
    <tetbody name="a" shape="box" size="0.05 0.05 0.05" resolution="4 4 4" pos="%.6f 0 0"
             vel="%.6f 0 0" young="1e5"/>
    <tetbody name="b" shape="box" size="0.05 0.05 0.05" resolution="4 4 4" pos="%.6f 0 0"
             vel="%.6f 0 0" young="1e5"/>
  </deformable>
</mujoco>)",
                stiffness.c_str(), -0.05 - gap / 2, speed / 2, 0.05 + gap / 2, -speed / 2);
  return text;
}

TEST(RolloutMetrics, OverlappingCubesAreStickingByTheExactDepth) {
  TempDir dir("tetcosim_metrics");
  // b starts 2 cm inside a, at rest: the deepest point of a inside b is the
  // middle vertex of a's +x face, 2 cm from b's -x face (its sides are 5 cm
  // away)
  Scenario scenario(dir.Write("overlap.xml", TwoCubes(-0.02, 0.0, "1e-6")));
  RolloutSummary s = scenario.Summarize();
  EXPECT_NEAR(s.residual_max_depth, 0.02, 1e-12);
  EXPECT_EQ(s.sticking_pairs, 1);      // 2 cm > 5% of 10 cm
  EXPECT_EQ(s.pass_through_pairs, 0);  // 2 cm < 30% of 10 cm
  ASSERT_EQ(s.events.size(), 1u);
  EXPECT_EQ(s.events[0].kind, "sticking");
  EXPECT_EQ(s.events[0].name_a, "a");
  EXPECT_EQ(s.events[0].name_b, "b");
  // Summarize() does not disturb anything: the same twice
  RolloutSummary again = scenario.Summarize();
  EXPECT_EQ(again.residual_max_depth, s.residual_max_depth);
  EXPECT_EQ(again.events.size(), s.events.size());
}

TEST(RolloutMetrics, CubesPassingThroughEachOtherAreCaught) {
  TempDir dir("tetcosim_metrics");
  // a contact too weak to stop 2 m/s: the cubes cross within 0.15 s
  Scenario soft(dir.Write("soft.xml", TwoCubes(0.01, 2.0, "1e-3")));
  ASSERT_TRUE(soft.Run(0.15));
  RolloutSummary s = soft.Summarize();
  EXPECT_EQ(s.pass_through_pairs, 1);
  EXPECT_EQ(s.residual_points, 0) << "already apart again";
  World& world = soft.world();
  EXPECT_GT(world.deformable(0).CenterOfMass().x(), world.deformable(1).CenterOfMass().x());
  // with the automatic contact stiffness they bounce: no pass-through
  Scenario stiff(dir.Write("stiff.xml", TwoCubes(0.01, 2.0, "0")));
  ASSERT_TRUE(stiff.Run(0.15));
  EXPECT_EQ(stiff.Summarize().pass_through_pairs, 0);
}

TEST(RolloutMetrics, FallingThroughTheFloorIsAPassThrough) {
  TempDir dir("tetcosim_metrics");
  const char* scene = R"(<mujoco>
  <option timestep="0.002" gravity="0 0 0"/>
  <worldbody><geom name="floor" type="plane" size="1 1 0.1"/></worldbody>
  <deformable>
    <contact stiffness="%s"/>
    <tetbody name="cube" shape="box" size="0.05 0.05 0.05" resolution="3 3 3" pos="0 0 0.052"
             vel="0 0 -2" young="1e5"/>
  </deformable>
</mujoco>)";
  char text[1024];
  std::snprintf(text, sizeof(text), scene, "1e-3");
  Scenario through(dir.Write("through.xml", text));
  ASSERT_TRUE(through.Run(0.15));
  RolloutSummary s = through.Summarize();
  EXPECT_EQ(s.pass_through_pairs, 1);
  ASSERT_FALSE(s.events.empty());
  EXPECT_EQ(s.events[0].name_b, "world");
  std::snprintf(text, sizeof(text), scene, "0");
  Scenario bounce(dir.Write("bounce.xml", text));
  ASSERT_TRUE(bounce.Run(0.15));
  EXPECT_EQ(bounce.Summarize().pass_through_pairs, 0);
}

// A soft sheet dropped across a support drapes over it: its centre of mass
// ends below the support's top (a static geom) or its centre (a free box,
// a soft block), but it lies on the support and has not passed through it.
// The support, 8 cm wide and 20 cm tall: a static post (the world, whose
// centre is the contact's), a free box on the floor, a soft block. (Judged
// by the centres alone, each was a pass-through.)
TEST(RolloutMetrics, ASheetDrapedOverASupportHasNotPassedThroughIt) {
  TempDir dir("tetcosim_metrics");
  struct Support {
    const char* name;
    const char* bodies;      // in <worldbody>
    const char* deformable;  // in <deformable>
    double top;              // m: the height the sheet's centre ends below
  };
  const Support supports[] = {
      {"post", R"(<geom name="post" type="box" size="0.04 0.1 0.1" pos="0 0 0.1"/>)", "", 0.2},
      {"box", R"(<body name="box" pos="0 0 0.1"><freejoint/>
                   <geom type="box" size="0.04 0.1 0.1" mass="2"/></body>)",
       "", 0.1},
      {"block", "",
       R"(<tetbody name="block" shape="box" size="0.04 0.1 0.1" resolution="2 4 4" pos="0 0 0.1"
                   young="1e5"/>)",
       0.1}};
  for (const Support& support : supports) {
    SCOPED_TRACE(support.name);
    char text[2000];
    std::snprintf(text, sizeof(text), R"(<mujoco>
  <option timestep="0.002"/>
  <worldbody><geom name="floor" type="plane" size="1 1 0.1"/>%s</worldbody>
  <deformable>
    <contact friction="0.3"/>
    <tetbody name="sheet" shape="box" size="0.35 0.05 0.005" resolution="70 2 1" pos="0 0 0.21"
             density="1000" young="2e4" damping="0.5 0.001"/>
    %s
  </deformable>
</mujoco>)",
                  support.bodies, support.deformable);
    Scenario scenario(dir.Write("drape.xml", text));
    ASSERT_TRUE(scenario.Run(0.6)) << scenario.message();
    World& world = scenario.world();
    const int sheet = world.DeformableIndex("sheet");
    // draped: its centre below the support's top or centre, its middle on it
    ASSERT_LT(world.deformable(sheet).CenterOfMass().z(), support.top - 0.01);
    const Positions& x = world.deformable(sheet).positions();
    for (int v = 0; v < x.rows(); ++v) {
      if (std::abs(x(v, 0)) < 0.01) {
        EXPECT_GT(x(v, 2), 0.19) << "vertex " << v;
      }
    }
    RolloutSummary s = scenario.Summarize();
    EXPECT_EQ(s.pass_through_pairs, 0);
    for (const PairEvent& event : s.events) EXPECT_NE(event.kind, "pass-through");
  }
}

// A scene without gravity, of 0.5 ms steps and next to no contact
// stiffness, with `rigid` in its worldbody and `soft` in its deformable
// section.
std::string Closing(const std::string& rigid, const std::string& soft) {
  return R"(<mujoco>
  <option timestep="0.0005" gravity="0 0 0"/>
  <worldbody>)" +
         rigid + R"(</worldbody>
  <deformable>
    <contact stiffness="1e-3"/>)" +
         soft + R"(</deformable>
</mujoco>)";
}

// Metrics without the depth rule (pass_through_fraction): only the
// centres' rule can count a pass-through.
RolloutMetricsOptions CentresAlone() {
  RolloutMetricsOptions metrics;
  metrics.pass_through_fraction = 1e3;
  return metrics;
}

// Two of the paper's 20-tetrahedron spheres passing into each other (next
// to no contact stiffness), caught just after their centres crossed, with
// the depth rule (pass_through_fraction) out of the way: neither lies past
// the other's centre, but both have their centres inside themselves, so
// the swap counts. (Two coarse bodies can be half inside each other, edges
// through faces, with no vertex deep: the pile of the paper's spheres had
// such a pair, centres 1.45 cm apart, its deepest vertex 2.4 mm.)
TEST(RolloutMetrics, CompactBodiesWhoseCentresCrossedHavePassedThrough) {
  TempDir dir("tetcosim_metrics");
  Scenario scenario(dir.Write("spheres.xml", Closing("", R"(
    <tetbody name="a" shape="sphere" size="0.018" resolution="0" pos="-0.02 0 0" vel="0.5 0 0"/>
    <tetbody name="b" shape="sphere" size="0.018" resolution="0" pos="0.02 0 0" vel="-0.5 0 0"
             euler="30 40 50"/>)")),
                    {}, CentresAlone());
  World& world = scenario.world();
  auto crossed = [](const World& w) {
    return w.deformable(0).CenterOfMass().x() - w.deformable(1).CenterOfMass().x() > 0.001;
  };
  ASSERT_TRUE(scenario.RunUntil(crossed, 0.1)) << scenario.message();
  for (int i = 0; i < 2; ++i) {  // neither past the other's centre
    const Positions& x = world.deformable(i).positions();
    const double other = world.deformable(1 - i).CenterOfMass().x();
    const double sign = i == 0 ? 1.0 : -1.0;  // a came from -x, b from +x
    ASSERT_GT((sign * (x.col(0).array() - other)).maxCoeff(), 0.0);
  }
  RolloutSummary s = scenario.Summarize();
  EXPECT_EQ(s.pass_through_pairs, 1);
}

// The same with a rigid ball (a free MuJoCo body) passing into the soft
// one: a rigid body is taken as compact, so the swap of centres counts
// while neither lies past the other's centre.
TEST(RolloutMetrics, ARigidBodyWhoseCentreCrossedASoftOnesHasPassedThroughIt) {
  TempDir dir("tetcosim_metrics");
  Scenario scenario(
      dir.Write("balls.xml",
                Closing(R"(<body name="ball" pos="-0.02 0 0"><freejoint/>
                                <geom type="sphere" size="0.015" mass="0.02"/></body>)",
                        R"(<tetbody name="soft" shape="sphere" size="0.018" resolution="1"
                                    pos="0.02 0 0" vel="-0.5 0 0"/>)")),
      {}, CentresAlone());
  World& world = scenario.world();
  auto crossed = [](const World& w) {
    return w.RigidBodyCenterOfMass(1).x() - w.deformable(0).CenterOfMass().x() > 0.001;
  };
  ASSERT_TRUE(scenario.RunUntil(crossed, 0.2)) << scenario.message();
  ASSERT_EQ(world.RigidBodyName(1), "ball");
  const Positions& x = world.deformable(0).positions();  // not past the ball's centre
  ASSERT_GT(x.col(0).maxCoeff(), world.RigidBodyCenterOfMass(1).x());
  RolloutSummary s = scenario.Summarize();
  EXPECT_EQ(s.pass_through_pairs, 1);
  ASSERT_FALSE(s.events.empty());
  EXPECT_EQ(s.events[0].kind, "pass-through");
}

// A soft ring (its centre in its hole, outside itself) dropped through a
// thin floor with next to no contact stiffness: it ends wholly below the
// floor and out of contact, a pass-through.
TEST(RolloutMetrics, ARingFallingThroughAThinFloorIsAPassThrough) {
  TempDir dir("tetcosim_metrics");
  Scenario scenario(dir.Write("ring.xml", R"(<mujoco>
  <option timestep="0.002" gravity="0 0 0"/>
  <worldbody><geom name="floor" type="box" size="0.2 0.2 0.005" pos="0 0 -0.005"/></worldbody>
  <deformable>
    <contact stiffness="1e-3"/>
    <tetbody name="ring" shape="torus" size="0.05 0.01" pos="0 0 0.011" vel="0 0 -2"/>
  </deformable>
</mujoco>)"));
  ASSERT_TRUE(scenario.Run(0.1)) << scenario.message();
  const Positions& x = scenario.world().deformable(0).positions();
  ASSERT_LT(x.col(2).maxCoeff(), -0.01) << "below the floor";
  RolloutSummary s = scenario.Summarize();
  EXPECT_EQ(s.residual_points, 0);
  EXPECT_EQ(s.pass_through_pairs, 1);
}

// A cube left 2 cm deep in the floor with next to no contact stiffness,
// at rest: sticking, whether the floor is a geom (met by its signed
// distance or the consistent method's crossings) or a mesh (a proxy). A
// geom holds a body stuck inside a thin one as a mesh does
// (tests/scenarios/thin_wall_test.cc).
TEST(RolloutMetrics, DeepInAGeomOrAMeshAtRestIsSticking) {
  TempDir dir("tetcosim_metrics");
  const char* scene = R"(<mujoco>
  <option gravity="0 0 0"/>
  <worldbody><body name="ground"><geom name="ground" type="%s" pos="0 0 %s" size="1 1 0.05"/></body></worldbody>
  <deformable>
    <contact stiffness="1e-6"/>
    <tetbody name="cube" shape="box" size="0.05 0.05 0.05" resolution="3 3 3" pos="0 0 0.03"/>
    %s
  </deformable>
</mujoco>)";
  struct Floor {
    const char* type;
    const char* height;  // of the geom's centre: its top at 0
    const char* proxy;
  };
  for (const Floor& floor :
       {Floor{"plane", "0", ""}, Floor{"box", "-0.05", ""},
        Floor{"box", "-0.05", "<rigidtet body='ground' geom='ground' resolution='8'/>"}}) {
    SCOPED_TRACE(std::string(floor.type) + " " + floor.proxy);
    char text[1000];
    std::snprintf(text, sizeof(text), scene, floor.type, floor.height, floor.proxy);
    Scenario scenario(dir.Write("sunk.xml", text));
    RolloutSummary s = scenario.Summarize();
    EXPECT_NEAR(s.residual_max_depth, 0.02, 1e-9);
    EXPECT_EQ(s.interpenetrating_pairs, 1);
    EXPECT_EQ(s.sticking_pairs, 1);
    EXPECT_EQ(s.pass_through_pairs, 0);
  }
}

// spatial and temporal figures of every step against a brute-force count over
// all pairs of results
// Two 5 cm balls 20 cm either side of a vertical hinge through their centre
// of mass, turning at `omega` (rad/s): their outermost points, 25 cm out,
// move at 0.25 omega while the centre of mass stands still.
TEST(RolloutMetrics, ABodySpinningInPlaceIsNotAtRest) {
  TempDir dir("tetcosim_metrics");
  auto summary_at = [&](double omega) {
    char scene[1024];
    std::snprintf(scene, sizeof(scene), R"(<mujoco>
  <option gravity="0 0 0"/>
  <worldbody>
    <body name="wheel" pos="0 0 1">
      <joint type="hinge" axis="0 0 1"/>
      <geom type="sphere" size="0.05" pos="0.2 0 0"/><geom type="sphere" size="0.05" pos="-0.2 0 0"/>
    </body>
  </worldbody>
  <keyframe><key qvel="%g"/></keyframe>
</mujoco>)",
                  omega);
    Scenario scenario(dir.Write("wheel.xml", scene));
    return scenario.Summarize();
  };
  const RolloutSummary fast = summary_at(2.0);
  EXPECT_NEAR(fast.max_speed, 0.5, 1e-12);
  EXPECT_FALSE(fast.at_rest);
  const RolloutSummary slow = summary_at(0.04);  // 1 cm/s: below rest_speed
  EXPECT_NEAR(slow.max_speed, 0.01, 1e-12);
  EXPECT_TRUE(slow.at_rest);
}

TEST(RolloutMetrics, DirectionFiguresMatchBruteForce) {
  for (DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
    WorldOptions options;
    options.method = method;
    options.timestep = 0.004;
    Scenario scenario(std::string(TETCOSIM_SOURCE_DIR) + "/models/paper/cubes.xml", options);
    std::vector<PenetrationResult> previous;
    double max_change_seen = 0.0;
    int steps_with_edges = 0;
    for (int step = 0; step < 20; ++step) {
      ASSERT_TRUE(scenario.Run(scenario.world().timestep()));
      const World& world = scenario.world();
      const std::vector<PenetrationResult>& results = world.penetrations();
      double sum = 0.0;
      int count = 0;
      double max_change = 0.0;
      for (size_t i = 0; i < results.size(); ++i) {
        const PenetrationResult& r = results[i];
        const TetMesh& mesh = *world.collision_objects()[r.object].mesh;
        for (size_t j = 0; j < results.size(); ++j) {
          const PenetrationResult& q = results[j];
          if (q.object != r.object || q.penetrated != r.penetrated || q.vertex <= r.vertex) {
            continue;
          }
          for (Eigen::Index e = 0; e < mesh.edges().rows(); ++e) {
            if (mesh.edges()(e, 0) == r.vertex && mesh.edges()(e, 1) == q.vertex) {
              sum += std::acos(std::clamp(r.direction.dot(q.direction), -1.0, 1.0)) * kDegrees;
              ++count;
            }
          }
        }
        for (const PenetrationResult& p : previous) {
          if (p.object == r.object && p.penetrated == r.penetrated && p.vertex == r.vertex) {
            max_change =
                std::max(max_change,
                         std::acos(std::clamp(r.direction.dot(p.direction), -1.0, 1.0)) * kDegrees);
          }
        }
      }
      const RolloutMetrics& metrics = scenario.metrics();
      EXPECT_NEAR(metrics.step_mean_neighbour_angle(), count > 0 ? sum / count : 0.0, 1e-9);
      EXPECT_NEAR(metrics.step_max_direction_change(), max_change, 1e-9);
      if (count > 0) ++steps_with_edges;
      max_change_seen = std::max(max_change_seen, max_change);
      previous = results;
    }
    EXPECT_GT(steps_with_edges, 3) << "the test saw contacts";
    EXPECT_NEAR(scenario.Summarize().max_direction_change, max_change_seen, 1e-9);
  }
}

// Scenario::Run with a duration that is not a count of steps is an error
// (NaN and 1e30 s rounded to no step at all, and Run said it succeeded);
// message() tells of the last run only: after a run that diverged, one that
// does not leaves it empty.
TEST(Scenario, BadDurationsAreErrorsAndMessagesAreOfTheLastRun) {
  Scenario scenario(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml");
  for (double bad : {std::nan(""), 1e30, -1.0, std::numeric_limits<double>::infinity()}) {
    EXPECT_THROW(scenario.Run(bad), Error) << bad;
    EXPECT_THROW(scenario.RunUntil([](const World&) { return false; }, bad), Error) << bad;
  }
  scenario.SetController([](World& w) { w.mj_data()->qvel[0] = std::nan(""); });
  EXPECT_FALSE(scenario.Run(0.01));
  EXPECT_FALSE(scenario.ok());
  EXPECT_NE(scenario.message().find("non-finite"), std::string::npos) << scenario.message();
  scenario.SetController({});
  EXPECT_TRUE(scenario.Run(0.01));
  EXPECT_TRUE(scenario.ok()) << scenario.message();
}

}  // namespace
}  // namespace tetcosim

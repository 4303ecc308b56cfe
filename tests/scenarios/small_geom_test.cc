// A rigid geom narrower than the gaps between a soft block's surface vertices,
// dropped on the middle of one of its surface cells. Deformables meet a geom
// at their vertices, so such a geom, met as a geom, touches none: it sinks
// in between them and falls through the block. With the proxy made for it
// (World::made_proxies, <contact autoproxy>, on by default), its vertices
// meet the block's tetrahedra and it comes to rest on the block.
// Labelled "scenario".

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <string>
#include <string_view>

#include "mujoco_bridge/scenario.h"
#include "tests/mujoco_bridge/temp_dir.h"

namespace tetcosim {
namespace {

// The block is 10 cm across, 3 cells a side (vertices 3.3 cm apart, the
// gaps between them 4.7 cm: the cells' diagonals), its top at z = 0.1, a
// cell's middle right above the origin; each geom is 8 to 12 mm wide and
// up to 3.2 cm long, so that it fits within a cell, or a 4 cm ball, and
// placed (and turned) in its body's frame, its lowest point 1 cm or more
// above the block; the mesh is a 1 cm cube.
struct SmallGeom {
  const char* name;
  const char* geom;    // its MJCF attributes
  double half_height;  // how far its lowest point is below its centre, m
};

constexpr SmallGeom kSmallGeoms[] = {
    {"sphere", R"(type="sphere" size="0.006")", 0.006},
    {"capsule", R"(type="capsule" size="0.005 0.01" euler="0 90 0")", 0.005},
    {"box", R"(type="box" size="0.004 0.016 0.005")", 0.005},
    {"cylinder", R"(type="cylinder" size="0.005 0.01" euler="90 0 0")", 0.005},
    {"ellipsoid", R"(type="ellipsoid" size="0.006 0.012 0.004")", 0.004},
    {"mesh", R"(type="mesh" mesh="cube")", 0.005},
    // (wider than a cell, narrower than its diagonal: it passes between
    // the cell's four corners)
    {"ball", R"(type="sphere" size="0.02")", 0.02},
};
constexpr double kTop = 0.1;

// autoproxy: "true", "narrow" or "false"
std::string Scene(const SmallGeom& geom, const std::string& auto_proxy) {
  return std::string(R"(<mujoco>
  <option timestep="0.001"/>
  <asset><mesh name="cube" vertex="-0.005 -0.005 -0.005  0.005 -0.005 -0.005  -0.005 0.005 -0.005
    0.005 0.005 -0.005  -0.005 -0.005 0.005  0.005 -0.005 0.005  -0.005 0.005 0.005
    0.005 0.005 0.005"/></asset>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="drop" pos="0 0 0.15"><freejoint/><geom name="drop" density="300" pos="0 0 )") +
         std::to_string(std::max(-0.02, geom.half_height - 0.04)) + "\" " + geom.geom +
         R"(/></body>
  </worldbody>
  <deformable>
    <contact autoproxy=")" +
         auto_proxy + R"("/>
    <tetbody name="block" shape="box" size="0.05 0.05 0.05" resolution="3" pos="0 0 0.05"
             density="300" young="5e4"/>
  </deformable>
</mujoco>)";
}

struct Outcome {
  double z = 0.0;           // the geom's centre at the end, m
  double speed = 0.0;       // m/s
  double off_centre = 0.0;  // the centre's horizontal distance from the block's middle, m
  int made_proxies = 0;
  std::string warnings;
};

Outcome Drop(const SmallGeom& geom, const std::string& auto_proxy, double seconds = 3.0) {
  TempDir dir("tetcosim_small_geom");
  Scenario scenario(dir.Write("drop.xml", Scene(geom, auto_proxy)));
  // (3 s: the 4 cm ball rolls about in its dent for 2 s before it settles)
  EXPECT_TRUE(scenario.Run(seconds)) << scenario.message();
  const World& world = scenario.world();
  const int body = world.BodyId("drop");
  Outcome outcome;
  outcome.z = world.RigidBodyCenterOfMass(body).z();
  outcome.speed = world.RigidBodyPointVelocity(body, world.RigidBodyCenterOfMass(body)).norm();
  outcome.made_proxies = static_cast<int>(world.made_proxies().size());
  for (const std::string& warning : world.load_warnings()) outcome.warnings += warning + "\n";
  outcome.off_centre = world.RigidBodyCenterOfMass(body).head<2>().norm();
  std::printf(
      "%s, autoproxy %s: centre at z = %.4f m, %.2g m into the block, %.2g m off its middle, "
      "speed %.2g m/s\n",
      geom.name, auto_proxy.c_str(), outcome.z, kTop + geom.half_height - outcome.z,
      outcome.off_centre, outcome.speed);
  return outcome;
}

TEST(SmallGeom, RestsOnACoarseBlockThroughTheProxyMadeForIt) {
  for (const SmallGeom& geom : kSmallGeoms) {
    SCOPED_TRACE(geom.name);
    const Outcome outcome = Drop(geom, "true");
    EXPECT_EQ(outcome.made_proxies, 1);
    EXPECT_EQ(outcome.warnings, "");
    // on the block, at most 2 mm into it, and at rest
    EXPECT_GT(outcome.z, kTop + geom.half_height - 0.002);
    EXPECT_LT(outcome.z, kTop + geom.half_height + 0.001);
    EXPECT_LT(outcome.speed, 0.01);
  }
}

TEST(SmallGeom, MetAsAGeomItFallsThroughTheBlockAndIsWarnedOf) {
  for (const SmallGeom& sphere : {kSmallGeoms[0], kSmallGeoms[6]}) {
    SCOPED_TRACE(sphere.name);
    const Outcome outcome = Drop(sphere, "false");
    EXPECT_EQ(outcome.made_proxies, 0);
    EXPECT_NE(outcome.warnings.find("geom 'drop': 0."), std::string::npos) << outcome.warnings;
    EXPECT_NE(outcome.warnings.find(" m wide, less than the 0.0471 m gaps between the surface "
                                    "vertices of tetbody 'block'"),
              std::string::npos)
        << outcome.warnings;
    // through the block, down to the floor under it
    EXPECT_LT(outcome.z, sphere.half_height + 0.002);
  }
}

// Round geoms wider than the gaps (4.7 cm), but less than 8 times: a 6 cm
// and an 8 cm ball, and a capsule 6 cm across lying down. Met as geoms
// (autoproxy "narrow"), they sink in between the block's vertices: a ball
// by at least the geometry's sag, R - sqrt(R^2 - r^2) with r = 2.36 cm from
// the middle of a cell to its corners (6 cm: 11.5 mm; 8 cm: 7.7 mm; and by
// at most 2 mm more, its contacts' depth and the block's give), the capsule
// by more than 4 mm. Given the proxy made for them by default (round), they
// rest on top, at most 2.5 mm in, after 1.5 s. (Not at rest: a ball on so
// coarse a block meets flat cells that tilt towards the vertex it presses
// most, and it rolls slowly away from a cell's middle, as it did not while
// it sat sunk among the cell's corners: the 8 cm ball 1.8 cm in 1.6 s, then
// off the block's side at 4.4 s.)
TEST(SmallGeom, WiderRoundGeomsRestOnTheBlockThroughTheProxyMadeForThem) {
  constexpr SmallGeom kWide[] = {
      {"6 cm ball", R"(type="sphere" size="0.03")", 0.03},
      {"8 cm ball", R"(type="sphere" size="0.04")", 0.04},
      {"6 cm capsule", R"(type="capsule" size="0.03 0.03" euler="0 90 0")", 0.03},
  };
  constexpr double kCorner = 0.05 / 3.0 * std::numbers::sqrt2;  // (a cell's half-diagonal)
  for (const SmallGeom& geom : kWide) {
    SCOPED_TRACE(geom.name);
    const Outcome made = Drop(geom, "true", 1.5);
    EXPECT_EQ(made.made_proxies, 1);
    EXPECT_EQ(made.warnings, "");
    EXPECT_GT(made.z, kTop + geom.half_height - 0.0025);
    EXPECT_LT(made.z, kTop + geom.half_height + 0.001);
    EXPECT_LT(made.off_centre, 0.03);
    const Outcome met = Drop(geom, "narrow", 1.5);
    EXPECT_EQ(met.made_proxies, 0);
    EXPECT_EQ(met.warnings, "");
    const double sink = kTop + geom.half_height - met.z;
    if (std::string_view(geom.geom).starts_with(R"(type="sphere")")) {
      const double r = geom.half_height;
      const double sag = r - std::sqrt(r * r - kCorner * kCorner);
      EXPECT_GT(sink, sag);
      EXPECT_LT(sink, sag + 0.002);
    } else {
      EXPECT_GT(sink, 0.004);
    }
  }
}

// A soft slab dropped across a 1 cm bar fixed in the world (its surface
// vertices 3.3 cm apart on the grid, none over the bar): with the bar's
// proxy it lands on the bar, where it balances a while (sagging on either
// side) before it tips off; met as a geom, the bar passes up through it
// between its vertices, and it falls.
TEST(SmallGeom, ASlabLandsOnAThinBarFixedInTheWorld) {
  for (bool auto_proxy : {true, false}) {
    SCOPED_TRACE(auto_proxy ? "proxy made" : "geom");
    TempDir dir("tetcosim_small_geom");
    Scenario scenario(dir.Write("bar.xml", std::string(R"(<mujoco>
  <option timestep="0.001"/>
  <worldbody>
    <geom name="bar" type="capsule" fromto="0 -0.2 0.1 0 0.2 0.1" size="0.005"/>
  </worldbody>
  <deformable>
    <contact autoproxy=")") + (auto_proxy ? "true" : "false") +
                                               R"("/>
    <tetbody name="slab" shape="box" size="0.05 0.05 0.02" resolution="3 3 1" pos="0 0 0.14"
             density="300" young="5e4"/>
  </deformable>
</mujoco>)"));
    ASSERT_TRUE(scenario.Run(0.3)) << scenario.message();
    const double centre = scenario.world().deformable(0).CenterOfMass().z();
    std::printf("%s: the slab's centre at z = %.4f m (on the bar: 0.125)\n",
                auto_proxy ? "proxy made" : "geom", centre);
    if (auto_proxy) {
      EXPECT_GT(centre, 0.125 - 0.003);  // (2 cm above the bar's top, less its sag)
      EXPECT_LT(centre, 0.125 + 0.001);
    } else {
      EXPECT_LT(centre, 0.105 - 0.02);  // (fallen through)
    }
  }
}

}  // namespace
}  // namespace tetcosim

// Coulomb friction against its analytic answer: a soft block on a floor
// under gravity tilted by theta (the same as a slope) slides with
// acceleration g (sin theta - mu cos theta) when tan theta > mu, and holds
// when tan theta < mu: still with static friction (the default), and but
// for the creep of the smooth friction law alone (contact.h, <contact
// stick="false">): mu f_n v / sqrt(v^2 + v_s^2) = m g sin theta gives
// v = v_s q / sqrt(1 - q^2), q = tan theta / mu. On a MuJoCo plane (signed
// distance), on the tetrahedral proxy of a static box and on a stiff
// pinned deformable slab (the consistent penetration depth, both ways: the
// block's vertices in the floor and the floor's coarse vertices in the
// block). Labelled "scenario".

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <string>

#include <mujoco/mujoco.h>
#include "deformable/contact.h"

#include "mujoco_bridge/world.h"
#include "tests/mujoco_bridge/temp_dir.h"

namespace tetcosim {
namespace {

constexpr double kGravity = 9.81;
constexpr double kMu = 0.4;

// the floor the block stands on: a MuJoCo plane, the proxy of a static box,
// or a stiff deformable slab whose bottom is pinned to a static body (the
// box and the slab: 2 x 0.6 x 0.1 m in 8 x 8 x 8 cells, whose surface
// vertices each stand for far more area than the block's bottom)
enum class Floor { kPlaneGeom, kStaticProxy, kDeformableSlab };
std::string Scene(Floor floor, double theta, const std::string& contact) {
  char gravity[96];
  std::snprintf(gravity, sizeof gravity, "%.17g 0 %.17g", kGravity * std::sin(theta),
                -kGravity * std::cos(theta));
  std::string floor_xml, proxy_xml;
  if (floor == Floor::kPlaneGeom) {
    floor_xml = "<geom name='floor' type='plane' size='5 5 0.1' friction='0.4'/>";
  } else if (floor == Floor::kStaticProxy) {
    floor_xml =
        "<body name='slab' pos='0 0 -0.05'>"
        "<geom name='slab' type='box' size='1 0.3 0.05' friction='0.4' contype='0' "
        "conaffinity='0'/></body>";
    proxy_xml = "<rigidtet body='slab' geom='slab' resolution='8'/>";
  } else {
    floor_xml = "<body name='anchor'/>";
    proxy_xml =
        "<tetbody name='slab' shape='box' size='1 0.3 0.05' resolution='8' pos='0 0 -0.05' "
        "density='1000' young='1e8' poisson='0.3' friction='0.4'/>"
        "<attach tetbody='slab' body='anchor' box='-2 -1 -0.2 2 1 -0.09'/>";
  }
  return std::string("<mujoco><option timestep='0.002' gravity='") + gravity + "'/><worldbody>" +
         floor_xml + "</worldbody><deformable><contact friction='0.4'" + contact + "/>" +
         proxy_xml +
         "<tetbody name='block' shape='box' size='0.05 0.05 0.03' resolution='8' "
         "pos='-0.5 0 0.031' density='1000' young='2e5' poisson='0.3' damping='0 0.002'/>"
         "</deformable></mujoco>";
}

// the block's mean velocity along the slope: its change over steps 100 to
// 400 (0.2 to 0.8 s, after landing), and its largest size there and over
// steps 200 to 400 (once the landing's elastic oscillation has died out)
struct Slide {
  double acceleration = 0.0;
  double max_speed = 0.0;
  double late_max_speed = 0.0;
};

// (contact: more attributes of <contact>)
Slide RunOnSlope(Floor floor, double theta, const std::string& contact = "") {
  TempDir dir("tetcosim_friction");
  std::unique_ptr<World> world = World::Load(dir.Write("scene.xml", Scene(floor, theta, contact)));
  const DeformableBody& block = world->deformable(world->DeformableIndex("block"));
  const double mass = block.model().total_mass();
  auto speed = [&] { return block.LinearMomentum().x() / mass; };
  Slide slide;
  double v0 = 0.0;
  for (int s = 0; s < 400; ++s) {
    world->Step();
    EXPECT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    if (s == 99) v0 = speed();
    if (s >= 99) slide.max_speed = std::max(slide.max_speed, std::abs(speed()));
    if (s >= 199) slide.late_max_speed = std::max(slide.late_max_speed, std::abs(speed()));
  }
  slide.acceleration = (speed() - v0) / (300 * world->timestep());
  return slide;
}

const char* Name(Floor floor) {
  return floor == Floor::kPlaneGeom ? "plane" : floor == Floor::kStaticProxy ? "proxy" : "slab";
}

TEST(Friction, SlidesAboveTheFrictionAngleAsCoulombSays) {
  const double theta = std::atan(2 * kMu);
  const double expected = kGravity * (std::sin(theta) - kMu * std::cos(theta));
  for (const char* law : {"", " stick='false'"}) {
    for (Floor floor : {Floor::kPlaneGeom, Floor::kStaticProxy, Floor::kDeformableSlab}) {
      const Slide slide = RunOnSlope(floor, theta, law);
      std::printf("%s%s: acceleration %.4f m/s^2, Coulomb %.4f\n", Name(floor), law,
                  slide.acceleration, expected);
      EXPECT_NEAR(slide.acceleration, expected, 0.02 * expected) << Name(floor) << law;
    }
  }
}

// Static friction holds the block still (once the landing's oscillation on
// its contacts' springs has died out) where the smooth law alone lets it
// creep at v_s q / sqrt(1 - q^2): 0.58 mm/s at half the friction angle,
// 2.1 mm/s at 0.9 of it.
TEST(Friction, StaticFrictionHoldsBelowTheFrictionAngle) {
  for (double q : {0.5, 0.9}) {  // tan theta / mu
    const double theta = std::atan(q * kMu);
    const double creep = ContactSettings{}.slip_velocity * q / std::sqrt(1.0 - q * q);
    for (Floor floor : {Floor::kPlaneGeom, Floor::kStaticProxy, Floor::kDeformableSlab}) {
      const Slide slide = RunOnSlope(floor, theta);
      std::printf(
          "%s, q = %.1f: largest speed %.3g m/s from 0.2 s, %.3g from 0.4 s (the smooth "
          "law's creep %.3g)\n",
          Name(floor), q, slide.max_speed, slide.late_max_speed, creep);
      EXPECT_LT(slide.late_max_speed, 1e-3 * creep) << Name(floor) << ", q = " << q;
      EXPECT_NEAR(slide.acceleration, 0.0, 1e-4) << Name(floor) << ", q = " << q;
    }
  }
}

TEST(Friction, HoldsBelowTheFrictionAngleButForTheSmoothingsCreep) {
  const double q = 0.5;  // tan theta / mu
  const double theta = std::atan(q * kMu);
  const double creep = ContactSettings{}.slip_velocity * q / std::sqrt(1.0 - q * q);
  for (Floor floor : {Floor::kPlaneGeom, Floor::kStaticProxy, Floor::kDeformableSlab}) {
    const Slide slide = RunOnSlope(floor, theta, " stick='false'");
    std::printf("%s: acceleration %.3g m/s^2, largest speed %.4g m/s, creep %.4g m/s\n",
                Name(floor), slide.acceleration, slide.max_speed, creep);
    EXPECT_NEAR(slide.max_speed, creep, 0.02 * creep) << Name(floor);
    EXPECT_NEAR(slide.acceleration, 0.0, 1e-3) << Name(floor);
  }
}

// The scene's slip velocity sets the creep: a tenth of the default, a
// tenth of the creep
TEST(Friction, TheSceneSlipVelocitySetsTheCreep) {
  const double q = 0.5;
  const double theta = std::atan(q * kMu);
  const double slip = 0.1 * ContactSettings{}.slip_velocity;
  const double creep = slip * q / std::sqrt(1.0 - q * q);
  for (Floor floor : {Floor::kPlaneGeom, Floor::kDeformableSlab}) {
    const Slide slide =
        RunOnSlope(floor, theta, " stick='false' slip='" + std::to_string(slip) + "'");
    std::printf("%s: largest speed %.4g m/s, creep %.4g m/s\n", Name(floor), slide.max_speed,
                creep);
    EXPECT_NEAR(slide.max_speed, creep, 0.02 * creep) << Name(floor);
    EXPECT_NEAR(slide.acceleration, 0.0, 1e-4) << Name(floor);
  }
}

// A block carried round on a turntable (a MuJoCo body on a hinge, servoed
// to 1 rad/s): a soft block on the table's box geom (without a proxy), on
// its tetrahedral proxy, and on a stiff slab glued to it (the consistent
// penetration depth, both ways); and a rigid block (its proxy) on the slab.
// Static friction holds the block well inside its cone (the pull it needs
// is w^2 r = 0.15 m/s^2 against mu g = 7.8), so it turns with the table as
// one: it keeps its place on the table, every contact sticks, and the
// contacts' friction is the centripetal force m w^2 r on it. A stuck
// contact's friction spring is how far A's point has moved from where it
// stuck on B. A turning body's points move along arcs, a deformable's
// vertices along their velocities: springs that missed the arcs'
// difference (r w^2 dt / 2 a step) let the soft block creep 75 um in the
// second, unseen, and the rigid one slip on every contact; springs kept in
// world axes, not turned with the table, let the soft block creep 0.18 mm.
// With two substeps (each a MuJoCo step's half, the rigid bodies' velocities
// taken at the step's start) the blocks keep their place as well (their
// last substep's contacts are not the step's force, nor all stuck: only the
// place is asserted); taking a later substep's arm where it was at the
// step's start, the soft block crept 37 um. At 3 rad/s the stiff slab
// stretches under the rigid block as it spins (about 0.5 um across it) by
// more than a spring as stiff as the contact's normal gives before it slides
// (mu times the depth, 0.14 um): every contact slid and the block crept 0.16
// mm in the second. A spring a tenth as stiff (<contact stickstiffness>)
// holds it, its edge contacts sliding a little.
std::string TurntableScene(Floor floor, bool rigid_block, int substeps,
                           const std::string& contact) {
  std::string table =
      "<geom name='top' type='box' size='0.3 0.3 0.05' pos='0 0 -0.05' "
      "density='20000' friction='0.8'";
  std::string deformable;
  if (floor == Floor::kPlaneGeom) {
    table += "/>";
  } else {
    table += " contype='0' conaffinity='0'/>";
    deformable = floor == Floor::kStaticProxy
                     ? "<rigidtet body='table' geom='top' resolution='8'/>"
                     : "<tetbody name='slab' shape='box' size='0.3 0.3 0.05' resolution='8' "
                       "pos='0 0 -0.05' density='1000' young='1e8' poisson='0.3' friction='0.8'/>"
                       "<attach tetbody='slab' body='table' box='-1 -1 -0.2 1 1 -0.09'/>";
  }
  std::string free_body;
  if (rigid_block) {
    free_body =
        "<body name='block' pos='0.15 0 0.0299'><freejoint/><geom name='block' type='box' "
        "size='0.03 0.03 0.03' density='1000' friction='0.8' contype='0' "
        "conaffinity='0'/></body>";
    deformable += "<rigidtet body='block' geom='block' resolution='4'/>";
  } else {
    deformable +=
        "<tetbody name='block' shape='box' size='0.03 0.03 0.03' resolution='4' "
        "pos='0.15 0 0.0301' density='1000' young='2e5' poisson='0.3' damping='0 0.002'/>";
  }
  return "<mujoco><option timestep='0.001'/><worldbody><body name='table'>"
         "<joint name='spin' type='hinge' axis='0 0 1'/>" +
         table + "</body>" + free_body +
         "</worldbody><actuator><velocity joint='spin' kv='1e4'/></actuator>"
         "<deformable><solver substeps='" +
         std::to_string(substeps) + "'/><contact friction='0.8'" + contact + "/>" + deformable +
         "</deformable></mujoco>";
}

TEST(Friction, ABlockOnATurntableTurnsWithIt) {
  struct Case {
    Floor floor;
    bool rigid_block;
    int substeps;
    double omega;         // rad/s, reached at 0.5 s
    std::string contact;  // more attributes of <contact>
    bool all_stick;       // every contact sticks, and its force is the step's
  };
  const Case cases[] = {{Floor::kPlaneGeom, false, 1, 1.0, "", true},
                        {Floor::kStaticProxy, false, 1, 1.0, "", true},
                        {Floor::kDeformableSlab, false, 1, 1.0, "", true},
                        {Floor::kDeformableSlab, true, 1, 1.0, "", true},
                        {Floor::kPlaneGeom, false, 2, 1.0, "", false},
                        {Floor::kDeformableSlab, true, 2, 1.0, "", false},
                        {Floor::kDeformableSlab, true, 1, 3.0, " stickstiffness='0.1'", false}};
  for (const Case& test : cases) {
    // (copies: clang 14 lets no lambda capture a structured binding)
    const Floor floor = test.floor;
    const bool rigid_block = test.rigid_block;
    const double omega = test.omega;
    char rate[32];
    std::snprintf(rate, sizeof rate, "%g rad/s", omega);
    const std::string name = std::string(rigid_block ? "rigid block on " : "soft block on ") +
                             (floor == Floor::kStaticProxy ? "proxy" : Name(floor)) + ", " +
                             std::to_string(test.substeps) + " substep(s), " + rate + test.contact;
    TempDir dir("tetcosim_turntable");
    std::unique_ptr<World> world = World::Load(
        dir.Write("scene.xml", TurntableScene(floor, rigid_block, test.substeps, test.contact)));
    world->SetController(
        [&](World& w) { w.controls()[0] = omega * std::min(1.0, w.time() / 0.5); });
    // the block: its mass, centre of mass, and the contacts' force on it
    const int deformable = rigid_block ? -1 : world->DeformableIndex("block");
    const int body = rigid_block ? world->BodyId("block") : -1;
    const double mass = rigid_block ? world->mj_model()->body_mass[body]
                                    : world->deformable(deformable).model().total_mass();
    auto centre = [&] {
      return rigid_block ? world->RigidBodyCenterOfMass(body)
                         : world->deformable(deformable).CenterOfMass();
    };
    // its place in the table's frame: its angle from the table's, and its
    // distance from the axis
    auto place = [&] {
      const Eigen::Vector3d c = centre();
      const double turn =
          std::remainder(std::atan2(c.y(), c.x()) - world->mj_data()->qpos[0], 2.0 * M_PI);
      return Eigen::Vector2d(turn, c.head<2>().norm());
    };
    Eigen::Vector2d start;
    double moved = 0.0, worst_force = 0.0;
    int slipped = 0;
    for (int s = 0; s < 2000; ++s) {
      world->Step();
      ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
      if (s < 999) continue;
      if (s == 999) start = place();
      const Eigen::Vector2d now = place();
      moved = std::max(moved, std::hypot(now.y() * (now.x() - start.x()), now.y() - start.y()));
      Eigen::Vector3d force = Eigen::Vector3d::Zero();
      int contacts = 0;
      for (size_t c = 0; c < world->contacts().size(); ++c) {
        const ContactPoint& contact = world->contacts()[c];
        const bool on_a = rigid_block
                              ? contact.body_a < 0 && world->contact_rigid_bodies()[c] == body
                              : contact.body_a == deformable;
        const bool on_b = rigid_block
                              ? contact.body_b < 0 && world->contact_rigid_bodies()[c] == body
                              : contact.body_b == deformable;
        if (!on_a && !on_b) continue;
        force += on_a ? contact.force : Eigen::Vector3d(-contact.force);
        ++contacts;
        slipped += !contact.stuck;
      }
      ASSERT_GT(contacts, 0) << name;
      // horizontal, against m w^2 r toward the axis
      Eigen::Vector3d centripetal = -mass * omega * omega * centre();
      centripetal.z() = 0.0;
      force.z() = 0.0;
      worst_force = std::max(worst_force, (force - centripetal).norm() / centripetal.norm());
    }
    std::printf(
        "%s: moved on the table by at most %.3g m over 1 s, %d contact-steps slipped, "
        "friction off m w^2 r by at most %.3g of it\n",
        name.c_str(), moved, slipped, worst_force);
    EXPECT_LT(moved, 1e-6) << name;
    if (!test.all_stick) continue;
    EXPECT_EQ(slipped, 0) << name;
    EXPECT_LT(worst_force, 0.02) << name;
  }
}

}  // namespace
}  // namespace tetcosim

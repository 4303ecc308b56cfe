// A soft ball on a slope against a rigid ball's analytic answer, and
// dropped on a floor. With friction enough (mu above 2/7 tan theta for a
// uniform ball) it rolls without slipping, its centre gaining speed at g
// sin theta / (1 + I / (m h^2)) (5/7 g sin theta for a uniform ball),
// where I is its moment of inertia about the axis through its centre and
// h its radius; with less it slides, its centre at g (sin theta - mu cos
// theta), while friction spins it up at mu m g cos theta h / I. I and h
// are the ball's own (lumped masses on a polyhedron), measured as it is
// let go: h is its centre's height then (the soft ball flattens and its
// centre sinks, but it rolls at that radius: its spin times h is its
// speed). These test friction's torque, not only its force (the blocks of
// friction_test.cc do not turn), on a MuJoCo plane, on the tetrahedral
// proxy of a static box and on a stiff pinned deformable slab. Then a
// rigid ball and a rigid capsule on a coarse slab, met as geoms and given
// proxies; last, the soft ball's bounce.
//
// The backward-Euler step takes the contact forces of the step's end at
// the vertices' places at its start (a step changes a body's angular
// momentum by the sum of x_start x f dt, exactly). A turning ball's front
// vertices go down into the floor within the step and its back ones come
// up, so the normal forces, which sum to N, act about omega h dt ahead of
// the centre: a torque of about omega h N dt against the spin. Rolling,
// that is a resistance of about N omega dt; sliding, the spin-up falls
// short by omega dt / mu of itself. Both are first order in the step, and
// shrink with it: the tests hold the step's share to what that predicts.
// Labelled "scenario".

#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include "mujoco_bridge/world.h"
#include "tests/mujoco_bridge/temp_dir.h"

namespace tetcosim {
namespace {

constexpr double kGravity = 9.81;
constexpr double kTheta = 20.0 * std::numbers::pi / 180.0;

enum class Floor { kPlaneGeom, kStaticProxy, kDeformableSlab };

const char* Name(Floor floor) {
  return floor == Floor::kPlaneGeom ? "plane" : floor == Floor::kStaticProxy ? "proxy" : "slab";
}

// <option>'s gravity tilted by kTheta about y: the same as a slope going
// down along +x
std::string TiltedGravity() {
  char gravity[96];
  std::snprintf(gravity, sizeof gravity, "gravity='%.17g 0 %.17g'", kGravity * std::sin(kTheta),
                -kGravity * std::cos(kTheta));
  return gravity;
}

// a stiff deformable slab 2 x 0.6 x 0.1 m of `cells`, its top at z = 0,
// its bottom pinned to the static body 'anchor' (which the scene has)
std::string PinnedSlab(const std::string& cells) {
  return "<tetbody name='slab' shape='box' size='1 0.3 0.05' resolution='" + cells +
         "' pos='0.3 0 -0.05' density='1000' young='1e8' poisson='0.3'/>"
         "<attach tetbody='slab' body='anchor' box='-2 -1 -0.2 2 1 -0.09'/>";
}

// the floor at z = 0 under the tilted gravity, friction mu, and a ball of
// radius 5 cm (a level-3 sphere: 10,240 tetrahedra, its 642 surface
// vertices about 8 degrees apart) resting on it
std::string Scene(Floor floor, double mu, double timestep) {
  char numbers[96];
  std::snprintf(numbers, sizeof numbers, "timestep='%.17g'", timestep);
  const std::string friction = "friction='" + std::to_string(mu) + "'";
  std::string floor_xml, proxy_xml;
  if (floor == Floor::kPlaneGeom) {
    floor_xml = "<geom name='floor' type='plane' size='5 5 0.1' " + friction + "/>";
  } else if (floor == Floor::kStaticProxy) {
    floor_xml =
        "<body name='slab' pos='0.3 0 -0.05'><geom name='slab' type='box' size='1 0.3 0.05' "
        "contype='0' conaffinity='0' " +
        friction + "/></body>";
    proxy_xml = "<rigidtet body='slab' geom='slab' resolution='8'/>";
  } else {
    floor_xml = "<body name='anchor'/>";
    proxy_xml = PinnedSlab("16 6 2");
  }
  return std::string("<mujoco><option ") + numbers + " " + TiltedGravity() + "/><worldbody>" +
         floor_xml + "</worldbody><deformable><contact " + friction + "/>" + proxy_xml +
         "<tetbody name='ball' shape='sphere' size='0.05' resolution='3' pos='-0.5 0 0.05' "
         "density='1000' young='2e5' poisson='0.3'/></deformable></mujoco>";
}

// the slope of the least-squares line through (t_i, y_i)
double FittedRate(const std::vector<double>& t, const std::vector<double>& y) {
  const double n = static_cast<double>(t.size());
  double st = 0.0, sy = 0.0, stt = 0.0, sty = 0.0;
  for (size_t i = 0; i < t.size(); ++i) {
    st += t[i];
    sy += y[i];
    stt += t[i] * t[i];
    sty += t[i] * y[i];
  }
  return (n * sty - st * sy) / (n * stt - st * st);
}

// The ball let go on the slope, stepped to kEnd. Its centre's speed along
// the slope and its spin about y times h (the speed its spin alone gives
// its centre about the point it rolls on) grow at rates fitted from
// kFirst on (the ball rolls over its vertices: both swing by a per cent or
// two about their lines); its slip, the one less the other, and its speed
// are means over the same steps.
// On the plane, where every contact's inside point is the ball's vertex,
// also the angular momentum about its centre it gained from kFirst on, and
// what its contacts' forces gave it about the centre at each step's start.
constexpr double kFirst = 0.05;  // s
constexpr double kEnd = 0.3;     // s

struct Roll {
  double acceleration = 0.0, spin_up = 0.0;  // m/s^2
  double slip = 0.0, speed = 0.0;            // m/s, means over the fit
  double mean_spin = 0.0;                    // rad/s, over the fit
  double inertia_ratio = 0.0;                // I / (m h^2)
  double gained = 0.0, given = 0.0;          // kg m^2/s, about y (the plane only)
};

Roll RunOnSlope(Floor floor, double mu, double timestep) {
  TempDir dir("tetcosim_ball");
  std::unique_ptr<World> world = World::Load(dir.Write("scene.xml", Scene(floor, mu, timestep)));
  const int index = world->DeformableIndex("ball");
  const DeformableBody& ball = world->deformable(index);
  const double mass = ball.model().total_mass();
  auto inertia = [&] {  // about y through the centre
    const Eigen::Vector3d c = ball.CenterOfMass();
    double sum = 0.0;
    for (int i = 0; i < ball.num_vertices(); ++i) {
      const Eigen::Vector3d r = ball.positions().row(i).transpose() - c;
      sum += ball.model().masses()[i] * (r.x() * r.x() + r.z() * r.z());
    }
    return sum;
  };
  auto momentum = [&] {  // angular, about y through the centre
    return (ball.AngularMomentum() - ball.CenterOfMass().cross(ball.LinearMomentum())).y();
  };
  const double h = ball.CenterOfMass().z();
  Roll roll;
  roll.inertia_ratio = inertia() / (mass * h * h);
  std::vector<double> times, speeds, spins;
  const int steps = static_cast<int>(std::lround(kEnd / timestep));
  const int first = static_cast<int>(std::lround(kFirst / timestep));
  Positions start;
  for (int s = 1; s <= steps; ++s) {
    start = ball.positions();
    const Eigen::Vector3d centre = ball.CenterOfMass();
    if (s == first + 1) roll.gained = -momentum();
    world->Step();
    EXPECT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    if (s <= first) continue;
    if (floor == Floor::kPlaneGeom) {
      for (const ContactPoint& contact : world->contacts()) {
        EXPECT_EQ(contact.body_a, index);
        const Eigen::Vector3d r = start.row(contact.vertex_a).transpose() - centre;
        roll.given += r.cross(contact.force).y() * timestep;
      }
    }
    const double spin = momentum() / inertia();
    times.push_back(s * timestep);
    speeds.push_back(ball.CenterOfMassVelocity().x());
    spins.push_back(spin * h);
    roll.mean_spin += spin;
  }
  roll.gained += momentum();
  roll.mean_spin /= static_cast<double>(times.size());
  roll.acceleration = FittedRate(times, speeds);
  roll.spin_up = FittedRate(times, spins);
  for (size_t i = 0; i < times.size(); ++i) {
    roll.slip += speeds[i] - spins[i];
    roll.speed += speeds[i];
  }
  roll.slip /= static_cast<double>(times.size());
  roll.speed /= static_cast<double>(times.size());
  return roll;
}

// Rolling: the centre's rate is the rigid ball's less the step's
// resistance, N omega dt over the mass and the inertia it accelerates (m (1
// + I / (m h^2))), at the fit's mean spin, to 2% of the rigid rate (the
// ball is soft: its centre sinks 1.8 mm, 3.6% of its radius, as it
// flattens on the floor; measured, 0.7% at 2 ms and 1.3% at 1 ms, and
// 0.2% and 0.7% for a ball of E = 1e6 Pa); the ball rolls (its mean
// slip stays within 0.5% of its mean speed: without the friction springs
// carried from step to step, 1.5 to 3.6%); and halving the step takes off
// at least a fifth of what it lost (measured: a third).
TEST(Rolling, ABallRollsDownASlopeAsARigidBallDoesLessTheStepsResistance) {
  const double mu = 0.5;
  double loss_2ms = 0.0, loss_1ms = 0.0;
  for (const double dt : {0.002, 0.001}) {
    for (Floor floor : {Floor::kPlaneGeom, Floor::kStaticProxy, Floor::kDeformableSlab}) {
      if (dt < 0.002 && floor != Floor::kPlaneGeom) continue;  // (the time CI spends)
      const Roll roll = RunOnSlope(floor, mu, dt);
      const double rigid = kGravity * std::sin(kTheta) / (1.0 + roll.inertia_ratio);
      const double resistance =
          kGravity * std::cos(kTheta) * roll.mean_spin * dt / (1.0 + roll.inertia_ratio);
      std::printf(
          "%s, dt %g s: %.4f m/s^2, rigid %.4f, less the step's %.4f: %.4f; spin-up "
          "%.4f; slip %.1e m/s at %.3f m/s\n",
          Name(floor), dt, roll.acceleration, rigid, resistance, rigid - resistance, roll.spin_up,
          roll.slip, roll.speed);
      EXPECT_LT(roll.acceleration, rigid) << Name(floor) << " " << dt;
      EXPECT_NEAR(roll.acceleration, rigid - resistance, 0.02 * rigid) << Name(floor) << " " << dt;
      EXPECT_LT(std::abs(roll.slip), 0.005 * roll.speed) << Name(floor) << " " << dt;
      if (floor == Floor::kPlaneGeom) {
        double& loss = dt == 0.002 ? loss_2ms : loss_1ms;
        loss = rigid - roll.acceleration;
      }
    }
  }
  EXPECT_LT(loss_1ms, 0.8 * loss_2ms);
}

// Sliding: the centre as Coulomb says, to 1%; the ball slides (its slip
// is most of its speed); friction spins it up, short of mu g cos theta
// h^2 m / I by the step's share, omega dt / mu of it, at the fit's mean
// spin, to 3%; and on the plane the angular momentum it gains is what its
// contacts' forces give it about its centre at each step's start, to 1%
// (the step's own identity: what it misses is the element forces' torque).
TEST(Rolling, ABallWithTooLittleFrictionSlidesAsCoulombSaysAndSpinsUp) {
  const double mu = 0.05;  // (2/7 tan 20 degrees = 0.104)
  const double sliding = kGravity * (std::sin(kTheta) - mu * std::cos(kTheta));
  for (const double dt : {0.002, 0.001}) {
    const Roll roll = RunOnSlope(Floor::kPlaneGeom, mu, dt);
    const double spin_up = mu * kGravity * std::cos(kTheta) / roll.inertia_ratio;
    const double short_by = roll.mean_spin * dt / mu;
    std::printf(
        "dt %g s: %.4f m/s^2, Coulomb %.4f; spin-up %.4f, rigid %.4f, less the step's "
        "%.1f%%: %.4f; slip %.3f m/s at %.3f m/s; angular momentum gained %.6f, given "
        "%.6f\n",
        dt, roll.acceleration, sliding, roll.spin_up, spin_up, 100.0 * short_by,
        spin_up * (1.0 - short_by), roll.slip, roll.speed, roll.gained, roll.given);
    EXPECT_NEAR(roll.acceleration, sliding, 0.01 * sliding) << dt;
    EXPECT_GT(roll.slip, 0.5 * roll.speed) << dt;
    EXPECT_LT(roll.spin_up, spin_up) << dt;
    EXPECT_NEAR(roll.spin_up, spin_up * (1.0 - short_by), 0.03 * spin_up) << dt;
    EXPECT_NEAR(roll.gained, roll.given, 0.01 * std::abs(roll.given)) << dt;
  }
}

// A rigid ball (a MuJoCo sphere) and a rigid capsule lying across the
// slope (radius 5 cm, half-length 10 cm) rolling down it on a stiff slab
// whose surface vertices are 5 cm apart, half their width. Met as a geom
// (<contact autoproxy="narrow">: it is wider than the gaps), only at the
// slab's vertices, each sinks in between them and rolls over them as over
// a bed of nails (measured: the ball at 35% of a rigid body's rate, g sin
// theta / (1 + I / (m r^2)), I its moment of inertia about the axis it
// rolls on: 2/5 m r^2 for the ball, the least of the capsule's; the capsule
// at 38%). Given a proxy, made for it by default (autoproxy "true": round
// and narrower than 8 gaps; its fine surface coned to its centre or its
// axis) or, for the ball, by a <rigidtet> (the solid level-3 sphere), the
// proxy's vertices meet the slab's tetrahedra and the slab's vertices its
// tetrahedra, and it rolls at 93% (the capsule 95%: what the step's
// resistance and the proxy's facets leave; the ball's two proxies alike to
// 1e-3 of the rate).
TEST(Rolling, ARigidBallOrCapsuleRollsOverACoarseSlabsVerticesUnlessItHasAProxy) {
  enum class Contact { kGeom, kMadeProxy, kRigidTet };
  struct Body {
    const char* name;
    const char* geom;  // MJCF attributes
  };
  const Body bodies[] = {{"ball", "type='sphere' size='0.05'"},
                         {"capsule", "type='capsule' size='0.05 0.1' euler='90 0 0'"}};
  for (const Body& body : bodies) {
    SCOPED_TRACE(body.name);
    const bool ball = std::string(body.name) == "ball";
    double made = 0.0, given = 0.0;
    for (const Contact contact : {Contact::kGeom, Contact::kMadeProxy, Contact::kRigidTet}) {
      if (contact == Contact::kRigidTet && !ball) continue;
      const bool rigidtet = contact == Contact::kRigidTet;
      const std::string scene =
          "<mujoco><option timestep='0.002' " + TiltedGravity() +
          "/><worldbody><body name='anchor'/><body name='body' pos='-0.5 0 0.0502'><freejoint/>"
          "<geom name='body' " +
          body.geom + " density='1000' friction='0.5'" +
          (rigidtet ? " contype='0' conaffinity='0'" : "") +
          "/></body></worldbody><deformable><contact friction='0.5'" +
          (contact == Contact::kGeom ? " autoproxy='narrow'" : "") + "/>" +
          (rigidtet ? "<rigidtet body='body' geom='body' resolution='3'/>" : "") +
          PinnedSlab("40 12 2") + "</deformable></mujoco>";
      TempDir dir("tetcosim_ball");
      std::unique_ptr<World> world = World::Load(dir.Write("scene.xml", scene));
      EXPECT_EQ(world->made_proxies().size(), contact == Contact::kMadeProxy ? 1u : 0u);
      EXPECT_EQ(world->num_proxies(), contact == Contact::kGeom ? 0 : 1);
      const int id = world->BodyId("body");
      const mjModel* m = world->mj_model();
      const double* inertia = m->body_inertia + 3 * id;
      const double least = std::min({inertia[0], inertia[1], inertia[2]});
      const double rigid =
          kGravity * std::sin(kTheta) / (1.0 + least / (m->body_mass[id] * 0.05 * 0.05));
      if (ball) {
        EXPECT_NEAR(rigid, 5.0 / 7.0 * kGravity * std::sin(kTheta), 1e-6 * rigid);
      }
      std::vector<double> times, speeds;
      for (int s = 1; s <= static_cast<int>(std::lround(kEnd / world->timestep())); ++s) {
        world->Step();
        ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
        if (s * world->timestep() < kFirst - 1e-9) continue;
        times.push_back(s * world->timestep());
        speeds.push_back(world->RigidBodyLinearVelocity(id).x());
      }
      const double acceleration = FittedRate(times, speeds);
      std::printf("%s %s: %.4f m/s^2, rigid %.4f\n", body.name,
                  contact == Contact::kGeom        ? "met as a geom"
                  : contact == Contact::kMadeProxy ? "with the proxy made for it"
                                                   : "with a <rigidtet>",
                  acceleration, rigid);
      if (contact == Contact::kGeom) {
        EXPECT_LT(acceleration, 0.5 * rigid);
      } else {
        EXPECT_GT(acceleration, 0.9 * rigid);
        EXPECT_LT(acceleration, rigid);
        (rigidtet ? given : made) = acceleration;
      }
    }
    if (ball) {
      EXPECT_NEAR(made, given, 0.01 * given);
    }
  }
}

// Dropped 0.2 m on a floor, with neither contact damping nor Rayleigh
// damping, the soft ball rebounds slower than it hit (0.61, 0.75 and 0.85
// of its speed at 2, 1 and 0.5 ms): backward Euler damps what moves fast
// within a step (the contact lasts 22 ms, so 11 to 44 steps), and never
// adds energy. Each halving of the step takes at least a quarter off the
// speed lost (measured: 34% and 41%).
TEST(Bouncing, ABallBouncesBackSlowerThanItHitAndLessSoAtSmallerSteps) {
  double last_loss = 1.0;
  for (const double dt : {0.002, 0.001, 0.0005}) {
    char timestep[32];
    std::snprintf(timestep, sizeof timestep, "%.17g", dt);
    TempDir dir("tetcosim_ball");
    std::unique_ptr<World> world = World::Load(
        dir.Write("scene.xml", std::string("<mujoco><option timestep='") + timestep +
                                   "'/><worldbody><geom name='floor' type='plane' size='5 5 0.1'/>"
                                   "</worldbody><deformable><contact damping='0' friction='0'/>"
                                   "<tetbody name='ball' shape='sphere' size='0.05' resolution='2' "
                                   "pos='0 0 0.25' density='1000' young='2e5' poisson='0.3'/>"
                                   "</deformable></mujoco>"));
    const DeformableBody& ball = world->deformable(0);
    double impact = 0.0, rebound = 0.0;
    for (int s = 1; s <= static_cast<int>(std::lround(0.45 / dt)); ++s) {
      world->Step();
      ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
      const double v = ball.CenterOfMassVelocity().z();
      if (rebound == 0.0 && v < impact) impact = v;  // (falling, then pressing in)
      if (impact < 0.0 && v > 0.0) rebound = std::max(rebound, v);
    }
    const double restitution = -rebound / impact;
    std::printf("dt %g s: hit at %.4f m/s, back at %.4f: %.3f\n", dt, -impact, rebound,
                restitution);
    EXPECT_NEAR(impact, -std::sqrt(2.0 * kGravity * 0.2), 0.01) << dt;
    EXPECT_LT(restitution, 1.0) << dt;
    EXPECT_LT(1.0 - restitution, 0.75 * last_loss) << dt;
    last_loss = 1.0 - restitution;
  }
}

}  // namespace
}  // namespace tetcosim

#include "mujoco_bridge/world.h"

#include <gtest/gtest.h>
#include <mujoco/mujoco.h>
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <numbers>
#include <set>
#include <sstream>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "mesh/error.h"
#include "mesh/text_reader.h"
#include "tests/mujoco_bridge/lid_scene.h"
#include "tests/mujoco_bridge/stiff_slab_scenes.h"
#include "tests/mujoco_bridge/temp_dir.h"

namespace tetcosim {
namespace {

const std::string kData = TETCOSIM_TEST_DATA_DIR;

// Runs a shell command: its exit status (as pclose gives it) and its output.
std::pair<int, std::string> RunShell(const std::string& command) {
  FILE* pipe = popen(command.c_str(), "r");
  std::string text;
  char buffer[512];
  while (fgets(buffer, sizeof(buffer), pipe)) text += buffer;
  return {pclose(pipe), text};
}

// After a step: the largest difference between the velocities the step
// predicted for the MuJoCo trees it solved (RigidTree::velocity_end) and
// those MuJoCo then found; 0 where it solved none
double PredictionError(const World& world) {
  const mjModel* m = world.mj_model();
  const mjData* d = world.mj_data();
  const RigidSystem& rigid = world.rigid_system();
  double largest = 0.0;
  for (size_t t = 0; t < rigid.trees.size(); ++t) {
    const int root = world.rigid_system_roots()[t];
    int first = 0;  // the tree's first degree of freedom
    while (m->body_rootid[m->dof_bodyid[first]] != root) ++first;
    const Eigen::VectorXd& predicted = rigid.trees[t].velocity_end;
    const Eigen::Map<const Eigen::VectorXd> found(d->qvel + first, predicted.size());
    largest = std::max(largest, (predicted - found).norm());
  }
  return largest;
}

// A CSV file tetcosim wrote, line by line (the header first), and a line's
// fields (for lines whose names hold no comma).
std::vector<std::string> CsvLines(const std::filesystem::path& path) {
  std::ifstream file(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(file, line);) lines.push_back(line);
  return lines;
}
std::vector<std::string> CsvFields(const std::string& line) {
  std::istringstream fields(line);
  std::vector<std::string> result;
  for (std::string field; std::getline(fields, field, ',');) result.push_back(field);
  return result;
}

std::string ErrorOf(const std::string& path, const WorldOptions& options = {}) {
  try {
    World::Load(path, options);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(SceneLoading, IncludesAndRelativeFilesResolveFromAnotherWorkingDirectory) {
  std::filesystem::path cwd = std::filesystem::current_path();
  std::filesystem::current_path(std::filesystem::temp_directory_path());
  std::unique_ptr<World> world = World::Load(kData + "/scenes/with_include.xml");
  std::filesystem::current_path(cwd);
  EXPECT_EQ(world->num_deformables(), 1);
  EXPECT_EQ(world->num_proxies(), 1);
  EXPECT_GE(world->BodyId("table"), 1);
  // meshdir assets too
  std::filesystem::current_path(std::filesystem::temp_directory_path());
  std::unique_ptr<World> with_mesh = World::Load(kData + "/scenes/with_meshdir.xml");
  std::filesystem::current_path(cwd);
  EXPECT_GE(with_mesh->BodyId("wedge"), 1);
}

TEST(SceneLoading, BadScenesNameTheLine) {
  TempDir dir;
  const std::string head =
      "<mujoco>\n<worldbody>\n<body name=\"b\"><freejoint/><geom name=\"g\" type=\"box\" size=\".1 "
      ".1 .1\"/></body>\n</worldbody>\n<deformable>\n";
  struct Case {
    std::string body;
    std::string expected;
  };
  const Case cases[] = {
      {"<blob/>\n", "scene.xml:6: <blob>: unknown element inside <deformable>"},
      {"<tetbody name=\"a\" shape=\"sphere\" size=\"0.1\" colour=\"red\"/>\n",
       "scene.xml:6: <tetbody>: unknown attribute 'colour'"},
      {"<tetbody name=\"a\" shape=\"sphere\" size=\"0.1\" young=\"-5\"/>\n",
       "scene.xml:6: <tetbody>: young = -5 is outside"},
      {"<tetbody name=\"a\" shape=\"sphere\" size=\"0.1\" poisson=\"0.5\"/>\n",
       "poisson = 0.5 is outside"},
      {"<tetbody name=\"a\" file=\"missing.msh\"/>\n",
       "scene.xml:6: <tetbody>: file 'missing.msh' does not exist"},
      {"<tetbody name=\"a/b\" shape=\"sphere\" size=\"0.1\"/>\n",
       "scene.xml:6: <tetbody>: name has '/', which a file name cannot hold"},
      {"<tetbody name=\"" + std::string(201, 'n') + "\" shape=\"sphere\" size=\"0.1\"/>\n",
       "scene.xml:6: <tetbody>: name is 201 bytes long, more than the 200 a file name"},
      {"<tetbody name=\"a&#10;b\" shape=\"sphere\" size=\"0.1\"/>\n",
       "scene.xml:6: <tetbody>: name has a control character (0x0A)"},
      {"<tetbody name=\"caf\xE9\" shape=\"sphere\" size=\"0.1\"/>\n",
       "scene.xml:6: byte 0xE9 (column 19) is not UTF-8 text; save the scene as UTF-8"},
      {"<tetbody name=\"a\" shape=\"blob\" size=\"0.1\"/>\n",
       "scene.xml:6: <tetbody name=\"a\">: tetbody 'a': unknown shape 'blob'"},
      {"<tetbody name=\"a\" shape=\"sphere\" size=\"0.1\" pos=\"1 2\"/>\n",
       "pos takes 3 numbers, got 2"},
      {"<tetbody name=\"a\" shape=\"sphere\" size=\"0.1\" vel=\"0 1e200 0\"/>\n",
       "scene.xml:6: <tetbody>: vel = 1e+200 m/s is faster than light"},
      {"<rigidtet body=\"nobody\" geom=\"g\"/>\n",
       "scene.xml:6: <rigidtet>: no MuJoCo body named 'nobody'; the scene has the named bodies: "
       "'world' and 'b'"},
      {"<rigidtet body=\"b\" geom=\"h\"/>\n",
       "scene.xml:6: <rigidtet>: no geom named 'h'; body 'b' has the named geoms: 'g'"},
      {"<rigidtet body=\"world\" geom=\"g\"/>\n",
       "scene.xml:6: <rigidtet>: geom 'g' does not belong to body 'world'; body 'world' has no "
       "named geom"},
      {"<contact method=\"nearest\"/>\n",
       "scene.xml:6: <contact>: method must be consistent or closest"},
      {"<solver rigid=\"semi\"/>\n", "scene.xml:6: <solver>: rigid must be implicit or explicit"},
      {"<solver linear=\"lu\"/>\n", "scene.xml:6: <solver>: linear must be cg or ldlt"},
      {"<solver constraints=\"exact\"/>\n",
       "scene.xml:6: <solver>: constraints must be linearized or lagged"},
      {"<tetbody name=\"a\" shape=\"sphere\" size=\"0.1\"/>\n<attach tetbody=\"zz\" body=\"b\" "
       "vertices=\"0\"/>\n",
       "scene.xml:7: <attach>: no tetbody named 'zz'; the tetbodies: 'a'"},
      {"<tetbody name=\"a\" shape=\"sphere\" size=\"0.1\"/>\n<attach tetbody=\"a\" body=\"zz\" "
       "vertices=\"0\"/>\n",
       "scene.xml:7: <attach>: no MuJoCo body named 'zz'; the scene has the named bodies: 'world' "
       "and 'b'"},
      {"<tetbody name=\"a\" shape=\"sphere\" size=\"0.1\"/>\n<attach tetbody=\"a\" body=\"b\" "
       "vertices=\"0 2\"/>\n<attach tetbody=\"a\" body=\"world\" vertices=\"1 2\"/>\n",
       "scene.xml:8: <attach>: vertex 2 of tetbody 'a' is glued to body 'b' already; a vertex "
       "follows one body: make the regions apart"},
      // written but blank is not left out (it gave the default)
      {"<tetbody name=\"a\" shape=\"sphere\" size=\"0.1\" damping=\" \"/>\n",
       "scene.xml:6: <tetbody>: damping takes 1 to 2 numbers, got 0; give a value or leave the "
       "attribute out"},
      {"<contact friction=\"\"/>\n", "scene.xml:6: <contact>: friction takes 1 number, got 0"},
      // no smoothing at all: a sticking contact's friction damping divides by 0
      {"<contact slip=\"0\"/>\n", "scene.xml:6: <contact>: slip = 0 is outside [1e-06, 1]"},
      {"<contact stick=\"yes\"/>\n", "scene.xml:6: <contact>: stick must be true or false"},
      {"<contact area=\"flat\"/>\n", "scene.xml:6: <contact>: area must be whole or facing"},
      {"<contact stickstiffness=\"0\"/>\n",
       "scene.xml:6: <contact>: stickstiffness = 0 is outside [0.001, 1000]"},
      // a second settings element replaced the first's settings
      {"<contact friction=\"0.5\"/>\n<contact damping=\"0.1\"/>\n",
       "scene.xml:7: <contact>: only one <contact> is allowed inside <deformable> (the first is on "
       "line 6)"},
      {"<solver substeps=\"2\"/>\n<solver maxiter=\"10\"/>\n",
       "scene.xml:7: <solver>: only one <solver> is allowed"},
      // two proxies of one geom counted its contacts twice
      {"<rigidtet body=\"b\" geom=\"g\"/>\n<rigidtet body=\"b\" geom=\"g\" resolution=\"2\"/>\n",
       "scene.xml:7: <rigidtet>: geom 'g' of body 'b' has a <rigidtet> already (line 6)"},
  };
  for (const Case& c : cases) {
    std::string path = dir.Write("scene.xml", head + c.body + "</deformable>\n</mujoco>\n");
    std::string message = ErrorOf(path);
    EXPECT_NE(message.find(c.expected), std::string::npos)
        << "got: " << message << "\nexpected: " << c.expected;
  }
  // a long list of names is cut after twelve (the world and 14 bodies)
  std::string many = "<mujoco>\n<worldbody>\n";
  for (int i = 0; i < 14; ++i) {
    many += "<body name=\"b" + std::to_string(i) + "\"><geom size=\".1\"/></body>\n";
  }
  many +=
      "</worldbody>\n<deformable>\n<rigidtet body=\"b14\" geom=\"g\"/>\n</deformable>\n</mujoco>\n";
  EXPECT_NE(
      ErrorOf(dir.Write("many.xml", many))
          .find("many.xml:19: <rigidtet>: no MuJoCo body named 'b14'; the scene has the named "
                "bodies: 'world', 'b0', 'b1', 'b2', 'b3', 'b4', 'b5', 'b6', 'b7', 'b8', 'b9', "
                "'b10' and 3 more"),
      std::string::npos);
  // an element without attributes says so (it listed none after "allowed:")
  EXPECT_NE(ErrorOf(dir.Write("bare.xml",
                              "<mujoco>\n<deformable young=\"1e5\">\n</deformable>\n"
                              "</mujoco>\n"))
                .find("bare.xml:2: <deformable>: unknown attribute 'young'; this element takes no "
                      "attributes"),
            std::string::npos);
  // MuJoCo's own message, on one line with the line it names
  const std::string rejected = ErrorOf(
      dir.Write("bad.xml", "<mujoco><worldbody>\n<geom type=\"nonsense\"/></worldbody></mujoco>"));
  EXPECT_NE(rejected.find("bad.xml: MuJoCo rejected the scene: "), std::string::npos) << rejected;
  EXPECT_NE(rejected.find("; Element 'geom', line 2"), std::string::npos) << rejected;
  EXPECT_EQ(rejected.find('\n'), std::string::npos) << rejected;
  // MuJoCo takes "nan" and "inf" with a console warning only (a static geom
  // at NaN met nothing, and the rollout's metrics came out NaN)
  EXPECT_NE(
      ErrorOf(dir.Write("nan.xml",
                        "<mujoco><worldbody>\n<geom name=\"rim\" type=\"box\" "
                        "pos=\"1 nan 1\" size=\".1 .1 .1\"/></worldbody></mujoco>"))
          .find("nan.xml: MuJoCo's model has a number that is not finite (nan) in geom_pos of "
                "geom 'rim'"),
      std::string::npos);
  EXPECT_NE(ErrorOf(dir.Write("inf.xml", "<mujoco><option gravity=\"0 0 -inf\"/></mujoco>"))
                .find("inf.xml: MuJoCo's <option> has a number that is not finite"),
            std::string::npos);
  // (MuJoCo itself takes a negative damping)
  EXPECT_NE(ErrorOf(dir.Write("pump.xml",
                              "<mujoco><worldbody>\n<body name=\"lid\"><joint name=\"hinge\" "
                              "damping=\"-1\"/><geom size=\".1\"/></body></worldbody></mujoco>"))
                .find("pump.xml: joint 'hinge' of body 'lid' has damping -1 < 0, which adds "
                      "energy"),
            std::string::npos);
  // (MuJoCo itself takes a negative time step)
  EXPECT_NE(ErrorOf(dir.Write("back.xml", "<mujoco><option timestep=\"-0.001\"/></mujoco>"))
                .find("back.xml: the time step is -0.001 s (<option timestep>)"),
            std::string::npos);
  EXPECT_NE(ErrorOf(dir.Write("xml.xml", "<mujoco>\n<worldbody>\n</mujoco>"))
                .find("xml.xml:2: not well-formed XML: a closing tag does not match the element "
                      "it closes (in <worldbody>); mend the file"),
            std::string::npos);
  EXPECT_NE(ErrorOf(dir.Write("comment.xml", "<mujoco>\n<!-- a note\n</mujoco>"))
                .find("comment.xml:2: not well-formed XML: a comment is not closed with -->"),
            std::string::npos);
  EXPECT_NE(ErrorOf(dir.Write("empty.xml", ""))
                .find("empty.xml: not well-formed XML: the file holds no element"),
            std::string::npos);
  EXPECT_NE(ErrorOf((dir.path() / "none.xml").string()).find("cannot open"), std::string::npos);
  EXPECT_NE(ErrorOf(dir.path().string()).find("is a folder, not a scene file"), std::string::npos);
}

// zero gravity: a soft ball thrown at a free rigid box with a tetrahedral proxy
const char* const kImpactScene = R"(<mujoco>
  <option timestep="0.001" gravity="0 0 0"/>
  <worldbody>
    <body name="box" pos="0.2 0 0"><freejoint/><geom name="box" type="box" size="0.05 0.05 0.05" mass="0.5"/></body>
  </worldbody>
  <deformable>
    <rigidtet body="box" geom="box" resolution="4"/>
    <tetbody name="ball" shape="sphere" size="0.05" resolution="2" pos="0 0.01 0" vel="2 0 0" young="1e5"/>
  </deformable>
</mujoco>)";

// zero gravity: a soft ball thrown at a free rigid box (with a tetrahedral
// proxy): the total linear momentum of deformable vertices and MuJoCo bodies
// is conserved through the impact
TEST(Coupling, MomentumIsConservedThroughARigidImpact) {
  TempDir dir;
  std::string path = dir.Write("impact.xml", kImpactScene);
  std::unique_ptr<World> world = World::Load(path);
  const Eigen::Vector3d p0 = world->LinearMomentum();
  int contact_steps = 0;
  for (int s = 0; s < 200; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    contact_steps += world->metrics().colliding_points > 0;
  }
  const Eigen::Vector3d p1 = world->LinearMomentum();
  EXPECT_GT(contact_steps, 10);
  EXPECT_GT(world->RigidBodyLinearVelocity(world->BodyId("box")).x(), 0.5) << "the box was hit";
  EXPECT_LT((p1 - p0).norm(), 1e-3 * p0.norm())
      << "before " << p0.transpose() << " after " << p1.transpose();
}

// zero gravity: a soft ball thrown past the edge of a free rigid box, with
// friction: the box is set spinning. Step by step, the angular momentum the
// box gains about the world origin is exactly what the contacts take from the
// ball: the sum over the ball's vertices of x0 x (contact impulse), x0 where
// the vertex was at the step's start (backward Euler changes a vertex's
// angular momentum by x0 x its change of momentum). (The ball's own step is
// not exactly conservative while it spins deformed: the co-rotational
// linearization turns its angular momentum by 0.27% of the total in this
// impact; a stiff ball does not.) Linear momentum is conserved as a whole.
TEST(Coupling, AngularMomentumIsExchangedExactlyThroughAnOffCentreImpact) {
  TempDir dir;
  std::string path = dir.Write("spin_impact.xml", R"(<mujoco>
  <option timestep="0.001" gravity="0 0 0"/>
  <worldbody>
    <body name="box" pos="0.2 0 0"><freejoint/>
      <geom name="box" type="box" size="0.05 0.05 0.05" mass="0.5"/>
    </body>
  </worldbody>
  <deformable>
    <contact friction="0.5"/>
    <rigidtet body="box" geom="box" resolution="4"/>
    <tetbody name="ball" shape="sphere" size="0.05" resolution="2" pos="0 0.06 0.01" vel="2 0 0"
             young="1e5"/>
  </deformable>
</mujoco>)");
  std::unique_ptr<World> world = World::Load(path);
  const DeformableBody& ball = world->deformable(0);
  const double dt = world->mj_model()->opt.timestep;
  auto rigid_angular_momentum = [&]() -> Eigen::Vector3d {
    return world->AngularMomentum() - ball.AngularMomentum();
  };
  const Eigen::Vector3d p0 = world->LinearMomentum();
  const double L = world->AngularMomentum().norm();
  int contact_steps = 0;
  double largest = 0.0;
  for (int s = 0; s < 200; ++s) {
    const Positions x0 = ball.positions();
    const Eigen::Vector3d rigid_before = rigid_angular_momentum();
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    contact_steps += world->metrics().colliding_points > 0;
    // the angular impulse of the contacts on the ball's vertices
    Eigen::Vector3d impulse = Eigen::Vector3d::Zero();
    for (const ContactPoint& contact : world->contacts()) {
      if (contact.body_a == 0) {
        impulse += x0.row(contact.vertex_a).transpose().cross(contact.force * dt);
        continue;
      }
      ASSERT_EQ(contact.body_b, 0);  // a proxy vertex inside the ball
      const auto tet = ball.mesh().tets().row(contact.tet_b);
      for (int k = 0; k < 4; ++k) {
        impulse -= x0.row(tet[k]).transpose().cross(contact.barycentric_b[k] * contact.force * dt);
      }
    }
    largest = std::max(largest, (rigid_angular_momentum() - rigid_before + impulse).norm());
  }
  EXPECT_GT(contact_steps, 10);
  EXPECT_GT(world->RigidBodyAngularVelocity(world->BodyId("box")).norm(), 10.0) << "rad/s";
  EXPECT_LT(largest, 1e-12 * L) << "kg m^2/s, of " << L;
  EXPECT_LT((world->LinearMomentum() - p0).norm(), 1e-5 * p0.norm());
}

// a constant force the user put in xfrc_applied keeps acting while contacts
// come and go: the total momentum grows by exactly F t
TEST(Coupling, UserAppliedForcePersistsThroughContacts) {
  TempDir dir;
  std::string path = dir.Write("push.xml", kImpactScene);
  std::unique_ptr<World> world = World::Load(path);
  const int box = world->BodyId("box");
  world->mj_data()->xfrc_applied[6 * box + 1] = 0.3;  // 0.3 N along +y, set once
  const Eigen::Vector3d p0 = world->LinearMomentum();
  int contact_steps = 0;
  const int steps = 300;
  for (int s = 0; s < steps; ++s) {
    world->Step();
    contact_steps += world->metrics().colliding_points > 0;
  }
  EXPECT_GT(contact_steps, 10);
  EXPECT_LT(contact_steps, steps) << "contacts also ended";
  EXPECT_DOUBLE_EQ(
      world->mj_data()->xfrc_applied[6 * box + 1] - world->coupling_forces()[6 * box + 1], 0.3);
  const Eigen::Vector3d dp = world->LinearMomentum() - p0;
  EXPECT_NEAR(dp.y(), 0.3 * steps * 0.001, 1e-3 * 0.3 * steps * 0.001 + 1e-6);
}

TEST(Coupling, CubeRestsOnAFreeBoxWithoutDrift) {
  std::unique_ptr<World> world =
      World::Load(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml");
  for (int s = 0; s < 1000; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
  }
  Eigen::Vector3d cube = world->deformable(0).CenterOfMass();
  Eigen::Vector3d box = world->RigidBodyPosition(world->BodyId("box"));
  for (int s = 0; s < 500; ++s) world->Step();
  EXPECT_LT((world->deformable(0).CenterOfMass() - cube).norm(), 1e-4)
      << "no drift over one second";
  EXPECT_LT((world->RigidBodyPosition(world->BodyId("box")) - box).norm(), 1e-4);
  EXPECT_LT(world->DeformableKineticEnergy(), 1e-6);
  EXPECT_LT(world->RigidKineticEnergy(), 1e-6);
  EXPECT_NEAR(world->deformable(0).CenterOfMass().z(), 0.1 + 0.04, 0.002)
      << "resting on the box top";
}

// A patch test of contact through MuJoCo: a rigid plate (2 kg, on a
// vertical slide) rests on a soft block (10 cm, E = 1e5 Pa) on the floor,
// all without friction, so that the block is in uniaxial stress: it
// shortens by (M g / A + rho g H / 2) H / E, which linear tetrahedra hold
// exactly at any resolution, and contact presses every vertex of its top
// and bottom faces to the same depth, the pressure over the contact
// stiffness kappa = 10 E / L (the default), M g / (kappa A') on top and
// (M + m) g / (kappa A') below, A' the face's area as the block's Poisson
// bulge widens it. So each vertex's contact stiffness must be kappa times
// the area it shows the contact (<contact area="facing">,
// FacingContactArea): with its whole share of the surface (area="whole",
// the default), the edge and corner vertices count their side faces' area
// too, and the depths are up to 63% off (the corners'). The block's
// own weight bows its cross sections a little (nu rho g r^2 / (2 E), 7e-6
// m): the depths are even to 0.4% (measured), not exactly.
TEST(Coupling, ARigidPlateCompressesASoftBlockUniformlyAsSigmaOverESays) {
  constexpr double kHalf = 0.05, kYoung = 1e5, kDensity = 100, kPlateMass = 2, kG = 9.81;
  for (const int resolution : {3, 6}) {
    SCOPED_TRACE(::testing::Message() << "resolution " << resolution);
    TempDir dir;
    const std::string path = dir.Write("plate.xml", R"(<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1" friction="0 0 0"/>
    <body name="plate" pos="0 0 0.105">
      <joint type="slide" axis="0 0 1"/>
      <geom type="box" size="0.1 0.1 0.005" mass="2" friction="0 0 0"/>
    </body>
  </worldbody>
  <deformable>
    <contact friction="0" area="facing"/>
    <tetbody name="block" shape="box" size="0.05 0.05 0.05" pos="0 0 0.05" resolution=")" +
                                                        std::to_string(resolution) + R"("
             density="100" young="1e5" poisson="0.3" damping="2 0"/>
  </deformable>
</mujoco>)");
    std::unique_ptr<World> world = World::Load(path);
    for (int s = 0; s < 1500; ++s) {
      world->Step();
      ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    }
    ASSERT_LT(world->DeformableKineticEnergy() + world->RigidKineticEnergy(), 1e-12) << "J";
    const Positions& x = world->deformable(0).positions();
    const double plate_bottom = world->RigidBodyPosition(world->BodyId("plate")).z() - 0.005;
    // the top and bottom faces' vertices, and each face's area as it is now
    std::vector<double> top_z, bottom_z;
    Eigen::Vector2d top_min = Eigen::Vector2d::Constant(1.0), top_max = -top_min;
    Eigen::Vector2d bottom_min = top_min, bottom_max = top_max;
    for (Eigen::Index v = 0; v < x.rows(); ++v) {
      const Eigen::Vector2d xy = x.row(v).head<2>().transpose();
      if (x(v, 2) > 1.8 * kHalf) {
        top_z.push_back(x(v, 2));
        top_min = top_min.cwiseMin(xy), top_max = top_max.cwiseMax(xy);
      } else if (x(v, 2) < 0.01 * kHalf) {
        bottom_z.push_back(x(v, 2));
        bottom_min = bottom_min.cwiseMin(xy), bottom_max = bottom_max.cwiseMax(xy);
      }
    }
    ASSERT_EQ(top_z.size(), static_cast<size_t>((resolution + 1) * (resolution + 1)));
    ASSERT_EQ(bottom_z.size(), top_z.size());
    const double area = 4 * kHalf * kHalf, height = 2 * kHalf;
    const double kappa = 10 * kYoung / height;  // L = (volume)^(1/3)
    const double block_weight = kDensity * area * height * kG;
    const double top_depth = kPlateMass * kG / (kappa * (top_max - top_min).prod());
    const double bottom_depth =
        (kPlateMass * kG + block_weight) / (kappa * (bottom_max - bottom_min).prod());
    double top_error = 0.0, bottom_error = 0.0;  // relative
    for (double z : top_z) {
      top_error = std::max(top_error, std::abs(z - plate_bottom - top_depth) / top_depth);
    }
    for (double z : bottom_z) {
      bottom_error = std::max(bottom_error, std::abs(-z - bottom_depth) / bottom_depth);
    }
    EXPECT_LT(top_error, 0.01) << "of " << top_depth << " m, the depth under the plate";
    EXPECT_LT(bottom_error, 0.01) << "of " << bottom_depth << " m, the depth in the floor";
    const double shortening = (kPlateMass * kG / area + block_weight / area / 2) * height / kYoung;
    const auto mean = [](const std::vector<double>& z) {
      double sum = 0.0;
      for (double value : z) sum += value;
      return sum / static_cast<double>(z.size());
    };
    const double shortened = height - (mean(top_z) - mean(bottom_z));
    std::printf("resolution %d: depths off by %.2g (top), %.2g (bottom), shortening by %.2g\n",
                resolution, top_error, bottom_error, std::abs(shortened / shortening - 1));
    EXPECT_NEAR(shortened, shortening, 0.01 * shortening);
  }
}

// Every path a contact takes honours <contact area="facing">: a soft block
// whose base is in the floor (a geom), a soft lid pressed into its top
// (deformable in deformable, both ways) and a fixed box's proxy pressed
// into its side (deformable in proxy, proxy in deformable). Each contact's
// stiffness is kappa times the area its vertex shows the contact, summed by
// brute force over its object's surface triangles at the step's start, and
// bounded by the penetrated mesh's surface area per vertex (World's
// contacts); kappa the softer deformable's, or the deformable's against a
// proxy or a geom.
TEST(Coupling, EveryContactsStiffnessIsKappaTimesTheAreaItsVertexShowsTheContact) {
  TempDir dir;
  const std::string path = dir.Write("paths.xml", R"(<mujoco>
  <option gravity="0 0 0"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="wall" pos="0.078 0.01 0.05"><geom name="wall" type="box" size="0.03 0.03 0.03"/></body>
  </worldbody>
  <deformable>
    <contact area="facing"/>
    <rigidtet body="wall" geom="wall" resolution="3"/>
    <tetbody name="block" shape="box" size="0.05 0.05 0.05" pos="0 0 0.048" resolution="3"/>
    <tetbody name="lid" shape="box" size="0.03 0.03 0.03" pos="0.01 -0.005 0.126" resolution="2"
             young="1e6" euler="0 0 10"/>
  </deformable>
</mujoco>)");
  std::unique_ptr<World> world = World::Load(path);
  // the positions the step's contacts are collected at
  std::vector<Positions> start;
  start.reserve(world->num_deformables());
  for (int i = 0; i < world->num_deformables(); ++i) {
    start.push_back(world->deformable(i).positions());
  }
  world->Step();
  ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
  const std::vector<CollisionObject>& objects = world->collision_objects();
  const int deformables = world->num_deformables();
  const auto positions = [&](int object) -> const Positions& {
    return object < deformables ? start[object] : *objects[object].positions;
  };
  std::vector<Eigen::VectorXd> whole;  // each object's vertices' whole shares
  std::vector<double> area_per_vertex;
  for (const CollisionObject& object : objects) {
    whole.push_back(ComputeContactAreas(*object.mesh));
    area_per_vertex.push_back(MeanSurfaceVertexArea(*object.mesh, whole.back()));
  }
  const auto facing_area = [&](int object, int vertex, const Eigen::Vector3d& direction) {
    const TetMesh& mesh = *objects[object].mesh;
    const Positions& x = positions(object);
    double facing = 0.0;
    for (Eigen::Index f = 0; f < mesh.surface().rows(); ++f) {
      const Eigen::RowVector3i corners = mesh.surface().row(f);
      if ((corners.array() != vertex).all()) continue;
      const Eigen::Vector3d a = x.row(corners[0]).transpose();
      const Eigen::Vector3d b = x.row(corners[1]).transpose();
      const Eigen::Vector3d c = x.row(corners[2]).transpose();
      const Eigen::Vector3d inward = -0.5 * (b - a).cross(c - a);  // times the area
      facing += std::max(0.0, inward.dot(direction)) / 3;
    }
    return std::max(facing, kMinFacingShare * whole[object][vertex]);
  };
  std::set<std::pair<bool, bool>> kinds;  // (A deformable, B deformable)
  int smaller_than_whole = 0;
  const std::vector<PenetrationResult>& results = world->penetrations();
  for (size_t i = 0; i < results.size(); ++i) {
    const PenetrationResult& r = results[i];
    const bool a_deformable = r.object < deformables, b_deformable = r.penetrated < deformables;
    kinds.insert({a_deformable, b_deformable});
    const double kappa =
        a_deformable ? (b_deformable ? std::min(world->contact_pressure_stiffness(r.object),
                                                world->contact_pressure_stiffness(r.penetrated))
                                     : world->contact_pressure_stiffness(r.object))
                     : world->contact_pressure_stiffness(r.penetrated);
    const double area = facing_area(r.object, r.vertex, r.direction);
    const double expected = kappa * std::min(area, area_per_vertex[r.penetrated]);
    EXPECT_NEAR(world->contacts()[i].stiffness, expected, 1e-12 * expected)
        << "object " << r.object << " vertex " << r.vertex << " in object " << r.penetrated;
    smaller_than_whole += area < 0.9 * whole[r.object][r.vertex];
  }
  const std::set<std::pair<bool, bool>> all_kinds = {{true, true}, {true, false}, {false, true}};
  EXPECT_EQ(kinds, all_kinds);
  int in_the_floor = 0;
  for (size_t i = results.size(); i < world->contacts().size(); ++i) {
    const ContactPoint& contact = world->contacts()[i];
    ASSERT_EQ(contact.body_a, 0) << "only the block is in the floor";
    const double expected =
        world->contact_pressure_stiffness(0) * facing_area(0, contact.vertex_a, contact.direction);
    EXPECT_NEAR(contact.stiffness, expected, 1e-12 * expected) << "vertex " << contact.vertex_a;
    ++in_the_floor;
  }
  EXPECT_EQ(in_the_floor, 16) << "the block's base";
  EXPECT_GT(smaller_than_whole, 0)
      << "edge or corner vertices whose whole share the side faces add to";
}

// The same cube at 10 and 20 ms. The floor holds the box up through
// MuJoCo's contacts, which the step linearizes about their active set
// (<solver constraints="linearized">, the default): the step's prediction
// of the box's velocity is then what MuJoCo finds, to its solver's
// tolerance (2e-9 and 5e-9 m/s measured), and the cube comes to rest on
// the box. So with MuJoCo's elliptic friction cone, whose contacts are
// linearized whole (taken as lagged, the cube walked off the box), and
// with its CG and PGS solvers, which solve the same problem, to their own
// tolerance: CG's step was off the prediction by 8e-7 m/s at most, PGS's
// at its default 100 iterations by 2.5e-3 and 1.4e-3 (pyramidal and
// elliptic; the cube walked 3e-7 and 5e-8 m), and PGS's run to
// convergence (3000 iterations, tolerance 1e-15) by 9e-9, as Newton's. Taken as the force MuJoCo
// last solved (constraints="lagged", and before, always under PGS), they let the box give way in
// the prediction (off by 1.2 m/s at 20 ms, measured; 1.1 and 1.4 under PGS), and the cube bounces
// in a limit cycle and walks, 19 cm in 4 s. Under MuJoCo's RK4, whose four stages re-solve the
// floor's contacts, the step predicts the box as an Euler step: off by up to 4e-3 m/s where the
// cube lands (measured 4.3e-3 and 3.4e-3 at 10 and 20 ms; 2.2e-4 at 2 ms), and the cube rests.
TEST(Coupling, CubeRestsOnAFreeBoxAtLargeTimeStepsAsMuJoCoPredicted) {
  TempDir dir;
  std::ifstream file(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml");
  std::stringstream text;
  text << file.rdbuf();
  struct Variant {
    const char* constraints;
    const char* jacobian;  // MuJoCo's constraint Jacobian, dense or sparse
    const char* cone;      // MuJoCo's friction cone
    const char* solver;    // MuJoCo's constraint solver
    double dt;
    double largest_error = 1e-6;     // m/s, the prediction's, linearized
    const char* iterations = "100";  // MuJoCo's solver's, at most (its defaults)
    const char* tolerance = "1e-8";
    const char* integrator = "Euler";
  };
  for (const Variant& variant :
       {Variant{"linearized", "dense", "pyramidal", "Newton", 0.01},
        Variant{"linearized", "dense", "pyramidal", "Newton", 0.02},
        Variant{"linearized", "sparse", "pyramidal", "Newton", 0.02},
        Variant{"linearized", "dense", "elliptic", "Newton", 0.02},
        Variant{"linearized", "sparse", "pyramidal", "CG", 0.02, 1e-5},
        Variant{"linearized", "dense", "pyramidal", "PGS", 0.02, 1e-2},
        Variant{"linearized", "dense", "elliptic", "PGS", 0.02, 1e-2},
        Variant{"linearized", "dense", "pyramidal", "PGS", 0.02, 1e-6, "3000", "1e-15"},
        Variant{"linearized", "dense", "elliptic", "PGS", 0.02, 1e-6, "3000", "1e-15"},
        Variant{"linearized", "dense", "pyramidal", "Newton", 0.01, 1e-2, "100", "1e-8", "RK4"},
        Variant{"linearized", "dense", "pyramidal", "Newton", 0.02, 1e-2, "100", "1e-8", "RK4"},
        Variant{"lagged", "dense", "pyramidal", "Newton", 0.02}}) {
    const std::string name = std::string(variant.constraints) + ", " + variant.jacobian + ", " +
                             variant.cone + ", " + variant.solver + " (" + variant.iterations +
                             " iterations), " + variant.integrator + ", dt " +
                             std::to_string(variant.dt);
    SCOPED_TRACE(name);
    std::string scene = text.str();
    scene.insert(scene.find("<rigidtet "),
                 std::string("<solver constraints=\"") + variant.constraints + "\"/>");
    scene.insert(scene.find("<option ") + 8,
                 std::string("jacobian=\"") + variant.jacobian + "\" cone=\"" + variant.cone +
                     "\" solver=\"" + variant.solver + "\" iterations=\"" + variant.iterations +
                     "\" tolerance=\"" + variant.tolerance + "\" integrator=\"" +
                     variant.integrator + "\" ");
    WorldOptions options;
    options.timestep = variant.dt;
    std::unique_ptr<World> world = World::Load(dir.Write("scene.xml", scene), options);
    const mjModel* m = world->mj_model();
    ASSERT_EQ(mj_isSparse(m), variant.jacobian == std::string("sparse"));
    ASSERT_EQ(m->opt.cone == mjCONE_ELLIPTIC, variant.cone == std::string("elliptic"));
    ASSERT_EQ(m->opt.solver == mjSOL_PGS, variant.solver == std::string("PGS"));
    ASSERT_EQ(m->opt.integrator == mjINT_RK4, variant.integrator == std::string("RK4"));
    double largest_error = 0.0;
    Eigen::Vector3d settled = Eigen::Vector3d::Zero();
    const int steps = static_cast<int>(std::lround(6.0 / variant.dt));
    for (int s = 0; s < steps; ++s) {
      world->Step();
      ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
      if (s == steps / 3) settled = world->deformable(0).CenterOfMass();
      largest_error = std::max(largest_error, PredictionError(*world));
    }
    const double walked = (world->deformable(0).CenterOfMass() - settled).head<2>().norm();
    std::printf("%s: prediction off by %.3g m/s at most; walked %.3g m\n", name.c_str(),
                largest_error, walked);
    if (variant.constraints == std::string("linearized")) {
      EXPECT_LT(largest_error, variant.largest_error) << "m/s";
      EXPECT_LT(walked, 1e-6) << "m in the last 4 s";
      EXPECT_LT(world->DeformableKineticEnergy(), 1e-10);
      EXPECT_NEAR(world->deformable(0).CenterOfMass().z(), 0.1 + 0.04, 0.002) << "on the box";
    } else {
      EXPECT_GT(largest_error, 0.1) << "m/s";
      EXPECT_GT(walked, 0.01) << "m in the last 4 s";
    }
  }
}

// The same on a stack: the cube's box rests on a second free box, which
// the step does not solve (nothing soft touches it). The contacts between
// the boxes are taken with the lower box held still, so at 20 ms the cube
// rests as on one box. (Taken as MuJoCo last solved them, it walked off.)
TEST(Coupling, CubeRestsOnAStackOfFreeBoxesAtLargeTimeSteps) {
  TempDir dir;
  std::ifstream file(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml");
  std::stringstream text;
  text << file.rdbuf();
  std::string scene = text.str();
  const std::string box = R"(<body name="box" pos="0 0 0.05">)";
  scene.replace(scene.find(box), box.size(),
                R"(<body name="low" pos="0 0 0.05"><freejoint/>
                     <geom type="box" size="0.15 0.15 0.05" mass="2"/></body>
                   <body name="box" pos="0 0 0.15">)");
  const std::string cube = R"(pos="0.01 0 0.2")";
  scene.replace(scene.find(cube), cube.size(), R"(pos="0.01 0 0.3")");
  WorldOptions options;
  options.timestep = 0.02;
  std::unique_ptr<World> world = World::Load(dir.Write("stack.xml", scene), options);
  Eigen::Vector3d settled = Eigen::Vector3d::Zero();
  for (int s = 0; s < 300; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    if (s == 100) settled = world->deformable(0).CenterOfMass();
  }
  const Eigen::Vector3d center = world->deformable(0).CenterOfMass();
  EXPECT_LT((center - settled).head<2>().norm(), 1e-4) << "m walked in the last 4 s";
  EXPECT_NEAR(center.z(), 0.2 + 0.04, 0.002) << "on the upper box";
  EXPECT_LT(world->DeformableKineticEnergy(), 1e-10);
}

// Two free boxes that both touch soft bodies: a small box on a long one,
// a soft cube on each, at 20 ms. The contacts between the boxes are on two
// trees the step solves, and are taken as one constraint coupling them, so
// the step predicts both boxes' velocities as MuJoCo then finds them, and
// the cubes rest. (Taken as MuJoCo last solved them, the upper cube walked
// 1.7 cm in the last 4 s, 10 cm in all.)
TEST(Coupling, CubesRestOnTwoStackedBoxesThatBothTouchSoftBodies) {
  TempDir dir;
  const std::string path = dir.Write("two_boxes.xml", R"(<mujoco>
  <option timestep="0.02"/>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <body name="low" pos="0 0 0.05">
      <freejoint/>
      <geom name="low" type="box" size="0.3 0.15 0.05" mass="2"/>
    </body>
    <body name="box" pos="-0.12 0 0.15">
      <freejoint/>
      <geom name="box" type="box" size="0.12 0.12 0.05" mass="2"/>
    </body>
  </worldbody>
  <deformable>
    <contact friction="0.6"/>
    <rigidtet body="box" geom="box" resolution="4"/>
    <rigidtet body="low" geom="low" resolution="4"/>
    <tetbody name="upper" shape="box" size="0.04 0.04 0.04" resolution="4" pos="-0.11 0 0.3"
             euler="10 5 0" density="1000" young="1e5" damping="1 0"/>
    <tetbody name="lower" shape="box" size="0.04 0.04 0.04" resolution="4" pos="0.15 0 0.2"
             euler="10 5 0" density="1000" young="1e5" damping="1 0"/>
  </deformable>
</mujoco>)");
  std::unique_ptr<World> world = World::Load(path);
  double largest_error = 0.0;
  int coupled_steps = 0;
  std::array<Eigen::Vector3d, 2> settled;
  for (int s = 0; s < 300; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    if (s == 100) {
      settled = {world->deformable(0).CenterOfMass(), world->deformable(1).CenterOfMass()};
    }
    const RigidSystem& rigid = world->rigid_system();
    coupled_steps += std::any_of(rigid.constraints.begin(), rigid.constraints.end(),
                                 [](const RigidConstraint& c) { return c.trees[1] >= 0; });
    largest_error = std::max(largest_error, PredictionError(*world));
  }
  EXPECT_GT(coupled_steps, 250) << "steps with a constraint between the boxes in the system";
  EXPECT_LT(largest_error, 1e-6) << "m/s";
  for (int k = 0; k < 2; ++k) {
    SCOPED_TRACE(world->deformable(k).name());
    EXPECT_LT((world->deformable(k).CenterOfMass() - settled[static_cast<size_t>(k)]).norm(), 1e-4)
        << "m walked in the last 4 s";
  }
  // (each on its box's top, half its height above it)
  for (const auto& [cube, box] : {std::pair{0, "box"}, std::pair{1, "low"}}) {
    EXPECT_NEAR(world->deformable(cube).CenterOfMass().z(),
                world->RigidBodyPosition(world->BodyId(box)).z() + 0.05 + 0.04, 0.001)
        << "on " << box;
  }
  EXPECT_LT(world->DeformableKineticEnergy(), 1e-10);
  std::printf("two boxes: prediction off by %.3g m/s at most\n", largest_error);
}

// cube_on_box on a floor of little friction (0.2) under gravity tilted
// along x (3 m/s^2), so that the box slides with the cube on it, at 20 ms,
// in MuJoCo's elliptic and pyramidal cones. In the elliptic cone the
// floor's contacts are in the cone's middle zone, their force on its
// surface, which the step linearizes about MuJoCo's solution and again
// about its own (Newton's method); in the pyramidal cone the rows of a
// sliding contact that MuJoCo's solution at the step's start has satisfied
// are taken released, and taken back where the step's solution has them
// push. The step then predicts the box's velocity as MuJoCo finds it
// (measured: elliptic, median 8e-7 m/s, 9 steps in 10 within 2e-5, 4e-3
// at most; pyramidal, 3e-8, 3e-7, 9e-6), and the cube rides on the box.
// (Elliptic contacts taken as MuJoCo last solved them: off by 0.33 m/s in
// the median step, 1.8 at most, the box hopped and the cube fell off it
// within 1.2 s; satisfied pyramidal rows left out: 0.24 m/s at most.)
// Under MuJoCo's PGS solver, pyramidal, at its default 100 iterations:
// 4e-7, 3e-4, 7e-4 (taken as lagged, as they were under PGS before: 1.9
// m/s in the median step, and the cube fell off). Not tested: PGS in the
// elliptic cone, where in two steps MuJoCo's PGS stopped after one
// iteration (mjData::solver_iter; 450 to 750 in the other steps with four
// contacts) and its step was off the prediction by 0.39 and 0.78 m/s
// (the same with 10,000 iterations), and the cube fell off. MuJoCo's
// Newton solver, stepping the same states with the same forces, agreed
// with the prediction to 4e-7 and 6e-6 m/s: PGS stalled short of the
// problem's solution.
TEST(Coupling, ABoxSlidingUnderASoftCubeIsPredictedAsMuJoCoSlidesIt) {
  TempDir dir;
  std::ifstream file(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml");
  std::stringstream text;
  text << file.rdbuf();
  struct Variant {
    const char* cone;
    const char* solver;
    double median, ninety, largest;  // bounds on the prediction's error, m/s
  };
  for (const Variant& variant : {Variant{"elliptic", "Newton", 1e-5, 1e-4, 1e-2},
                                 Variant{"pyramidal", "Newton", 1e-6, 1e-5, 1e-4},
                                 Variant{"pyramidal", "PGS", 1e-5, 1e-3, 1e-2}}) {
    SCOPED_TRACE(std::string(variant.cone) + ", " + variant.solver);
    std::string scene = text.str();
    for (const auto& [from, to] : {
             std::pair<std::string, std::string>{
                 R"(gravity="0 0 -9.81")", std::string(R"(gravity="3 0 -9.81" cone=")") +
                                               variant.cone + "\" solver=\"" + variant.solver +
                                               "\""},
             {R"(type="plane" size="1 1 0.1")", R"(type="plane" size="5 5 0.1" friction="0.2")"},
             {R"(mass="2")", R"(mass="2" friction="0.2")"},
         }) {
      ASSERT_NE(scene.find(from), std::string::npos) << from;
      scene.replace(scene.find(from), from.size(), to);
    }
    WorldOptions options;
    options.timestep = 0.02;
    std::unique_ptr<World> world = World::Load(dir.Write("sliding.xml", scene), options);
    const mjData* d = world->mj_data();
    std::vector<double> errors;
    int sliding_steps = 0;
    for (int s = 0; s < 100; ++s) {
      world->Step();
      ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
      const RigidSystem& rigid = world->rigid_system();
      if (rigid.trees.empty()) continue;
      sliding_steps += std::any_of(rigid.constraints.begin(), rigid.constraints.end(),
                                   [](const RigidConstraint& c) { return c.sliding; });
      errors.push_back(PredictionError(*world));
    }
    ASSERT_FALSE(errors.empty());
    EXPECT_GT(errors.size(), 80U) << "steps with the box in the system";
    if (variant.cone == std::string("elliptic")) {
      EXPECT_GT(sliding_steps, 50);
    }
    std::sort(errors.begin(), errors.end());
    const double median = errors[errors.size() / 2], ninety = errors[errors.size() * 9 / 10];
    EXPECT_LT(median, variant.median) << "m/s";
    EXPECT_LT(ninety, variant.ninety) << "m/s";
    EXPECT_LT(errors.back(), variant.largest) << "m/s";
    EXPECT_GT(d->qvel[0], 1.0) << "m/s: the box slides";
    const Eigen::Vector3d cube = world->deformable(0).CenterOfMass();
    EXPECT_LT(std::abs(cube.x() - d->qpos[0]), 0.15) << "over the box";
    EXPECT_GT(cube.z(), d->qpos[2] + 0.05) << "above its top";
    std::printf(
        "sliding box, %s, %s: prediction off by %.3g m/s (median), %.3g (9 in 10), %.3g at "
        "most\n",
        variant.cone, variant.solver, median, ninety, errors.back());
  }
}

// A lid (0.3 kg, 30 cm) held level on its hinge by the hinge's dry
// friction (frictionloss 0.6 N m against gravity's 0.44), until a soft
// cube lands on it and it turns down, at 10 ms. The friction loss row is
// taken in its state (quadratic while the lid holds, a constant torque
// while it turns), so the step predicts the lid as MuJoCo turns it
// (measured: 7e-7 rad/s at most). (Taken as MuJoCo last solved it, it was
// 0.18 rad/s off where the cube landed; held in its start state through
// the step, 5 rad/s.)
TEST(Coupling, AHingeHeldByItsFrictionLossTurnsAsMuJoCoTurnsIt) {
  TempDir dir;
  const std::string path =
      dir.Write("friction_loss.xml", LidScene("frictionloss=\"0.6\"", "pos=\"0.05 0 0.3\""));
  std::unique_ptr<World> world = World::Load(path);
  const mjData* d = world->mj_data();
  double largest_error = 0.0, fastest = 0.0;
  int slipping_steps = 0;
  for (int s = 0; s < 60; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    fastest = std::max(fastest, std::abs(d->qvel[0]));
    const RigidSystem& rigid = world->rigid_system();
    if (rigid.trees.empty()) continue;
    slipping_steps += std::any_of(
        rigid.constraints.begin(), rigid.constraints.end(), [](const RigidConstraint& c) {
          return c.kind == RigidConstraint::Kind::kFrictionLoss && c.sliding;
        });
    largest_error = std::max(largest_error, PredictionError(*world));
  }
  EXPECT_GT(slipping_steps, 3) << "steps with the lid turning against its friction";
  EXPECT_GT(fastest, 2.0) << "rad/s: the cube turned the lid down";
  EXPECT_LT(largest_error, 1e-5) << "rad/s";
  std::printf("friction loss: prediction off by %.3g rad/s at most, fastest %.3g rad/s\n",
              largest_error, fastest);
}

// MuJoCo's Euler step takes a joint's damping B implicitly, (M + h B) (v' -
// v) = h f (f with the damping's -B v at the step's start), and solves its
// constraints' forces with M alone; its implicit step takes so an
// actuator's rate with its velocity and a tendon's damping too. A lid (0.3
// kg, 30 cm) on a hinge damped to about its inertia over a step (h B / I =
// 1.1, at 10 ms), which a soft cube lands on: free; held on its joint limit
// (MuJoCo's Jacobians dense and sparse); swinging up into a cube thrown
// down at it with three substeps (each substep's trees that it does not
// solve moving on as MuJoCo's step will move them); damped half by the
// joint and half by a velocity servo with the implicit integrator; by an
// affine velocity gain whose control is beyond its range; and by a damped
// tendon (implicit, sparse and dense). The step predicts the lid as MuJoCo
// turns it (measured: 9e-8 to 9e-7 rad/s at most). (With the damping taken
// at the step's start alone, the prediction was 2.2, 0.18 and 2.0 rad/s off
// in the first three; with the limit's law on J u / h rather than MuJoCo's
// J a, 0.16 rad/s; the unsolved lid moved on without the damping between
// substeps, 9e-3 rad/s; the servo's rate left out, 0.84 rad/s; the gain's
// with the control clamped, 0.3 rad/s; the tendon's damping left out, 2.2
// rad/s.) Under RK4, which takes the damping explicitly at each of its
// four stages, the step's matrix is RK4's for M v' = f - B v (World::
// TreeMass), B the joint's damping, a velocity servo's or a tendon's:
// 3.6e-3 rad/s free (with each of the three), and 1.7e-2 on the limit,
// where RK4's stages also move the gravity's torque and re-solve the limit
// (with M + h B as for Euler, 0.65 and 0.044; with M alone, 1.67 and 0.14;
// with the servo's and the tendon's left out of B, 0.80 and 1.67).
TEST(Coupling, ADampedHingeTurnsAsMuJoCoTurnsIt) {
  struct Case {
    const char* name;
    const char* joint;
    const char* option;
    const char* before;               // before <deformable>
    const char* first_in_deformable;  // <solver>
    const char* cube;                 // its position and velocity
    int steps;
    double largest_error = 1e-5;  // rad/s, the prediction's
  };
  const char* tendon =
      "<tendon><fixed damping=\"1\"><joint joint=\"hinge\" coef=\"1\"/></fixed></tendon>";
  const Case cases[] = {
      {"free", "damping=\"1\"", "", "", "", "pos=\"0.05 0 0.3\"", 80},
      {"on its limit", "damping=\"1\" range=\"-60 0\" limited=\"true\"", "", "", "",
       "pos=\"0.05 0 0.3\"", 80},
      {"on its limit, sparse", "damping=\"1\" range=\"-60 0\" limited=\"true\"",
       "jacobian=\"sparse\"", "", "", "pos=\"0.05 0 0.3\"", 80},
      {"swinging, three substeps", "damping=\"1\"", "",
       "<keyframe><key qpos=\"0.3\" qvel=\"-4\"/></keyframe>", "<solver substeps=\"3\"/>",
       "pos=\"0.1 0 0.3\" vel=\"0 0 -1.3\"", 40},
      {"a velocity servo, implicit", "damping=\"0.5\"", "integrator=\"implicit\"",
       "<actuator><velocity joint=\"hinge\" kv=\"0.5\"/></actuator>", "", "pos=\"0.05 0 0.3\"", 80},
      {"a velocity gain beyond its control range, implicit", "", "integrator=\"implicit\"",
       "<actuator><general joint=\"hinge\" gaintype=\"affine\" gainprm=\"0 0 -1\" "
       "ctrllimited=\"true\" ctrlrange=\"0 0.5\"/></actuator>\n"
       "<keyframe><key ctrl=\"0.8\"/></keyframe>",
       "", "pos=\"0.05 0 0.3\"", 80},
      {"a damped tendon, implicit, sparse", "", "integrator=\"implicit\" jacobian=\"sparse\"",
       tendon, "", "pos=\"0.05 0 0.3\"", 80},
      {"a damped tendon, implicit, dense", "", "integrator=\"implicit\" jacobian=\"dense\"", tendon,
       "", "pos=\"0.05 0 0.3\"", 80},
      {"free, RK4", "damping=\"1\"", "integrator=\"RK4\"", "", "", "pos=\"0.05 0 0.3\"", 80, 1e-2},
      {"on its limit, RK4", "damping=\"1\" range=\"-60 0\" limited=\"true\"", "integrator=\"RK4\"",
       "", "", "pos=\"0.05 0 0.3\"", 80, 3e-2},
      {"a velocity servo, RK4", "damping=\"0.5\"", "integrator=\"RK4\"",
       "<actuator><velocity joint=\"hinge\" kv=\"0.5\"/></actuator>", "", "pos=\"0.05 0 0.3\"", 80,
       1e-2},
      {"a damped tendon, RK4", "", "integrator=\"RK4\"", tendon, "", "pos=\"0.05 0 0.3\"", 80,
       1e-2},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    TempDir dir;
    const std::string scene = LidScene(c.joint, c.cube, c.option, c.before, c.first_in_deformable);
    std::unique_ptr<World> world = World::Load(dir.Write("damped.xml", scene));
    double largest_error = 0.0;
    int solved_steps = 0, constrained_steps = 0;
    for (int s = 0; s < c.steps; ++s) {
      world->Step();
      ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
      if (world->rigid_system().trees.empty()) continue;
      ++solved_steps;
      constrained_steps += !world->rigid_system().constraints.empty();
      largest_error = std::max(largest_error, PredictionError(*world));
    }
    EXPECT_GT(solved_steps, 5) << "steps with the cube on the lid";
    if (std::string(c.joint).find("limited") == std::string::npos) {
      EXPECT_EQ(constrained_steps, 0);
    } else {
      EXPECT_GT(constrained_steps, 5) << "steps with the lid on its limit";
    }
    EXPECT_LT(largest_error, c.largest_error) << "rad/s";
    std::printf("damped lid, %s: prediction off by %.3g rad/s at most\n", c.name, largest_error);
  }
}

// The same damping on a tree of two degrees of freedom: a light two-link arm
// (hinges damped 0.5 and 0.3 N m s, h B / I about 1.3 and 5 at 10 ms)
// lowering its hand onto a soft slab, its elbow held on a joint limit. The
// limit's law, taken on tau J u / h for MuJoCo's J a (tau exact for the
// limit's own response, not for the cross terms of M^-1 B), leaves the
// prediction off where the hand lands (measured: 0.05 rad/s in one step, a
// median of 2e-13); with the damping taken at the step's start, the median
// step was 1.7e-3 rad/s off and the largest 0.8.
TEST(Coupling, ADampedArmIsPredictedAsMuJoCoMovesItButWhereItLands) {
  TempDir dir;
  const std::string path = dir.Write("arm.xml", R"(<mujoco>
  <option timestep="0.01"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="upper" pos="0 0 0.3">
      <joint type="hinge" axis="0 1 0" damping="0.5" range="-30 80" limited="true"/>
      <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.01" mass="0.05"/>
      <body name="fore" pos="0.15 0 0">
        <joint type="hinge" axis="0 1 0" damping="0.3" range="-10 10" limited="true"/>
        <geom type="capsule" fromto="0 0 0 0.12 0 0" size="0.01" mass="0.04"/>
        <geom name="hand" type="box" pos="0.14 0 0" size="0.02 0.02 0.01" mass="0.02"/>
      </body>
    </body>
  </worldbody>
  <deformable>
    <rigidtet body="fore" geom="hand" resolution="2"/>
    <tetbody name="slab" shape="box" size="0.08 0.08 0.02" resolution="4" pos="0.12 0 0.02"
             density="1000" young="1e5"/>
  </deformable>
</mujoco>)");
  std::unique_ptr<World> world = World::Load(path);
  std::vector<double> errors;
  for (int s = 0; s < 700; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    if (!world->rigid_system().trees.empty()) errors.push_back(PredictionError(*world));
  }
  ASSERT_GT(errors.size(), 300u) << "steps with the hand on the slab";
  std::sort(errors.begin(), errors.end());
  const double median = errors[errors.size() / 2];
  EXPECT_LT(median, 1e-9) << "rad/s";
  EXPECT_LT(errors.back(), 0.1) << "rad/s";
  std::printf("damped arm: prediction off by %.3g rad/s (median), %.3g at most\n", median,
              errors.back());
}

// A lid (0.3 kg, 30 cm, hinged at one end) resting on its joint limit,
// struck from below by a soft cube at 3 m/s, at 10 ms. The limit holds the
// lid against gravity until the blow opens it: the step releases it as
// MuJoCo does, so that its prediction of the lid's velocity is MuJoCo's in
// every step, the blow included (measured: 9e-6 rad/s at 7 rad/s), and the
// lid takes no more energy than the cube brought. Held, the limit kept the
// lid to it in the prediction: the cube stopped against it as against a
// heavy body, whose blow then flung the lid at 13 rad/s (12.3 rad/s off the
// prediction) and added 0.03 J.
TEST(Coupling, AJointLimitStruckOpenIsReleasedAsMuJoCoReleasesIt) {
  TempDir dir;
  const std::string path = dir.Write(
      "lid.xml", LidScene("range=\"-90 0\" limited=\"true\"", "pos=\"0.05 0 0.1\" vel=\"0 0 3\""));
  std::unique_ptr<World> world = World::Load(path);
  const mjModel* m = world->mj_model();
  mjData* d = world->mj_data();
  // kinetic and gravitational energy of the cube and the lid
  auto energy = [&] {
    const DeformableBody& cube = world->deformable(0);
    return world->DeformableKineticEnergy() + world->RigidKineticEnergy() +
           cube.GravitationalEnergy(Eigen::Vector3d(0, 0, -9.81)) +
           9.81 * m->body_mass[1] * d->xipos[3 * 1 + 2];
  };
  const double start = energy();
  double largest_error = 0.0, fastest = 0.0, highest = start;
  int solved_with = 0;
  for (int s = 0; s < 40; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    highest = std::max(highest, energy());
    const RigidSystem& rigid = world->rigid_system();
    if (rigid.trees.empty()) continue;
    ++solved_with;
    largest_error = std::max(largest_error, PredictionError(*world));
    fastest = std::max(fastest, std::abs(d->qvel[0]));
  }
  EXPECT_GE(solved_with, 3);
  EXPECT_GT(fastest, 5.0) << "rad/s: struck open";
  EXPECT_LT(largest_error, 1e-4 * fastest) << "rad/s";
  EXPECT_LT(highest, start * (1.0 + 1e-3)) << "J";
  std::printf(
      "lid: prediction off by %.3g rad/s at most, fastest %.3g rad/s; energy %.9g J at "
      "the start, %.9g at most\n",
      largest_error, fastest, start, highest);
}

// A board (0.3 kg) resting on two rails in MuJoCo's elliptic friction cone,
// struck from below between them by a soft cube at 3 m/s, at 10 ms. The
// rails' contacts are linearized as whole cones: held while the board
// rests, and released as one where the blow lifts it off them (their top
// zone), as MuJoCo releases them, so that the step's prediction of the
// board's velocity is MuJoCo's in every step. Held through the blow (never
// released), they would keep the board on the rails in the prediction.
TEST(Coupling, AnEllipticConeContactStruckOpenIsReleasedAsMuJoCoReleasesIt) {
  TempDir dir;
  const std::string path = dir.Write("board.xml", R"(<mujoco>
  <option timestep="0.01" cone="elliptic"/>
  <worldbody>
    <geom type="box" pos="-0.1 0 0.2" size="0.05 0.1 0.01"/>
    <geom type="box" pos="0.1 0 0.2" size="0.05 0.1 0.01"/>
    <body name="board" pos="0 0 0.225">
      <freejoint/>
      <geom name="board" type="box" size="0.15 0.1 0.015" mass="0.3"/>
    </body>
  </worldbody>
  <deformable>
    <rigidtet body="board" geom="board" resolution="4"/>
    <tetbody name="cube" shape="box" size="0.03 0.03 0.03" resolution="3" pos="0 0 0.1"
             vel="0 0 3" density="1000" young="1e5"/>
  </deformable>
</mujoco>)");
  std::unique_ptr<World> world = World::Load(path);
  const mjData* d = world->mj_data();
  double largest_error = 0.0, fastest = 0.0, highest = 0.0;
  int solved_with = 0, on_rails = 0;
  for (int s = 0; s < 20; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    highest = std::max(highest, d->qpos[2]);
    const RigidSystem& rigid = world->rigid_system();
    if (rigid.trees.empty()) continue;
    ++solved_with;
    for (const RigidConstraint& constraint : rigid.constraints) {
      on_rails += constraint.kind == RigidConstraint::Kind::kEllipticCone;
    }
    largest_error = std::max(largest_error, PredictionError(*world));
    fastest = std::max(fastest, Eigen::Vector3d(d->qvel).norm());
  }
  EXPECT_GE(solved_with, 2);
  EXPECT_GT(on_rails, 0) << "the rails' contacts taken as cones";
  EXPECT_GT(highest, 0.25) << "m: the board flew off the rails";
  EXPECT_LT(largest_error, 1e-4 * fastest) << "m/s, of " << fastest;
  std::printf("board: prediction off by %.3g m/s at most, fastest %.3g m/s\n", largest_error,
              fastest);
}

// Bodies whose centre of mass is off their frame's origin (offset geoms, a
// hinge at one end) moving with arbitrary velocities: what the world reports
// of them agrees with MuJoCo's own kinematics. Oracles: central differences of
// positions integrated by mj_integratePos (velocities), 1/2 v^T M v through
// mj_mulM (kinetic energy), the subtree momenta of mj_subtreeVel (momenta).
TEST(RigidBodies, VelocitiesEnergyAndMomentaAgreeWithMuJoCoOffTheOrigin) {
  TempDir dir;
  const std::string path = dir.Write("offset.xml", R"(<mujoco>
  <option gravity="0 0 0"/>
  <worldbody>
    <body name="free" pos="0.3 0.1 0.5" quat="0.9 0.1 0.3 -0.2">
      <freejoint/>
      <geom type="box" pos="0.2 -0.1 0.05" size="0.1 0.05 0.02" mass="1"/>
      <geom type="capsule" fromto="0 0 0 0.05 0.2 0.1" size="0.02" mass="0.4"/>
    </body>
    <body name="arm" pos="0 0 1">
      <joint type="hinge" axis="0.3 1 0.2"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 -0.1" size="0.02" mass="0.7"/>
      <body name="forearm" pos="0.3 0 -0.1">
        <joint type="ball"/>
        <geom type="box" pos="0.1 0.05 0" size="0.1 0.02 0.02" mass="0.3"/>
      </body>
    </body>
  </worldbody>
</mujoco>)");
  std::unique_ptr<World> world = World::Load(path);
  const mjModel* m = world->mj_model();
  mjData* d = world->mj_data();
  ASSERT_EQ(m->nv, 6 + 1 + 3);
  const double qvel[10] = {0.4, -0.2, 0.3, 2.0, -1.5, 3.0, 2.5, -1.0, 4.0, 0.5};
  std::copy(qvel, qvel + m->nv, d->qvel);
  mj_forward(m, d);
  const std::vector<double> qpos(d->qpos, d->qpos + m->nq);

  // world points moving with each body (its centre of mass, its origin and
  // one more), at qpos moved by +-h along qvel
  const Eigen::Vector3d p_B(0.05, -0.2, 0.1);
  auto points_at = [&](double h) {
    std::copy(qpos.begin(), qpos.end(), d->qpos);
    mj_integratePos(m, d->qpos, d->qvel, h);
    mj_kinematics(m, d);
    std::vector<Eigen::Vector3d> points;
    for (int b = 1; b < m->nbody; ++b) {
      const Eigen::Isometry3d X_WB =
          Eigen::Translation3d(world->RigidBodyPosition(b)) * world->RigidBodyOrientation(b);
      points.push_back(world->RigidBodyCenterOfMass(b));
      points.push_back(X_WB.translation());
      points.push_back(X_WB * p_B);
    }
    return points;
  };
  const double h = 1e-6;
  const std::vector<Eigen::Vector3d> ahead = points_at(h), behind = points_at(-h);
  const std::vector<Eigen::Vector3d> now = points_at(0.0);
  mj_forward(m, d);
  Eigen::Vector3d momentum = Eigen::Vector3d::Zero();
  for (int b = 1; b < m->nbody; ++b) {
    const int i = 3 * (b - 1);
    auto rate = [&](int k) -> Eigen::Vector3d { return (ahead[i + k] - behind[i + k]) / (2 * h); };
    ASSERT_GT((world->RigidBodyCenterOfMass(b) - world->RigidBodyPosition(b)).norm(), 0.05) << b;
    for (int k : {0, 2}) {
      EXPECT_LT((world->RigidBodyPointVelocity(b, now[i + k]) - rate(k)).norm(), 1e-7)
          << "body " << b << " point " << k << ": " << rate(k).transpose();
    }
    EXPECT_LT((world->RigidBodyLinearVelocity(b) - rate(1)).norm(), 1e-7)
        << "body " << b << " origin: " << rate(1).transpose();
    momentum += m->body_mass[b] * rate(0);
  }
  std::vector<double> Mv(m->nv);
  mj_mulM(m, d, Mv.data(), d->qvel);
  EXPECT_NEAR(world->RigidKineticEnergy(), 0.5 * mju_dot(d->qvel, Mv.data(), m->nv), 1e-12);
  EXPECT_LT((world->LinearMomentum() - momentum).norm(), 1e-7);
  mj_subtreeVel(m, d);
  const Eigen::Vector3d com(d->subtree_com), linvel(d->subtree_linvel);
  const Eigen::Vector3d spin(d->subtree_angmom);
  EXPECT_LT((world->LinearMomentum() - m->body_subtreemass[0] * linvel).norm(), 1e-12);
  EXPECT_LT((world->AngularMomentum() - (spin + m->body_subtreemass[0] * com.cross(linvel))).norm(),
            1e-12);
}

// Vertices attached to a body spinning about a hinge through its origin, its
// centre of mass 20 cm off the axis: they stay where the body carries them
// (the pins are moved with the velocity of the body's origin, not of its
// centre of mass), and the pins' reactions keep the angular momentum about
// the axis. With substeps too: the pins follow the pose the substeps
// predict; the angular momentum is then kept to 1.0e-5 (measured), not to
// round-off, as the pad moves between substeps while MuJoCo takes the
// mean of their reactions at the step's start.
TEST(Coupling, AttachedVerticesFollowABodySpinningAboutItsOrigin) {
  for (const int substeps : {1, 3}) {
    SCOPED_TRACE(::testing::Message() << substeps << " substeps");
    TempDir dir;
    const std::string path = dir.Write("spin.xml", R"(<mujoco>
  <option timestep="0.001" gravity="0 0 0"/>
  <worldbody>
    <body name="wheel" pos="0 0 0.5">
      <joint type="hinge" axis="0 0 1"/>
      <geom type="box" pos="0.2 0 0" size="0.05 0.05 0.05" mass="5"/>
    </body>
  </worldbody>
  <deformable>
    <solver substeps=")" + std::to_string(substeps) + R"("/>
    <tetbody name="pad" shape="box" size="0.02 0.02 0.02" resolution="2" pos="0.2 0 0.57"
             young="1e5"/>
    <attach tetbody="pad" body="wheel" box="0.15 -0.05 0.54 0.25 0.05 0.56"/>
  </deformable>
</mujoco>)");
    std::unique_ptr<World> world = World::Load(path);
    const int wheel = world->BodyId("wheel");
    world->mj_data()->qvel[0] = 3.0;  // rad/s
    mj_forward(world->mj_model(), world->mj_data());
    auto pose = [&] {
      return Eigen::Translation3d(world->RigidBodyPosition(wheel)) *
             world->RigidBodyOrientation(wheel);
    };
    const DeformableBody& pad = world->deformable(0);
    ASSERT_EQ(pad.pinned_vertices().size(), 9u);
    std::vector<Eigen::Vector3d> p_B;  // in the wheel's frame
    for (int v : pad.pinned_vertices()) {
      p_B.push_back(pose().inverse() * Eigen::Vector3d(pad.positions().row(v).transpose()));
    }
    const double L0 = world->AngularMomentum().z();
    ASSERT_GT(L0, 0.5);
    double error = 0.0;
    for (int s = 0; s < 300; ++s) {
      world->Step();
      ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
      for (size_t k = 0; k < p_B.size(); ++k) {
        const Eigen::Vector3d x = pad.positions().row(pad.pinned_vertices()[k]).transpose();
        error = std::max(error, (x - pose() * p_B[k]).norm());
      }
    }
    EXPECT_GT(world->RigidBodyAngularVelocity(wheel).z(), 2.5) << "still spinning";
    EXPECT_LT(error, 1e-5) << "m, largest distance of a pin from its place on the body";
    // the hinge's axis is the world's z axis: nothing turns the whole about it
    EXPECT_NEAR(world->AngularMomentum().z(), L0, (substeps == 1 ? 2e-6 : 3e-5) * L0);
  }
}

// A light rigid box (50 g, its proxy) resting on a stiff deformable slab
// (E = 1e7 Pa, pinned): each proxy vertex's contact is far stiffer than the
// box's mass allows an explicit step (dt sqrt(k / m) > 2; moved at its start
// velocity and pushed after the step, the box was thrown a metre up). Solved
// with the step (RigidSystem), it rests: the contacts carry its weight. So
// it does with substeps, each starting from the box's velocity and pose as
// the substeps before left them (started from the step's, the box was
// thrown 2 cm up with two substeps: the second stopped it again).
TEST(Coupling, LightRigidBodyRestsOnAStiffDeformable) {
  for (const int substeps : {1, 2, 4}) {
    SCOPED_TRACE(::testing::Message() << substeps << " substeps");
    TempDir dir;
    const std::string path = dir.Write("light.xml", OnAStiffSlab(R"(
    <body name="box" pos="0 0 0.0205"><freejoint/>
      <geom name="box" type="box" size="0.02 0.02 0.02" mass="0.05" contype="0" conaffinity="0"/>
    </body>)",
                                                                 R"(
    <solver substeps=")" + std::to_string(substeps) +
                                                                     R"("/>
    <rigidtet body="box" geom="box" resolution="3"/>)",
                                                                 "0.1 0.1", "10 10"));
    std::unique_ptr<World> world = World::Load(path);
    const int box = world->BodyId("box");
    double highest = 0.0;
    for (int s = 0; s < 250; ++s) {
      world->Step();
      ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
      highest = std::max(highest, world->RigidBodyPosition(box).z());
    }
    EXPECT_LT(highest, 0.0206) << "m: never thrown up";
    EXPECT_NEAR(world->RigidBodyPosition(box).z(), 0.02, 1e-4) << "resting on the slab";
    EXPECT_LT(world->RigidKineticEnergy(), 1e-10);
    EXPECT_NEAR(world->coupling_forces()[6 * box + 2], 0.05 * 9.81, 1e-4 * 0.05 * 9.81)
        << "N: the contacts carry the box's weight";
  }
}

// The same for a mechanism: a light two-link arm on hinges (80 g) lays its
// hand, a box proxy 2 cm off the lower link's axis, on a stiff slab.
// Solved with the step (the links' joint velocities, the tree's block of
// the mass matrix, the hand's point Jacobians), the arm comes to rest; at
// rest the contacts' moment about each hinge balances the weight of the
// links beyond it. (Explicit, the arm was thrown about at 1e4 J.)
TEST(Coupling, LightArmRestsItsHandOnAStiffDeformable) {
  TempDir dir;
  const std::string path = dir.Write("arm.xml", ArmOnAStiffSlab(1));
  std::unique_ptr<World> world = World::Load(path);
  // nothing else acts on the arm (no joint limits, no MuJoCo contacts): the
  // step's prediction of its joint velocities is what MuJoCo then finds
  const mjModel* m = world->mj_model();
  double largest_error = 0.0, largest_speed = 0.0;
  int solved_with = 0;
  for (int s = 0; s < 1000; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    const RigidSystem& rigid = world->rigid_system();
    if (rigid.trees.empty()) continue;
    ++solved_with;
    ASSERT_EQ(rigid.trees.size(), 1u);
    ASSERT_EQ(world->rigid_system_roots()[0], world->BodyId("upper"));
    const Eigen::Map<const Eigen::VectorXd> qvel(world->mj_data()->qvel, m->nv);
    largest_error = std::max(largest_error, PredictionError(*world));
    largest_speed = std::max(largest_speed, qvel.norm());
  }
  EXPECT_GT(solved_with, 800);
  EXPECT_GT(largest_speed, 1.0) << "rad/s: the arm fell onto the slab";
  EXPECT_LT(largest_error, 1e-9 * largest_speed);
  EXPECT_LT(world->RigidKineticEnergy(), 1e-12);
  const int upper = world->BodyId("upper"), lower = world->BodyId("lower");
  EXPECT_NEAR(world->RigidBodyPosition(lower).z(), 0.04, 1e-4) << "the hand on the slab";
  const Eigen::Vector3d g(0.0, 0.0, -9.81);
  const double* wrench = world->coupling_forces().data() + 6 * lower;  // force, torque at xipos
  const Eigen::Vector3d force(wrench), torque(wrench + 3);
  // moments about the y axis through a point q: the contacts', each link's weight
  auto contacts_about = [&](const Eigen::Vector3d& q) {
    return (torque + (world->RigidBodyCenterOfMass(lower) - q).cross(force)).y();
  };
  auto weight_about = [&](int body, const Eigen::Vector3d& q) {
    return (world->RigidBodyCenterOfMass(body) - q)
        .cross(world->mj_model()->body_mass[body] * g)
        .y();
  };
  const Eigen::Vector3d elbow = world->RigidBodyPosition(lower);
  const Eigen::Vector3d shoulder = world->RigidBodyPosition(upper);
  const double scale = std::abs(weight_about(lower, shoulder));
  EXPECT_NEAR(contacts_about(elbow), -weight_about(lower, elbow), 1e-4 * scale);
  EXPECT_NEAR(contacts_about(shoulder),
              -weight_about(lower, shoulder) - weight_about(upper, shoulder), 1e-4 * scale);
}

// A proxy of a static body (a table welded to the world) is placed once and handed to
// the penetration solver as fixed; a proxy of a moving body (the crate) is
// placed every step and is not. The table's proxy stays where its body is,
// also after the user moves the body in MuJoCo's model (then it is placed
// again, and no longer fixed), and a soft cube comes to rest on it. The
// crate's proxy moves with its body's frame, which the solver uses.
TEST(Coupling, StaticProxyIsFixedAndFollowsItsBody) {
  TempDir dir;
  const std::string path = dir.Write("table.xml", R"(
<mujoco model="table">
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="table" pos="0 0 0.05">
      <geom name="table" type="box" size="0.2 0.2 0.05"/>
    </body>
    <body name="crate" pos="0.5 0 0.06">
      <freejoint/>
      <geom name="crate" type="box" size="0.05 0.05 0.05" mass="1"/>
    </body>
  </worldbody>
  <deformable>
    <rigidtet body="table" geom="table" resolution="6"/>
    <rigidtet body="crate" geom="crate" resolution="2"/>
    <tetbody name="cube" shape="box" size="0.03 0.03 0.03" resolution="3" pos="0 0 0.14"
             density="1000" young="1e5" poisson="0.3" damping="1 0"/>
  </deformable>
</mujoco>)");
  std::unique_ptr<World> world = World::Load(path);
  ASSERT_EQ(world->num_proxies(), 2);
  const int table_body = world->BodyId("table");
  ASSERT_EQ(world->ProxyBody(0), table_body);
  ASSERT_TRUE(world->RigidBodyIsStatic(table_body));
  const int table = world->num_deformables();  // (collision objects)
  const int crate = table + 1;
  auto expect_placed = [&](int object, int body) {
    const CollisionObject& proxy = world->collision_objects()[object];
    Eigen::Isometry3d X_WB = Eigen::Isometry3d::Identity();
    X_WB.translation() = world->RigidBodyPosition(body);
    X_WB.linear() = world->RigidBodyOrientation(body).toRotationMatrix();
    double error = 0.0;
    for (int v = 0; v < proxy.mesh->num_vertices(); ++v) {
      const Eigen::Vector3d rest = proxy.mesh->positions().row(v).transpose();
      const Eigen::Vector3d x = proxy.positions->row(v).transpose();
      error = std::max(error, (x - X_WB * rest).norm());
    }
    EXPECT_LT(error, 1e-12) << "object " << object;
  };
  int contact_steps = 0;
  for (int s = 0; s < 500; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    contact_steps += world->metrics().colliding_points > 0;
    EXPECT_TRUE(world->collision_objects()[table].fixed) << "step " << s;
    EXPECT_EQ(world->collision_objects()[table].frame, nullptr) << "step " << s;
    if (s > 0) {
      EXPECT_FALSE(world->collision_objects()[crate].fixed) << "step " << s;
      const RigidFrame* frame = world->collision_objects()[crate].frame;
      ASSERT_NE(frame, nullptr) << "step " << s;
      // (the frame of its positions: the body's pose when they were placed)
      const CollisionObject& object = world->collision_objects()[crate];
      double error = 0.0;
      for (int v = 0; v < object.mesh->num_vertices(); ++v) {
        const Eigen::Vector3d rest = object.mesh->positions().row(v).transpose();
        const Eigen::Vector3d x = object.positions->row(v).transpose();
        error = std::max(error, (x - frame->rotation * rest - frame->translation).norm());
      }
      EXPECT_LT(error, 1e-12) << "step " << s;
      // (both solved from what the solver kept: the table fixed, the crate
      // moving with its frame)
      EXPECT_EQ(world->metrics().kept_proxies, 2) << "step " << s;
    }
  }
  expect_placed(table, table_body);
  expect_placed(crate, world->BodyId("crate"));
  EXPECT_GT(contact_steps, 100);
  EXPECT_NEAR(world->deformable(0).CenterOfMass().z(), 0.1 + 0.03, 0.002) << "resting on the table";
  EXPECT_LT(world->DeformableKineticEnergy(), 1e-6);
  // the user lifts the table in MuJoCo's model: its proxy follows, and is
  // no longer fixed
  world->mutable_mj_model()->body_pos[3 * table_body + 2] += 0.01;
  for (int s = 0; s < 5; ++s) world->Step();
  EXPECT_FALSE(world->collision_objects()[table].fixed);
  EXPECT_NE(world->collision_objects()[table].frame, nullptr);
  EXPECT_NEAR(world->RigidBodyPosition(table_body).z(), 0.06, 1e-12);
  expect_placed(table, table_body);
}

// the same scene with the same thread count gives bit-identical states
// (deformables and MuJoCo) through contacts: two soft cubes meeting at 10 m/s,
// and a soft cube landing on a free MuJoCo box. 1 and 2 threads do too: the
// penetration solver's results do not depend on the thread count, and a body
// below 16384 tets is stepped whole on one thread, whichever (StepCoupled)
TEST(WorldStep, SameInputAndThreadCountGiveBitIdenticalStates) {
  struct State {
    std::vector<Positions> x, v;
    std::vector<double> qpos, qvel;
    int colliding = 0;
  };
  // (the gripper: attachments carried by their tree, RigidPin)
  for (const auto& [scene, steps] : {std::pair<std::string, int>{"paper/cubes.xml", 30},
                                     std::pair<std::string, int>{"scenes/cube_on_box.xml", 300},
                                     std::pair<std::string, int>{"scenes/gripper.xml", 100}}) {
    SCOPED_TRACE(scene);
    // (copied in: clang before 16 cannot capture a structured binding)
    auto run = [&, scene = scene, steps = steps](int threads) {
      WorldOptions options;
      options.threads = threads;
      std::unique_ptr<World> world =
          World::Load(std::string(TETCOSIM_SOURCE_DIR) + "/models/" + scene, options);
      State state;
      for (int s = 0; s < steps; ++s) {
        world->Step();
        EXPECT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
        state.colliding += world->metrics().colliding_points;
      }
      for (int i = 0; i < world->num_deformables(); ++i) {
        state.x.push_back(world->deformable(i).positions());
        state.v.push_back(world->deformable(i).velocities());
      }
      const mjModel* m = world->mj_model();
      state.qpos.assign(world->mj_data()->qpos, world->mj_data()->qpos + m->nq);
      state.qvel.assign(world->mj_data()->qvel, world->mj_data()->qvel + m->nv);
      return state;
    };
    const State one = run(1), one_again = run(1);
    const State two = run(2), two_again = run(2);
    EXPECT_GT(one.colliding, 100) << "the bodies are in contact";
    for (size_t i = 0; i < one.x.size(); ++i) {
      EXPECT_TRUE(one.x[i] == one_again.x[i]) << "deformable " << i;
      EXPECT_TRUE(one.v[i] == one_again.v[i]) << "deformable " << i;
      EXPECT_TRUE(two.x[i] == two_again.x[i]) << "deformable " << i;
      EXPECT_TRUE(two.v[i] == two_again.v[i]) << "deformable " << i;
      EXPECT_TRUE(one.x[i] == two.x[i]) << "deformable " << i;
      EXPECT_TRUE(one.v[i] == two.v[i]) << "deformable " << i;
    }
    EXPECT_EQ(one.qpos, one_again.qpos);
    EXPECT_EQ(one.qvel, one_again.qvel);
    EXPECT_EQ(two.qpos, two_again.qpos);
    EXPECT_EQ(two.qvel, two_again.qvel);
    EXPECT_EQ(one.qpos, two.qpos);
    EXPECT_EQ(one.qvel, two.qvel);
  }
}

// What a step undone must put back, bit for bit: the time, MuJoCo's state
// and what the user sets in it, the last step's coupling forces, and the
// deformables' state.
struct WorldState {
  double time = 0.0;
  std::vector<double> qpos, qvel, ctrl, qfrc_applied, xfrc_applied, coupling;
  std::vector<Positions> x, v;
  bool operator==(const WorldState&) const = default;
};

WorldState StateOf(const World& world) {
  const mjModel* m = world.mj_model();
  const mjData* d = world.mj_data();
  WorldState state;
  state.time = d->time;
  state.qpos.assign(d->qpos, d->qpos + m->nq);
  state.qvel.assign(d->qvel, d->qvel + m->nv);
  state.ctrl.assign(d->ctrl, d->ctrl + m->nu);
  state.qfrc_applied.assign(d->qfrc_applied, d->qfrc_applied + m->nv);
  state.xfrc_applied.assign(d->xfrc_applied, d->xfrc_applied + 6 * m->nbody);
  state.coupling = world.coupling_forces();
  for (int i = 0; i < world.num_deformables(); ++i) {
    state.x.push_back(world.deformable(i).positions());
    state.v.push_back(world.deformable(i).velocities());
  }
  return state;
}

// MuJoCo resets its state on a NaN (clearing the controls, the applied
// forces and its warnings, the count of this one too before counting it)
// and only warns: the world reports it and undoes the step, every time
TEST(WorldStep, AStepMuJoCoFindsABadStateInIsUndoneEveryTime) {
  std::unique_ptr<World> world =
      World::Load(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml");
  for (int s = 0; s < 20; ++s) world->Step();
  ASSERT_EQ(world->metrics().status, StepStatus::kOk);
  world->mj_data()->xfrc_applied[6 * 1 + 2] = 0.5;  // the user's own force, kept
  world->Step();
  const WorldState before = StateOf(*world);
  ASSERT_NE(before.qvel[0], 0.0) << "the box moves (MuJoCo's reset would set it at rest)";
  world->SetController([](World& w) {
    w.mj_data()->xfrc_applied[6 * 1 + 0] = 3.0;
    w.mj_data()->qvel[0] = std::nan("");
  });
  for (int attempt = 0; attempt < 3; ++attempt) {
    world->Step();
    EXPECT_EQ(world->metrics().status, StepStatus::kDiverged) << "attempt " << attempt;
    EXPECT_NE(world->metrics().message.find(
                  "MuJoCo found a non-finite or huge velocity qvel[0] at step 21; the step is "
                  "undone"),
              std::string::npos)
        << world->metrics().message;
    EXPECT_TRUE(StateOf(*world) == before) << "attempt " << attempt;
  }
  world->SetController(nullptr);
  world->Step();
  EXPECT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
  EXPECT_EQ(world->time(), before.time + world->timestep());
  // the user's own force kept, and the controller's of the steps undone not
  const double* xfrc = world->mj_data()->xfrc_applied + 6 * 1;
  const double* ours = world->coupling_forces().data() + 6 * 1;
  EXPECT_NEAR(xfrc[2] - ours[2], 0.5, 1e-12);
  EXPECT_NEAR(xfrc[0] - ours[0], 0.0, 1e-12);
}

// MuJoCo checks a step's positions and velocities at the next step's
// start: the world checks them as the step ends, so that a step done leaves
// a state MuJoCo takes (a slide joint 1e10 m out, MuJoCo's limit, after
// this step). The same out there at the start, or as fast, is a clear
// error.
TEST(WorldStep, AStepThatLeavesAStateMuJoCoRefusesIsUndone) {
  TempDir dir;
  const char* scene = R"(<mujoco>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <body name="sled" pos="0 0 0.2"><joint type="slide" axis="1 0 0"/>
      <geom type="box" size="0.05 0.05 0.05"/></body>
  </worldbody>
  <keyframe><key qpos="%s" qvel="%s"/></keyframe>
  <deformable><tetbody name="cube" shape="box" size="0.05 0.05 0.05" pos="0 0.5 0.05"/></deformable>
</mujoco>)";
  char text[1024];
  std::snprintf(text, sizeof(text), scene, "9.99e9", "9e9");
  std::unique_ptr<World> world = World::Load(dir.Write("far.xml", text));
  const WorldState before = StateOf(*world);
  world->Step();
  EXPECT_EQ(world->metrics().status, StepStatus::kDiverged);
  EXPECT_NE(world->metrics().message.find(
                "MuJoCo's step left a non-finite or huge position qpos[0] at step 0; the step "
                "is undone"),
            std::string::npos)
      << world->metrics().message;
  EXPECT_TRUE(StateOf(*world) == before);
  for (const auto& [qpos, qvel, bad] : {std::tuple{"1.01e10", "9e9", "qpos[0] = 1.01e+10"},
                                        std::tuple{"0", "-1.01e10", "qvel[0] = -1.01e+10"}}) {
    std::snprintf(text, sizeof(text), scene, qpos, qvel);
    const std::string path = dir.Write("farther.xml", text);
    EXPECT_NE(ErrorOf(path).find(path + ": the initial state (the first keyframe) has " + bad +
                                 ", which MuJoCo does not step"),
              std::string::npos)
        << ErrorOf(path);
  }
}

// A body of eight 5 cm balls falling onto a plane from `height`, or set on
// it by the first keyframe, beside a soft cube, with MuJoCo's stack
// `nstack` numbers: 300 hold the step before the balls land, not the one
// with their eight contacts.
std::string BallsOnAPlane(int nstack, const char* keyframe = "") {
  char text[2048];
  std::snprintf(text, sizeof(text), R"(<mujoco>
  <size nstack="%d"/>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <body name="balls" pos="0 0 0.1"><freejoint/>
      <geom type="sphere" size="0.05" pos="0 0 0"/><geom type="sphere" size="0.05" pos="0.1 0 0"/>
      <geom type="sphere" size="0.05" pos="0.2 0 0"/><geom type="sphere" size="0.05" pos="0.3 0 0"/>
      <geom type="sphere" size="0.05" pos="0 0.1 0"/><geom type="sphere" size="0.05" pos="0.1 0.1 0"/>
      <geom type="sphere" size="0.05" pos="0.2 0.1 0"/><geom type="sphere" size="0.05" pos="0.3 0.1 0"/>
    </body>
  </worldbody>
  %s
  <deformable>
    <tetbody name="cube" shape="box" size="0.03 0.03 0.03" resolution="2" pos="0.6 0 0.029"/>
  </deformable>
</mujoco>)",
                nstack, keyframe);
  return text;
}

// A linear solve held to 3 iterations stops short of its tolerance, and the
// step says so (it was reported as any other); with the default limit, the
// same steps converge, to the residual the tolerance asks for.
TEST(WorldStep, ASolveStoppedShortOfItsToleranceIsReported) {
  TempDir dir("tetcosim_world_solve");
  auto scene = [&](const char* maxiter) {
    return dir.Write("cube.xml", std::string(R"(<mujoco>
  <worldbody><geom type="plane" size="1 1 0.1"/></worldbody>
  <deformable>
    <solver tolerance="1e-7" )") + maxiter +
                                     R"(/>
    <tetbody name="cube" shape="box" size="0.05 0.05 0.05" resolution="4" pos="0 0 0.0495"
             young="1e5"/>
  </deformable>
</mujoco>)");
  };
  std::unique_ptr<World> held = World::Load(scene(R"(maxiter="3")"));
  std::unique_ptr<World> free = World::Load(scene(""));
  for (int step = 0; step < 10; ++step) {
    held->Step();
    free->Step();
    ASSERT_EQ(held->metrics().status, StepStatus::kOk);
    EXPECT_LE(held->metrics().solver_iterations, 3 * held->metrics().contact_rounds);
    EXPECT_FALSE(held->metrics().solver_converged) << "step " << step;
    EXPECT_GT(held->metrics().solver_residual, 1e-7);
    EXPECT_TRUE(free->metrics().solver_converged) << "step " << step;
    EXPECT_LE(free->metrics().solver_residual, 1e-7 * (1 + 1e-9));
    EXPECT_GT(free->metrics().solver_iterations, 3 * free->metrics().contact_rounds);
  }
}

// MuJoCo raises a fatal error when its stack cannot hold a step (it used to
// wait for Enter and exit the process): the step reports it, and the world
// steps no further.
TEST(WorldStep, AStepBeyondMuJoCosStackIsAStatusAndTheWorldStopsThere) {
  TempDir dir("tetcosim_world_stack");
  std::unique_ptr<World> world = World::Load(dir.Write("small.xml", BallsOnAPlane(300)));
  long failed_at = -1;
  WorldState before;  // the state the step that failed started from
  for (long step = 0; step < 200 && failed_at < 0; ++step) {
    before = StateOf(*world);
    world->Step();
    if (world->metrics().status != StepStatus::kOk) failed_at = step;
  }
  ASSERT_GT(failed_at, 0) << "the balls fall for some steps first";
  EXPECT_TRUE(StateOf(*world) == before) << "the step is undone";
  EXPECT_EQ(world->metrics().status, StepStatus::kFailed) << world->metrics().message;
  const std::string message = world->metrics().message;
  EXPECT_NE(message.find("MuJoCo failed step " + std::to_string(failed_at) + ": Stack overflow"),
            std::string::npos)
      << message;
  EXPECT_NE(message.find("<size nstack=\""), std::string::npos) << message;
  EXPECT_EQ(world->steps(), failed_at);
  const double time = world->time();
  EXPECT_NEAR(time, static_cast<double>(failed_at) * world->timestep(), 1e-12);
  // later steps only report it
  world->Step();
  EXPECT_EQ(world->metrics().status, StepStatus::kFailed);
  EXPECT_EQ(world->metrics().message, message);
  EXPECT_EQ(world->time(), time);
  EXPECT_EQ(world->steps(), failed_at);
  EXPECT_TRUE(StateOf(*world) == before);
  // with the stack of the failure's advice, the same steps go through
  std::unique_ptr<World> large = World::Load(dir.Write("large.xml", BallsOnAPlane(4000)));
  for (long step = 0; step <= failed_at + 20; ++step) {
    if (step == failed_at) {
      EXPECT_TRUE(StateOf(*large) == before);
    }
    large->Step();
    ASSERT_EQ(large->metrics().status, StepStatus::kOk) << large->metrics().message;
  }
}

TEST(WorldLoad, AnInitialStateBeyondMuJoCosStackIsAClearError) {
  TempDir dir("tetcosim_world_stack");
  // (MuJoCo's compiler steps nothing with the balls down: the keyframe sets
  // them on the plane)
  const char* keyframe = R"(<keyframe><key qpos="0 0 0.049 1 0 0 0"/></keyframe>)";
  const std::string path = dir.Write("small.xml", BallsOnAPlane(300, keyframe));
  const std::string error = ErrorOf(path);
  EXPECT_NE(
      error.find(path + ": MuJoCo failed computing the scene's initial state: Stack overflow"),
      std::string::npos)
      << error;
  EXPECT_NE(error.find("<size nstack=\""), std::string::npos) << error;
  EXPECT_EQ(ErrorOf(dir.Write("large.xml", BallsOnAPlane(4000, keyframe))), "");
}

// A step undone with substeps, which moved the box and the cube along
// their paths before MuJoCo's step, and set friction springs and warm
// starts: a reset inside mj_step2 (a huge force on the box while the cube
// lies on it, so that its acceleration is beyond what MuJoCo accepts, and
// a force on it the user sets), or a non-finite force on a vertex of the
// cube. The step is undone, the forces set too, and the world goes on as if
// the step had never been tried, bit for bit.
TEST(WorldStep, AStepUndoneWithSubstepsLeavesNoTrace) {
  TempDir dir;
  std::string scene =
      ReadFileContents(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml");
  const std::string contact = "<contact method=\"consistent\" friction=\"0.6\"/>";
  ASSERT_NE(scene.find(contact), std::string::npos);
  scene.replace(scene.find(contact), contact.size(), contact + "<solver substeps=\"3\"/>");
  const std::string path = dir.Write("substeps.xml", scene);
  const std::pair<std::function<void(World&)>, std::string> failures[] = {
      {[](World& w) {
         w.mj_data()->xfrc_applied[6 * 1 + 0] = 3.0;
         w.mj_data()->qfrc_applied[2] = 1e15;
       },
       "MuJoCo found a non-finite or huge acceleration qacc[2] at step "},
      {[](World& w) { w.deformable(0).applied_forces()(5, 2) = std::nan(""); },
       "tetbody 'cube' vertex 5 became non-finite (its velocity, position or a force on it) at "
       "step "}};
  for (const auto& [failure, message] : failures) {
    SCOPED_TRACE(message);
    std::unique_ptr<World> tried = World::Load(path);
    std::unique_ptr<World> untried = World::Load(path);
    // (a force of the user's on the box all along, beside the contact
    // forces: xfrc_applied holds their sum)
    tried->mj_data()->xfrc_applied[6 * 1 + 1] = 0.0123;
    untried->mj_data()->xfrc_applied[6 * 1 + 1] = 0.0123;
    int steps = 0;
    for (; steps < 400 && tried->metrics().stuck_contacts < 8; ++steps) {
      tried->Step();
      untried->Step();
    }
    ASSERT_GE(tried->metrics().stuck_contacts, 8) << "the cube lies on the box, held by friction";
    const WorldState before = StateOf(*tried);
    tried->SetController(failure);
    tried->Step();
    EXPECT_EQ(tried->metrics().status, StepStatus::kDiverged);
    EXPECT_NE(tried->metrics().message.find(message + std::to_string(steps)), std::string::npos)
        << tried->metrics().message;
    EXPECT_TRUE(StateOf(*tried) == before);
    EXPECT_TRUE(tried->deformable(0).applied_forces().isZero(0.0));
    tried->SetController(nullptr);
    for (int s = 0; s < 50; ++s) {
      tried->Step();
      untried->Step();
      ASSERT_EQ(tried->metrics().status, StepStatus::kOk) << tried->metrics().message;
    }
    EXPECT_TRUE(StateOf(*tried) == StateOf(*untried));
  }
}

// The two-word keywords of <contact> and <solver>: each word read as
// itself, and the defaults where they are absent.
TEST(WorldLoad, KeywordAttributesAreRead) {
  TempDir dir;
  auto parse = [&](const std::string& deformable) {
    return ParseScene(dir.Write("keywords.xml", "<mujoco>\n  <deformable>\n" + deformable +
                                                    "  </deformable>\n</mujoco>\n"));
  };
  // every attribute its first word (the default), or every one its second
  auto expect = [](const SceneSpec& spec, bool first) {
    EXPECT_EQ(spec.method, first ? DepthMethod::kConsistent : DepthMethod::kClosest);
    EXPECT_EQ(spec.stick, first);
    EXPECT_EQ(spec.solver.implicit_rigid, first);
    EXPECT_EQ(spec.solver.linearize_constraints, first);
    EXPECT_EQ(spec.solver.linear_solver,
              first ? LinearSolver::kConjugateGradient : LinearSolver::kCholesky);
  };
  expect(parse(""), true);
  expect(parse("<contact method=\"closest\" stick=\"false\"/>\n"
               "<solver rigid=\"explicit\" constraints=\"lagged\" linear=\"ldlt\"/>\n"),
         false);
  expect(parse("<contact method=\"consistent\" stick=\"true\"/>\n"
               "<solver rigid=\"implicit\" constraints=\"linearized\" linear=\"cg\"/>\n"),
         true);
}

// A scene whose meshes would need more memory than there is is an error at
// the element that goes over, before any mesh is built (else the kernel
// kills the process while it builds them). cube_on_box's deformable has 384
// tetrahedra (about 0.6 MB) and its rigid proxy 384 (about 0.23 MB).
TEST(WorldLoad, MemoryBeyondTheLimitIsAClearError) {
  const std::string path = std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml";
  for (const auto& [limit, message] :
       {std::pair{1e5, "cube_on_box.xml:17: <tetbody name=\"cube\">: 384 tetrahedra"},
        std::pair{7e5, "cube_on_box.xml:16: <rigidtet>: 384 tetrahedra"}}) {
    WorldOptions options;
    options.memory_limit = limit;
    const std::string error = ErrorOf(path, options);
    EXPECT_NE(error.find(message), std::string::npos) << limit << ": " << error;
    EXPECT_NE(error.find("the memory limit is"), std::string::npos) << error;
  }
  WorldOptions options;
  options.memory_limit = 1e6;
  EXPECT_NO_THROW(World::Load(path, options));
}

// A deformable placed so far out that its vertices round together (at
// 1e30 m a 4 cm cube is one point, which ran with kinetic energy from
// nowhere) is an error; at 1e4 m the same scene loads.
TEST(WorldLoad, BodyTooFarForDoublePrecisionIsAClearError) {
  TempDir dir;
  const std::string scene =
      ReadFileContents(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml");
  const std::string at = "pos=\"0.01 0 0.2\"";
  ASSERT_NE(scene.find(at), std::string::npos);
  auto moved_to = [&](const std::string& x) {
    std::string moved = scene;
    moved.replace(moved.find(at), at.size(), "pos=\"" + x + " 0 0.2\"");
    return dir.Write("far_" + x + ".xml", moved);
  };
  EXPECT_NO_THROW(World::Load(moved_to("1e4")));
  const std::string message = ErrorOf(moved_to("1e30"));
  EXPECT_NE(message.find(":17: <tetbody name=\"cube\">: placed 1e+30 m from the origin, "
                         "rounding changes"),
            std::string::npos)
      << message;
}

// A scene of a pad (15 g, E = 1e7 Pa) glued to a body of `mass` kg on two
// slide joints (x, z) without damping, the body moving at 0.5 m/s along x
// and the pad at rest (its `vel` takes off the body's, which a tetbody
// glued to one body starts with).
std::string PadOnFingerScene(const char* mass, const char* solver) {
  return std::string(
             "<mujoco><option timestep='0.001' gravity='0 0 -9.81'/><worldbody>\n"
             "<body name='finger' pos='0 0 0.2'>"
             "<joint name='x' type='slide' axis='1 0 0'/><joint name='z' type='slide' axis='0 0 "
             "1'/>"
             "<geom type='box' size='0.005 0.03 0.05' mass='") +
         mass + "' contype='0' conaffinity='0'/></body></worldbody>\n" +
         "<keyframe><key qvel='0.5 0'/></keyframe>\n<deformable>" + solver +
         "\n<tetbody name='pad' shape='box' size='0.006 0.025 0.025' resolution='2 4 4' "
         "pos='0.011 0 0.2' vel='-0.5 0 0' density='500' young='1e7' poisson='0.3' "
         "damping='0 0.001'/>\n"
         "<attach tetbody='pad' body='finger' box='0.004 -0.1 -0.1 0.0051 0.1 0.3'/>\n"
         "</deformable></mujoco>";
}

// Whether 1000 steps of `world` end in a bad state.
bool Diverges(World& world) {
  for (int step = 0; step < 1000; ++step) {
    world.Step();
    if (world.metrics().status != StepStatus::kOk) return true;
  }
  return false;
}

// An attachment's pins ride on their body's tree within the step (RigidPin,
// implicit, the default): a 3 g body carrying a 15 g pad, which diverged
// when the pins' force reached the body only after the step, moves on
// steadily; the total momentum changes only by gravity's impulse (the
// pins' forces are exchanged exactly), and the pinned vertices stay where
// the body carries them.
TEST(Attachments, ALightBodyCarriesAHeavyDeformableWithinTheStep) {
  TempDir dir;
  const std::unique_ptr<World> world =
      World::Load(dir.Write("light.xml", PadOnFingerScene("0.003", "")));
  EXPECT_TRUE(world->load_warnings().empty());
  const mjModel* m = world->mj_model();
  const mjData* d = world->mj_data();  // (at the keyframe: World::Load)
  const int finger = mj_name2id(m, mjOBJ_BODY, "finger");
  const DeformableBody& pad = world->deformable(0);
  const double total_mass = m->body_mass[finger] + pad.model().masses().sum();
  auto momentum = [&]() -> Eigen::Vector3d {
    return Eigen::Vector3d(m->body_mass[finger] * d->qvel[0], 0.0,
                           m->body_mass[finger] * d->qvel[1]) +
           pad.LinearMomentum();
  };
  const Eigen::Vector3d start = momentum();
  ASSERT_NEAR(start.x(), 0.0015, 1e-12);  // (the pad at rest)
  // each pinned vertex's place from the finger's origin (it only slides)
  auto origin = [&]() -> Eigen::Vector3d {
    return Eigen::Vector3d(d->xpos[3 * finger], d->xpos[3 * finger + 1], d->xpos[3 * finger + 2]);
  };
  std::vector<Eigen::Vector3d> local;
  for (int v : pad.pinned_vertices()) {
    local.push_back(Eigen::Vector3d(pad.positions().row(v).transpose()) - origin());
  }
  double worst_momentum = 0.0, worst_place = 0.0;
  for (int step = 0; step < 1000; ++step) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk)
        << "step " << step << ": " << world->metrics().message;
    Eigen::Vector3d expected = start;
    expected.z() -= 9.81 * total_mass * d->time;
    worst_momentum = std::max(worst_momentum, (momentum() - expected).norm());
    for (size_t k = 0; k < local.size(); ++k) {
      const Eigen::Vector3d carried = origin() + local[k];
      worst_place =
          std::max(worst_place,
                   (pad.positions().row(pad.pinned_vertices()[k]).transpose() - carried).norm());
    }
  }
  // (against 0.0015 kg m/s along x, and 0.18 kg m/s of gravity's impulse)
  EXPECT_LT(worst_momentum, 1e-6);
  EXPECT_LT(worst_place, 1e-6);
  EXPECT_GT(d->qpos[0], 0.01);  // (it moved along x, with the pad)
}

// A soft strap glued at each end to its own free body, without gravity:
// the bodies fly apart and spin, the strap stretches and pulls them back.
// Oracles: the linear momentum of the whole (bodies and strap) stays as it
// started; each body's momentum changes by dt times the force the world
// put on it, which is not zero: each takes its own end's pull; each end's
// pinned vertices keep their places in their own body's frame (to 3.4e-9 m
// at dt = 1 ms, 7.5e-10 m at 0.5 ms: the pins follow a first-order
// prediction of the body's pose). Angular momentum is not asserted: the
// linearized co-rotational step does not keep it exactly (this strap alone,
// spinning at 3 rad/s and bending, loses 1.4e-4 of it in 1.2 s; this
// scene, run for 1.5 s, 3.3e-4, at dt = 1 ms and 0.5 ms alike).
TEST(Attachments, ASoftStrapBetweenTwoBodiesExchangesMomentumWithBoth) {
  TempDir dir;
  const std::unique_ptr<World> world = World::Load(dir.Write("strap.xml", R"(<mujoco>
  <option timestep="0.001" gravity="0 0 0"/>
  <worldbody>
    <body name="left" pos="-0.11 0 0"><freejoint/>
      <geom type="box" size="0.01 0.02 0.02" mass="0.05" contype="0" conaffinity="0"/></body>
    <body name="right" pos="0.11 0 0"><freejoint/>
      <geom type="box" size="0.01 0.02 0.02" mass="0.08" contype="0" conaffinity="0"/></body>
  </worldbody>
  <keyframe><key qvel="-0.2 0.05 0  0 0 1   0.2 -0.05 0.02  0.5 0 0"/></keyframe>
  <deformable>
    <tetbody name="strap" shape="box" size="0.1 0.01 0.005" resolution="6" young="1e5"
             density="1000"/>
    <attach tetbody="strap" body="left" box="-0.11 -0.1 -0.1 -0.09 0.1 0.1"/>
    <attach tetbody="strap" body="right" box="0.09 -0.1 -0.1 0.11 0.1 0.1"/>
  </deformable>
</mujoco>)"));
  const mjModel* m = world->mj_model();
  const mjData* d = world->mj_data();
  const double dt = m->opt.timestep;
  const DeformableBody& strap = world->deformable(0);
  const int left = world->BodyId("left"), right = world->BodyId("right");
  // each pinned vertex's place in its body's frame
  auto in_body = [&](int body, const Eigen::Vector3d& p_W) -> Eigen::Vector3d {
    const Eigen::Vector3d p_WB = Eigen::Map<const Eigen::Vector3d>(d->xpos + 3 * body);
    const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> R_WB(d->xmat + 9 * body);
    return R_WB.transpose() * (p_W - p_WB);
  };
  std::vector<int> pin_body;
  std::vector<Eigen::Vector3d> local;
  for (size_t k = 0; k < strap.pinned_vertices().size(); ++k) {
    const Eigen::Vector3d p = strap.positions().row(strap.pinned_vertices()[k]).transpose();
    pin_body.push_back(p.x() < 0.0 ? left : right);
    local.push_back(in_body(pin_body.back(), p));
  }
  ASSERT_GT(std::count(pin_body.begin(), pin_body.end(), left), 0);
  ASSERT_GT(std::count(pin_body.begin(), pin_body.end(), right), 0);
  const Eigen::Vector3d p0 = world->LinearMomentum();
  double worst_p = 0.0, worst_impulse = 0.0, worst_place = 0.0;
  double largest_force[2] = {0.0, 0.0};
  bool turned[2] = {false, false};
  for (int step = 0; step < 300; ++step) {
    const Eigen::Vector3d v_before[2] = {world->RigidBodyLinearVelocity(left),
                                         world->RigidBodyLinearVelocity(right)};
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk)
        << "step " << step << ": " << world->metrics().message;
    worst_p = std::max(worst_p, (world->LinearMomentum() - p0).norm());
    for (int side = 0; side < 2; ++side) {
      const int body = side == 0 ? left : right;
      const Eigen::Vector3d force(world->coupling_forces().data() + 6 * body);
      const Eigen::Vector3d change =
          m->body_mass[body] * (world->RigidBodyLinearVelocity(body) - v_before[side]);
      worst_impulse = std::max(worst_impulse, (change - dt * force).norm());
      largest_force[side] = std::max(largest_force[side], force.norm());
      const double outward = world->RigidBodyLinearVelocity(body).x() * (side == 0 ? -1.0 : 1.0);
      turned[side] |= outward < 0.0;
    }
    for (size_t k = 0; k < local.size(); ++k) {
      const Eigen::Vector3d p = strap.positions().row(strap.pinned_vertices()[k]).transpose();
      worst_place = std::max(worst_place, (in_body(pin_body[k], p) - local[k]).norm());
    }
  }
  // (against 0.026 kg m/s of each body's start momentum; the coupled
  // solve's tolerance is 1e-6 of a step's impulse)
  EXPECT_LT(worst_p, 1e-8) << "linear momentum";
  EXPECT_LT(worst_impulse, 1e-12) << "a body's momentum changed by other than its force";
  EXPECT_GT(largest_force[0], 0.1) << "N, the strap's pull on the left body";
  EXPECT_GT(largest_force[1], 0.1) << "N, the strap's pull on the right body";
  EXPECT_LT(worst_place, 1e-8) << "m, a pinned vertex left its place on its body";
  EXPECT_TRUE(turned[0] && turned[1]) << "each body turned back";
}

// A soft bob glued to the end of a light arm on a hinge (a compound
// pendulum), the first keyframe turning the arm: the tetbody's `pos` and
// its <attach> region are in the model's own pose (qpos0), as the MJCF's
// bodies are, so the bob starts at the arm's end where the keyframe puts
// it, unstrained, glued by the same vertices, and moving with the arm.
// Before, it stayed where `pos` put it, glued to the turned arm there: a
// pendulum whose bob hung straight below the pivot, and did not swing.
std::string PendulumScene(const std::string& key) {
  return R"(<mujoco>
  <option timestep="0.001"/>
  <worldbody>
    <body name="arm" pos="0 0 1">
      <joint name="hinge" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.005" mass="0.001" contype="0"
            conaffinity="0"/>
    </body>
  </worldbody>
  <keyframe><key )" +
         key + R"(/></keyframe>
  <deformable>
    <tetbody name="bob" shape="box" size="0.05 0.05 0.05" resolution="4" pos="0 0 0.45"
             young="1e7" density="1000"/>
    <attach tetbody="bob" body="arm" box="-0.1 -0.1 0.49 0.1 0.1 0.51"/>
  </deformable>
</mujoco>)";
}

TEST(Attachments, AGluedTetbodyStartsWhereTheFirstKeyframeTakesItsBody) {
  TempDir dir;
  const double angle = 0.3, rate = 0.5;  // rad, rad/s
  const std::unique_ptr<World> world = World::Load(
      dir.Write("pendulum.xml", PendulumScene("qpos=\"" + std::to_string(angle) + "\" qvel=\"" +
                                              std::to_string(rate) + "\"")));
  const DeformableBody& bob = world->deformable(0);
  const Eigen::Vector3d pivot(0.0, 0.0, 1.0);
  const Eigen::AngleAxisd turn(angle, Eigen::Vector3d::UnitY());
  // each vertex: the model's own place turned about the pivot, moving at
  // omega x r
  const Positions& rest = bob.mesh().positions();
  double place = 0.0, velocity = 0.0;
  for (int k = 0; k < bob.num_vertices(); ++k) {
    const Eigen::Vector3d own = rest.row(k).transpose() + Eigen::Vector3d(0.0, 0.0, 0.45);
    const Eigen::Vector3d x = pivot + turn * (own - pivot);
    place = std::max(place, (bob.positions().row(k).transpose() - x).norm());
    const Eigen::Vector3d v = Eigen::Vector3d(0.0, rate, 0.0).cross(x - pivot);
    velocity = std::max(velocity, (bob.velocities().row(k).transpose() - v).norm());
  }
  EXPECT_LT(place, 1e-12) << "m";
  EXPECT_LT(velocity, 1e-12) << "m/s";
  // glued by its top face in the model's own pose (5 x 5 vertices at z = 0.5)
  ASSERT_EQ(bob.pinned_vertices().size(), 25u);
  for (int v : bob.pinned_vertices()) EXPECT_NEAR(rest(v, 2), 0.05, 1e-12) << v;
  // and it swings on from there with its pins, without a jolt: the first
  // step's pull on the arm is below the bob's weight and centripetal force
  // (its lower part still falls: it starts unstrained), where a bob at
  // rest would be jerked to the arm's 0.28 m/s within the step (270 N)
  world->Step();
  ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
  const double mass = bob.model().total_mass();
  const double hold = mass * (9.81 * std::cos(angle) + rate * rate * 0.55);
  const Eigen::Vector3d pull(world->coupling_forces().data() + 6 * world->BodyId("arm"));
  EXPECT_LT(pull.norm(), hold);
  EXPECT_GT(pull.norm(), 0.5 * hold);
}

// The same pendulum let go from 0.05 rad swings with a compound
// pendulum's period, 2 pi sqrt(I / (m g d)) (1 + theta^2 / 16), I = m (d^2
// + a^2 / 6) about the pivot for a cube of side a whose centre is d below
// it (the arm's 1 g left out): measured 0.03% longer (the bob is soft);
// its arm's fastest spin is 0.05 rad times 2 pi / T.
TEST(Attachments, AGluedBobSwingsWithACompoundPendulumsPeriod) {
  TempDir dir;
  const std::unique_ptr<World> world =
      World::Load(dir.Write("pendulum.xml", PendulumScene("qpos=\"0.05\"")));
  const int arm = world->BodyId("arm");
  const double dt = world->timestep();
  std::vector<double> crossings;  // of the arm's spin upward through zero
  double last = 0.0, fastest = 0.0;
  for (int s = 1; s <= 3200; ++s) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
    const double w = world->RigidBodyAngularVelocity(arm).y();
    if (last < 0.0 && w >= 0.0) crossings.push_back((s - 1 + -last / (w - last)) * dt);
    last = w;
    fastest = std::max(fastest, std::abs(w));
  }
  ASSERT_EQ(crossings.size(), 2u);
  const double d = 0.55, a = 0.1;
  const double period = 2.0 * std::numbers::pi * std::sqrt((d * d + a * a / 6.0) / (9.81 * d)) *
                        (1.0 + 0.05 * 0.05 / 16.0);
  EXPECT_NEAR(crossings[1] - crossings[0], period, 1e-3 * period);
  // swinging 0.05 rad each way (a bob left below the pivot swings 2e-5 rad)
  EXPECT_NEAR(fastest, 0.05 * 2.0 * std::numbers::pi / period, 0.01 * fastest);
}

// A tetbody glued to two bodies is placed in the model's own pose: a
// keyframe that moves the bodies apart leaves no place where it is glued
// to both, which is an error; one that moves them together moves it too.
TEST(Attachments, AKeyframeThatMovesATetbodysBodiesApartIsAnError) {
  TempDir dir;
  auto scene = [&](const std::string& key) {
    return dir.Write("apart.xml", R"(<mujoco>
  <worldbody>
    <body name="base"><freejoint/>
      <geom type="box" size="0.01 0.01 0.01" mass="0.1" contype="0" conaffinity="0"/>
      <body name="left" pos="-0.11 0 0"><joint name="slide" type="slide" axis="1 0 0"/>
        <geom type="box" size="0.01 0.02 0.02" mass="0.05" contype="0" conaffinity="0"/></body>
      <body name="right" pos="0.11 0 0">
        <geom type="box" size="0.01 0.02 0.02" mass="0.08" contype="0" conaffinity="0"/></body>
    </body>
  </worldbody>
  <keyframe><key qpos=")" + key + R"("/></keyframe>
  <deformable>
    <tetbody name="strap" shape="box" size="0.1 0.01 0.005" resolution="6" young="1e5"/>
    <attach tetbody="strap" body="left" box="-0.11 -0.1 -0.1 -0.09 0.1 0.1"/>
    <attach tetbody="strap" body="right" box="0.09 -0.1 -0.1 0.11 0.1 0.1"/>
  </deformable>
</mujoco>)");
  };
  // the slide apart: an error at the second <attach>
  const std::string message = ErrorOf(scene("0 0 0 1 0 0 0 -0.03"));
  EXPECT_NE(message.find("apart.xml:15: <attach>: the first keyframe moves body 'left' and body "
                         "'right' apart, by up to 0.03 m at tetbody 'strap'"),
            std::string::npos)
      << message;
  // the base, carrying both, 0.2 m up: the strap with it
  const std::unique_ptr<World> world = World::Load(scene("0 0 0.2 1 0 0 0 0"));
  const DeformableBody& strap = world->deformable(0);
  EXPECT_NEAR(strap.CenterOfMass().z(), 0.2, 1e-12);
  EXPECT_EQ(strap.pinned_vertices().size(), 2u * 7 * 7);
}

// With <solver rigid="explicit">, the pins' force reaches the body after the
// step, and a body much lighter than the deformable glued to it diverges:
// the load warns, naming the line, both masses and the remedies, exactly
// when that happens (a 15 g pad on a 30 g body diverges within a second,
// on a 50 g one it does not; with 2 substeps the 30 g one does not either).
TEST(Attachments, ExplicitlyALightBodyCarryingAHeavyDeformableIsWarnedOf) {
  TempDir dir;
  const std::string explicit_rigid = "<solver rigid='explicit'/>";
  const std::unique_ptr<World> light =
      World::Load(dir.Write("light.xml", PadOnFingerScene("0.03", explicit_rigid.c_str())));
  ASSERT_EQ(light->load_warnings().size(), 1u);
  const std::string& warning = light->load_warnings()[0];
  EXPECT_EQ(warning.rfind(dir.path().string() +
                              "/light.xml:6: <attach>: tetbody 'pad' (0.015 kg) is glued to body "
                              "'finger', which with what it carries weighs 0.03 kg",
                          0),
            0u)
      << warning;
  EXPECT_NE(warning.find("about 3 times"), std::string::npos) << warning;
  EXPECT_NE(warning.find("substeps"), std::string::npos) << warning;
  EXPECT_TRUE(Diverges(*light));
  const std::unique_ptr<World> heavy =
      World::Load(dir.Write("heavy.xml", PadOnFingerScene("0.05", explicit_rigid.c_str())));
  EXPECT_TRUE(heavy->load_warnings().empty());
  EXPECT_FALSE(Diverges(*heavy));
  const std::unique_ptr<World> substepped = World::Load(
      dir.Write("sub.xml", PadOnFingerScene("0.03", "<solver rigid='explicit' substeps='2'/>")));
  EXPECT_TRUE(substepped->load_warnings().empty());
  EXPECT_FALSE(Diverges(*substepped));
}

// What a mesh's reader or validation noted (here: a second-order mesh read as
// linear, and its mid-edge nodes dropped) comes with the scene's line, the
// element and the file; a scene of clean meshes has none.
TEST(WorldLoad, MeshWarningsNameTheSceneLineAndFile) {
  TempDir dir;
  const std::string scene =
      ReadFileContents(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml");
  EXPECT_TRUE(World::Load(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml")
                  ->load_warnings()
                  .empty());
  const std::string shape = "shape=\"box\" size=\"0.04 0.04 0.04\" resolution=\"4\"";
  ASSERT_NE(scene.find(shape), std::string::npos);
  std::string quadratic = scene;
  const std::string file = kData + "/lshape_order2_meshio.vtu";
  quadratic.replace(quadratic.find(shape), shape.size(), "file=\"" + file + "\"");
  const std::string path = dir.Write("quadratic.xml", quadratic);
  const std::vector<std::string> warnings = World::Load(path)->load_warnings();
  ASSERT_EQ(warnings.size(), 2u);
  const std::string where = path + ":17: <tetbody name=\"cube\">: " + file + ": ";
  EXPECT_EQ(warnings[0].rfind(where + "178 higher-order tetrahedra were read as linear", 0), 0u)
      << warnings[0];
  EXPECT_EQ(warnings[1].rfind(where + "328 vertices are used by no tetrahedron", 0), 0u)
      << warnings[1];
}

// MuJoCo's RK4 integrator. Where nothing soft touches the rigid bodies, a
// World steps MuJoCo as mj_step does (a damped double pendulum, a free box
// falling onto the floor, a soft cube far from both), to rounding (the
// free box's last bits differ, with Euler too: the World's MuJoCo calls
// around a step), while RK4's and Euler's rollouts differ in the third
// digit. (MuJoCo 2.2.2 integrates a step taken in two parts, mj_step1 and
// mj_step2, with Euler when RK4 is asked for; the World does RK4's second
// part itself.)
TEST(WorldStep, RungeKuttaStepsTheRigidBodiesAsMjStepDoes) {
  TempDir dir;
  std::vector<double> final_angle;
  for (const std::string integrator : {"RK4", "Euler"}) {
    SCOPED_TRACE(integrator);
    const std::string path = dir.Write(integrator + ".xml", R"(<mujoco>
  <option timestep="0.005" integrator=")" + integrator + R"("/>
  <worldbody>
    <geom type="plane" size="2 2 0.1"/>
    <body name="upper" pos="0 0 1">
      <joint type="hinge" axis="0 1 0" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="0.5"/>
      <body name="lower" pos="0.3 0 0">
        <joint type="hinge" axis="0 1 0" damping="0.02"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="0.3"/>
      </body>
    </body>
    <body name="box" pos="1 0 0.3" euler="10 20 30">
      <freejoint/>
      <geom type="box" size="0.05 0.05 0.05" mass="1"/>
    </body>
  </worldbody>
  <deformable>
    <tetbody name="cube" shape="box" size="0.05 0.05 0.05" resolution="2" pos="-1 0 0.0501"
             density="1000" young="1e5"/>
  </deformable>
</mujoco>)");
    std::unique_ptr<World> world = World::Load(path);
    EXPECT_TRUE(world->load_warnings().empty());
    const mjModel* m = world->mj_model();
    const std::unique_ptr<mjData, decltype(&mj_deleteData)> data(mj_makeData(m), mj_deleteData);
    mjData* d = data.get();
    mj_forward(m, d);
    for (int step = 0; step < 400; ++step) {
      world->Step();
      mj_step(m, d);
      ASSERT_EQ(world->metrics().status, StepStatus::kOk);
    }
    EXPECT_GT(d->ncon, 0) << "the box landed";
    for (int i = 0; i < m->nq; ++i) EXPECT_NEAR(world->mj_data()->qpos[i], d->qpos[i], 1e-12) << i;
    for (int i = 0; i < m->nv; ++i) EXPECT_NEAR(world->mj_data()->qvel[i], d->qvel[i], 1e-12) << i;
    final_angle.push_back(d->qpos[0]);
  }
  EXPECT_GT(std::abs(final_angle[0] - final_angle[1]), 1e-3) << "RK4 against Euler, rad";
}

// Bodies placed inside each other are warned of, a pair each, on the line
// of a tetbody of the pair, with the depth (the exact one, as the metrics
// measure it) against the thinner deformable's thickness: two 10 cm cubes
// overlapping by 4 cm, a cube 2 cm into the floor plane; a cube resting on
// the floor, 0.1 mm into it, and cubes side by side are not. No bundled
// scene has such a pair (the paper's spheres had 15, up to 5 mm deep).
TEST(WorldLoad, BodiesStartingInsideEachOtherAreWarnedOf) {
  TempDir dir;
  auto warnings_of = [&](const std::string& name, double b_x, double c_z) {
    char scene[1024];
    std::snprintf(scene, sizeof(scene), R"(<mujoco>
  <worldbody><geom name="floor" type="plane" size="1 1 0.1"/></worldbody>
  <deformable>
    <tetbody name="a" shape="box" size="0.05 0.05 0.05" pos="0 0 0.3"/>
    <tetbody name="b" shape="box" size="0.05 0.05 0.05" pos="%.17g 0 0.3"/>
    <tetbody name="c" shape="box" size="0.02 0.02 0.02" pos="0.5 0 %.17g"/>
  </deformable>
</mujoco>)",
                  b_x, c_z);
    return World::Load(dir.Write(name, scene))->load_warnings();
  };
  EXPECT_TRUE(warnings_of("apart.xml", 0.1, 0.0199).empty());
  const std::vector<std::string> warnings = warnings_of("inside.xml", 0.06, 0.0);
  ASSERT_EQ(warnings.size(), 2u);
  const std::string where = dir.path().string() + "/inside.xml:";
  EXPECT_EQ(warnings[0].rfind(where + "4: <tetbody name=\"a\">: tetbody '", 0), 0u) << warnings[0];
  EXPECT_NE(warnings[0].find(" starts 0.04 m inside tetbody '"), std::string::npos) << warnings[0];
  EXPECT_NE(warnings[0].find("40% of the thinner deformable's thickness (0.1 m)"),
            std::string::npos)
      << warnings[0];
  EXPECT_EQ(
      warnings[1].rfind(where + "6: <tetbody name=\"c\">: tetbody 'c' starts 0.02 m inside "
                                "the world's geoms, 50% of the thinner deformable's thickness "
                                "(0.04 m)",
                        0),
      0u)
      << warnings[1];
  for (const char* scene :
       {"paper/cubes", "paper/spheres", "paper/mixed", "paper/rigid", "scenes/cube_on_box",
        "scenes/gripper", "scenes/terrain", "bench/jelly", "bench/tray"}) {
    const std::string path = std::string(TETCOSIM_SOURCE_DIR) + "/models/" + scene + ".xml";
    EXPECT_TRUE(World::Load(path)->load_warnings().empty()) << scene;
  }
}

TEST(RunCommand, OutputsParse) {
  TempDir dir;
  std::string command = std::string(TETCOSIM_BINARY) + " run " + TETCOSIM_SOURCE_DIR +
                        "/models/scenes/cube_on_box.xml --duration 0.2 --vtk --fps 50 --out " +
                        (dir.path() / "out").string() + " > /dev/null";
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  std::ifstream summary_file(dir.path() / "out" / "summary.json");
  nlohmann::json summary = nlohmann::json::parse(summary_file);
  EXPECT_EQ(summary["status"], "ok");
  EXPECT_EQ(summary["steps"], 100);
  EXPECT_EQ(summary["unconverged_steps"], 0);
  EXPECT_LE(summary["max_solver_residual"].get<double>(), 1e-6 * (1 + 1e-9));
  EXPECT_GT(summary["max_solver_residual"].get<double>(), 0.0);
  EXPECT_NEAR(summary["sim_time"].get<double>(), 0.2, 1e-9);
  std::ifstream steps(dir.path() / "out" / "steps.csv");
  std::string header, line;
  std::getline(steps, header);
  EXPECT_EQ(header,
            "step,time,colliding_points,max_depth,mean_depth,kinetic_deformable,kinetic_rigid,px,"
            "py,pz,direction_change_max_deg,neighbour_angle_mean_deg,fallback_points,"
            "unresolved_points,solver_iterations,contact_rounds,released_contacts,stuck_contacts,"
            "wall_ms");
  // the cube lands on the box: contacts, none of them an artifact
  const nlohmann::json& metrics = summary["metrics"];
  EXPECT_GT(metrics["colliding_points"].get<long>(), 0);
  EXPECT_EQ(metrics["pass_through_pairs"], 0);
  EXPECT_EQ(metrics["sticking_pairs"], 0);
  EXPECT_LT(metrics["residual_max_depth"].get<double>(), 1e-3);
  // the penetration solver (the box is a proxy) runs inside the collision
  // phase: its time is part of that phase's
  const nlohmann::json& contacts = summary["contacts"];
  EXPECT_GT(contacts["penetration_ms_per_step"].get<double>(), 0.0);
  EXPECT_LE(contacts["penetration_ms_per_step"].get<double>(),
            summary["ms_per_step"]["collision"].get<double>());
  EXPECT_GT(contacts["penetration_us_per_point"].get<double>(), 0.0);
  // the solver's columns add up to the summary's means; every step solves
  // at least once, twice with contacts (settling, then precise), and
  // releases no more contacts than it has, nor sticks more than it keeps
  int rows = 0;
  long iterations = 0, rounds = 0, released = 0;
  std::vector<double> kinetic(1, 0.0);  // the deformable's, after each step
  while (std::getline(steps, line)) {
    std::vector<std::string> fields;
    std::stringstream row(line);
    for (std::string field; std::getline(row, field, ',');) fields.push_back(field);
    ASSERT_EQ(fields.size(), 19u) << line;
    const int colliding = std::stoi(fields[2]);
    const int step_rounds = std::stoi(fields[15]), step_released = std::stoi(fields[16]);
    EXPECT_GE(step_rounds, colliding > 0 ? 2 : 1) << line;
    EXPECT_LE(step_released, colliding) << line;
    EXPECT_LE(std::stoi(fields[17]), colliding - step_released) << line << ": stuck, not released";
    kinetic.push_back(std::stod(fields[5]));
    iterations += std::stol(fields[14]);
    rounds += step_rounds;
    released += step_released;
    ++rows;
  }
  EXPECT_EQ(rows, 100);
  EXPECT_DOUBLE_EQ(summary["mean_solver_iterations"].get<double>(), iterations / 100.0);
  EXPECT_DOUBLE_EQ(summary["mean_contact_rounds"].get<double>(), rounds / 100.0);
  // (the cube lands and bounces: some contacts leave the box)
  EXPECT_GT(released, 0);
  // frames: the initial state, then every 10 steps (50 per second), the
  // last the final state, in bodies.csv (one row per frame: one MuJoCo
  // body) and vtk/
  std::ifstream bodies(dir.path() / "out" / "bodies.csv");
  std::getline(bodies, header);
  int frames = 0;
  while (std::getline(bodies, line)) {
    std::stringstream row(line);
    std::string frame, time;
    std::getline(row, frame, ',');
    std::getline(row, time, ',');
    EXPECT_EQ(std::stoi(frame), frames) << line;
    EXPECT_NEAR(std::stod(time), 0.02 * frames, 1e-9) << line;
    ++frames;
  }
  EXPECT_EQ(frames, 11);
  // deformables.csv, a row per deformable per frame: the cube's kinetic
  // energy is steps.csv's; until it lands (at 0.1 s) it falls without
  // turning or deforming: its energy is that of its centre's velocity
  // (0.512 kg) and its box keeps its height
  std::ifstream deformables(dir.path() / "out" / "deformables.csv");
  std::getline(deformables, header);
  EXPECT_EQ(header, "frame,time,body,cx,cy,cz,vx,vy,vz,kinetic,xmin,ymin,zmin,xmax,ymax,zmax");
  frames = 0;
  double height = 0.0;
  while (std::getline(deformables, line)) {
    std::vector<std::string> fields;
    std::stringstream row(line);
    for (std::string field; std::getline(row, field, ',');) fields.push_back(field);
    ASSERT_EQ(fields.size(), 16u) << line;
    EXPECT_EQ(std::stoi(fields[0]), frames) << line;
    EXPECT_EQ(fields[2], "cube");
    const double energy = std::stod(fields[9]);
    EXPECT_NEAR(energy, kinetic[10 * frames], 1e-8 * kinetic[10 * frames]) << line;
    if (frames == 0) {  // the 8 cm cube turned by euler="10 5 0": its box
      const double a = 10 * std::numbers::pi / 180, b = 5 * std::numbers::pi / 180;
      EXPECT_NEAR(std::stod(fields[13]) - std::stod(fields[10]), 0.08 * (std::cos(b) + std::sin(b)),
                  1e-9);
      height = std::stod(fields[15]) - std::stod(fields[12]);
      EXPECT_NEAR(height,
                  0.08 * (std::cos(a) * std::sin(b) + std::sin(a) + std::cos(a) * std::cos(b)),
                  1e-9);
    }
    if (std::stod(fields[1]) < 0.09) {
      const Eigen::Vector3d v(std::stod(fields[6]), std::stod(fields[7]), std::stod(fields[8]));
      EXPECT_NEAR(energy, 0.5 * 0.512 * v.squaredNorm(), 1e-6 * energy + 1e-15) << line;
      EXPECT_NEAR(std::stod(fields[15]) - std::stod(fields[12]), height, 1e-9) << line;
    }
    ++frames;
  }
  EXPECT_EQ(frames, 11);
  EXPECT_TRUE(std::filesystem::exists(dir.path() / "out" / "vtk" / "series.pvd"));
  EXPECT_TRUE(std::filesystem::exists(dir.path() / "out" / "vtk" / "cube_10.vtu"));
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "out" / "vtk" / "cube_11.vtu"));
  if (std::system("/usr/bin/python3 -c 'import meshio' 2>/dev/null") == 0) {
    std::string check =
        "/usr/bin/python3 -c \"import meshio; m = meshio.read('" +
        (dir.path() / "out" / "vtk" / "cube_9.vtu").string() +
        "'); assert len(m.points) == 125 and len(m.get_cells_type('tetra')) == 384\"";
    EXPECT_EQ(std::system(check.c_str()), 0);
  }
}

// A shell command that starts a long rollout of cube_on_box into `out`
// (`prefix` before the binary, e.g. "nohup "), waits until it has written
// 20 steps (at most 60 s), then runs `then`, the rollout's process id in
// $pid.
std::string DuringALongRollout(const std::string& prefix, const std::string& out,
                               const std::string& then) {
  const std::string run = prefix + TETCOSIM_BINARY + " run " + TETCOSIM_SOURCE_DIR +
                          "/models/scenes/cube_on_box.xml --duration 1000 --out " + out;
  return "sh -c '" + run + " > /dev/null 2>&1 & pid=$!; i=0; while [ $(cat " + out +
         "/steps.csv 2>/dev/null | wc -l) -lt 20 ] && [ $i -lt 1200 ]; do sleep 0.05; " +
         "i=$((i+1)); done; " + then + "'";
}

// A rollout stopped by SIGTERM (kill, timeout, a cancelled CI job) stops at
// the next step with its files complete: summary.json says "interrupted",
// every row of steps.csv is whole.
TEST(RunCommand, TerminatedRunKeepsValidOutputs) {
  TempDir dir;
  const std::string out = (dir.path() / "out").string();
  const auto [status, text] =
      RunShell(DuringALongRollout("", out, "kill -TERM $pid; wait $pid; exit $?"));
  ASSERT_TRUE(WIFEXITED(status)) << "killed by the signal instead of stopping";
  EXPECT_EQ(WEXITSTATUS(status), 1);  // (an interrupted run is not a success)
  std::ifstream summary_file(out + "/summary.json");
  const nlohmann::json summary = nlohmann::json::parse(summary_file);
  EXPECT_EQ(summary["status"], "interrupted");
  const long steps = summary["steps"].get<long>();
  EXPECT_GE(steps, 19);
  EXPECT_LT(steps, 500000);
  const std::vector<std::string> rows = CsvLines(out + "/steps.csv");
  ASSERT_FALSE(rows.empty());
  const auto columns = std::count(rows[0].begin(), rows[0].end(), ',');
  for (size_t r = 1; r < rows.size(); ++r) {
    EXPECT_EQ(std::count(rows[r].begin(), rows[r].end(), ','), columns) << "row " << r - 1;
  }
  EXPECT_EQ(static_cast<long>(rows.size()) - 1, steps);
  // the last frame is the state the run stopped in
  const std::vector<std::string> frames = CsvLines(out + "/bodies.csv");
  ASSERT_GT(frames.size(), 1u);
  const std::string& last = frames.back();
  EXPECT_NEAR(std::stod(CsvFields(last)[1]), summary["sim_time"].get<double>(), 1e-6) << last;
}

// Names with commas, quotes and markup, and long ones, come through every
// output as they were given: the CSV files read back (by Python's csv
// module, an independent reader) with the same columns in every row and the
// names whole; series.pvd parses and its files exist; summary.json parses,
// and a MuJoCo body's name that is not UTF-8 (from an included file, which
// tetcosim does not read) is in it with U+FFFD for the byte. (A comma
// shifted the CSV columns; a quote in a tetbody's name broke the skin
// tetcosim adds to MuJoCo's MJCF; a name longer than the CSV line buffer cut
// its row; a byte that is not UTF-8 failed summary.json.)
TEST(RunCommand, NamesWithCommasQuotesAndMarkupComeThroughEveryOutput) {
  TempDir dir("tetcosim_run_names");
  const std::string long_name(200, 'n');  // (the longest a tetbody's may be)
  const std::string longer_name(600, 'r');
  dir.Write("box.xml",
            "<mujoco><worldbody><body name=\"box, caf\xE9\" pos=\"0 0 0.05\">"
            "<freejoint/><geom type=\"box\" size=\"0.1 0.1 0.05\"/></body>"
            "</worldbody></mujoco>");
  dir.Write("names.xml", R"(<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="ball, &quot;big&quot;" pos="0.3 0 0.05"><freejoint/><geom size="0.05"/></body>
    <body name=")" + longer_name +
                             R"(" pos="0.5 0 0.5"><freejoint/><geom size="0.01"/></body>
  </worldbody>
  <include file="box.xml"/>
  <deformable>
    <tetbody name="a, &quot;b&quot; &lt;c&gt; &amp; &apos;d&apos;" shape="box" size="0.03 0.03 0.03"
             resolution="2" pos="0 0 0.131"/>
    <tetbody name=")" + long_name +
                             R"(" shape="sphere" size="0.03" pos="0.5 0 0.1"/>
  </deformable>
</mujoco>)");
  const auto [status, text] = RunShell("cd " + dir.path().string() + " && " + TETCOSIM_BINARY +
                                       " run names.xml --steps 20 --fps 100 --vtk --out out 2>&1");
  ASSERT_EQ(status, 0) << text;
  const std::string check = R"(
import csv, json, os, sys, xml.dom.minidom
out = sys.argv[1]
names = set()
for file in ("bodies.csv", "deformables.csv"):
    lines = open(os.path.join(out, file), newline="", errors="surrogateescape")
    rows = list(csv.reader(lines))
    assert all(len(row) == len(rows[0]) for row in rows), file + ": columns differ"
    names |= {row[2] for row in rows[1:]}
expected = ["box, caf\udce9", "ball, \x22big\x22", "a, \x22b\x22 <c> & 'd'", "n" * 200, "r" * 600]
print(sorted(names) == sorted(expected), end=" ")
pvd = xml.dom.minidom.parse(os.path.join(out, "vtk", "series.pvd"))
files = [d.getAttribute("file") for d in pvd.getElementsByTagName("DataSet")]
print(len(files) > 0 and all(os.path.exists(os.path.join(out, "vtk", f)) for f in files), end=" ")
summary = json.load(open(os.path.join(out, "summary.json"), encoding="utf-8"))
pairs = summary["metrics"]["deepest_pairs"]
print(any(p["a"] == "box, caf\ufffd" or p["b"] == "box, caf\ufffd" for p in pairs))
)";
  const std::string script = dir.Write("check.py", check);
  const auto [check_status, result] =
      RunShell("/usr/bin/python3 " + script + " " + (dir.path() / "out").string() + " 2>&1");
  EXPECT_EQ(check_status, 0) << result;
  EXPECT_EQ(result, "True True True\n");
}

// A box resting on a plane needs four contacts: with room for two, MuJoCo
// drops the others (and the box sinks in, tilted) but goes on, warning
// once on stderr. The summary says so, with what to do; with room for
// eight, there is nothing to say.
TEST(RunCommand, ContactsMuJoCoDroppedAreInTheSummary) {
  TempDir dir("tetcosim_run_warnings");
  auto run = [&](int nconmax) {
    dir.Write("box.xml", R"(<mujoco>
  <size nconmax=")" + std::to_string(nconmax) +
                             R"("/>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <body pos="0 0 0.1"><freejoint/><geom type="box" size="0.1 0.1 0.1"/></body>
  </worldbody>
  <deformable>
    <tetbody name="cube" shape="box" size="0.03 0.03 0.03" resolution="2" pos="0.5 0 0.03"/>
  </deformable>
</mujoco>)");
    const auto [status, text] = RunShell("cd " + dir.path().string() + " && " + TETCOSIM_BINARY +
                                         " run box.xml --steps 50 --out out 2>/dev/null");
    EXPECT_EQ(status, 0) << text;
    std::ifstream summary_file(dir.path() / "out" / "summary.json");
    return std::make_pair(nlohmann::json::parse(summary_file)["mujoco_warnings"], text);
  };
  const auto [dropped, printed] = run(2);
  ASSERT_EQ(dropped.size(), 1u) << dropped;
  const std::string warning = dropped[0]["warning"].get<std::string>();
  EXPECT_NE(warning.find("contacts were dropped: raise <size nconmax> (it is 2)"),
            std::string::npos)
      << warning;
  EXPECT_GT(dropped[0]["count"].get<int>(), 0);
  EXPECT_NE(printed.find("MuJoCo warned"), std::string::npos) << printed;
  const auto [none, quiet] = run(8);
  EXPECT_TRUE(none.is_array());
  EXPECT_TRUE(none.empty()) << none;
  EXPECT_EQ(quiet.find("MuJoCo warned"), std::string::npos) << quiet;
}

// A step MuJoCo fails ends the run at once, though standard input stays
// open (a fifo opened for reading and writing never ends; MuJoCo's own
// handler waited there for Enter), with status 1, the outputs valid and
// nothing written outside --out (MuJoCo appended to MUJOCO_LOG.TXT in the
// working directory).
TEST(RunCommand, AFailedStepEndsTheRunAtOnceWithValidOutputs) {
  TempDir dir("tetcosim_run_failed");
  dir.Write("balls.xml", BallsOnAPlane(300));
  const std::string command = "cd " + dir.path().string() + " && mkfifo input && timeout 60 " +
                              TETCOSIM_BINARY +
                              " run balls.xml --duration 1 --out out 0<>input 2>&1";
  const auto [status, text] = RunShell(command);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 1) << text;  // (124: timed out)
  EXPECT_NE(text.find("tetcosim: error: MuJoCo failed step"), std::string::npos) << text;
  EXPECT_EQ(text.find("Press Enter"), std::string::npos) << text;
  std::vector<std::string> written;
  for (const auto& entry : std::filesystem::directory_iterator(dir.path())) {
    written.push_back(entry.path().filename().string());
  }
  std::sort(written.begin(), written.end());
  EXPECT_EQ(written, (std::vector<std::string>{"balls.xml", "input", "out"}));
  std::ifstream summary_file(dir.path() / "out" / "summary.json");
  const nlohmann::json summary = nlohmann::json::parse(summary_file);
  EXPECT_EQ(summary["status"], "failed");
  EXPECT_NE(summary["message"].get<std::string>().find("Stack overflow"), std::string::npos);
  const long steps = summary["steps"].get<long>();
  EXPECT_GT(steps, 0);
  EXPECT_EQ(static_cast<long>(CsvLines(dir.path() / "out" / "steps.csv").size()) - 1, steps);
}

// A run that diverges (an arm on a hinge whose position servo is too stiff
// for the time step, beside a box for which MuJoCo drops contacts) ends
// with the state of the last step done, whole: the summary's time, final
// energies and MuJoCo's warnings (which MuJoCo's reset cleared) agree with
// the last row of steps.csv, and the last frame is that state's.
TEST(RunCommand, ADivergedRunEndsWithTheLastStepDone) {
  TempDir dir("tetcosim_run_diverged");
  dir.Write("servo.xml", R"(<mujoco>
  <size nconmax="2"/>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <body><freejoint/><geom type="box" size="0.1 0.1 0.1"/></body>
    <body name="arm" pos="0 0 0.5"><joint name="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/></body>
  </worldbody>
  <actuator><position joint="hinge" kp="6000"/></actuator>
  <keyframe><key qpos="0 0 0.1 1 0 0 0 0.1"/></keyframe>
  <deformable>
    <tetbody name="cube" shape="box" size="0.05 0.05 0.05" pos="0.5 0 0.05" resolution="2"/>
  </deformable>
</mujoco>)");
  const auto [status, text] = RunShell("cd " + dir.path().string() + " && " + TETCOSIM_BINARY +
                                       " run servo.xml --duration 1 --out out 2>&1");
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 1) << text;
  std::ifstream summary_file(dir.path() / "out" / "summary.json");
  const nlohmann::json summary = nlohmann::json::parse(summary_file);
  ASSERT_EQ(summary["status"], "diverged") << summary;
  EXPECT_NE(summary["message"].get<std::string>().find("the step is undone"), std::string::npos);
  const long steps = summary["steps"].get<long>();
  ASSERT_GT(steps, 0);
  const double time = summary["sim_time"].get<double>();
  EXPECT_NEAR(time, static_cast<double>(steps) * summary["dt"].get<double>(), 1e-12);
  // steps.csv's last row: step, time, ..., kinetic energies in columns 6 and 7
  const std::vector<std::string> rows = CsvLines(dir.path() / "out" / "steps.csv");
  ASSERT_GT(rows.size(), 1u);
  EXPECT_EQ(static_cast<long>(rows.size()) - 1, steps);
  std::vector<double> row;
  for (const std::string& field : CsvFields(rows.back())) row.push_back(std::stod(field));
  ASSERT_GE(row.size(), 7u);
  EXPECT_EQ(row[0], static_cast<double>(steps));
  EXPECT_NEAR(row[1], time, 1e-9 * time);
  const nlohmann::json& energy = summary["final_kinetic_energy"];
  EXPECT_NEAR(row[5], energy["deformable"].get<double>(), 1e-8 * row[5]);
  EXPECT_NEAR(row[6], energy["rigid"].get<double>(), 1e-8 * row[6]);
  // the last frame: the final state, finite
  // (frame, time, body, then numbers; the body's name has no comma here)
  const std::vector<std::string> frames = CsvLines(dir.path() / "out" / "bodies.csv");
  ASSERT_GT(frames.size(), 1u);
  for (size_t r = 1; r < frames.size(); ++r) {
    const std::vector<std::string> fields = CsvFields(frames[r]);
    for (size_t k = 3; k < fields.size(); ++k) {
      EXPECT_TRUE(std::isfinite(std::stod(fields[k]))) << frames[r];
    }
  }
  EXPECT_NEAR(std::stod(CsvFields(frames.back())[1]), time, 1e-9 * time);
  // MuJoCo warned of dropped contacts in every step and at loading
  ASSERT_EQ(summary["mujoco_warnings"].size(), 1u) << summary["mujoco_warnings"];
  EXPECT_EQ(summary["mujoco_warnings"][0]["count"].get<long>(), steps + 1);
}

// Under nohup (SIGHUP ignored from the start) a hangup does not stop the
// rollout; SIGTERM still does.
TEST(RunCommand, NohupRunIgnoresHangup) {
  TempDir dir;
  const std::string out = (dir.path() / "out").string();
  const auto [status, text] = RunShell(
      DuringALongRollout("nohup ", out,
                         "kill -HUP $pid; sleep 0.5; kill -0 $pid && echo alive; kill -TERM $pid; "
                         "wait $pid"));
  EXPECT_NE(text.find("alive"), std::string::npos) << "stopped by SIGHUP under nohup";
  std::ifstream summary_file(out + "/summary.json");
  EXPECT_EQ(nlohmann::json::parse(summary_file)["status"], "interrupted");
}

// A run is plausible only if every step's solve converged and MuJoCo
// dropped no contact: a soft cube resting on a box on a plane, with the
// solve held to 3 iterations, or MuJoCo's contact buffer at 2 (the box needs
// 4), is not; the same scene with neither is.
TEST(CompareCommand, AnInexactRunIsNotPlausible) {
  TempDir dir("tetcosim_compare_inexact");
  auto plausible = [&](const std::string& size, const std::string& solver) {
    dir.Write("scene.xml", R"(<mujoco>
  )" + size + R"(
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <body pos="0 0 0.1"><freejoint/><geom type="box" size="0.1 0.1 0.1"/></body>
  </worldbody>
  <deformable>
    )" + solver + R"(
    <tetbody name="cube" shape="box" size="0.03 0.03 0.03" resolution="3" pos="0 0 0.2295"/>
  </deformable>
</mujoco>)");
    const std::string out = (dir.path() / "compare").string();
    std::filesystem::remove_all(out);
    const auto [status, text] = RunShell(
        std::string(TETCOSIM_BINARY) + " compare " + (dir.path() / "scene.xml").string() +
        " --methods consistent --dt 2ms --duration 0.04 --no-render --out " + out + " 2>&1");
    EXPECT_EQ(status, 0) << text;
    std::ifstream file(out + "/runs/consistent-2ms/summary.json");
    const nlohmann::json summary = nlohmann::json::parse(file);
    return std::make_pair(summary["plausible"].get<bool>(), summary);
  };
  const auto [exact, exact_summary] = plausible("", "");
  EXPECT_TRUE(exact) << exact_summary;
  EXPECT_EQ(exact_summary["unconverged_steps"], 0);
  const auto [held, held_summary] = plausible("", R"(<solver maxiter="3"/>)");
  EXPECT_FALSE(held) << held_summary;
  EXPECT_GT(held_summary["unconverged_steps"].get<long>(), 0);
  const auto [dropped, dropped_summary] = plausible(R"(<size nconmax="2"/>)", "");
  EXPECT_FALSE(dropped) << dropped_summary;
  EXPECT_EQ(dropped_summary["mujoco_warnings"].size(), 1u) << dropped_summary;
}

TEST(CompareCommand, WritesOneRowPerMethodAndTimestep) {
  TempDir dir;
  const std::string out = (dir.path() / "compare").string();
  std::string command = std::string(TETCOSIM_BINARY) + " compare " + TETCOSIM_SOURCE_DIR +
                        "/models/paper/cubes.xml --dt 2,4ms --duration 0.02 --no-render --out " +
                        out + " > /dev/null 2>&1";
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  std::ifstream table(out + "/table.csv");
  std::string header, line;
  std::getline(table, header);
  EXPECT_EQ(header.rfind("method,dt_ms,status,plausible,", 0), 0u) << header;
  std::vector<std::string> rows;
  while (std::getline(table, line)) rows.push_back(line.substr(0, line.find(",ok,")));
  EXPECT_EQ(rows,
            (std::vector<std::string>{"consistent,2", "closest,2", "consistent,4", "closest,4"}));
  EXPECT_TRUE(std::filesystem::exists(out + "/table.md"));
  EXPECT_TRUE(std::filesystem::exists(out + "/runs/closest-4ms/steps.csv"));
  std::ifstream run_summary(out + "/runs/closest-4ms/summary.json");
  EXPECT_EQ(nlohmann::json::parse(run_summary)["dt"].get<double>(), 0.004);
  // a bad time step list is a clear error
  std::string bad = std::string(TETCOSIM_BINARY) + " compare " + TETCOSIM_SOURCE_DIR +
                    "/models/paper/cubes.xml --dt 1,fast --out " + out + " 2>&1";
  const auto [status, text] = RunShell(bad);
  EXPECT_NE(status, 0);
  EXPECT_NE(text.find("'fast' is not a positive time step"), std::string::npos) << text;
}

// Numbers on the command line that are not finite (CLI11's own range checks
// let NaN through: `--duration nan` ran the default second) or that make
// more steps than can be counted are clear errors, before anything runs.
TEST(Commands, BadNumbersAreClearErrors) {
  TempDir dir;
  const std::string tetcosim = std::string(TETCOSIM_BINARY) + " ";
  const std::string scene = std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml";
  const std::string out = " --out " + (dir.path() / "out").string();
  const std::string box = " box:size=0.1:res=2 ";
  const std::pair<std::string, std::string> cases[] = {
      {"run " + scene + " --duration nan" + out, "--duration: 'nan' must be a finite number > 0"},
      {"run " + scene + " --fps inf" + out, "--fps: 'inf' must be a finite number > 0"},
      {"run " + scene + " --timestep -0.001" + out, "--timestep: '-0.001' must be a finite"},
      {"run " + scene + " --duration 1e30" + out, "--duration 1e+30 s is 5e+32 steps"},
      {"run " + scene + " --steps 0" + out, "--steps: '0' must be a whole number from 1 to 2^53"},
      {"run " + scene + " --steps -3" + out, "--steps: '-3' must be a whole number"},
      {"run " + scene + " --steps 1.5" + out, "--steps: '1.5' must be a whole number"},
      {"run " + scene + " --steps 1e20" + out, "--steps: '1e20' must be a whole number"},
      {"run " + scene + " --steps 9007199254740993" + out, "'9007199254740993' must be a whole"},
      {"compare " + scene + " --duration 1e300" + out, "--duration 1e+300 s is"},
      {"compare " + scene + " --dt 2,0.002s" + out, "--dt: '0.002s' repeats a time step"},
      {"compare " + scene + " --methods closest,closest" + out,
       "--methods: 'closest' is given twice"},
      {"depth" + box + box + "--move-b 0 nan 0", "--move-b: 'nan' must be a finite number"},
      {"depth" + box + box + "--rotate-b 1e999 0 0", "--rotate-b: '1e999' must be a finite"},
      {"depth" + box + box + "--cell-size nan", "--cell-size: 'nan' must be a finite number >= 0"},
      {"depth" + box + box + "--out x.txt", "--out: 'x.txt' must end in .vtu (XML) or .vtk"},
  };
  for (const auto& [arguments, message] : cases) {
    const std::string command = tetcosim + arguments + " 2>&1";
    const auto [status, text] = RunShell(command);
    EXPECT_NE(status, 0) << command;
    EXPECT_NE(text.find(message), std::string::npos) << command << "\n" << text;
  }
  // (nothing ran: no rollout wrote its outputs)
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "out" / "steps.csv"));
}

// A duration that is not a whole number of time steps runs the nearest
// whole number (at least one), and says so; a whole number runs silently.
TEST(Commands, ADurationOfPartStepsIsRoundedWithAWarning) {
  TempDir dir;
  const std::string run = std::string(TETCOSIM_BINARY) + " run " + TETCOSIM_SOURCE_DIR +
                          "/models/scenes/cube_on_box.xml --out " + (dir.path() / "out").string();
  const std::pair<std::string, std::string> cases[] = {
      // (cube_on_box's time step: 2 ms)
      {" --duration 0.0105",
       "--duration 0.0105 s is not a whole number of 0.002 s steps; running "
       "5 steps (0.01 s)"},
      {" --duration 0.05 --timestep 0.5",
       "--duration 0.05 s is not a whole number of 0.5 s steps; running 1 step (0.5 s)"},
      {" --duration 0.3 --timestep 0.001", ""},
      {" --duration 0.01", ""},
  };
  for (const auto& [arguments, warning] : cases) {
    const auto [status, text] = RunShell(run + arguments + " 2>&1 > /dev/null");
    EXPECT_EQ(status, 0) << arguments << "\n" << text;
    if (warning.empty()) {
      EXPECT_EQ(text.find("warning"), std::string::npos) << arguments << "\n" << text;
    } else {
      EXPECT_NE(text.find("tetcosim: warning: " + warning), std::string::npos) << arguments << "\n"
                                                                               << text;
    }
  }
}

// The proxies made for narrow geoms (<contact autoproxy>) are told: by
// info (text and JSON), check and run.
TEST(Commands, ProxiesMadeForNarrowGeomsAreListed) {
  TempDir dir;
  const std::string scene = dir.Write("ball.xml", R"(<mujoco>
  <worldbody>
    <body name="ball" pos="0 0 0.2"><freejoint/><geom name="ball" type="sphere" size="0.006"/></body>
  </worldbody>
  <deformable>
    <tetbody name="block" shape="box" size="0.05 0.05 0.05" resolution="3"/>
  </deformable>
</mujoco>)");
  const std::string tetcosim = std::string(TETCOSIM_BINARY) + " ";
  const std::string why =
      "(0.012 m wide, less than the 0.0471 m gaps between the surface vertices of tetbody 'block'";
  const std::pair<std::string, std::string> cases[] = {
      {"info " + scene, "geom         ball: a proxy of 1280 tetrahedra made for it " + why + ")"},
      {"info --json " + scene, "\"why\": \"0.012 m wide, less than"},
      {"info --json " + scene, "\"tetrahedra\": 1280"},
      {"check " + scene, "  geom ball: a proxy made for it " + why + ")"},
      {"run " + scene + " --steps 2 --out " + (dir.path() / "out").string(),
       "tetcosim: note: geom ball is given a proxy " + why + "; <contact autoproxy>)"},
  };
  for (const auto& [arguments, line] : cases) {
    const std::string command = tetcosim + arguments + " 2>&1";
    const auto [status, text] = RunShell(command);
    EXPECT_EQ(status, 0) << command << "\n" << text;
    EXPECT_NE(text.find(line), std::string::npos) << command << "\n" << text;
  }
}

// `info` tells each tetbody's contact stiffness per area and depth: the
// automatic kappa = 10 E / L (L the cube root of its volume), or its own
// `stiffness`; and what area a vertex stands for (<contact area>).
TEST(Commands, InfoTellsEachBodysContactStiffnessAndTheAreaRule) {
  TempDir dir;
  const std::string scene = dir.Write("two.xml", R"(<mujoco>
  <deformable>
    <contact area="facing"/>
    <tetbody name="auto" shape="box" size="0.05 0.1 0.2" young="2e5" resolution="2"/>
    <tetbody name="own" shape="sphere" size="0.1" pos="1 0 0" stiffness="3e6"/>
  </deformable>
</mujoco>)");
  const std::string info = std::string(TETCOSIM_BINARY) + " info ";
  const auto [status, json_text] = RunShell(info + "--json " + scene);
  ASSERT_EQ(status, 0) << json_text;
  const nlohmann::json out = nlohmann::json::parse(json_text);
  EXPECT_EQ(out["contact_area"], "facing");
  const double automatic = 10 * 2e5 / std::cbrt(0.1 * 0.2 * 0.4);
  EXPECT_NEAR(out["deformables"][0]["contact_stiffness"].get<double>(), automatic,
              1e-12 * automatic);
  EXPECT_EQ(out["deformables"][1]["contact_stiffness"].get<double>(), 3e6);
  const auto [text_status, text] = RunShell(info + scene);
  ASSERT_EQ(text_status, 0) << text;
  EXPECT_NE(text.find("method consistent, contact area facing"), std::string::npos) << text;
  EXPECT_NE(text.find("E = 100000 Pa, contact stiffness 3e+06 Pa/m"), std::string::npos) << text;
}

}  // namespace
}  // namespace tetcosim

#include "mujoco_bridge/renderer.h"

namespace tetcosim {
namespace {

TEST(Rendering, FrameIsNotBlankAndShowsTheDeformable) {
  std::unique_ptr<World> world =
      World::Load(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/cube_on_box.xml");
  world->Step();
  Renderer renderer(*world, 160, 120, "side");
  const std::vector<unsigned char> before = renderer.Render();
  ASSERT_EQ(before.size(), 160u * 120u * 3u);
  // not blank: many distinct colours
  std::set<int> colours;
  for (size_t i = 0; i < before.size(); i += 3) {
    colours.insert(before[i] << 16 | before[i + 1] << 8 | before[i + 2]);
  }
  EXPECT_GT(colours.size(), 50u);
  // move only the deformable: the image changes where it was and is
  world->deformable(0).mutable_positions().col(0).array() += 0.15;
  const std::vector<unsigned char>& after = renderer.Render();
  int changed = 0;
  for (size_t i = 0; i < before.size(); i += 3) {
    changed += std::abs(before[i] - after[i]) + std::abs(before[i + 1] - after[i + 1]) > 30;
  }
  EXPECT_GT(changed, 200) << "pixels that changed when the deformable moved";
  try {
    const Renderer unknown_camera(*world, 100, 100, "no-such-camera");
    ADD_FAILURE() << "an unknown camera was taken";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no camera named 'no-such-camera' in "), std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("cube_on_box.xml; the scene has the named cameras: 'side' "
                                         "(leave the camera out for the free view)"),
              std::string::npos)
        << e.what();
  }
}

}  // namespace

}  // namespace tetcosim

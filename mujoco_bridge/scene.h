#pragma once

// A tetcosim scene: an MJCF file whose top-level <deformable> element
// describes the soft bodies and their coupling (docs/scene-format.md). This
// file parses that element; everything else goes to MuJoCo unchanged.

#include <Eigen/Geometry>
#include <optional>
#include <string>
#include <vector>

#include "collision/penetration.h"
#include "deformable/deformable_body.h"
#include "deformable/fem_model.h"
#include "deformable/material.h"

namespace tetcosim {

// Contact parameters; unset values inherit (body from scene, scene from the
// documented defaults).
struct ContactParams {
  std::optional<double> stiffness;  // Pa/m (force per contact area per depth); default 10 E / L
  std::optional<double> damping;    // fraction of critical damping; default 0.5
  std::optional<double> friction;   // Coulomb coefficient; default 0.5
};

struct TetBodySpec {
  std::string name;
  long line = 0;
  std::string file;   // mesh file (absolute), or empty with `shape`
  std::string shape;  // box, sphere, cylinder, capsule, torus
  std::vector<double> size;
  std::vector<int> resolution;
  int split = 6;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // X_WB
  double scale = 1.0;
  Material material;
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero();
  Eigen::Vector4d rgba = Eigen::Vector4d(0.8, 0.4, 0.3, 1.0);
  bool self_collide = false;
  ContactParams contact;
};

struct RigidTetSpec {
  long line = 0;
  std::string body;  // MuJoCo body name
  std::string geom;  // one of its geoms (not a plane or height field), or empty with `file`
  std::string file;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // X_BM: mesh in the body frame
  double scale = 1.0;
  int resolution = 3;
};

struct AttachSpec {
  long line = 0;
  std::string tetbody;  // the deformable
  std::string body;     // the MuJoCo body it is glued to
  std::vector<int> vertices;
  // world frame, in the model's own pose (qpos0: World::PlaceGluedTetbodies)
  std::optional<std::pair<Eigen::Vector3d, Eigen::Vector3d>> box;  // min, max
  std::optional<std::pair<Eigen::Vector3d, double>> sphere;        // centre, radius
};

struct SolverSpec {
  int substeps = 1;
  // MuJoCo bodies in contact solved with the deformables' step (implicit on
  // both sides), or moving at their start velocity through it (explicit)
  bool implicit_rigid = true;
  // MuJoCo's constraints on those bodies linearized about their active set
  // in the step (World::LinearizeConstraints), or taken as the force MuJoCo
  // solved for them (lagged)
  bool linearize_constraints = true;
  LinearSolver linear_solver = LinearSolver::kConjugateGradient;
  double tolerance = 1e-6;
  int max_iterations = 1000;
};

// Which geoms that deformables meet get a proxy made for them without a
// <rigidtet> (<contact autoproxy>): those narrower than the gaps between a
// deformable's surface vertices (which could sink in between them and pass
// through), and round ones (spheres, ellipsoids, capsules, cylinders) up to
// several times as wide (which would sink in between them and roll over
// them as over a bed of nails); World::Load has the numbers.
enum class AutoProxies {
  kNone,            // "false"
  kNarrow,          // "narrow"
  kNarrowAndRound,  // "true" (the default)
};

struct SceneSpec {
  std::string path;  // the scene file
  std::string mjcf;  // the MJCF without <deformable>
  DepthMethod method = DepthMethod::kConsistent;
  ContactParams contact;
  // friction's smoothing velocity v_s (m/s): below it, friction grows with
  // the slip (ContactSettings); default 1e-3
  std::optional<double> slip;
  // static friction (ContactSettings::stick): contacts inside the friction
  // cone stick; false: the smooth law alone, which creeps under load
  bool stick = true;
  // the sticking spring's stiffness k_t as a fraction of the contact's
  // normal k (ContactSettings::stick_stiffness); default 1
  std::optional<double> stick_stiffness;
  // which geoms get a generated <rigidtet> (World::made_proxies)
  AutoProxies auto_proxies = AutoProxies::kNarrowAndRound;
  // what area a vertex stands for in a contact (ContactAreaOf)
  ContactArea contact_area = ContactArea::kWhole;
  SolverSpec solver;
  std::vector<TetBodySpec> tetbodies;
  std::vector<RigidTetSpec> rigidtets;
  std::vector<AttachSpec> attachments;
};

// Reads and validates the scene. Throws Error with file and line for
// unknown elements or attributes, bad values and missing files.
SceneSpec ParseScene(const std::string& path);

}  // namespace tetcosim

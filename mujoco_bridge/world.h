#pragma once

// tetcosim::World: a MuJoCo model with tetrahedral deformable bodies, coupled
// both ways. One Step() (docs/architecture.md, "A step"):
//   1. mj_step1: MuJoCo's positions, velocities and forces of the step start;
//   2. rigid proxies follow their bodies (xpos, xmat); rigid point
//      velocities from mj_objectVelocity;
//   3. collision: consistent (or closest-feature) penetration depth between
//      deformables and proxies, and between deformables and the other geoms
//      (collision/shape_depth.h with geom_shape.h; their signed distance
//      for the closest-feature method);
//   4. the deformables advance by dt (or substeps) in one coupled implicit
//      solve, with the MuJoCo trees in contact as unknowns of it too
//      (RigidSystem), which yields the contact forces actually integrated;
//   5. xfrc_applied = the user's own applied forces + the reactions of those
//      contact forces and of attachments, each turned into force plus torque
//      about the body's centre of mass xipos, world frame, from the points
//      where they acted at the step's start;
//   6. mj_step2 with those forces.
// The force on a deformable vertex is exactly opposite to what the rigid
// body receives.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "collision/penetration.h"
#include "collision/shape_depth.h"
#include "deformable/coupled_step.h"
#include "deformable/deformable_body.h"
#include "mujoco_bridge/geom_shape.h"
#include "mujoco_bridge/scene.h"

struct mjModel_;
struct mjData_;

namespace tetcosim {

struct WorldOptions {
  std::optional<DepthMethod> method;  // overrides the scene's <contact method>
  int threads = 1;
  std::optional<double> timestep;  // overrides the MJCF's <option timestep>
  // The most memory (bytes) the scene's meshes may take, estimated from
  // their tetrahedra before they are built (a load that would need more is
  // an Error naming the element); unset: what the machine has available.
  std::optional<double> memory_limit;
};

// A point of one object inside another, measured exactly on the current
// state (World::MeasureInterpenetration). Objects are numbered for metrics:
// deformable i is i, MuJoCo body b is num_deformables() + b.
struct Interpenetration {
  int inside = -1;      // the object the point belongs to
  int penetrated = -1;  // the object it is inside
  double depth = 0.0;   // m: distance to the penetrated object's surface
  Eigen::Vector3d point = Eigen::Vector3d::Zero();  // world frame
};

// Per-step figures (the last Step()).
struct StepMetrics {
  int colliding_points = 0;  // penetration results + geom contacts
  int fallback_points = 0;   // penetration results + geom contacts (kFallback)
  int unresolved_points = 0;
  double max_depth = 0.0;
  double mean_depth = 0.0;
  double collision_ms = 0.0;
  // the penetration solver's part of collision_ms, and its colliding points
  // (penetration results; colliding_points adds the geom contacts)
  double penetration_ms = 0.0;
  int penetration_points = 0;
  // proxies the penetration solver solved from what it kept of them: fixed
  // (a static body's) or moving rigidly with their body's frame
  int kept_proxies = 0;
  double deformable_ms = 0.0;
  double mujoco_ms = 0.0;
  double total_ms = 0.0;
  int solver_iterations = 0;  // conjugate-gradient iterations, over substeps and rounds
  // the linear solve's final residual relative to the step's impulse (its
  // last round, the largest over substeps), and whether it reached the
  // solver's tolerance (<solver tolerance>) within <solver maxiter>: a step
  // that did not is finite but inexact
  double solver_residual = 0.0;
  bool solver_converged = true;
  // the coupled step's solves (one without contacts, at least two with
  // them, more when contacts that would pull are released: coupled_step.h)
  // and the contacts released, over substeps
  int contact_rounds = 0;
  int released_contacts = 0;
  int stuck_contacts = 0;  // held by static friction (ContactPoint::stuck), over substeps
  StepStatus status = StepStatus::kOk;
  std::string message;  // with kDiverged: body, vertex, step; with kFailed: MuJoCo's error
};

// The whole number of steps of dt (s, > 0) in `seconds`, rounded to the
// nearest; nothing for seconds that are NaN, infinite or negative, or that
// make more than kMaxWholeSteps (2^53: where the count stops being exact in
// a double, and far beyond any run that could end): callers say which value
// was bad.
inline constexpr double kMaxWholeSteps = 9007199254740992.0;
std::optional<long> WholeSteps(double seconds, double dt);

class World {
 public:
  static std::unique_ptr<World> Load(const std::string& scene_path,
                                     const WorldOptions& options = {});
  ~World();
  World(const World&) = delete;
  World& operator=(const World&) = delete;

  // Advances everything by one MuJoCo time step. A step that cannot be
  // completed is undone and reported in metrics().status, with a message:
  // kDiverged for a deformable's velocity, position or a force on a vertex
  // not finite, or a rigid-body state MuJoCo finds bad, or would at the
  // next step (MuJoCo resets its bodies, and clears its warnings and the
  // controls, and warns); kFailed for a fatal error MuJoCo raises in the
  // step (its stack too small for the step's contacts, say: mujoco_errors.h),
  // with MuJoCo's message and what to do, after which every later Step()
  // does nothing but report the same. Undone: the world is as the step found
  // it, before the controller ran (time, positions and velocities of
  // everything, controls, applied forces, mocap poses, MuJoCo's warnings,
  // the friction springs of its contacts and the solvers' warm starts), and
  // goes on as if it had not been tried.
  void Step();
  // Called at the start of every Step(), before mj_step1: set ctrl, apply
  // forces (xfrc_applied is kept as the user left it).
  void SetController(std::function<void(World&)> controller) {
    controller_ = std::move(controller);
  }

  double time() const;
  double timestep() const;
  long steps() const { return steps_; }
  const StepMetrics& metrics() const { return metrics_; }
  const SceneSpec& scene() const { return scene_; }
  // What loading the scene noted that is not an error, a line each, with the
  // scene's line and element: a mesh's inverted tetrahedra flipped, unused
  // vertices dropped, higher-order tetrahedra read as linear. The commands
  // print them; a test may assert there are none.
  const std::vector<std::string>& load_warnings() const { return load_warnings_; }
  // MuJoCo's warnings since loading that do not stop a step (its contact or
  // constraint buffer full, so that some were dropped, and the like): what
  // each means and what to do, and how many times MuJoCo raised it. A bad
  // qpos, qvel or qacc is a kDiverged step instead.
  struct MuJoCoWarning {
    std::string what;
    int count = 0;
    bool dropped = false;  // contacts or constraints were left out: the run is wrong
  };
  std::vector<MuJoCoWarning> MuJoCoWarnings() const;

  const mjModel_* mj_model() const { return model_; }
  mjModel_* mutable_mj_model() { return model_; }
  // MuJoCo's ctrl (nu values), for controllers.
  double* controls();
  int num_controls() const;
  mjData_* mj_data() { return data_; }
  const mjData_* mj_data() const { return data_; }
  int BodyId(const std::string& name) const;
  // MuJoCo bodies 0 (world) .. num_rigid_bodies() - 1.
  int num_rigid_bodies() const;
  std::string RigidBodyName(int body) const;
  // Position (xpos) and orientation (xquat, w x y z) of a body, world frame.
  Eigen::Vector3d RigidBodyPosition(int body) const;
  Eigen::Quaterniond RigidBodyOrientation(int body) const;
  // Linear velocity of the body origin (xpos, not the centre of mass) and
  // angular velocity, world frame.
  Eigen::Vector3d RigidBodyLinearVelocity(int body) const;
  Eigen::Vector3d RigidBodyAngularVelocity(int body) const;

  int num_deformables() const { return static_cast<int>(bodies_.size()); }
  DeformableBody& deformable(int i) { return *bodies_[i]; }
  const DeformableBody& deformable(int i) const { return *bodies_[i]; }
  int DeformableIndex(const std::string& name) const;
  // A deformable's contact stiffness per area and depth, kappa (Pa/m): its
  // `stiffness`, the scene's, or the automatic 10 E / L.
  double contact_pressure_stiffness(int i) const { return kappa_[i]; }
  // What area a vertex stands for in a contact (<contact area>).
  ContactArea contact_area() const { return contact_area_; }
  const std::vector<ContactPoint>& contacts() const { return contacts_; }
  // The penetration results of the last step (its start state); they are the
  // first penetrations().size() entries of contacts(), in the same order;
  // contacts with geoms without proxies follow.
  const std::vector<PenetrationResult>& penetrations() const { return solver_.results(); }
  // The MuJoCo trees solved with the last step's deformables (RigidSystem,
  // coupled_step.h; empty with <solver rigid="explicit">), each by its root
  // body, with their predicted velocities.
  const RigidSystem& rigid_system() const { return rigid_; }
  const std::vector<int>& rigid_system_roots() const { return rigid_roots_; }
  // Per entry of contacts(): the MuJoCo body on the rigid side, or -1.
  const std::vector<int>& contact_rigid_bodies() const { return contact_rigid_body_; }
  // The collision objects of the last step: deformables 0 .. D-1, then the
  // proxies; PenetrationResult::object indexes this.
  const std::vector<CollisionObject>& collision_objects() const { return objects_; }
  int num_proxies() const { return static_cast<int>(proxies_.size()); }
  // The geoms deformables meet without proxies (geom_shape.h), in geom
  // order: its name ("rock", or "#3 of body 'arm'" for one without) and
  // how it is met ("plane", "mesh: convex hull of 14 planes", "height field
  // 41 x 41").
  struct GeomSummary {
    std::string name;
    std::string shape;
  };
  std::vector<GeomSummary> GeomsMetByShape() const;
  // The geoms given a proxy without a <rigidtet> (<contact autoproxy>, on by
  // default): geoms narrower than the gaps between a deformable's surface
  // vertices (GeomPassageWidth), and round ones less than 8 times as wide,
  // in geom order: the geom, named as GeomsMetByShape names it, why ("0.012
  // m wide, less than the 0.0471 m gaps between the surface vertices of
  // tetbody 'block'"), and its proxy's tetrahedra.
  struct MadeProxy {
    std::string geom;
    std::string why;
    int num_tets = 0;
  };
  const std::vector<MadeProxy>& made_proxies() const { return made_proxies_; }
  int ProxyBody(int proxy) const;
  // Metrics numbering (see Interpenetration) of a collision object.
  int MetricObject(int collision_object) const;
  // Exact interpenetration of the current state, method-independent: for
  // every point inside another object, its distance to that object's surface
  // (closest feature on the surface triangles; signed distance for geoms
  // without proxies). Used to judge both depth methods by the same ruler.
  std::vector<Interpenetration> MeasureInterpenetration();
  // Centre of mass (xipos) of a MuJoCo body, world frame; and whether the body
  // never moves: welded to the world, and not to a mocap body (which a
  // program moves, though MuJoCo 2.2.2 gives it no velocity).
  Eigen::Vector3d RigidBodyCenterOfMass(int body) const;
  bool RigidBodyIsStatic(int body) const;
  // Velocity of the world point p_W moving with a MuJoCo body (zero for the
  // world body), world frame, m/s.
  Eigen::Vector3d RigidBodyPointVelocity(int body, const Eigen::Vector3d& p_W) const;
  // Radius (m) about a MuJoCo body's centre of mass of a sphere that holds
  // its geoms (their bounding spheres), or, for a body without geoms, its
  // radius of gyration sqrt(trace(I) / 2m); 0 for the world body. A point of
  // its geoms moves no faster than |v_com| + |omega| times it.
  double RigidBodyRadius(int body) const;

  // Totals over deformables and MuJoCo bodies (world frame; angular momentum
  // about the world origin).
  Eigen::Vector3d LinearMomentum() const;
  Eigen::Vector3d AngularMomentum() const;
  double DeformableKineticEnergy() const;
  double RigidKineticEnergy() const;
  // Forces this world put on each MuJoCo body in the last step (nbody x 6,
  // laid out as xfrc_applied: force, then torque about xipos; world frame),
  // without the user's.
  const std::vector<double>& coupling_forces() const { return ours_; }

 private:
  World() = default;
  struct Proxy;
  // Step() but for MuJoCo's fatal errors, which it throws (MuJoCoError)
  void StepOnce();
  struct GeomContact;

  // a load warning for each pair of bodies that start deep inside each other
  void WarnOfStartingOverlaps(const std::string& scene_path);
  // Each tetbody glued to bodies (<attach>) that the first keyframe moves
  // from the model's own pose (qpos0, mocap bodies at their MJCF place),
  // moved with them, rigidly; one glued to a single body also starts with
  // its velocity (added to its own `vel`). Throws Error where the keyframe
  // moves a tetbody's bodies apart, or an <attach> names no body. Returns
  // each tetbody's move (the identity for most).
  std::vector<Eigen::Isometry3d> PlaceGluedTetbodies(const std::string& scene_path);
  // mesh's warnings, as load_warnings() gives them: where, `element`, `file`
  // (empty for a generated shape)
  void AddLoadWarnings(const TetMesh& mesh, const std::string& scene_path, long line,
                       const std::string& element, const std::string& file);
  void UpdateProxies();
  void CollectContacts(double dt);
  void AddGeomContacts(double dt);
  void BuildCollisionObjects();
  // calls visit(deformable, vertex, geom, depth, direction out of the geom)
  // for every deformable vertex inside a geom without a proxy (geom_shape.h):
  // the consistent method's depth and direction (collision/shape_depth.h),
  // or with `consistent` false, the signed distance's (the closest feature).
  // Returns how many of those points the consistent method did not reach
  // (given the signed distance instead, as its fallback).
  int ForEachGeomPenetration(
      bool consistent,
      const std::function<void(int, int, int, double, const Eigen::Vector3d&)>& visit);
  // Before a step: where the reactions of the contacts with MuJoCo bodies,
  // then of the pins, will act (reaction_points_).
  void KeepReactionPoints();
  // The rigid system of this substep (dt), its trees at substep_velocity_:
  // the trees in contact and those carrying attachments' pins.
  void BuildRigidSystem(double dt);
  void FindOtherForces();  // other_forces_, once a step
  // MuJoCo's step after mj_step1 and our forces: mj_step2, or RK4's
  void StepMuJoCoSecondPart();
  // whether the step linearizes MuJoCo's constraints (<solver constraints>)
  bool LinearizedConstraints() const;
  // MuJoCo's constraints on the trees of the rigid system, linearized about
  // their active set, as their RigidConstraints (once every tree of the
  // system is in: tree_slot_ tells which are)
  void LinearizeConstraints(double dt);
  // the constraint's rows and forces scaled for the damping MuJoCo's step
  // takes implicitly on its trees (TreeMass), with each tree's M and
  // TreeMass factorized once a substep, by its slot in rigid_
  struct DampingFactors {
    Eigen::LDLT<Eigen::MatrixXd> undamped, damped;
    bool factored = false;  // in this substep
  };
  void ScaleForDamping(RigidConstraint* constraint);
  // the rows of the constraint whose first row is `row`: an elliptic cone
  // contact's dim, else 1
  int ConstraintRows(int row) const;
  void AdvanceUnsolvedTrees(double dt);                   // (substeps)
  void MassBlock(int root, Eigen::MatrixXd* mass) const;  // the tree's block of M
  // The tree's block of the matrix MuJoCo's step integrates its velocities
  // with: M plus the time step times the joints' damping, which its Euler
  // (and implicit) integrator takes implicitly, and (implicit) the
  // actuators' rates with their velocities and the tendons' damping; for
  // RK4, which takes those explicitly at each stage, RK4's matrix for M v'
  // = f - B v
  void TreeMass(int root, Eigen::MatrixXd* mass);
  double ActuatorForceRate(int actuator) const;
  void AddRigidForce(int body, const Eigen::Vector3d& point, const Eigen::Vector3d& force);
  // The MuJoCo body that pin `pin` of deformable `deformable` follows, or
  // -1 (a fixed pin).
  int PinBody(size_t deformable, size_t pin) const;
  // Substeps (MuJoCo steps once, after them): a body's pose in this substep
  // (MuJoCo's in the first, then moved by the velocities the substeps
  // predicted); where a point of it there was at the step's start; its
  // angular velocity and its origin's velocity in this substep (MuJoCo's,
  // or its tree's as a substep predicted it); every moving body's pose
  // advanced by a substep of dt.
  Eigen::Isometry3d SubstepPose(int body) const;
  Eigen::Vector3d AtStepStart(int body, const Eigen::Vector3d& p) const;
  // The world point p_W of a MuJoCo body (where this substep has it) over a
  // (sub)step of dt: its velocity where it was at the step's start
  // (RigidBodyPointVelocity there), and how far beyond dt times that it
  // moves, per dt (ContactPoint::arc): the body turns about its origin at
  // its angular velocity (as MuJoCo turns a free body, or one on a hinge
  // through its origin), and in a later substep has turned since the step's
  // start, its point's velocity with it. Zero for the world body.
  struct PointMotion {
    Eigen::Vector3d velocity = Eigen::Vector3d::Zero();
    Eigen::Vector3d arc = Eigen::Vector3d::Zero();
  };
  PointMotion RigidPointMotion(int body, const Eigen::Vector3d& p_W, double dt) const;
  void SubstepTwist(int body, Eigen::Vector3d& omega, Eigen::Vector3d& v);
  void AdvanceSubstepPoses(double dt);
  // After MuJoCo's step: moves the trees the substeps solved as far as the
  // substeps did (see the definition).
  void FollowSubstepPaths();
  // Keeps the state a step starts from, and puts it back (Step()'s
  // "undone"); for a step MuJoCo found a bad state in, its warning
  // `bad_warning` (an mjtWarning) is then counted once more, with `info`.
  void SaveStepStart();
  void RestoreStepStart(int bad_warning = -1, int info = 0);

  SceneSpec scene_;
  WorldOptions options_;
  mjModel_* model_ = nullptr;
  mjData_* data_ = nullptr;
  std::vector<std::unique_ptr<DeformableBody>> bodies_;
  std::vector<DeformableBody*> body_pointers_;  // bodies_'s, for StepCoupled
  std::vector<std::string> load_warnings_;
  std::vector<double> kappa_;              // per deformable: contact stiffness per area and depth
  std::vector<double> mean_surface_area_;  // per deformable: MeanSurfaceVertexArea
  std::vector<double> friction_;           // per deformable
  std::vector<double> damping_;            // per deformable: damping ratio
  std::vector<std::vector<int>> attach_bodies_;  // per deformable: the body of each pin frame
  std::vector<std::unique_ptr<Proxy>> proxies_;
  std::vector<char> geom_has_proxy_;
  std::vector<MadeProxy> made_proxies_;
  std::vector<std::pair<int, GeomShape>> geom_shapes_;  // (geom, its shape): geoms met by shape
  ShapeDepthSolver geom_depth_;                         // the consistent method against geoms
  std::vector<ShapePoint> geom_points_;                 // a deformable's vertices inside one geom
  std::vector<Eigen::Vector3d> geom_box_lo_, geom_box_hi_;  // per deformable (scratch)
  PenetrationSolver solver_;
  PenetrationSolver exact_solver_;  // closest-feature, for MeasureInterpenetration
  std::vector<CollisionObject> objects_;
  std::vector<ContactPoint> contacts_;
  std::vector<int> contact_rigid_body_;  // per contact: MuJoCo body on the rigid side, or -1
  // Static friction: a contact is the same from step to step while the same
  // point is inside the same object or geom, and its friction spring
  // (ContactPoint::stick) carries over (springs_, sorted by key). A key:
  // the point's collision object in objects_ (or its deformable, against a
  // geom), its vertex, the penetrated collision object (or -1 - the geom).
  // A spring is kept in the frame of what the point is inside (B) and turns
  // with it: B's body, or the rotation of B's tetrahedron under the point
  // (PenetratedFrame, contact_frame_ when the contacts were collected).
  using ContactKey = std::array<int, 3>;
  std::vector<ContactKey> contact_key_;            // per contact
  std::vector<Eigen::Quaterniond> contact_frame_;  // per contact
  std::vector<std::pair<ContactKey, Eigen::Vector3d>> springs_;
  Eigen::Quaterniond PenetratedFrame(size_t contact) const;
  void RestoreFrictionSprings();
  void KeepFrictionSprings();
  std::vector<Eigen::Vector3d> reaction_points_;  // see KeepReactionPoints
  // MuJoCo's trees (by root body): first DoF and count; this substep's
  // trees in the rigid system (BuildRigidSystem) and each root's slot among them
  std::vector<int> tree_first_dof_;
  std::vector<int> tree_num_dofs_;
  // per root body: MuJoCo's step takes more than M for its tree (TreeMass)
  std::vector<char> tree_damped_;
  // MuJoCo's implicit or RK4 step takes actuators' rates or tendons'
  // damping with the joints' (TreeMass)
  bool damps_velocity_terms_ = false;
  std::vector<int> tree_slot_;
  std::vector<int> rigid_roots_;
  RigidSystem rigid_;
  CoupledStepWorkspace step_workspace_;
  // kept from step to step: ScaleForDamping's factors (by slot in rigid_)
  // and solution, a tree's block of M and its factors, TreeMass's tendon
  // moment arms
  std::vector<DampingFactors> damping_factors_;
  std::vector<double> damping_solution_;
  Eigen::MatrixXd mass_block_;
  Eigen::LDLT<Eigen::MatrixXd> mass_factor_;
  // TreeMass's under RK4
  Eigen::LDLT<Eigen::MatrixXd> rk4_factor_;
  Eigen::MatrixXd rk4_damping_, rk4_inverse_, rk4_x_, rk4_product_, rk4_p_;
  std::vector<double> tendon_arms_;
  std::vector<double> jacobian_;      // 3 x nv, row-major
  std::vector<double> other_forces_;  // nv
  // each MuJoCo constraint's trees (their root bodies; -1: none, -2: three
  // or more), at its first row (ConstraintRows; FindOtherForces, with the
  // rows linearized)
  std::vector<std::array<int, 2>> row_trees_;
  // nefc: J qacc, each row's rate at MuJoCo's solution (FindOtherForces)
  std::vector<double> constraint_rates_;
  // nv: the generalized velocities a substep's trees start at: MuJoCo's at
  // the step's start, each tree's as the last substep that solved it
  // predicted (MuJoCo steps once, after the substeps: its velocities stay
  // those of the step's start)
  std::vector<double> substep_velocity_;
  // nv: other_forces_ solved with each tree's TreeMass (substeps)
  std::vector<double> free_acceleration_;
  bool free_acceleration_ready_ = false;
  std::vector<char> tree_carried_;  // per root body: substep_velocity_ is a substep's
  // per root body: a substep of this step solved the tree (RigidSystem)
  std::vector<char> tree_solved_;
  // nv: the sum over this step's substeps of dt times substep_velocity_ at
  // each one's end: how far the substeps moved the bodies (FollowSubstepPaths
  // turns it into what is left to move them after MuJoCo's step)
  std::vector<double> substep_path_;
  std::vector<double> kept_qpos_;                // nq: see FollowSubstepPaths
  std::vector<Eigen::Isometry3d> substep_pose_;  // per body: see SubstepPose
  std::vector<char> substep_moved_;  // per body: substep_pose_ holds its pose (0 between steps)
  std::vector<double> rotation_jacobian_;  // 3 x nv, row-major
  std::vector<double> ours_;               // nbody x 6, written last step
  std::vector<double> user_;               // nbody x 6, the user's part of xfrc_applied
  std::vector<double> written_;            // nbody x 6, xfrc_applied as written last step
  std::vector<double> accumulated_;        // nbody x 6, this step
  // the state the step started from (SaveStepStart): MuJoCo's time, its
  // arrays mj_resetData sets (StateArrays) one after another, its warnings
  // (number and lastinfo of each), and the deformables' memories; with
  // ours_, user_, written_ and springs_
  struct StepStart {
    double time = 0.0;
    std::vector<double> mujoco;
    std::vector<int> warnings;
    std::vector<DeformableBody::Memory> deformables;
    std::vector<double> ours, user, written;
    std::vector<std::pair<ContactKey, Eigen::Vector3d>> springs;
  };
  StepStart step_start_;
  // whether other_forces_ holds this step's (MuJoCo's state does not change
  // between substeps: found once a step)
  bool other_forces_ready_ = false;
  std::function<void(World&)> controller_;
  StepSettings step_settings_;
  ContactSettings contact_settings_;
  ContactArea contact_area_ = ContactArea::kWhole;  // <contact area>
  StepMetrics metrics_;
  long steps_ = 0;
  std::string failure_;  // kFailed's message, once MuJoCo failed a step
};

}  // namespace tetcosim

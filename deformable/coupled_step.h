#pragma once

// One backward-Euler step of several deformable bodies coupled through their
// contacts, solved as one linear system so that contact forces stay exactly
// equal and opposite (total momentum is conserved up to the solver's
// tolerance). Each contact c couples the relative velocity at the contact,
//   u_c = J_c v + c_c   (A's vertex minus B's barycentric point, a rigid
//                        side solved with the step (RigidSystem below) as
//                        its point's J_r q; c_c holds the known point
//                        velocity of a rigid side that is not),
// and its force is integrated as
//   f_c(v+) = f_c - K_c dt u_c(v+) - D_c (J_c v+ - J_c v),
// giving
//   [A_bodies + sum_c J_c^T (dt^2 K_c + dt D_c) J_c] v+
//       = b_bodies + dt sum_c J_c^T (f_c - dt K_c c_c + D_c J_c v).
// Solved for the velocity change by block-Jacobi-preconditioned conjugate
// gradients, filtered on pinned degrees of freedom (Baraff and Witkin 1998),
// warm-started from each body's last change.
//
// A penalty contact pushes and never pulls. Linearized, f_c(v+) pulls when
// the depth runs out within the step: bodies parting, or a body sliding
// under a contact direction that the smooth normals tilt near an edge (the
// depth of a vertex under a flat face does not change as it slides, the
// linearization along a tilted direction says it does). Left in, such
// contacts glued parting bodies for a step and held a block sliding over a
// proxy's vertex at a standstill. So a contact whose integrated force would
// pull is released (no force at all) and the step solved again; a released
// one that would then push is taken back, and kept. The first guess is the
// sign at the warm start; rounds solve to kSettlingTolerance until no
// contact changes, then once to the settings' tolerance. From the
// kMaxContactRounds-th solve on, contacts are only relaxed until none
// changes: one that pulls and so adds energy is released, a sliding one
// whose friction drives its slip sticks (so a step whose contacts have not
// settled does not end with forces that add energy).
// After the step, every contact's `force` is the force actually
// integrated (what a rigid side must receive, opposite; zero if
// released).
//
// Static friction (contact.h, ContactSettings::stick) is decided the same
// way: a contact with friction first sticks unless its force at the warm
// start leaves the friction cone (it then slides, along the sticking force
// at the step's start velocities: its slip's way); one whose integrated
// force leaves the cone slides from the next round on, Coulomb's force
// along that force; a sliding one that the solution turns around sticks
// again (at most three switches a contact, the last to sliding); and a
// sliding contact's force follows the normal force each solution
// integrates (to kSlidingForceTolerance). After the step each contact's
// `stick` holds its friction spring for the next.

#include <array>
#include <memory>
#include <span>
#include <vector>

#include "deformable/contact.h"
#include "deformable/deformable_body.h"

namespace tetcosim {

struct CoupledStepReport {
  StepStatus status = StepStatus::kOk;
  int bad_body = -1;  // with kDiverged: the body and vertex
  int bad_vertex = -1;
  int iterations = 0;         // CG iterations, over all rounds
  double residual = 0.0;      // relative, of the last round
  int rounds = 1;             // solves
  int released_contacts = 0;  // left without force after the last round
  int stuck_contacts = 0;     // held by static friction (ContactPoint::stuck)
};

// Rigid bodies solved with the step. A rigid side that keeps its velocity
// through the step and takes the integrated force after it (explicit) is
// stable only while dt sqrt(k / m) stays below about 2 for the contact's
// stiffness k and the body's mass m at the point, which a stiff body's
// contacts or the smooth friction law's steep slope (mu f_n / v_s) on a
// light body break: a rigid ball on a stiff slab flew off. Here the rigid
// bodies' generalized velocities (a free body's six, a mechanism's joint
// velocities) are unknowns of the same system, tree by tree, with the
// tree's block of the mass matrix; a contact's rigid point moves at J x.
// The step then integrates each contact's force implicitly on both sides;
// the caller applies it to the rigid bodies (their own solver steps them,
// with whatever else acts on them, which the prediction here leaves out
// beyond `impulse`).
//
// A constraint of the rigid bodies' own solver on one tree or between two,
// linearized about its state at the step's start: the force of each of its
// rows is D (aref - J a), a the trees' accelerations over the step
// (MuJoCo's constraint rows in their quadratic state, D their efc_D, aref
// their efc_aref), so it adds J^T D J to the trees' mass (between two
// trees, coupling them) and dt J^T D aref to their impulse. A unilateral
// one (a contact's, a joint limit's) only pushes: it starts in the state
// the rigid solver's solution at the step's start has it in
// (start_residual); where a solution has it pull, it is released (no
// force), as the rigid solver will find it released, and taken back where
// it then pushes, as the rigid solver's active set does
// (kMaxConstraintSwitches times at most). (Held, a joint limit under a lid
// struck from below held the lid to it in the prediction, and the lid took
// the blow of a body that had stopped against it as against a heavy one.)
// A contact in an elliptic friction cone is one constraint of its normal
// row and its friction rows, in the zone of the cone a solution puts it in
// (with r the rows' J a - aref, N = mu r_0 and T the norm of the friction
// rows' r_j scaled by their coefficients): released in the top zone (no
// force: N >= mu T); in the bottom zone (sticking: mu N + T <= 0) each
// row's force is D (aref - J a) as above; in the middle zone (sliding) the
// force lies on the cone's surface, the rigid solver's -d/dr of
// 0.5 Dm (N - mu T)^2 (Dm = D_0 / (mu^2 (1 + mu^2))), which is not linear:
// the step takes it linearized about a solution, f + H (r_0 - r) with
// H = -df/dr at r_0 (positive semidefinite: the cost is convex), and
// linearizes it again about each solution whose force differs from that
// line's by more than kConeForceTolerance (Newton's method over the
// rounds, kMaxConeLinearizations times at most). A friction loss row (a
// joint's or tendon's dry friction) pushes either way: D (aref - J a)
// while |r| < friction_loss / D, else friction_loss against r (sliding, a
// constant force), switched as a solution moves it between the three.
// The most rows a RigidConstraint has (an elliptic cone contact's, condim 6)
inline constexpr int kMaxConstraintRows = 6;
// A value per row of a RigidConstraint, held inline (no heap storage); room
// for 8 rather than kMaxConstraintRows, whole packets of four (with 6,
// GCC's -Warray-bounds takes a norm over 5 rows for reads past the end)
using ConstraintVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 8, 1>;

struct RigidConstraint {
  enum class Kind { kEquality, kUnilateral, kEllipticCone, kFrictionLoss };
  // the trees it acts on (RigidSystem::trees): trees[1] < 0 for one
  std::array<int, 2> trees = {-1, -1};
  // rows x (n_0 + n_1): J, the rates of its rows from the velocities of
  // trees[0], then of trees[1] (one row, or an elliptic cone contact's
  // normal row then its 1 to 5 friction rows)
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> jacobian;
  ConstraintVector mass;       // per row: D (> 0)
  ConstraintVector reference;  // per row: aref
  Kind kind = Kind::kEquality;
  // kEllipticCone: per row, the scale into the cone's space: mu for the
  // normal row, then each friction row's coefficient
  ConstraintVector cone;
  double friction_loss = 0.0;  // kFrictionLoss: the most force it exerts
  // A unilateral one's rows' J a - aref at the rigid solver's solution at
  // the step's start, which sets the state the step starts it in: a row
  // released where it is > 0; a cone contact in its zone, and linearized
  // about it in the middle zone; a friction loss row in its state. Empty:
  // held.
  ConstraintVector start_residual;
  bool released = false;  // out: released by the step
  // out: kEllipticCone in the cone's middle zone, kFrictionLoss at its
  // constant force
  bool sliding = false;
  int switches = 0;  // out: how often the step released it or took it back
};
struct RigidTree {
  Eigen::MatrixXd mass;          // n x n (n: the tree's degrees of freedom), positive definite
  Eigen::VectorXd velocity;      // n, at the step's start
  Eigen::VectorXd impulse;       // n, dt x the other generalized forces (gravity, bias, springs)
  Eigen::VectorXd velocity_end;  // out: n, at the step's end as the step predicts it
};
struct RigidPoint {
  int tree = -1;
  // 3 x n: the world velocity of the contact's point on the body from the
  // tree's generalized velocities
  Eigen::Matrix<double, 3, Eigen::Dynamic> jacobian;
};
// A pinned vertex carried by a rigid body solved with the step (an
// attachment): its velocity at the step's end is J q+ + (p - J q), with J
// its point's Jacobian, q and q+ the tree's velocities at the step's start
// and end, and p its pin velocity (DeformableBody::PinVelocity), so that it
// moves with the body as the pin says and the body takes the deformable's
// inertia and stiffness within the step. (Its force reaching the body only
// after the step, a body lighter than about three times the deformable
// diverged, at any time step.) The system is solved for the free vertices
// and the trees: with v = T y + c (T: the identity but on these vertices,
// which it sets to J y's tree part; c: p - J q on them), T^T A T y =
// T^T (b - A c).
struct RigidPin {
  int body = -1;   // the deformable
  int pin = -1;    // its pinned vertex pinned_vertices()[pin], a kinematic pin
  int point = -1;  // the vertex's point on the rigid body, in RigidSystem::points
};
struct RigidSystem {
  std::vector<RigidTree> trees;
  std::vector<RigidPoint> points;  // ContactPoint::rigid_point and RigidPin::point index this
  std::vector<RigidPin> pins;
  std::vector<RigidConstraint> constraints;

  // For a caller that builds the system anew every step without allocating
  // once warm: Clear() empties it but keeps the arrays of its trees, points
  // and constraints, and each Add* appends an element as default-constructed
  // but for arrays taken from those kept (an array then reallocates only
  // where its new size differs).
  void Clear();
  RigidTree& AddTree();
  RigidPoint& AddPoint();
  RigidConstraint& AddConstraint();

 private:
  std::vector<RigidTree> spare_trees_;
  std::vector<RigidPoint> spare_points_;
  std::vector<RigidConstraint> spare_constraints_;
};

// Solves per step in which contacts may change any way; from the last of
// them on, they are only relaxed (released, or made to stick), each at
// most twice.
inline constexpr int kMaxContactRounds = 8;
// How often a rigid tree's unilateral constraint may be released or taken
// back in a step (RigidConstraint).
inline constexpr int kMaxConstraintSwitches = 4;
// An elliptic cone contact sliding in a step (RigidConstraint) is
// linearized again about a solution where its force there differs from the
// linearized one by more than this share, at most kMaxConeLinearizations
// times.
inline constexpr double kConeForceTolerance = 1e-4;
inline constexpr int kMaxConeLinearizations = 8;
// The relative residual of the solves that only settle which contacts push.
inline constexpr double kSettlingTolerance = 1e-3;
// A sliding contact's friction is set again (and the step solved again)
// when the normal force a solve integrates differs from the one it took by
// more than this share.
inline constexpr double kSlidingForceTolerance = 0.01;
// Up to this many rigid degrees of freedom in a step, the preconditioner
// eliminates them exactly (a dense Schur complement over the vertices'
// blocks); beyond, each tree's block alone.
inline constexpr int kMaxEliminatedRigidDofs = 120;

// The arrays StepCoupled works in, kept from one step to the next by a
// caller that passes the same workspace each step: a step then allocates
// only where a size grows beyond what the workspace has held (more
// contacts, constraints or trees than before) or an array's size changes
// (the degrees of freedom in the system: trees joining or leaving it). Its
// contents mean nothing between steps. Not to be shared by two steps at
// once.
class CoupledStepWorkspace {
 public:
  CoupledStepWorkspace();
  ~CoupledStepWorkspace();
  CoupledStepWorkspace(CoupledStepWorkspace&&) noexcept;
  CoupledStepWorkspace& operator=(CoupledStepWorkspace&&) noexcept;

  struct Arrays;  // (coupled_step.cc)
  Arrays& arrays() { return *arrays_; }

 private:
  std::unique_ptr<Arrays> arrays_;
};

// `rigid` (may be null) holds the trees and points of contacts with
// rigid_point >= 0, and the pins its trees carry. `workspace` (may be
// null: the step makes its own) is the caller's CoupledStepWorkspace.
// A body whose new velocities or positions, or whose solve's residual (a
// non-finite force), are not finite at a vertex is not committed, and the
// report names the first such body and vertex (kDiverged); the other
// bodies are. A caller that must undo the whole step keeps each body's
// DeformableBody::Memory (World::Step does).
CoupledStepReport StepCoupled(std::span<DeformableBody* const> bodies,
                              std::span<ContactPoint> contacts,
                              const ContactSettings& contact_settings, const StepSettings& settings,
                              RigidSystem* rigid = nullptr,
                              CoupledStepWorkspace* workspace = nullptr);

}  // namespace tetcosim

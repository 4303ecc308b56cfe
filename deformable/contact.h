#pragma once

// Penalty contact response (Heidelberger et al. 2004, section 4; method.md,
// "Collision response"): a point A inside B at depth d along the unit
// direction r (out of B) gets
//   normal    f_n = k d + c max(0, -v_n),  v_n = (v_A - v_B) . r,  c = 2 zeta sqrt(k m)
//   friction  f_t = -mu f_n v_t / sqrt(|v_t|^2 + v_s^2)   (smooth Coulomb, |f_t| < mu f_n)
//             or, with static friction (ContactSettings::stick, below),
//             sticking  f_t = -k_t s - c_t v_t
//             sliding   f_t = mu f_n+ t   (t: a unit tangent, the way the sticking force pulled;
//                                          f_n+ the normal force the step integrates)
//   force on A = f_n r + f_t,  on B the opposite
// where v_B is B's velocity at the point (the barycentric velocity of B's
// containing tetrahedron, or a rigid body's point velocity) and m the
// reduced mass of the pair. On a deformable B the reaction is spread over
// the containing tetrahedron's vertices by barycentric weights w_i.
// Derivatives for the implicit step (positive semi-definite, with respect to
// the relative position and velocity; coupled_step.h integrates them):
//   stiffness  -df/dx = k r r^T  [+ k_t (I - r r^T) sticking]
//   damping    -df/dv = c r r^T [approaching]
//                       + mu f_n / sqrt(|v_t|^2 + v_s^2) (I - r r^T)  [smooth]
//                       + c_t (I - r r^T)                            [sticking]
//
// Static friction: the smooth law alone holds a loaded contact only while
// it slips, at v_s q / sqrt(1 - q^2) for a load q mu f_n, so a body that
// friction should hold creeps (0.58 mm/s at half the friction angle). With
// ContactSettings::stick, friction is elastoplastic instead (a spring and a
// slider, as in the friction models of Dahl or Kikuuwe et al. 2006, and
// return mapping in plasticity): a sticking contact is a tangential spring,
// s the elastic tangential displacement of A against B since it stuck,
// integrated with the step (s+ = (I - r r^T)(s + dt (v_t+ + arc)), the
// arc a turning rigid side's: ContactPoint::arc), k_t =
// stick_stiffness k and c_t = 2 zeta sqrt(k_t m); so a held body's
// relative velocity goes to zero. A contact whose sticking force would
// leave the cone |f_t| <= mu f_n slides instead: Coulomb's mu f_n, along the
// sticking force it replaces (the trial force projected onto the cone), a
// constant force through the step (no derivative) at the normal force the
// step integrates; s is then where the spring holds that force. A sliding
// contact that the step would turn around sticks instead. coupled_step.h
// decides, in the rounds of its solve; the caller keeps s from step to
// step (ContactPoint::stick), turning it with B (s is a displacement from a
// point of B's: World::PenetratedFrame).

#include <Eigen/Core>
#include <span>

#include "deformable/deformable_body.h"

namespace tetcosim {

struct ContactPoint {
  // A: the point that is inside. A deformable vertex (body_a >= 0), or a
  // point of a rigid body (body_a = -1) moving at velocity_a.
  int body_a = -1;
  int vertex_a = -1;
  Eigen::Vector3d velocity_a = Eigen::Vector3d::Zero();  // m/s, rigid A only
  double mass_a = 0.0;  // kg, rigid A only: the body's mass (<= 0: B's mass alone)
  // B: what A is inside. A deformable tetrahedron (body_b >= 0) with A's
  // barycentric coordinates in it, or a rigid or static body (body_b = -1)
  // whose point under A moves at velocity_b.
  int body_b = -1;
  int tet_b = -1;
  Eigen::Vector4d barycentric_b = Eigen::Vector4d::Zero();
  Eigen::Vector3d velocity_b = Eigen::Vector3d::Zero();  // m/s, rigid or static B only
  double mass_b = 0.0;  // kg, rigid B only (<= 0: infinite, static)
  // A turning rigid side's point moves over the step along an arc, not
  // along its velocity: how far beyond dt times its velocity, per dt (m/s),
  // A's minus B's. A part of the relative motion the step integrates (the
  // contact's depth and friction spring at the step's end), not of its
  // damping. Zero: straight (deformable sides; a body that does not turn).
  Eigen::Vector3d arc = Eigen::Vector3d::Zero();
  // The rigid side (A or B) solved with the step: its entry in
  // RigidSystem::points (coupled_step.h), whose velocities are unknowns of
  // the step like the deformables'; -1: the rigid side keeps velocity_a or
  // velocity_b through the step and takes the force after it.
  int rigid_point = -1;
  // geometry and material
  double depth = 0.0;                                    // m, >= 0
  Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();  // unit, out of B
  double stiffness = 0.0;                                // k, N/m
  double friction = 0.0;                                 // mu
  double damping_ratio = 0.5;  // zeta: fraction of critical damping on approach
  // static friction (ContactSettings::stick): the friction spring's
  // tangential displacement s (m, world frame, in the plane normal to
  // `direction`): in, the contact's s at the end of the step before (zero
  // for a new contact); out, at the end of this one
  Eigen::Vector3d stick = Eigen::Vector3d::Zero();
  // result: the force on A (newtons, world frame); B receives -force
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  bool stuck = false;  // result: friction held the contact (it stuck) this step
};

struct ContactSettings {
  double slip_velocity = 1e-3;   // v_s, m/s: the smooth law's (stick false) smoothing slip
  bool stick = true;             // static friction: a contact inside the cone sticks
  double stick_stiffness = 1.0;  // k_t / k: the sticking spring's stiffness, of the normal's
};

// A contact's force at the current state and its derivatives (see above),
// with the relative velocity at the contact and the constant part of the
// relative motion over the step (per dt): rigid or static sides' velocities
// (not a rigid side solved with the step, rigid_point >= 0) and the arcs
// (ContactPoint::arc).
struct ContactLinearization {
  Eigen::Vector3d force;              // on A
  Eigen::Matrix3d stiffness;          // -df/dx (relative position)
  Eigen::Matrix3d damping;            // -df/dv (relative velocity)
  Eigen::Vector3d relative_velocity;  // v_A - v_B
  Eigen::Vector3d rigid_velocity;     // constant: rigid/static sides and arcs
};
// The part of u in the plane normal to the unit `normal`: (I - n n^T) u,
// a contact's tangential part of a velocity, a force or a friction spring.
inline Eigen::Vector3d Tangential(const Eigen::Vector3d& u, const Eigen::Vector3d& normal) {
  return u - u.dot(normal) * normal;
}

// Which friction law a contact follows in a step (above): smooth, or with
// static friction sticking or sliding.
enum class FrictionLaw { kSmooth, kSticking, kSliding };
// (sliding: `slide` is the friction force on A, mu f_n t)
ContactLinearization LinearizeContact(std::span<DeformableBody* const> bodies,
                                      const ContactPoint& contact, const ContactSettings& settings,
                                      FrictionLaw law = FrictionLaw::kSmooth,
                                      const Eigen::Vector3d& slide = Eigen::Vector3d::Zero());

// The default contact stiffness per unit area and depth (Pa/m) of a body:
// kappa = 10 E / L with L = (volume)^(1/3). A vertex standing for area a gets
// k = kappa a, so the resting depth under a load p (Pa) is p / kappa, the
// same at every mesh resolution; for a block of height H resting on its base,
// d = rho g H L / (10 E) (0.1 mm for 10 cm of E = 1e5 Pa). The time step does
// not enter: contact is integrated implicitly and stays stable for any k.
double DefaultContactPressureStiffness(const FemModel& model);

// Contacts of body `index` with the static half-space n . x <= offset (n
// unit, pointing out of the solid): one per vertex below the plane, with
// stiffness kappa * contact area (by `rule`, ContactAreaOf).
void AddHalfSpaceContacts(int index, const DeformableBody& body, const Eigen::Vector3d& normal,
                          double offset, double kappa, double friction,
                          std::vector<ContactPoint>& contacts,
                          ContactArea rule = ContactArea::kWhole);

}  // namespace tetcosim

#pragma once

// One backward-Euler step of several deformable bodies coupled through their
// contacts, solved as one linear system so that contact forces stay exactly
// equal and opposite (total momentum is conserved up to the solver's
// tolerance). Each contact c couples the relative velocity at the contact,
//   u_c = J_c v + c_c   (A's vertex minus B's barycentric point; c_c holds a
//                        rigid side's known point velocity),
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
// contact changes, then once to the settings' tolerance, at most
// kMaxContactRounds solves. After the step, every contact's `force` is the
// force actually integrated (what a rigid side must receive, opposite;
// zero if released).

#include <span>

#include "deformable/contact.h"
#include "deformable/deformable_body.h"

namespace tetcosim {

struct CoupledStepReport {
  StepStatus status = StepStatus::kOk;
  int bad_body = -1;  // with kDiverged: the body and vertex
  int bad_vertex = -1;
  int iterations = 0;     // CG iterations, over all rounds
  double residual = 0.0;  // relative, of the last round
  int rounds = 1;         // solves
  int released_contacts = 0;
};

// Solves per step at most: after the last, contacts are kept as they are.
inline constexpr int kMaxContactRounds = 8;
// The relative residual of the solves that only settle which contacts push.
inline constexpr double kSettlingTolerance = 1e-3;

CoupledStepReport StepCoupled(std::span<DeformableBody* const> bodies,
                              std::span<ContactPoint> contacts,
                              const ContactSettings& contact_settings,
                              const StepSettings& settings);

}  // namespace tetcosim

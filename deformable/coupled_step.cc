#include "deformable/coupled_step.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <utility>

#include "mesh/parallel_for.h"
#include "mesh/vector_room.h"

namespace tetcosim {
namespace {

// The bodies that run their own loops on one thread are shared out among
// the step's threads from this many tetrahedra per thread (fewer: a
// parallel region costs more than the work it shares out).
constexpr long kMinSharedTetsPerThread = 1024;

// a contact's coupling: u = J v + c, J = [+1 at A's vertex, -w_i at B's,
// +-J_r on a rigid side's tree]
struct Coupling {
  int dof_a = -1;  // first global DoF of A's vertex, or -1
  std::array<int, 4> dof_b{-1, -1, -1, -1};
  Eigen::Vector4d w = Eigen::Vector4d::Zero();
  int rigid_offset = -1;  // first global DoF of a rigid side's tree, or -1
  const Eigen::Matrix<double, 3, Eigen::Dynamic>* rigid_jacobian = nullptr;
  double rigid_sign = 0.0;                             // +1: the rigid side is A, -1: B
  Eigen::Matrix3d gain;                                // dt^2 K + dt D
  Eigen::Vector3d Jv_start = Eigen::Vector3d::Zero();  // J v at the start of the step
  bool active = true;                                  // false: released (its force would pull)
  bool taken_back = false;  // released, then active again: kept from then on
  Eigen::Vector3d Jv(const VectorXdWithRoom& v) const {
    Eigen::Vector3d u = Eigen::Vector3d::Zero();
    if (dof_a >= 0) u += v.segment<3>(dof_a);
    for (int i = 0; i < 4; ++i) {
      if (dof_b[i] >= 0) u -= w[i] * v.segment<3>(dof_b[i]);
    }
    if (rigid_jacobian) {
      u += rigid_sign * (*rigid_jacobian) * v.segment(rigid_offset, rigid_jacobian->cols());
    }
    return u;
  }
  void AddJt(const Eigen::Vector3d& g, VectorXdWithRoom& y) const {
    if (dof_a >= 0) y.segment<3>(dof_a) += g;
    for (int i = 0; i < 4; ++i) {
      if (dof_b[i] >= 0) y.segment<3>(dof_b[i]) -= w[i] * g;
    }
    if (rigid_jacobian) {
      // noalias: J^T g straight into y (a temporary otherwise, allocated)
      y.segment(rigid_offset, rigid_jacobian->cols()).noalias() +=
          rigid_sign * rigid_jacobian->transpose() * g;
    }
  }
};

// a pinned vertex carried by a rigid tree (RigidPin): v = J q + constant
struct Slave {
  int dof = -1;           // first global DoF of the vertex
  int rigid_offset = -1;  // first global DoF of the tree
  const Eigen::Matrix<double, 3, Eigen::Dynamic>* jacobian = nullptr;
  Eigen::Vector3d constant = Eigen::Vector3d::Zero();  // its pin velocity - J q at the start
  int tree = -1;
};

// the vectors ConjugateGradients works in
struct CgVectors {
  VectorXdWithRoom z, p, q;
};

// Filtered, preconditioned conjugate gradients on A x = b from x (Baraff
// and Witkin 1998: the filter zeroes the pinned degrees of freedom, whose
// values x holds), until the filtered residual r is at most `threshold` or
// after max_iterations. Ax = A x is tracked through the iterations, so that
// the final residual needs no extra product; with Ax_given, Ax holds it
// already at the start. Returns the iterations.
template <typename Multiply, typename Precondition, typename Filter>
int ConjugateGradients(const Multiply& multiply, const Precondition& precondition,
                       const Filter& filter, const VectorXdWithRoom& b, double threshold,
                       int max_iterations, VectorXdWithRoom& x, VectorXdWithRoom& Ax,
                       VectorXdWithRoom& r, CgVectors& vectors, bool Ax_given = false) {
  const Eigen::Index n = b.size();
  VectorXdWithRoom& z = vectors.z;
  VectorXdWithRoom& p = vectors.p;
  VectorXdWithRoom& q = vectors.q;
  z.resize(n);
  p.resize(n);
  q.resize(n);
  if (!Ax_given) multiply(x, Ax);
  r = b - Ax;
  filter(r);
  precondition(r, z);
  filter(z);
  p = z;
  double rz = r.dot(z);
  int iteration = 0;
  while (r.norm() > threshold && iteration < max_iterations) {
    multiply(p, q);              // p is zero on pinned DoFs
    const double pq = p.dot(q);  // = p^T A p (filtering q would not change it)
    if (!(pq > 0.0)) break;      // not positive definite along p (or NaN): stop
    const double alpha = rz / pq;
    x += alpha * p;
    Ax += alpha * q;
    filter(q);
    r -= alpha * q;
    precondition(r, z);
    filter(z);
    const double rz_next = r.dot(z);
    p = z + (rz_next / rz) * p;
    rz = rz_next;
    ++iteration;
  }
  return iteration;
}

// work = C x on the vertices in `touched` (zero elsewhere there): the
// vertex-rigid blocks of the rigid contacts' J^T G J times x's rigid part
void MultiplyRigidToVertices(const std::vector<const Coupling*>& couplings,
                             const VectorXdWithRoom& x, const std::vector<int>& touched,
                             VectorXdWithRoom& work) {
  for (int block : touched) work.segment<3>(3 * block).setZero();
  for (const Coupling* coupling : couplings) {
    const auto& J = *coupling->rigid_jacobian;
    const Eigen::Vector3d g =
        coupling->gain * (coupling->rigid_sign * J * x.segment(coupling->rigid_offset, J.cols()));
    if (coupling->dof_a >= 0) work.segment<3>(coupling->dof_a) += g;
    for (int i = 0; i < 4; ++i) {
      if (coupling->dof_b[i] >= 0) work.segment<3>(coupling->dof_b[i]) -= coupling->w[i] * g;
    }
  }
}

// out = C^T y (the rigid degrees of freedom, from n_deformable on)
void MultiplyVerticesToRigid(const std::vector<const Coupling*>& couplings,
                             const VectorXdWithRoom& y, int n_deformable, VectorXdWithRoom& out) {
  out.setZero();
  for (const Coupling* coupling : couplings) {
    Eigen::Vector3d u = Eigen::Vector3d::Zero();
    if (coupling->dof_a >= 0) u += y.segment<3>(coupling->dof_a);
    for (int i = 0; i < 4; ++i) {
      if (coupling->dof_b[i] >= 0) u -= coupling->w[i] * y.segment<3>(coupling->dof_b[i]);
    }
    const auto& J = *coupling->rigid_jacobian;
    out.segment(coupling->rigid_offset - n_deformable, J.cols()).noalias() +=
        coupling->rigid_sign * J.transpose() * (coupling->gain * u);
  }
}

// a RigidConstraint's rows x rows matrix (held inline: no heap storage)
using ConstraintMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0,
                                       kMaxConstraintRows, kMaxConstraintRows>;

// Coulomb's limit on the friction of a contact whose force on A is `force`,
// mu f_n (f_n its normal part, or 0 where it pulls)
double FrictionLimit(const Eigen::Vector3d& force, const ContactPoint& contact) {
  return contact.friction * std::max(0.0, force.dot(contact.direction));
}

// whether a contact's force on A lies in its friction cone, |f_t| <= mu f_n
bool InsideFrictionCone(const Eigen::Vector3d& force, const ContactPoint& contact) {
  return Tangential(force, contact.direction).norm() <= FrictionLimit(force, contact);
}

// The side of a friction loss row (RigidConstraint) whose J a - aref is r:
// -1 where its force is +friction_loss (r <= -friction_loss / D), 1 where
// it is -friction_loss, 0 where it is D (aref - J a)
int FrictionLossSide(const RigidConstraint& constraint, double r) {
  const double limit = constraint.friction_loss / constraint.mass[0];
  return r <= -limit ? -1 : (r >= limit ? 1 : 0);
}

enum class ConeZone { kBottom, kMiddle, kTop };

// The zone of an elliptic cone contact (RigidConstraint) whose rows have
// J a - aref = r, as the rigid solver's: with u = cone r, N = u_0 and T the
// norm of the rest, the top (no force) where N >= mu T, the bottom (each
// row quadratic) where mu N + T <= 0
ConeZone Zone(const RigidConstraint& constraint, const ConstraintVector& r) {
  const ConstraintVector u = constraint.cone.cwiseProduct(r);
  const double mu = constraint.cone[0];
  const double normal = u[0];
  const double tangential = u.tail(u.size() - 1).norm();
  if (normal >= mu * tangential || (tangential <= 0.0 && normal >= 0.0)) return ConeZone::kTop;
  if (mu * normal + tangential <= 0.0 || (tangential <= 0.0 && normal < 0.0)) {
    return ConeZone::kBottom;
  }
  return ConeZone::kMiddle;
}

// An elliptic cone contact's force in the middle zone at r (coupled_step.h,
// RigidConstraint), and H = -df/dr there
void MiddleZoneForce(const RigidConstraint& constraint, const ConstraintVector& r,
                     ConstraintVector& force, ConstraintMatrix& hessian) {
  const Eigen::Index n = r.size();
  const ConstraintVector& scale = constraint.cone;
  const double mu = scale[0];
  const ConstraintVector u = scale.cwiseProduct(r);
  const ConstraintVector tangent = u.tail(n - 1);
  const double tangential = tangent.norm();
  const double gap = u[0] - mu * tangential;  // N - mu T (< 0 here)
  const double dm = constraint.mass[0] / (mu * mu * (1.0 + mu * mu));
  // the gradient of N - mu T in u, and the cost's second derivative in u
  ConstraintVector gradient(n);
  gradient[0] = 1.0;
  gradient.tail(n - 1) = -mu / tangential * tangent;
  ConstraintMatrix second = dm * gradient * gradient.transpose();
  second.bottomRightCorner(n - 1, n - 1) -=
      dm * gap * mu / tangential *
      (ConstraintMatrix::Identity(n - 1, n - 1) -
       tangent * tangent.transpose() / (tangential * tangential));
  force = -dm * gap * scale.cwiseProduct(gradient);
  hessian = scale.asDiagonal() * second * scale.asDiagonal();
}

// The state a RigidConstraint's rows' J a - aref = r put it in: released,
// held, or sliding (an elliptic cone contact in its middle zone: 1; a
// friction loss row at its constant force: its FrictionLossSide)
struct ConstraintState {
  bool released = false;
  int sliding = 0;
  bool operator==(const ConstraintState&) const = default;
};
ConstraintState StateAt(const RigidConstraint& constraint, const ConstraintVector& r) {
  switch (constraint.kind) {
    case RigidConstraint::Kind::kEquality:
      return {};
    case RigidConstraint::Kind::kUnilateral:
      return {.released = r[0] > 0.0};
    case RigidConstraint::Kind::kFrictionLoss:
      return {.sliding = FrictionLossSide(constraint, r[0])};
    case RigidConstraint::Kind::kEllipticCone:
      break;
  }
  const ConeZone zone = Zone(constraint, r);
  return {.released = zone == ConeZone::kTop, .sliding = zone == ConeZone::kMiddle ? 1 : 0};
}

// Each held constraint's force over the step, dt f = g - H (J v+ - J v -
// dt aref) (r = J a - aref; held in a row's quadratic state, or in a
// cone's bottom zone: H = D, g = 0; sliding in a cone's middle zone:
// linearized about r_0, where its force is f_0, g = dt (f_0 + H r_0))
struct ConstraintLaw {
  ConstraintMatrix hessian;  // H
  ConstraintVector offset;   // g
  ConstraintVector force;    // (sliding) f_0
  ConstraintVector about;    // (sliding) r_0
  int linearizations = 0;
  ConstraintState state;
};

// items.emplace_back(), default-constructed but for the arrays `reuse`
// moves into it from the last element kept in `spare`, if any
template <typename T, typename Reuse>
T& AddReusing(std::vector<T>& items, std::vector<T>& spare, const Reuse& reuse) {
  T& item = items.emplace_back();
  if (!spare.empty()) {
    reuse(spare.back(), item);
    spare.pop_back();
  }
  return item;
}

}  // namespace

// (StepCoupled's arrays, named as there)
struct CoupledStepWorkspace::Arrays {
  std::vector<int> offset, tree_offset;
  VectorXdWithRoom v, b, delta;
  std::vector<Eigen::Matrix3d> blocks, body_blocks;
  std::vector<char> pinned;
  std::vector<ConstraintLaw> laws;
  std::vector<int> shared_bodies, threaded_bodies, run_begin;
  std::vector<Slave> slaves;
  std::vector<Coupling> couplings;
  std::vector<ContactLinearization> linear;
  std::vector<Eigen::Vector3d> contact_rhs, slide;
  std::vector<FrictionLaw> law;
  std::vector<char> switches;
  VectorXdWithRoom carried, momentum, v_new, work, rigid_part, body_rhs, Av_new, r;
  VectorXdWithRoom impulse, reduced, unit, column, residual;
  std::vector<const Coupling*> rigid_couplings;
  std::vector<int> touched;
  Eigen::LDLT<Eigen::MatrixXd> schur_factor;
  std::vector<Eigen::LDLT<Eigen::MatrixXd>> tree_factors;
  Eigen::MatrixXd schur;
  std::vector<Eigen::MatrixXd> tree_diagonal;
  std::vector<double> product;  // J^T G of a rigid contact or a carried pin
  CgVectors cg;
};

void RigidSystem::Clear() {
  auto keep = [](auto& items, auto& spare) {
    for (auto& item : items) spare.push_back(std::move(item));
    items.clear();
  };
  keep(trees, spare_trees_);
  keep(points, spare_points_);
  keep(constraints, spare_constraints_);
  pins.clear();
}

RigidTree& RigidSystem::AddTree() {
  return AddReusing(trees, spare_trees_, [](RigidTree& kept, RigidTree& tree) {
    tree.mass = std::move(kept.mass);
    tree.velocity = std::move(kept.velocity);
    tree.impulse = std::move(kept.impulse);
    tree.velocity_end = std::move(kept.velocity_end);
  });
}

RigidPoint& RigidSystem::AddPoint() {
  return AddReusing(points, spare_points_, [](RigidPoint& kept, RigidPoint& point) {
    point.jacobian = std::move(kept.jacobian);
  });
}

RigidConstraint& RigidSystem::AddConstraint() {
  return AddReusing(constraints, spare_constraints_,
                    [](RigidConstraint& kept, RigidConstraint& constraint) {
                      constraint.jacobian = std::move(kept.jacobian);
                    });
}

CoupledStepWorkspace::CoupledStepWorkspace() : arrays_(std::make_unique<Arrays>()) {}
CoupledStepWorkspace::~CoupledStepWorkspace() = default;
CoupledStepWorkspace::CoupledStepWorkspace(CoupledStepWorkspace&&) noexcept = default;
CoupledStepWorkspace& CoupledStepWorkspace::operator=(CoupledStepWorkspace&&) noexcept = default;

CoupledStepReport StepCoupled(std::span<DeformableBody* const> bodies,
                              std::span<ContactPoint> contacts,
                              const ContactSettings& contact_settings, const StepSettings& settings,
                              RigidSystem* rigid, CoupledStepWorkspace* workspace) {
  settings.Validate();
  std::optional<CoupledStepWorkspace> own_workspace;
  if (workspace == nullptr) workspace = &own_workspace.emplace();
  CoupledStepWorkspace::Arrays& arrays = workspace->arrays();
  const double dt = settings.dt;
  const int num_bodies = static_cast<int>(bodies.size());
  std::vector<int>& offset = arrays.offset;
  offset.assign(static_cast<size_t>(num_bodies) + 1, 0);
  for (int k = 0; k < num_bodies; ++k) offset[k + 1] = offset[k] + 3 * bodies[k]->num_vertices();
  // the rigid trees' DoFs follow the deformables'
  const int num_trees = rigid ? static_cast<int>(rigid->trees.size()) : 0;
  std::vector<int>& tree_offset = arrays.tree_offset;
  tree_offset.assign(static_cast<size_t>(num_trees) + 1, offset[num_bodies]);
  for (int t = 0; t < num_trees; ++t) {
    tree_offset[t + 1] = tree_offset[t] + static_cast<int>(rigid->trees[t].velocity.size());
  }
  const int n = tree_offset[num_trees];

  // bodies' own systems and current velocities; the 3 x 3 diagonal blocks of
  // the system, per vertex, for a block-Jacobi preconditioner
  VectorXdWithRoom& v = arrays.v;
  VectorXdWithRoom& b = arrays.b;
  v.resize(n);
  b.resize(n);
  std::vector<Eigen::Matrix3d>& blocks = arrays.blocks;
  blocks.resize(static_cast<size_t>(offset[num_bodies] / 3));
  std::vector<char>& pinned = arrays.pinned;
  pinned.assign(static_cast<size_t>(n), 0);
  VectorXdWithRoom& delta = arrays.delta;
  delta.setZero(n);
  // a rigid tree: M q+ = M q + impulse + its contacts' and constraints' share
  const size_t num_constraints = rigid != nullptr ? rigid->constraints.size() : 0;
  std::vector<ConstraintLaw>& laws = arrays.laws;
  AssignWithRoom(laws, num_constraints, ConstraintLaw{});
  auto hold = [&](size_t k) {
    RigidConstraint& constraint = rigid->constraints[k];
    laws[k].hessian = constraint.mass.asDiagonal();
    laws[k].offset.setZero(constraint.mass.size());
    constraint.released = constraint.sliding = false;
  };
  // an elliptic cone's law linearized about r, given its force and Hessian
  // there (MiddleZoneForce; the caller has them: Newton's check needs them too)
  auto slide_about = [&](size_t k, const ConstraintVector& r, const ConstraintVector& force,
                         const ConstraintMatrix& hessian) {
    ConstraintLaw& law = laws[k];
    law.force = force;
    law.hessian = hessian;
    law.offset = dt * (law.force + law.hessian * r);
    law.about = r;
  };
  // constraint k in `state` at r (StateAt): released; held; sliding, a
  // friction loss row with H = 0, g = dt f, a cone linearized about r
  auto enter = [&](size_t k, ConstraintState state, const ConstraintVector& r) {
    RigidConstraint& constraint = rigid->constraints[k];
    hold(k);
    if (constraint.kind == RigidConstraint::Kind::kFrictionLoss && state.sliding != 0) {
      laws[k].hessian.setZero(1, 1);
      laws[k].offset =
          ConstraintVector::Constant(1, -dt * state.sliding * constraint.friction_loss);
    } else if (state.sliding != 0) {
      ConstraintVector force;
      ConstraintMatrix hessian;
      MiddleZoneForce(constraint, r, force, hessian);
      slide_about(k, r, force, hessian);
    }
    constraint.released = state.released;
    constraint.sliding = state.sliding != 0;
    laws[k].state = state;
  };
  for (size_t k = 0; k < num_constraints; ++k) {
    RigidConstraint& constraint = rigid->constraints[k];
    constraint.switches = 0;
    hold(k);
    laws[k].state = {};
    if (constraint.kind != RigidConstraint::Kind::kEquality &&
        constraint.start_residual.size() > 0) {
      enter(k, StateAt(constraint, constraint.start_residual), constraint.start_residual);
    }
  }
  // J_i x for row i of a constraint, with part(t) tree t's share of x;
  // y += s J_i^T
  auto constraint_rate = [&](const RigidConstraint& constraint, Eigen::Index i, auto&& part) {
    double rate = 0.0;
    Eigen::Index column = 0;
    for (const int t : constraint.trees) {
      if (t < 0) break;
      const Eigen::Index size = tree_offset[t + 1] - tree_offset[t];
      rate += constraint.jacobian.row(i).segment(column, size).dot(part(t));
      column += size;
    }
    return rate;
  };
  auto add_constraint_row = [&](const RigidConstraint& constraint, Eigen::Index i, double scale,
                                VectorXdWithRoom& y) {
    Eigen::Index column = 0;
    for (const int t : constraint.trees) {
      if (t < 0) break;
      const Eigen::Index size = tree_offset[t + 1] - tree_offset[t];
      y.segment(tree_offset[t], size) +=
          scale * constraint.jacobian.row(i).segment(column, size).transpose();
      column += size;
    }
  };
  for (int t = 0; t < num_trees; ++t) {
    RigidTree& tree = rigid->trees[t];
    const Eigen::Index size = tree.velocity.size();
    v.segment(tree_offset[t], size) = tree.velocity;
    b.segment(tree_offset[t], size).noalias() = tree.mass * tree.velocity;
    b.segment(tree_offset[t], size) += tree.impulse;
  }
  // The bodies that run their own loops on one thread (all but bodies of at
  // least 16384 tets: DeformableBody::RunsOnSeveralThreads) prepare their
  // systems and compute their products side by side, in runs of
  // consecutive bodies of about equal numbers of tetrahedra, one run per
  // thread. A body's part is the same whichever thread computes it, so
  // the result does not depend on how they are shared out.
  Eigen::setNbThreads(std::max(1, settings.num_threads));
  std::vector<int>& shared_bodies = arrays.shared_bodies;
  std::vector<int>& threaded_bodies = arrays.threaded_bodies;
  shared_bodies.clear();
  threaded_bodies.clear();
  long shared_tets = 0;
  for (int k = 0; k < num_bodies; ++k) {
    if (DeformableBody::RunsOnSeveralThreads(bodies[k]->model(), settings)) {
      threaded_bodies.push_back(k);
    } else {
      shared_bodies.push_back(k);
      shared_tets += bodies[k]->model().num_tets();
    }
  }
  const int num_runs = static_cast<int>(
      std::clamp<long>(std::min<long>(shared_tets / kMinSharedTetsPerThread, settings.num_threads),
                       1, std::max<long>(1, static_cast<long>(shared_bodies.size()))));
  std::vector<int>& run_begin = arrays.run_begin;
  run_begin.assign(static_cast<size_t>(num_runs) + 1, static_cast<int>(shared_bodies.size()));
  run_begin[0] = 0;
  long tets_before = 0;
  int run = 1;
  for (int i = 0; i < static_cast<int>(shared_bodies.size()) && run < num_runs; ++i) {
    // (body i opens run r once the bodies before it hold r / num_runs of the tets)
    while (run < num_runs && tets_before * num_runs >= shared_tets * run) run_begin[run++] = i;
    tets_before += bodies[shared_bodies[i]]->model().num_tets();
  }
  auto for_each_body = [&](const auto& visit) {  // visit(k) for every body k
    ParallelFor(num_runs, 0, num_runs, [&](int r) {
      for (int i = run_begin[r]; i < run_begin[r + 1]; ++i) visit(shared_bodies[i]);
    });
    for (int k : threaded_bodies) visit(k);
  };
  for_each_body([&](int k) { bodies[k]->PrepareStep(settings); });

  for (int k = 0; k < num_bodies; ++k) {
    DeformableBody& body = *bodies[k];
    const int size = 3 * body.num_vertices();
    v.segment(offset[k], size) = Eigen::Map<const Eigen::VectorXd>(body.velocities().data(), size);
    b.segment(offset[k], size) = body.system_rhs();
    for (int vertex = 0; vertex < body.num_vertices(); ++vertex) {
      const int block = offset[k] / 3 + vertex;
      blocks[block] = body.system_diagonal_block(vertex);
    }
    const Eigen::VectorXd& last = body.last_velocity_change();
    if (last.size() == size) delta.segment(offset[k], size) = last;  // (else zero)
    for (size_t i = 0; i < body.pinned_vertices().size(); ++i) {
      const int dof = offset[k] + 3 * body.pinned_vertices()[i];
      Eigen::Vector3d target = body.PinVelocity(i, dt);
      for (int r = 0; r < 3; ++r) {
        pinned[dof + r] = 1;
        delta[dof + r] = target[r] - v[dof + r];
      }
    }
  }

  // the pins that rigid trees carry (RigidPin): pinned as above, their
  // prescribed velocity now J q + constant
  std::vector<Slave>& slaves = arrays.slaves;
  slaves.clear();
  if (rigid) {
    for (const RigidPin& pin : rigid->pins) {
      const RigidPoint& point = rigid->points[static_cast<size_t>(pin.point)];
      DeformableBody& body = *bodies[pin.body];
      Slave& slave = slaves.emplace_back();
      slave.dof = offset[pin.body] + 3 * body.pinned_vertices()[static_cast<size_t>(pin.pin)];
      slave.rigid_offset = tree_offset[point.tree];
      slave.jacobian = &point.jacobian;
      slave.tree = point.tree;
      slave.constant = body.PinVelocity(static_cast<size_t>(pin.pin), dt) -
                       point.jacobian * v.segment(slave.rigid_offset, point.jacobian.cols());
    }
  }
  // x on the carried pins' DoFs from x's trees: J q, plus the constants
  auto carry = [&](VectorXdWithRoom& x, bool with_constant) {
    for (const Slave& slave : slaves) {
      const auto& J = *slave.jacobian;
      x.segment<3>(slave.dof) = J * x.segment(slave.rigid_offset, J.cols());
      if (with_constant) x.segment<3>(slave.dof) += slave.constant;
    }
  };
  // T^T y: the carried pins' rows of y onto their trees' (and zeroed)
  auto gather = [&](VectorXdWithRoom& y) {
    for (const Slave& slave : slaves) {
      const auto& J = *slave.jacobian;
      const Eigen::Vector3d row = y.segment<3>(slave.dof);
      y.segment<3>(slave.dof).setZero();
      // (noalias: else Eigen takes y on both sides for aliasing and puts
      // the product in a temporary on the heap, each pin and product)
      y.segment(slave.rigid_offset, J.cols()).noalias() += J.transpose() * row;
    }
  };

  // contacts: their linearizations and couplings
  std::vector<Coupling>& couplings = arrays.couplings;
  AssignWithRoom(couplings, contacts.size(), Coupling{});
  std::vector<ContactLinearization>& linear = arrays.linear;
  ResizeWithRoom(linear, contacts.size());
  std::vector<Eigen::Vector3d>& contact_rhs = arrays.contact_rhs;
  ResizeWithRoom(contact_rhs, contacts.size());
  // each contact's friction law in this step (contact.h): with static
  // friction, sticking first, sliding along the sticking force it would
  // leave its cone with (slide[c]), sticking again if it then slid back,
  // sliding again if that leaves the cone (at most three switches a step,
  // the last to sliding, which stays in the cone)
  std::vector<FrictionLaw>& law = arrays.law;
  AssignWithRoom(law, contacts.size(), FrictionLaw::kSmooth);
  std::vector<Eigen::Vector3d>& slide = arrays.slide;
  AssignWithRoom(slide, contacts.size(), Eigen::Vector3d::Zero().eval());
  std::vector<char>& switches = arrays.switches;
  AssignWithRoom(switches, contacts.size(), char{0});
  auto linearize = [&](size_t c) {
    linear[c] = LinearizeContact(bodies, contacts[c], contact_settings, law[c], slide[c]);
    Coupling& coupling = couplings[c];
    coupling.gain = dt * dt * linear[c].stiffness + dt * linear[c].damping;
    // dt J^T (f - dt K c + D J v)
    contact_rhs[c] = dt * (linear[c].force - dt * linear[c].stiffness * linear[c].rigid_velocity +
                           linear[c].damping * coupling.Jv_start);
  };
  // (to sliding, Coulomb's force along the tangential part of `along` at
  // the normal force of `force`: the sticking force at a trial solution)
  auto slide_along = [&](size_t c, const Eigen::Vector3d& along, const Eigen::Vector3d& force) {
    const Eigen::Vector3d tangential = Tangential(along, contacts[c].direction);
    const double length = tangential.norm();
    const double limit = FrictionLimit(force, contacts[c]);
    slide[c] = length > 0.0 ? (limit / length * tangential).eval() : Eigen::Vector3d::Zero();
    law[c] = FrictionLaw::kSliding;
    linearize(c);
  };
  // (to sticking again, from its spring at the step's start)
  auto stick_again = [&](size_t c) {
    law[c] = FrictionLaw::kSticking;
    linearize(c);
  };
  for (size_t c = 0; c < contacts.size(); ++c) {
    const ContactPoint& contact = contacts[c];
    Coupling& coupling = couplings[c];
    if (contact.body_a >= 0) coupling.dof_a = offset[contact.body_a] + 3 * contact.vertex_a;
    if (contact.body_b >= 0) {
      for (int i = 0; i < 4; ++i) {
        coupling.dof_b[i] =
            offset[contact.body_b] + 3 * bodies[contact.body_b]->mesh().tets()(contact.tet_b, i);
        coupling.w[i] = contact.barycentric_b[i];
      }
    }
    if (contact.rigid_point >= 0) {
      const RigidPoint& point = rigid->points[static_cast<size_t>(contact.rigid_point)];
      coupling.rigid_offset = tree_offset[point.tree];
      coupling.rigid_jacobian = &point.jacobian;
      coupling.rigid_sign = contact.body_a < 0 ? 1.0 : -1.0;
    }
    coupling.Jv_start = coupling.Jv(v);
    if (contact_settings.stick && contact.friction > 0.0 && contact.stiffness > 0.0) {
      law[c] = FrictionLaw::kSticking;
    }
    linearize(c);
  }

  // y = A x
  auto multiply_full = [&](const VectorXdWithRoom& x, VectorXdWithRoom& y) {
    for_each_body(
        [&](int k) { bodies[k]->MultiplySystem(x.data() + offset[k], y.data() + offset[k]); });
    for (int t = 0; t < num_trees; ++t) {
      const RigidTree& tree = rigid->trees[t];
      const Eigen::Index size = tree.mass.rows();
      y.segment(tree_offset[t], size).noalias() = tree.mass * x.segment(tree_offset[t], size);
    }
    auto part = [&](int t) {
      return x.segment(tree_offset[t], tree_offset[t + 1] - tree_offset[t]);
    };
    for (size_t k = 0; k < num_constraints; ++k) {
      const RigidConstraint& constraint = rigid->constraints[k];
      if (constraint.released) continue;
      // J^T H J x
      const Eigen::Index rows = constraint.jacobian.rows();
      std::array<double, kMaxConstraintRows> rate{};
      for (Eigen::Index i = 0; i < rows; ++i) {
        rate[static_cast<size_t>(i)] = constraint_rate(constraint, i, part);
      }
      for (Eigen::Index i = 0; i < rows; ++i) {
        double scale = 0.0;
        for (Eigen::Index j = 0; j < rows; ++j) {
          if (laws[k].hessian(i, j) != 0.0) {
            scale += laws[k].hessian(i, j) * rate[static_cast<size_t>(j)];
          }
        }
        add_constraint_row(constraint, i, scale, y);
      }
    }
    for (const Coupling& coupling : couplings) {
      if (coupling.active) coupling.AddJt(coupling.gain * coupling.Jv(x), y);
    }
  };
  // y = T^T A T x: the system the solve sees (A itself without carried pins)
  VectorXdWithRoom& carried = arrays.carried;  // (with carried pins only)
  if (!slaves.empty()) carried.resize(n);
  auto multiply = [&](const VectorXdWithRoom& x, VectorXdWithRoom& y) {
    if (slaves.empty()) {
      multiply_full(x, y);
      return;
    }
    carried = x;
    carry(carried, /*with_constant=*/false);
    multiply_full(carried, y);
    gather(y);
  };
  auto filter = [&](VectorXdWithRoom& x) {
    for (int i = 0; i < n; ++i) {
      if (pinned[i]) x[i] = 0.0;
    }
  };
  VectorXdWithRoom& momentum = arrays.momentum;
  momentum.resize(n);
  for (int k = 0; k < num_bodies; ++k) {
    bodies[k]->MultiplyMass(v.data() + offset[k], momentum.data() + offset[k]);
  }
  for (int t = 0; t < num_trees; ++t) {
    const Eigen::MatrixXd& mass = rigid->trees[t].mass;
    momentum.segment(tree_offset[t], mass.rows()).noalias() =
        mass * v.segment(tree_offset[t], mass.rows());
  }
  filter(momentum);

  // the relative velocity v_A - v_B of contact c at v+
  auto relative_velocity = [&](size_t c, const VectorXdWithRoom& v_plus) -> Eigen::Vector3d {
    return couplings[c].Jv(v_plus) + linear[c].rigid_velocity;
  };
  // the force of contact c integrated to the end of the step, at v+
  auto integrated_force = [&](size_t c, const VectorXdWithRoom& v_plus) -> Eigen::Vector3d {
    const Eigen::Vector3d Jv_plus = couplings[c].Jv(v_plus);
    return linear[c].force - dt * linear[c].stiffness * (Jv_plus + linear[c].rigid_velocity) -
           linear[c].damping * (Jv_plus - couplings[c].Jv_start);
  };

  // Rounds of solves, each with the contacts that push (coupled_step.h);
  // the first guess: those that push at the warm start.
  VectorXdWithRoom& v_new = arrays.v_new;
  v_new.resize(n);
  v_new = v + delta;
  carry(v_new, /*with_constant=*/true);  // (the same: J q + constant = the pin velocity)
  for (size_t c = 0; c < contacts.size(); ++c) {
    Eigen::Vector3d force = integrated_force(c, v_new);
    if (law[c] == FrictionLaw::kSticking && !InsideFrictionCone(force, contacts[c])) {
      // (sliding: along the sticking force at the step's start velocities,
      // which a slipping contact's slip sets, not the warm start's)
      slide_along(c, integrated_force(c, v), force);
      force = integrated_force(c, v_new);
    }
    couplings[c].active = force.dot(contacts[c].direction) >= 0.0;
  }
  // the rigid trees eliminated in the preconditioner (kMaxEliminatedRigidDofs)
  const int n_deformable = offset[num_bodies];
  const int n_rigid = n - n_deformable;
  const bool eliminate = n_rigid > 0 && n_rigid <= kMaxEliminatedRigidDofs;
  std::vector<const Coupling*>& rigid_couplings = arrays.rigid_couplings;
  std::vector<int>& touched = arrays.touched;  // vertex blocks of the active rigid contacts
  VectorXdWithRoom& work = arrays.work;
  work.setZero(n);
  Eigen::LDLT<Eigen::MatrixXd>& schur_factor = arrays.schur_factor;
  VectorXdWithRoom& rigid_part = arrays.rigid_part;  // (the preconditioner's)
  rigid_part.resize(n_rigid);
  arrays.body_rhs = b;
  const VectorXdWithRoom& body_rhs = arrays.body_rhs;
  arrays.body_blocks = blocks;
  const std::vector<Eigen::Matrix3d>& body_blocks = arrays.body_blocks;
  // (room for J^T G, n_rigid x 3, of a rigid contact or a carried pin)
  if (arrays.product.size() < 3 * static_cast<size_t>(n_rigid)) {
    arrays.product.resize(3 * static_cast<size_t>(n_rigid));
  }
  CoupledStepReport report;
  VectorXdWithRoom& Av_new = arrays.Av_new;
  VectorXdWithRoom& r = arrays.r;
  Av_new.resize(n);
  r.resize(n);
  // (until the contacts settle, rounds solve to kSettlingTolerance, then
  // once precisely from there: when the first guess holds, as many
  // iterations in all as one precise solve)
  bool precise = contacts.empty() || settings.cg_tolerance >= kSettlingTolerance;
  // From the kMaxContactRounds-th solve on, contacts are only relaxed, and
  // only those whose force adds energy at the solution: one that pulls
  // while its force does work on the relative motion (f . u > 0) is
  // released, and a sliding one whose Coulomb force drives the slip (its
  // force is set along an earlier solution's, which a large step's swing
  // can turn around) sticks instead, an implicit spring. A contact relaxes
  // at most twice (sticks, then is released), so the rounds end. A pull
  // that holds back parting bodies, or friction that slows a slip, only
  // takes energy out, and stays as the solve left it. (With a stiff contact
  // a long step's solutions swing, and the contacts with them: a steel
  // cube, E = 2e11 Pa, tumbling on a floor at 2 ms, ended its eighth solve
  // with pulls of 1e4 N and gained 1e4 J in the step; with those pulls
  // released, its Coulomb forces, 3.6 times their limit and driving the
  // slip at 10 m/s, 43 J; cut to their limit, a force within it that drove
  // the slip gave 43 J again in another build. Relaxing every pull took
  // the paper's 120 spheres at 8 ms from rest to creeping.)
  bool releasing = false;
  // (what the rounds' tolerance takes that the contacts do not change: the
  // deformables' momentum, and the squared impulse from outside them)
  const double body_momentum = momentum.head(offset[num_bodies]).norm();
  double bodies_outside = 0.0;
  for (int k = 0; k < num_bodies; ++k) {
    const double body_outside = bodies[k]->outside_impulse();
    bodies_outside += body_outside * body_outside;
  }
  auto relax = [&](size_t c, const Eigen::Vector3d& force, const VectorXdWithRoom& v_plus) {
    Coupling& coupling = couplings[c];
    if (!coupling.active) return false;
    const Eigen::Vector3d u = relative_velocity(c, v_plus);
    if (force.dot(contacts[c].direction) < 0.0) {
      if (force.dot(u) <= 0.0) return false;
      coupling.active = false;
      return true;
    }
    if (law[c] != FrictionLaw::kSliding || slide[c].dot(u) <= 0.0) return false;
    stick_again(c);
    return true;
  };
  for (int round = 0;; ++round) {
    releasing |= round + 1 >= kMaxContactRounds;
    precise |= releasing;
    // the active contacts' forces into b, gains into the diagonal
    b = body_rhs;
    blocks = body_blocks;
    // each tree's diagonal block of A, M + its active contacts' J^T G J
    // (inverted in place below unless the trees are eliminated)
    std::vector<Eigen::MatrixXd>& tree_diagonal = arrays.tree_diagonal;
    if (tree_diagonal.size() < static_cast<size_t>(num_trees)) tree_diagonal.resize(num_trees);
    for (int t = 0; t < num_trees; ++t) tree_diagonal[t] = rigid->trees[t].mass;
    // the held constraints: J^T H J (its blocks on each tree's diagonal),
    // and J^T (g + H (J v + dt aref)) into b
    auto start = [&](int t) -> const Eigen::VectorXd& { return rigid->trees[t].velocity; };
    for (size_t k = 0; k < num_constraints; ++k) {
      const RigidConstraint& constraint = rigid->constraints[k];
      if (constraint.released) continue;
      const ConstraintMatrix& hessian = laws[k].hessian;
      const Eigen::Index rows = constraint.jacobian.rows();
      std::array<double, kMaxConstraintRows> rate{};
      for (Eigen::Index i = 0; i < rows; ++i) {
        rate[static_cast<size_t>(i)] =
            constraint_rate(constraint, i, start) + dt * constraint.reference[i];
      }
      for (Eigen::Index i = 0; i < rows; ++i) {
        double scale = laws[k].offset[i];
        for (Eigen::Index j = 0; j < rows; ++j) {
          if (hessian(i, j) == 0.0) continue;
          scale += hessian(i, j) * rate[static_cast<size_t>(j)];
          Eigen::Index column = 0;
          for (const int t : constraint.trees) {
            if (t < 0) break;
            const Eigen::Index size = tree_diagonal[t].rows();
            const auto row_i = constraint.jacobian.row(i).segment(column, size);
            const auto row_j = constraint.jacobian.row(j).segment(column, size);
            tree_diagonal[t].noalias() += hessian(i, j) * row_i.transpose() * row_j;
            column += size;
          }
        }
        add_constraint_row(constraint, i, scale, b);
      }
    }
    rigid_couplings.clear();
    for (size_t c = 0; c < contacts.size(); ++c) {
      const Coupling& coupling = couplings[c];
      if (!coupling.active) continue;
      coupling.AddJt(contact_rhs[c], b);
      if (coupling.rigid_jacobian) {
        const auto& J = *coupling.rigid_jacobian;
        Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 3>> JtG(arrays.product.data(), J.cols(),
                                                                 3);
        JtG.noalias() = J.transpose() * coupling.gain;
        tree_diagonal[static_cast<size_t>(
                          rigid->points[static_cast<size_t>(contacts[c].rigid_point)].tree)]
            .noalias() += JtG * J;
        rigid_couplings.push_back(&coupling);
      }
      if (coupling.dof_a >= 0) blocks[static_cast<size_t>(coupling.dof_a / 3)] += coupling.gain;
      for (int i = 0; i < 4; ++i) {
        if (coupling.dof_b[i] >= 0) {
          // (eliminating a rigid side: w_i instead of w_i^2, see below)
          const double weight =
              eliminate && coupling.rigid_jacobian ? coupling.w[i] : coupling.w[i] * coupling.w[i];
          blocks[static_cast<size_t>(coupling.dof_b[i] / 3)] += weight * coupling.gain;
        }
      }
    }
    // a carried pin's block on its tree's (T^T A T's diagonal, but for the
    // vertex's coupling to the rest of its body)
    for (const Slave& slave : slaves) {
      const auto& J = *slave.jacobian;
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 3>> JtB(arrays.product.data(), J.cols(), 3);
      JtB.noalias() = J.transpose() * blocks[static_cast<size_t>(slave.dof / 3)];
      tree_diagonal[static_cast<size_t>(slave.tree)].noalias() += JtB * J;
    }
    // preconditioned CG on A v+ = b, warm-started from v plus each body's
    // last change, then from the last round's solution
    for (Eigen::Matrix3d& block : blocks) {
      // symmetric positive definite (mass + PSD terms): invert directly
      block = block.inverse().eval();
    }
    if (eliminate) {
      // The preconditioner is the exact inverse of P = [B C; C^T A_rr]: the
      // vertices' 3 x 3 blocks B, the rigid trees' rows of A whole (A_rr and
      // the vertex-rigid blocks C), so a rigid body's contacts act together
      // in it. P is positive definite: each contact's share of it is, with
      // a rigid side's barycentric weights w_i on B's diagonal instead of
      // w_i^2 (then [diag(w) -w; -w^T 1] (x) G has Schur complement
      // (1 - sum w_i) G = 0; with w_i^2, 1 - sum 1 < 0). Applied by block
      // elimination through the Schur complement S = A_rr - C^T B^-1 C.
      touched.clear();
      for (const Coupling* coupling : rigid_couplings) {
        if (coupling->dof_a >= 0) touched.push_back(coupling->dof_a / 3);
        for (int i = 0; i < 4; ++i) {
          if (coupling->dof_b[i] >= 0) touched.push_back(coupling->dof_b[i] / 3);
        }
      }
      std::sort(touched.begin(), touched.end());
      touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
      Eigen::MatrixXd& schur = arrays.schur;
      schur.setZero(n_rigid, n_rigid);
      for (int t = 0; t < num_trees; ++t) {
        const Eigen::Index first = tree_offset[t] - n_deformable;
        const Eigen::Index size = tree_offset[t + 1] - tree_offset[t];
        schur.block(first, first, size, size) = tree_diagonal[static_cast<size_t>(t)];
      }
      // (and the blocks J_0^T H J_1 of the constraints between two trees)
      for (size_t k = 0; k < num_constraints; ++k) {
        const RigidConstraint& constraint = rigid->constraints[k];
        if (constraint.released || constraint.trees[1] < 0) continue;
        const int t0 = constraint.trees[0], t1 = constraint.trees[1];
        const Eigen::Index size0 = tree_offset[t0 + 1] - tree_offset[t0];
        const Eigen::Index size1 = tree_offset[t1 + 1] - tree_offset[t1];
        const Eigen::Index rows = constraint.jacobian.rows();
        for (Eigen::Index i = 0; i < rows; ++i) {
          for (Eigen::Index j = 0; j < rows; ++j) {
            const double h = laws[k].hessian(i, j);
            if (h == 0.0) continue;
            const auto row0 = constraint.jacobian.row(i).head(size0);
            const auto row1 = constraint.jacobian.row(j).segment(size0, size1);
            const Eigen::Index first0 = tree_offset[t0] - n_deformable;
            const Eigen::Index first1 = tree_offset[t1] - n_deformable;
            schur.block(first0, first1, size0, size1).noalias() += h * row0.transpose() * row1;
            schur.block(first1, first0, size1, size0).noalias() += h * row1.transpose() * row0;
          }
        }
      }
      VectorXdWithRoom& unit = arrays.unit;
      VectorXdWithRoom& column = arrays.column;
      unit.setZero(n);
      column.resize(n_rigid);
      for (int j = 0; j < n_rigid; ++j) {
        unit[n_deformable + j] = 1.0;
        MultiplyRigidToVertices(rigid_couplings, unit, touched, work);
        for (int block : touched) {
          work.segment<3>(3 * block) =
              blocks[static_cast<size_t>(block)] * work.segment<3>(3 * block);
        }
        MultiplyVerticesToRigid(rigid_couplings, work, n_deformable, column);
        schur.col(j) -= column;
        unit[n_deformable + j] = 0.0;
      }
      schur_factor.compute(schur);
    } else {
      if (arrays.tree_factors.size() < static_cast<size_t>(num_trees)) {
        arrays.tree_factors.resize(num_trees);
      }
      for (int t = 0; t < num_trees; ++t) {
        Eigen::MatrixXd& block = tree_diagonal[static_cast<size_t>(t)];
        Eigen::LDLT<Eigen::MatrixXd>& factor = arrays.tree_factors[static_cast<size_t>(t)];
        factor.compute(block);
        block.setIdentity();
        block = factor.solve(block);
      }
    }
    auto precondition = [&](const VectorXdWithRoom& x, VectorXdWithRoom& y) {
      for (size_t i = 0; i < blocks.size(); ++i) {
        y.segment<3>(3 * static_cast<Eigen::Index>(i)) =
            blocks[i] * x.segment<3>(3 * static_cast<Eigen::Index>(i));
      }
      if (eliminate) {
        // y_r = S^-1 (x_r - C^T B^-1 x_v), y_v = B^-1 (x_v - C y_r)
        MultiplyVerticesToRigid(rigid_couplings, y, n_deformable, rigid_part);
        rigid_part = x.tail(n_rigid) - rigid_part;
        y.tail(n_rigid) = schur_factor.solve(rigid_part);
        MultiplyRigidToVertices(rigid_couplings, y, touched, work);
        for (int block : touched) {
          y.segment<3>(3 * block) -=
              blocks[static_cast<size_t>(block)] * work.segment<3>(3 * block);
        }
        return;
      }
      for (int t = 0; t < num_trees; ++t) {
        const Eigen::MatrixXd& inverse = tree_diagonal[static_cast<size_t>(t)];
        y.segment(tree_offset[t], inverse.rows()).noalias() =
            inverse * x.segment(tree_offset[t], inverse.rows());
      }
    };
    // the tolerance is relative to this step's impulse, b - (1 + dt alpha)
    // M v (what the forces add to the momentum), which needs no product
    // with A; floored at a millionth of the deformables' momentum for a
    // body on which nothing acts (not the rigid trees': a heavy fast body's
    // would loosen every contact's solve); and capped at that momentum plus
    // the impulse from outside the bodies (gravity, applied forces, the
    // active contacts, the rigid trees' forces). A stiff body's elastic
    // impulses can exceed its momentum a thousandfold while they cancel
    // almost everywhere: relative to them, the solve left a free steel cube
    // (E = 2e11 Pa, 2 cm elements, 2 ms) spinning at 12 rad/s errors of 1%
    // of its momentum a step, and it gained 13 times its kinetic energy in
    // a second
    VectorXdWithRoom& impulse = arrays.impulse;
    impulse.resize(n);
    impulse = b - momentum;
    filter(impulse);
    double outside = bodies_outside;  // (squared)
    for (size_t c = 0; c < contacts.size(); ++c) {
      if (couplings[c].active) outside += contact_rhs[c].squaredNorm();
    }
    for (int t = 0; t < num_trees; ++t) outside += rigid->trees[t].impulse.squaredNorm();
    const double reference = std::max(std::min(impulse.norm(), body_momentum + std::sqrt(outside)),
                                      1e-6 * body_momentum);
    const double threshold = (precise ? settings.cg_tolerance : kSettlingTolerance) * reference;
    // with carried pins: T^T b, and at the start T^T A (T x + c) (v_new: x
    // carried, with the constants c), so that the residual is
    // T^T (b - A c) - T^T A T x
    VectorXdWithRoom& reduced = arrays.reduced;
    if (!slaves.empty()) {
      reduced = b;  // (its size too)
      gather(reduced);
      multiply_full(v_new, Av_new);
      gather(Av_new);
    }
    report.iterations +=
        ConjugateGradients(multiply, precondition, filter, slaves.empty() ? b : reduced, threshold,
                           settings.cg_max_iterations, v_new, Av_new, r, arrays.cg,
                           /*Ax_given=*/!slaves.empty());
    carry(v_new, /*with_constant=*/true);  // (nothing without carried pins)
    report.residual = reference > 0.0 ? r.norm() / reference : 0.0;

    // the forces actually integrated (none for a released contact), and
    // the contacts whose force at this solution has the other sign than
    // their state
    bool changed = false;
    report.released_contacts = 0;
    for (size_t c = 0; c < contacts.size(); ++c) {
      Coupling& coupling = couplings[c];
      const Eigen::Vector3d force = integrated_force(c, v_new);
      const bool pushes = force.dot(contacts[c].direction) >= 0.0;
      if (releasing) {
        changed |= relax(c, force, v_new);
      } else {
        if (coupling.active && !pushes && !coupling.taken_back) {
          coupling.active = false;
          changed = true;
        } else if (!coupling.active && pushes) {
          coupling.active = true;
          coupling.taken_back = true;
          changed = true;
        } else if (coupling.active) {
          if (law[c] == FrictionLaw::kSticking && switches[c] < 3 &&
              !InsideFrictionCone(force, contacts[c])) {
            slide_along(c, force, force);
            ++switches[c];
            changed = true;
          } else if (law[c] == FrictionLaw::kSliding && switches[c] < 2 &&
                     relative_velocity(c, v_new).dot(slide[c]) > 0.0) {
            // (Coulomb's force turned A's slip around: it stops, so it sticks)
            stick_again(c);
            ++switches[c];
            changed = true;
          } else if (law[c] == FrictionLaw::kSliding) {
            // (Coulomb's force at the normal force this solution integrates:
            // at a stiff contact and a long step, the step's start's can be
            // far larger, and friction from it would throw the bodies)
            const double limit = FrictionLimit(force, contacts[c]);
            const double length = slide[c].norm();
            if (length > 0.0 && std::abs(length - limit) > kSlidingForceTolerance * length) {
              slide[c] *= limit / length;
              linearize(c);
              changed = true;
            }
          }
        }
      }
      contacts[c].force = coupling.active ? force : Eigen::Vector3d::Zero();
      report.released_contacts += !coupling.active;
    }
    // the trees' unilateral constraints whose state this solution changes:
    // held rows that pull, released ones that push, elliptic cone contacts
    // in another zone, friction loss rows on another side (StateAt; the
    // rigid solver's active set; switched at most kMaxConstraintSwitches
    // times, so that the rounds end), and sliding cones whose force here is
    // off their linearized one
    // (each tree's velocity change over the step, with the sign flipped)
    auto change = [&](int t) {
      return rigid->trees[t].velocity -
             v_new.segment(tree_offset[t], tree_offset[t + 1] - tree_offset[t]);
    };
    for (size_t k = 0; k < num_constraints; ++k) {
      RigidConstraint& constraint = rigid->constraints[k];
      if (constraint.kind == RigidConstraint::Kind::kEquality) continue;
      // r = J a - aref
      const Eigen::Index rows = constraint.jacobian.rows();
      ConstraintVector residual(rows);
      for (Eigen::Index i = 0; i < rows; ++i) {
        residual[i] = -(constraint_rate(constraint, i, change) + dt * constraint.reference[i]) / dt;
      }
      const ConstraintState state = StateAt(constraint, residual);
      if (state != laws[k].state && constraint.switches < kMaxConstraintSwitches) {
        enter(k, state, residual);
        ++constraint.switches;
        changed = true;
      } else if (state == laws[k].state && constraint.sliding &&
                 constraint.kind == RigidConstraint::Kind::kEllipticCone &&
                 laws[k].linearizations < kMaxConeLinearizations) {
        // (Newton's method: again about this solution where its force is
        // off the line)
        ConstraintVector force;
        ConstraintMatrix hessian;
        MiddleZoneForce(constraint, residual, force, hessian);
        const ConstraintVector on_line =
            laws[k].force - laws[k].hessian * (residual - laws[k].about);
        if ((force - on_line).norm() > kConeForceTolerance * force.norm()) {
          slide_about(k, residual, force, hessian);
          ++laws[k].linearizations;
          changed = true;
        }
      }
    }
    if (!changed && precise) break;
    precise |= !changed;
    report.rounds = round + 2;
  }

  for (int t = 0; t < num_trees; ++t) {
    RigidTree& tree = rigid->trees[t];
    tree.velocity_end = v_new.segment(tree_offset[t], tree.velocity.size());
  }

  // the friction springs at the end of the step (contact.h): a sticking
  // contact's integrated, a sliding one's where it holds the sliding force;
  // within the cone, and none for a released contact
  for (size_t c = 0; c < contacts.size(); ++c) {
    ContactPoint& contact = contacts[c];
    contact.stuck = couplings[c].active && law[c] == FrictionLaw::kSticking;
    report.stuck_contacts += contact.stuck;
    if (!couplings[c].active || law[c] == FrictionLaw::kSmooth) {
      contact.stick.setZero();
      continue;
    }
    const double k_t = contact_settings.stick_stiffness * contact.stiffness;
    Eigen::Vector3d s;
    if (contact.stuck) {
      s = contact.stick + dt * relative_velocity(c, v_new);
    } else {
      s = -contact.force / k_t;
    }
    s = Tangential(s, contact.direction);
    const double limit = FrictionLimit(contact.force, contact) / k_t;
    if (s.norm() > limit) s *= limit / s.norm();
    contact.stick = s;
  }

  // the pin residuals (with carried pins, of A itself: Av_new is the reduced system's)
  if (!slaves.empty()) multiply_full(v_new, Av_new);
  VectorXdWithRoom& residual = arrays.residual;
  residual.resize(n);
  residual = Av_new - b;
  for (int k = 0; k < num_bodies; ++k) {
    const int size = offset[k + 1] - offset[k];
    StepReport body_report =
        bodies[k]->FinishStep(v_new.segment(offset[k], size), residual.segment(offset[k], size),
                              settings, report.iterations);
    if (body_report.status != StepStatus::kOk && report.status == StepStatus::kOk) {
      report.status = body_report.status;
      report.bad_body = k;
      report.bad_vertex = body_report.bad_vertex;
    }
  }
  return report;
}

}  // namespace tetcosim

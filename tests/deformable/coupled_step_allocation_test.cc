// StepCoupled with a CoupledStepWorkspace (coupled_step.h) allocates
// nothing once the workspace has stepped the same sizes: every array the
// step works in is the workspace's, and a RigidConstraint's rows are held
// inline (ConstraintVector). tests/support/allocation_counter.h counts.

#include <gtest/gtest.h>

#include <memory>
#include <string>
#include <vector>

#include "deformable/contact.h"
#include "deformable/coupled_step.h"
#include "deformable/deformable_body.h"
#include "deformable/fem_model.h"
#include "mesh/generators.h"
#include "tests/support/allocation_counter.h"

namespace tetcosim {
namespace {

Eigen::Isometry3d At(const Eigen::Vector3d& p) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = p;
  return X;
}

// A row along `axis` of a tree's first three velocities (J: `columns`
// wide, axis^T then zeros), with D and aref = 0
RigidConstraint Row(RigidConstraint::Kind kind, int tree, const Eigen::Vector3d& axis,
                    int columns) {
  RigidConstraint constraint;
  constraint.kind = kind;
  constraint.trees = {tree, -1};
  constraint.jacobian.setZero(1, columns);
  for (int i = 0; i < 3; ++i) constraint.jacobian(0, i) = axis[i];
  constraint.mass = ConstraintVector::Constant(1, 50.0);
  constraint.reference = ConstraintVector::Zero(1);
  return constraint;
}

// A cube pressed onto a plate (a rigid tree solved with the step, its
// contacts sticking or sliding), a second cube hung by its top face from a
// point (a tree that carries the pins: RigidPin) and pressed onto a static
// floor, and constraints of every kind on the two trees: a unilateral row
// on the plate, an elliptic cone sliding in its middle zone and a friction
// loss row sliding on the point, and an equality row between the two.
// Stepped four times from the same system and contacts (the bodies move
// on): the first step sizes the workspace, the next three allocate
// nothing. With a plate of three degrees of freedom (the preconditioner
// eliminates the trees) and of 3 + kMaxEliminatedRigidDofs (it does not).
TEST(CoupledStepAllocation, AWarmWorkspaceStepsTheSameSizesWithoutAllocating) {
  auto model = FemModel::Build(
      std::make_shared<TetMesh>(TetMesh::Build(MakeShape("box:size=0.05:res=3"))), Material{});
  for (const int plate_dofs : {3, 3 + kMaxEliminatedRigidDofs}) {
    SCOPED_TRACE("plate of " + std::to_string(plate_dofs) + " degrees of freedom");
    DeformableBody pressed(model, "pressed"), hung(model, "hung");
    pressed.Reset(At({0.0, 0.0, 0.025 - 5e-4}));  // (the box spans +-0.025)
    hung.Reset(At({0.2, 0.0, 0.025 - 5e-4}), Eigen::Vector3d(0.01, 0.0, 0.0));
    std::vector<int> top;
    for (int v = 0; v < hung.num_vertices(); ++v) {
      if (hung.positions()(v, 2) > 0.02) top.push_back(v);
    }
    hung.PinToFrame(top, Eigen::Isometry3d::Identity());
    const double kappa = DefaultContactPressureStiffness(*model);
    std::vector<ContactPoint> start_contacts;
    AddHalfSpaceContacts(0, pressed, Eigen::Vector3d::UnitZ(), 0.0, kappa, 0.5, start_contacts);
    for (ContactPoint& contact : start_contacts) contact.rigid_point = 0;
    AddHalfSpaceContacts(1, hung, Eigen::Vector3d::UnitZ(), 0.0, kappa, 0.5, start_contacts);
    ASSERT_GT(start_contacts.front().rigid_point, -1);  // (both cubes touch)
    ASSERT_EQ(start_contacts.back().body_a, 1);

    RigidSystem start;
    RigidTree& plate = start.trees.emplace_back();
    plate.mass = 0.5 * Eigen::MatrixXd::Identity(plate_dofs, plate_dofs);
    plate.velocity = Eigen::VectorXd::Zero(plate_dofs);
    plate.impulse = Eigen::VectorXd::Zero(plate_dofs);
    plate.impulse[2] = -0.5 * 9.81 * 1e-3;
    plate.velocity_end = plate.velocity;  // (outputs sized, as RigidSystem::AddTree leaves them)
    RigidTree& point = start.trees.emplace_back();
    point.mass = 0.3 * Eigen::Matrix3d::Identity();
    point.velocity = Eigen::Vector3d(0.01, 0.0, 0.0);
    point.impulse = Eigen::Vector3d::Zero();
    point.velocity_end = point.velocity;
    RigidPoint& on_plate = start.points.emplace_back();
    on_plate.tree = 0;
    on_plate.jacobian = Eigen::MatrixXd::Identity(3, plate_dofs);  // (the first three)
    for (size_t pin = 0; pin < top.size(); ++pin) {
      start.points.push_back({1, Eigen::Matrix3d::Identity()});
      start.pins.push_back({1, static_cast<int>(pin), static_cast<int>(start.points.size()) - 1});
    }
    using Kind = RigidConstraint::Kind;
    start.constraints.push_back(Row(Kind::kUnilateral, 0, Eigen::Vector3d::UnitZ(), plate_dofs));
    RigidConstraint& cone = start.constraints.emplace_back();
    cone.kind = Kind::kEllipticCone;
    cone.trees = {1, -1};
    cone.jacobian.setZero(3, 3);
    cone.jacobian(0, 2) = cone.jacobian(1, 0) = cone.jacobian(2, 1) = 1.0;
    cone.mass = ConstraintVector::Constant(3, 50.0);
    cone.reference = ConstraintVector::Zero(3);
    cone.cone = ConstraintVector::Constant(3, 0.5);
    cone.start_residual = ConstraintVector::Zero(3);
    cone.start_residual[1] = 1.0;  // (u = (0, 0.5, 0): the middle zone, sliding)
    RigidConstraint loss = Row(Kind::kFrictionLoss, 1, Eigen::Vector3d::UnitX(), 3);
    loss.friction_loss = 1e-3;
    loss.start_residual = ConstraintVector::Constant(1, -1.0);  // (beyond its force: sliding)
    start.constraints.push_back(loss);
    RigidConstraint joint = Row(Kind::kEquality, 0, Eigen::Vector3d::UnitY(), plate_dofs + 3);
    joint.trees = {0, 1};
    joint.jacobian(0, plate_dofs + 1) = -1.0;
    start.constraints.push_back(joint);

    StepSettings settings;
    ContactSettings contact_settings;
    CoupledStepWorkspace workspace;
    DeformableBody* bodies[2] = {&pressed, &hung};
    for (int step = 0; step < 4; ++step) {
      std::vector<ContactPoint> contacts = start_contacts;  // (the same sizes every step)
      RigidSystem rigid = start;
      const long before = testing::HeapAllocations();
      const CoupledStepReport report =
          StepCoupled(bodies, contacts, contact_settings, settings, &rigid, &workspace);
      const long allocations = testing::HeapAllocations() - before;
      ASSERT_EQ(report.status, StepStatus::kOk) << "step " << step;
      if (step > 0) {
        EXPECT_EQ(allocations, 0) << "step " << step;
      }
    }
  }
}

// DeformableBody::Step with the conjugate gradients (the coupled step alone)
// keeps its workspace: a cube pinned by one face, swinging under gravity,
// allocates nothing after its first step.
TEST(CoupledStepAllocation, ABodySteppedOnItsOwnAllocatesNothingOnceWarm) {
  auto model = FemModel::Build(
      std::make_shared<TetMesh>(TetMesh::Build(MakeShape("box:size=0.05:res=3"))), Material{});
  DeformableBody body(model, "cube");
  for (int v = 0; v < body.num_vertices(); ++v) {
    if (body.positions()(v, 0) > 0.02) body.Pin(v);
  }
  StepSettings settings;
  ASSERT_EQ(body.Step(settings).status, StepStatus::kOk);
  const long before = testing::HeapAllocations();
  for (int step = 0; step < 5; ++step) ASSERT_EQ(body.Step(settings).status, StepStatus::kOk);
  EXPECT_EQ(testing::HeapAllocations() - before, 0);
  EXPECT_LT(body.positions().col(2).minCoeff(), -0.025);  // (it moved: sagging)
}

}  // namespace
}  // namespace tetcosim

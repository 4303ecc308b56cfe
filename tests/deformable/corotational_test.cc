#include "deformable/corotational.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <numbers>
#include <random>

#include "deformable/deformable_body.h"
#include "mesh/generators.h"

namespace tetcosim {
namespace {

constexpr double kMu = 3.8e4;  // E = 1e5, nu = 0.3
constexpr double kLambda = 5.8e4;

struct Element {
  Eigen::Vector3d X[4];
  Eigen::Matrix<double, 4, 3> b;
  double volume;
};

Element RestElement() {
  Element e;
  e.X[0] = {0.0, 0.0, 0.0};
  e.X[1] = {0.011, 0.001, -0.002};
  e.X[2] = {0.002, 0.009, 0.001};
  e.X[3] = {-0.001, 0.002, 0.010};
  e.b = ShapeGradients(e.X);
  e.volume = (e.X[1] - e.X[0]).cross(e.X[2] - e.X[0]).dot(e.X[3] - e.X[0]) / 6.0;
  return e;
}

// the element's elastic energy and forces at positions x (polar rotation
// converged from the warm start q)
double Energy(const Element& e, const Eigen::Vector3d x[4], Eigen::Quaterniond q) {
  Eigen::Matrix3d F = DeformationGradient(e.b, x);
  Eigen::Matrix3d R = ExtractRotation(F, q, 100, 1e-15);
  return e.volume * CorotatedEnergyDensity(F, R, kMu, kLambda);
}

Eigen::Matrix<double, 12, 1> Forces(const Element& e, const Eigen::Vector3d x[4],
                                    Eigen::Quaterniond q) {
  Eigen::Matrix3d F = DeformationGradient(e.b, x);
  Eigen::Matrix3d R = ExtractRotation(F, q, 100, 1e-15);
  Eigen::Matrix3d P = CorotatedStress(F, R, kMu, kLambda);
  Eigen::Matrix<double, 12, 1> f;
  for (int i = 0; i < 4; ++i) f.segment<3>(3 * i) = -e.volume * P * e.b.row(i).transpose();
  return f;
}

TEST(Corotational, ExtractRotationIsTheRotationOfTheDeformation) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 100; ++trial) {
    Eigen::Matrix3d R0 =
        Eigen::AngleAxisd(3.0 * u(rng), Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized())
            .toRotationMatrix();
    Eigen::Matrix3d S = Eigen::Matrix3d::Identity();
    for (int i = 0; i < 3; ++i) {
      for (int j = i; j < 3; ++j) S(i, j) = S(j, i) = (i == j ? 1.0 : 0.0) + 0.2 * u(rng);
    }
    Eigen::Quaterniond q(R0 * Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX()).toRotationMatrix());
    Eigen::Matrix3d R = ExtractRotation(R0 * S, q, 100, 1e-15);
    EXPECT_NEAR((R - R0).norm(), 0.0, 1e-9) << trial;
    EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
  }
}

// the four-lane version against the scalar one: the same rotations (to
// rounding) and the same number of steps, lane by lane, for warm starts near
// and far (the scalar fallback), inverted and degenerate deformations; and a
// lane's result does not depend on the other lanes (bit for bit)
TEST(Corotational, ExtractRotationsMatchesTheScalarIterationLaneByLane) {
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Eigen::Matrix3d> F;
  std::vector<Eigen::Quaterniond> q;
  for (int trial = 0; trial < 64; ++trial) {
    const Eigen::Matrix3d R0 =
        Eigen::AngleAxisd(3.0 * u(rng), Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized())
            .toRotationMatrix();
    Eigen::Matrix3d S = Eigen::Matrix3d::Identity();
    for (int i = 0; i < 3; ++i) {
      for (int j = i; j < 3; ++j) S(i, j) = S(j, i) = (i == j ? 1.0 : 0.0) + 0.2 * u(rng);
    }
    if (trial % 8 == 3) S(2, 2) = -0.5;                 // inverted
    if (trial % 8 == 5) S.row(1) = S.row(0);            // degenerate
    const double offset = trial % 4 == 0 ? 1.0 : 1e-3;  // far (> 0.1 rad) or near
    F.push_back(R0 * S);
    q.emplace_back(R0 * Eigen::AngleAxisd(offset * u(rng), Eigen::Vector3d::UnitY()));
  }
  for (double tolerance : {1e-8, 1e-15}) {
    std::vector<Eigen::Matrix3d> lane_R(F.size());
    std::vector<Eigen::Quaterniond> lane_q(F.size());
    for (size_t first = 0; first < F.size(); first += 4) {
      Lanes3x3 A;
      LaneQuaternion q4;
      for (int lane = 0; lane < 4; ++lane) {
        for (int i = 0; i < 3; ++i) {
          for (int j = 0; j < 3; ++j) A[i][j][lane] = F[first + lane](i, j);
        }
        const Eigen::Quaterniond& start = q[first + lane];
        q4[0][lane] = start.w();
        q4[1][lane] = start.x();
        q4[2][lane] = start.y();
        q4[3][lane] = start.z();
      }
      const Lanes3x3 R = ExtractRotations(A, q4, 20, tolerance);
      for (int lane = 0; lane < 4; ++lane) {
        for (int i = 0; i < 3; ++i) {
          for (int j = 0; j < 3; ++j) lane_R[first + lane](i, j) = R[i][j][lane];
        }
        lane_q[first + lane] =
            Eigen::Quaterniond(q4[0][lane], q4[1][lane], q4[2][lane], q4[3][lane]);
      }
    }
    for (size_t k = 0; k < F.size(); ++k) {
      Eigen::Quaterniond scalar_q = q[k];
      const Eigen::Matrix3d R = ExtractRotation(F[k], scalar_q, 20, tolerance);
      EXPECT_NEAR((lane_R[k] - R).norm(), 0.0, 1e-12) << k << " " << tolerance;
      EXPECT_NEAR(lane_R[k].determinant(), 1.0, 1e-12) << k;
      EXPECT_NEAR(lane_q[k].angularDistance(scalar_q), 0.0, 1e-12) << k;
      // the same element in lane 3 of a batch whose other lanes are the
      // identity: bit for bit the same
      Lanes3x3 A;
      LaneQuaternion q4 = {Lanes::Ones(), Lanes::Zero(), Lanes::Zero(), Lanes::Zero()};
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) A[i][j] = Lanes::Constant(i == j ? 1.0 : 0.0);
      }
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) A[i][j][3] = F[k](i, j);
      }
      q4[0][3] = q[k].w();
      q4[1][3] = q[k].x();
      q4[2][3] = q[k].y();
      q4[3][3] = q[k].z();
      const Lanes3x3 alone = ExtractRotations(A, q4, 20, tolerance);
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) EXPECT_EQ(alone[i][j][3], lane_R[k](i, j)) << k;
      }
    }
  }
}

TEST(Corotational, ForcesAreTheNegativeEnergyGradient) {
  const Element e = RestElement();
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-0.002, 0.002);
  for (int trial = 0; trial < 20; ++trial) {
    Eigen::Vector3d x[4];
    Eigen::Matrix3d rotation =
        Eigen::AngleAxisd(trial * 0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    for (int i = 0; i < 4; ++i) x[i] = rotation * e.X[i] + Eigen::Vector3d(u(rng), u(rng), u(rng));
    Eigen::Quaterniond q(rotation);
    Eigen::Matrix<double, 12, 1> f = Forces(e, x, q);
    // central differences of the energy
    const double h = 1e-7;
    Eigen::Matrix<double, 12, 1> fd;
    for (int k = 0; k < 12; ++k) {
      Eigen::Vector3d xp[4], xm[4];
      for (int i = 0; i < 4; ++i) xp[i] = xm[i] = x[i];
      xp[k / 3][k % 3] += h;
      xm[k / 3][k % 3] -= h;
      fd[k] = -(Energy(e, xp, q) - Energy(e, xm, q)) / (2.0 * h);
    }
    EXPECT_LT((f - fd).norm(), 1e-6 * f.norm() + 1e-9) << trial;
  }
}

TEST(Corotational, StiffnessMatchesForceDifferencesAtRotatedRest) {
  const Element e = RestElement();
  for (double angle : {0.0, 0.5, 2.0}) {
    Eigen::Matrix3d R =
        Eigen::AngleAxisd(angle, Eigen::Vector3d(0.3, -1, 2).normalized()).toRotationMatrix();
    Eigen::Vector3d x[4];
    for (int i = 0; i < 4; ++i) x[i] = R * e.X[i];
    Eigen::Quaterniond q(R);
    Eigen::Matrix<double, 12, 12> K = CorotatedStiffness(e.b, R, e.volume, kMu, kLambda);
    const double h = 1e-8;
    Eigen::Matrix<double, 12, 12> fd;
    for (int k = 0; k < 12; ++k) {
      Eigen::Vector3d xp[4], xm[4];
      for (int i = 0; i < 4; ++i) xp[i] = xm[i] = x[i];
      xp[k / 3][k % 3] += h;
      xm[k / 3][k % 3] -= h;
      fd.col(k) = -(Forces(e, xp, q) - Forces(e, xm, q)) / (2.0 * h);
    }
    EXPECT_LT((K - fd).norm(), 1e-6 * K.norm()) << angle;
    EXPECT_LT((K - K.transpose()).norm(), 1e-12 * K.norm());
  }
}

TEST(Corotational, StiffnessHasTheSixRigidModesInItsNullSpace) {
  const Element e = RestElement();
  for (double angle : {0.0, 1.0, std::numbers::pi}) {
    Eigen::Matrix3d R =
        Eigen::AngleAxisd(angle, Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix();
    Eigen::Matrix<double, 12, 12> K = CorotatedStiffness(e.b, R, e.volume, kMu, kLambda);
    for (int mode = 0; mode < 6; ++mode) {
      Eigen::Matrix<double, 12, 1> u;
      for (int i = 0; i < 4; ++i) {
        Eigen::Vector3d axis = Eigen::Vector3d::Unit(mode % 3);
        u.segment<3>(3 * i) = mode < 3 ? axis : Eigen::Vector3d(axis.cross(R * e.X[i]));
      }
      EXPECT_LT((K * u).norm(), 1e-10 * K.norm() * u.norm())
          << "angle " << angle << " mode " << mode;
    }
    // and no other: rank 6
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 12, 12>> eigen(K);
    EXPECT_GT(eigen.eigenvalues()[6], 1e-6 * eigen.eigenvalues()[11]);
  }
}

TEST(Corotational, RigidMotionsGiveZeroElasticForce) {
  auto model = FemModel::Build(
      std::make_shared<TetMesh>(TetMesh::Build(MakeShape("torus:size=0.1,0.03:res=3"))),
      Material{});
  DeformableBody body(model, "torus");
  for (double degrees : {0.0, 30.0, 90.0, 180.0}) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = Eigen::AngleAxisd(degrees * std::numbers::pi / 180.0,
                                   Eigen::Vector3d(1, -2, 0.5).normalized())
                     .toRotationMatrix();
    X.translation() = Eigen::Vector3d(0.3, -1.2, 2.0);
    body.Reset(X);
    Positions f = body.ElasticForces();
    EXPECT_LT(f.cwiseAbs().maxCoeff(), 1e-9) << degrees;
  }
  // reaching 180 degrees gradually, from warm starts, as a simulation would
  body.Reset(Eigen::Isometry3d::Identity());
  for (int step = 0; step <= 36; ++step) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = Eigen::AngleAxisd(step * std::numbers::pi / 36.0, Eigen::Vector3d::UnitZ())
                     .toRotationMatrix();
    const Positions& rest = model->mesh().positions();
    for (Eigen::Index v = 0; v < rest.rows(); ++v) {
      body.mutable_positions().row(v) = (X * rest.row(v).transpose()).transpose();
    }
    Positions f = body.ElasticForces();
    EXPECT_LT(f.cwiseAbs().maxCoeff(), 1e-9) << step * 5 << " degrees";
  }
}

TEST(Corotational, InternalForcesSumToZeroForceAndTorque) {
  auto model = FemModel::Build(
      std::make_shared<TetMesh>(TetMesh::Build(MakeShape("capsule:size=0.03,0.05:res=3"))),
      Material{});
  DeformableBody body(model, "capsule");
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-0.005, 0.005);
  for (Eigen::Index v = 0; v < body.num_vertices(); ++v) {
    body.mutable_positions().row(v) += Eigen::RowVector3d(u(rng), u(rng), u(rng));
  }
  Positions f = body.ElasticForces();
  Eigen::Vector3d force = f.colwise().sum().transpose();
  Eigen::Vector3d torque = Eigen::Vector3d::Zero();
  for (Eigen::Index v = 0; v < f.rows(); ++v) {
    torque += body.positions().row(v).transpose().cross(f.row(v).transpose());
  }
  double scale = f.cwiseAbs().maxCoeff();
  ASSERT_GT(scale, 1.0);
  EXPECT_LT(force.norm(), 1e-10 * scale);
  EXPECT_LT(torque.norm(), 1e-10 * scale * 0.1);
}

}  // namespace
}  // namespace tetcosim

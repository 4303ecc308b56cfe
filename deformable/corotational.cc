#include "deformable/corotational.h"

#include <cmath>

namespace tetcosim {

Eigen::Matrix3d ExtractRotation(const Eigen::Matrix3d& A, Eigen::Quaterniond& q, int max_iterations,
                                double tolerance) {
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    Eigen::Matrix3d R = q.toRotationMatrix();
    // omega = sum_i r_i x a_i / (|sum_i r_i . a_i| + eps): the rotation that
    // increases tr(R^T A) (Muller et al. 2016, eq. 7)
    Eigen::Vector3d omega =
        R.col(0).cross(A.col(0)) + R.col(1).cross(A.col(1)) + R.col(2).cross(A.col(2));
    double denominator =
        std::abs(R.col(0).dot(A.col(0)) + R.col(1).dot(A.col(1)) + R.col(2).dot(A.col(2))) + 1e-9;
    omega /= denominator;
    double angle = omega.norm();
    if (!(angle >= tolerance)) break;  // converged (or NaN input: keep q)
    q = Eigen::Quaterniond(Eigen::AngleAxisd(angle, omega / angle)) * q;
    q.normalize();
  }
  return q.toRotationMatrix();
}

Eigen::Matrix<double, 4, 3> ShapeGradients(const Eigen::Vector3d X[4]) {
  Eigen::Matrix3d Dm;
  Dm << X[1] - X[0], X[2] - X[0], X[3] - X[0];
  Eigen::Matrix3d Dm_inv = Dm.inverse();
  Eigen::Matrix<double, 4, 3> b;
  b.bottomRows<3>() = Dm_inv;
  b.row(0) = -Dm_inv.colwise().sum();
  return b;
}

Eigen::Matrix3d DeformationGradient(const Eigen::Matrix<double, 4, 3>& b,
                                    const Eigen::Vector3d x[4]) {
  Eigen::Matrix3d F = x[0] * b.row(0);
  for (int i = 1; i < 4; ++i) F.noalias() += x[i] * b.row(i);
  return F;
}

double CorotatedEnergyDensity(const Eigen::Matrix3d& F, const Eigen::Matrix3d& R, double mu,
                              double lambda) {
  double trace = (R.transpose() * F).trace() - 3.0;
  return mu * (F - R).squaredNorm() + 0.5 * lambda * trace * trace;
}

Eigen::Matrix3d CorotatedStress(const Eigen::Matrix3d& F, const Eigen::Matrix3d& R, double mu,
                                double lambda) {
  double trace = (R.transpose() * F).trace() - 3.0;
  return 2.0 * mu * (F - R) + lambda * trace * R;
}

Eigen::Matrix<double, 12, 12> CorotatedStiffness(const Eigen::Matrix<double, 4, 3>& b,
                                                 const Eigen::Matrix3d& R, double volume, double mu,
                                                 double lambda) {
  Eigen::Matrix<double, 4, 3> c = b * R.transpose();  // rows c_i = (R b_i)^T
  Eigen::Matrix<double, 12, 12> K;
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) {
      K.block<3, 3>(3 * i, 3 * j) =
          volume *
          (lambda * c.row(i).transpose() * c.row(j) + mu * c.row(j).transpose() * c.row(i) +
           mu * b.row(i).dot(b.row(j)) * Eigen::Matrix3d::Identity());
    }
  }
  return K;
}

}  // namespace tetcosim

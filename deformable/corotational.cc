#include "deformable/corotational.h"

#include <Eigen/LU>
#include <cmath>

namespace tetcosim {

Eigen::Matrix3d ExtractRotation(const Eigen::Matrix3d& A, Eigen::Quaterniond& q, int max_iterations,
                                double tolerance) {
  Eigen::Matrix3d R = q.toRotationMatrix();
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    // maximise tr(R^T A) over R = R Exp(w), w in R's own frame. With
    // B = R^T A the gradient is g = axial(B - B^T) (= R^T sum_i r_i x a_i,
    // Muller et al. 2016) and the Hessian H = tr(B) I - sym(B); take the
    // Newton step H^-1 g where H is positive definite (quadratic
    // convergence), else Muller's step g / |tr(B)| (robust for inverted A)
    const Eigen::Matrix3d B = R.transpose() * A;
    const Eigen::Vector3d g(B(2, 1) - B(1, 2), B(0, 2) - B(2, 0), B(1, 0) - B(0, 1));
    const double trace = B.trace();
    // H is symmetric: its upper triangle, and its cofactors (= adjugate)
    const double h00 = trace - B(0, 0), h11 = trace - B(1, 1), h22 = trace - B(2, 2);
    const double h01 = -0.5 * (B(0, 1) + B(1, 0));
    const double h02 = -0.5 * (B(0, 2) + B(2, 0));
    const double h12 = -0.5 * (B(1, 2) + B(2, 1));
    const double c00 = h11 * h22 - h12 * h12;
    const double c01 = h02 * h12 - h01 * h22;
    const double c02 = h01 * h12 - h02 * h11;
    // positive definite iff the leading minors are positive
    const double m1 = h00;
    const double m2 = h00 * h11 - h01 * h01;
    const double m3 = h00 * c00 + h01 * c01 + h02 * c02;  // det H
    const double scale = std::abs(trace) + 1e-300;
    const bool newton =
        m1 > 1e-6 * scale && m2 > 1e-6 * scale * scale && m3 > 1e-6 * scale * scale * scale;
    Eigen::Vector3d omega;
    if (newton) {
      const double c11 = h00 * h22 - h02 * h02;
      const double c12 = h01 * h02 - h00 * h12;
      const double c22 = m2;
      omega = Eigen::Vector3d(c00 * g.x() + c01 * g.y() + c02 * g.z(),
                              c01 * g.x() + c11 * g.y() + c12 * g.z(),
                              c02 * g.x() + c12 * g.y() + c22 * g.z()) /
              m3;
    } else {
      omega = g / (std::abs(trace) + 1e-9);
    }
    const double angle = omega.norm();
    if (!(angle >= tolerance)) break;  // converged (or NaN input: keep q)
    if (angle > 0.1) {
      q = q * Eigen::Quaterniond(Eigen::AngleAxisd(angle, omega / angle));
    } else {
      // small update: Exp(w / 2) ~ (1, w / 2) without trigonometry; the
      // fixed point (w = 0) is the same
      q = q * Eigen::Quaterniond(1.0, 0.5 * omega.x(), 0.5 * omega.y(), 0.5 * omega.z());
    }
    q.normalize();
    R = q.toRotationMatrix();
    // a Newton step converges quadratically: the next step would be of the
    // order of angle^2, below the tolerance, so stop without computing it
    if (newton && angle * angle < 0.1 * tolerance) break;
  }
  return R;
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

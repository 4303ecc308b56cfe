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
      const double inverse_det = 1.0 / m3;
      omega = Eigen::Vector3d(c00 * g.x() + c01 * g.y() + c02 * g.z(),
                              c01 * g.x() + c11 * g.y() + c12 * g.z(),
                              c02 * g.x() + c12 * g.y() + c22 * g.z()) *
              inverse_det;
    } else {
      omega = g / (std::abs(trace) + 1e-9);
    }
    // the rotation is off by about the Newton step's angle a (by a multiple
    // of the gradient step's): done below the tolerance; a Newton step below
    // tolerance^2 is skipped, else taken, since it leaves an error of only
    // about a^2 (squares compared: no square root on the common path)
    const double angle2 = omega.squaredNorm();
    const double skip = newton ? tolerance * tolerance : tolerance;
    if (!(angle2 >= skip * skip)) break;  // converged (or NaN input: keep q)
    if (angle2 > 0.01) {
      const double angle = std::sqrt(angle2);
      q = q * Eigen::Quaterniond(Eigen::AngleAxisd(angle, omega / angle));
    } else {
      // small update: Exp(w / 2) ~ (1, w / 2) without trigonometry; the
      // fixed point (w = 0) is the same
      q = q * Eigen::Quaterniond(1.0, 0.5 * omega.x(), 0.5 * omega.y(), 0.5 * omega.z());
    }
    q.coeffs() *= 1.0 / std::sqrt(q.coeffs().squaredNorm());
    R = q.toRotationMatrix();
    // a Newton step converges quadratically: the next step would be of the
    // order of angle^2; below the tolerance, stop without computing it
    if (newton && angle2 < tolerance) break;
  }
  return R;
}

namespace {

// Eigen's Quaternion::toRotationMatrix, lane by lane
Lanes3x3 RotationMatrix(const LaneQuaternion& q) {
  const Lanes tx = 2.0 * q[1], ty = 2.0 * q[2], tz = 2.0 * q[3];
  const Lanes twx = tx * q[0], twy = ty * q[0], twz = tz * q[0];
  const Lanes txx = tx * q[1], txy = ty * q[1], txz = tz * q[1];
  const Lanes tyy = ty * q[2], tyz = tz * q[2], tzz = tz * q[3];
  Lanes3x3 R;
  R[0] = {1.0 - (tyy + tzz), txy - twz, txz + twy};
  R[1] = {txy + twz, 1.0 - (txx + tzz), tyz - twx};
  R[2] = {txz - twy, tyz + twx, 1.0 - (txx + tyy)};
  return R;
}

}  // namespace

Lanes3x3 ExtractRotations(const Lanes3x3& A, LaneQuaternion& q, int max_iterations,
                          double tolerance) {
  const LaneQuaternion q_start = q;
  Lanes3x3 R = RotationMatrix(q);
  LaneMask done = LaneMask::Constant(false);
  LaneMask large = LaneMask::Constant(false);  // redone by the scalar path
  for (int iteration = 0; iteration < max_iterations && !done.all(); ++iteration) {
    // the steps of ExtractRotation, lane by lane
    Lanes B[3][3];  // R^T A
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) {
        B[i][j] = R[0][i] * A[0][j] + R[1][i] * A[1][j] + R[2][i] * A[2][j];
      }
    }
    const Lanes gx = B[2][1] - B[1][2], gy = B[0][2] - B[2][0], gz = B[1][0] - B[0][1];
    const Lanes trace = B[0][0] + B[1][1] + B[2][2];
    const Lanes h00 = trace - B[0][0], h11 = trace - B[1][1], h22 = trace - B[2][2];
    const Lanes h01 = -0.5 * (B[0][1] + B[1][0]);
    const Lanes h02 = -0.5 * (B[0][2] + B[2][0]);
    const Lanes h12 = -0.5 * (B[1][2] + B[2][1]);
    const Lanes c00 = h11 * h22 - h12 * h12;
    const Lanes c01 = h02 * h12 - h01 * h22;
    const Lanes c02 = h01 * h12 - h02 * h11;
    const Lanes m2 = h00 * h11 - h01 * h01;
    const Lanes m3 = h00 * c00 + h01 * c01 + h02 * c02;
    const Lanes scale = trace.abs() + 1e-300;
    const LaneMask newton =
        (h00 > 1e-6 * scale) && (m2 > 1e-6 * scale * scale) && (m3 > 1e-6 * scale * scale * scale);
    const Lanes c11 = h00 * h22 - h02 * h02;
    const Lanes c12 = h01 * h02 - h00 * h12;
    const Lanes inverse_det = 1.0 / newton.select(m3, Lanes::Ones());
    const Lanes inverse_trace = 1.0 / (trace.abs() + 1e-9);
    const Lanes wx =
        newton.select((c00 * gx + c01 * gy + c02 * gz) * inverse_det, gx * inverse_trace);
    const Lanes wy =
        newton.select((c01 * gx + c11 * gy + c12 * gz) * inverse_det, gy * inverse_trace);
    const Lanes wz =
        newton.select((c02 * gx + c12 * gy + m2 * gz) * inverse_det, gz * inverse_trace);
    const Lanes angle2 = wx * wx + wy * wy + wz * wz;
    const Lanes skip =
        newton.select(Lanes::Constant(tolerance * tolerance), Lanes::Constant(tolerance));
    const LaneMask converged = !(angle2 >= skip * skip);  // NaN: converged, q kept
    const LaneMask big = !converged && angle2 > 0.01;
    large = large || (big && !done);
    const LaneMask update = !done && !converged && !big;
    // q * (1, w / 2), normalised
    const Lanes hx = 0.5 * wx, hy = 0.5 * wy, hz = 0.5 * wz;
    const Lanes w = q[0] - q[1] * hx - q[2] * hy - q[3] * hz;
    const Lanes x = q[0] * hx + q[1] + q[2] * hz - q[3] * hy;
    const Lanes y = q[0] * hy + q[2] + q[3] * hx - q[1] * hz;
    const Lanes z = q[0] * hz + q[3] + q[1] * hy - q[2] * hx;
    const Lanes inverse_norm = (w * w + x * x + y * y + z * z).sqrt().inverse();
    q[0] = update.select(w * inverse_norm, q[0]);
    q[1] = update.select(x * inverse_norm, q[1]);
    q[2] = update.select(y * inverse_norm, q[2]);
    q[3] = update.select(z * inverse_norm, q[3]);
    done = done || converged || big || (update && newton && angle2 < tolerance);
    if (update.any()) R = RotationMatrix(q);
  }
  for (int lane = 0; lane < 4; ++lane) {
    if (!large[lane]) continue;
    Eigen::Matrix3d A_lane;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) A_lane(i, j) = A[i][j][lane];
    }
    Eigen::Quaterniond q_lane(q_start[0][lane], q_start[1][lane], q_start[2][lane],
                              q_start[3][lane]);
    const Eigen::Matrix3d R_lane = ExtractRotation(A_lane, q_lane, max_iterations, tolerance);
    q[0][lane] = q_lane.w();
    q[1][lane] = q_lane.x();
    q[2][lane] = q_lane.y();
    q[3][lane] = q_lane.z();
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) R[i][j][lane] = R_lane(i, j);
    }
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

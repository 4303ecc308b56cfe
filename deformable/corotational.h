#pragma once

// Co-rotational linear elasticity on linear tetrahedra.
//
// Deformation gradient  F = Ds Dm^-1 = sum_i x_i b_i^T, where Dm = [X1-X0,
// X2-X0, X3-X0] at rest, b_1..b_3 are the rows of Dm^-1 and b_0 = -(b_1 +
// b_2 + b_3) (the gradients of the linear shape functions).
// Rotation R: the rotational part of the polar decomposition F = R S, always
// a proper rotation (det R = +1). For an inverted element (det F < 0) the
// polar rotation of F would be a reflection; R stays the rotation closest to
// the last step's (warm-started iteration below), so S = R^T F has a negative
// eigenvalue and the elastic force drives the element back out of inversion.
// Energy density (corotated linear elasticity):
//   Psi(F) = mu |F - R|^2 + lambda / 2 tr(R^T F - I)^2
// First Piola-Kirchhoff stress  P = 2 mu (F - R) + lambda tr(R^T F - I) R
// Nodal forces  f_i = -V P b_i  (the exact gradient of V Psi when R is the
// polar rotation, since R^T F is then symmetric).
// Co-rotated stiffness (R held fixed; exact at undeformed configurations):
//   K_ij = V [lambda c_i c_j^T + mu c_j c_i^T + mu (b_i . b_j) I],  c_i = R b_i
// i.e. R K_lin R^T with K_lin the linear-elastic element stiffness, which has
// the six rigid-body modes in its null space.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>

namespace tetcosim {

// Rotational part of A: the rotation R maximising tr(R^T A), found from the
// warm start q (updated in place) by Newton steps on the rotation, falling
// back to the gradient step of Muller, Bender, Chentanez and Macklin ("A
// Robust Method to Extract the Rotational Part of Deformations", MIG 2016)
// where the Newton step is not defined (inverted or degenerate A). Stops
// once the rotation's estimated error is below `tolerance` radians: right
// after a Newton step of angle a with a^2 < tolerance (quadratic
// convergence: the next step would be about a^2), or when the next Newton
// step would be below tolerance^2 (a gradient step below tolerance), or
// after `max_iterations`. Always returns a proper rotation.
Eigen::Matrix3d ExtractRotation(const Eigen::Matrix3d& A, Eigen::Quaterniond& q,
                                int max_iterations = 20, double tolerance = 1e-12);

// Four elements at once, one per SIMD lane (Eigen packs an Array4d into
// AVX or SSE2 registers), for the element loops.
using Lanes = Eigen::Array4d;
using LaneMask = Eigen::Array<bool, 4, 1>;
using Lanes3x3 = std::array<std::array<Lanes, 3>, 3>;  // [row][column]
using LaneQuaternion = std::array<Lanes, 4>;           // w, x, y, z

// ExtractRotation lane by lane: the same iteration, with the same stopping
// rules per lane (a lane that has stopped no longer changes while others
// iterate, so a lane's result does not depend on the other lanes). A lane
// whose update would turn by more than 0.1 rad (no small-angle update)
// is redone by the scalar ExtractRotation from its warm start. Agrees with
// ExtractRotation lane by lane to rounding.
Lanes3x3 ExtractRotations(const Lanes3x3& A, LaneQuaternion& q, int max_iterations,
                          double tolerance);

// Shape-function gradients b_0..b_3 (rows) of a tetrahedron at rest.
Eigen::Matrix<double, 4, 3> ShapeGradients(const Eigen::Vector3d X[4]);

// F = sum_i x_i b_i^T.
Eigen::Matrix3d DeformationGradient(const Eigen::Matrix<double, 4, 3>& b,
                                    const Eigen::Vector3d x[4]);

// Psi(F) for the rotation R of F.
double CorotatedEnergyDensity(const Eigen::Matrix3d& F, const Eigen::Matrix3d& R, double mu,
                              double lambda);

// P(F) for the rotation R of F.
Eigen::Matrix3d CorotatedStress(const Eigen::Matrix3d& F, const Eigen::Matrix3d& R, double mu,
                                double lambda);

// The 12 x 12 co-rotated element stiffness (vertex-major: rows 3i..3i+2 for
// vertex i), positive semi-definite; df = -K dx.
Eigen::Matrix<double, 12, 12> CorotatedStiffness(const Eigen::Matrix<double, 4, 3>& b,
                                                 const Eigen::Matrix3d& R, double volume, double mu,
                                                 double lambda);

}  // namespace tetcosim

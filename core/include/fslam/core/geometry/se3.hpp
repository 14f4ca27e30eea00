// SE(3) and SO(3) utilities on Eigen types. Tangent vectors are ordered [rho (translation); phi
// (rotation)], T = exp(xi) with xi = [rho; phi]. Transforms are named T_to_from.
#pragma once

#include <array>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace fslam::core {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

// Skew-symmetric matrix with hat(a) * b = a x b.
Eigen::Matrix3d hat(const Eigen::Vector3d& a);
Eigen::Matrix3d so3_exp(const Eigen::Vector3d& phi);
// Rotation vector of R, angle in [0, pi].
Eigen::Vector3d so3_log(const Eigen::Matrix3d& R);
// Left Jacobian of SO(3): V in exp([rho; phi]).translation() = V(phi) * rho.
Eigen::Matrix3d so3_left_jacobian(const Eigen::Vector3d& phi);
Eigen::Matrix3d so3_left_jacobian_inverse(const Eigen::Vector3d& phi);

Eigen::Isometry3d se3_exp(const Vector6d& xi);
Vector6d se3_log(const Eigen::Isometry3d& T);

// Geodesic interpolation: a at s = 0, b at s = 1 (rotation by slerp, translation linear).
Eigen::Isometry3d interpolate(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, double s);

// Rotation angle of R in radians, in [0, pi].
double rotation_angle(const Eigen::Matrix3d& R);

// TUM order: tx ty tz qx qy qz qw (Eigen stores quaternions x, y, z, w too, but constructs w first).
std::array<double, 7> to_tum(const Eigen::Isometry3d& T);
// The quaternion is normalised; callers check its norm first if they must reject bad input.
Eigen::Isometry3d from_tum(const std::array<double, 7>& tum);

bool is_finite(const Eigen::Isometry3d& T);
// Rotation block orthonormal with det +1 within `tolerance`, last row [0 0 0 1].
bool is_rigid(const Eigen::Matrix4d& M, double tolerance = 1e-4);
// Nearest rotation (SVD) so poses read from text with few digits become exact isometries.
Eigen::Isometry3d orthonormalise(const Eigen::Matrix4d& M);

}  // namespace fslam::core

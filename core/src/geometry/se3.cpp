#include "fslam/core/geometry/se3.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/SVD>

namespace fslam::core {
namespace {
constexpr double kSmallAngle = 1e-8;  // below this, Taylor expansions replace the closed forms
}

Eigen::Matrix3d hat(const Eigen::Vector3d& a) {
  Eigen::Matrix3d m;
  m << 0.0, -a.z(), a.y(), a.z(), 0.0, -a.x(), -a.y(), a.x(), 0.0;
  return m;
}

Eigen::Matrix3d so3_exp(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  if (theta < kSmallAngle) return Eigen::Matrix3d::Identity() + hat(phi);
  return Eigen::AngleAxisd(theta, phi / theta).toRotationMatrix();
}

Eigen::Vector3d so3_log(const Eigen::Matrix3d& R) {
  // Through the quaternion: stable near 0 and near pi, unlike acos((tr - 1) / 2).
  Eigen::Quaterniond q(R);
  q.normalize();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  const double s = q.vec().norm();
  if (s < kSmallAngle) return 2.0 * q.vec();
  const double theta = 2.0 * std::atan2(s, q.w());
  return theta * q.vec() / s;
}

Eigen::Matrix3d so3_left_jacobian(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d W = hat(phi);
  if (theta < 1e-5) return Eigen::Matrix3d::Identity() + 0.5 * W + W * W / 6.0;
  const double t2 = theta * theta;
  return Eigen::Matrix3d::Identity() + (1.0 - std::cos(theta)) / t2 * W +
         (theta - std::sin(theta)) / (t2 * theta) * W * W;
}

Eigen::Matrix3d so3_left_jacobian_inverse(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d W = hat(phi);
  if (theta < 1e-5) return Eigen::Matrix3d::Identity() - 0.5 * W + W * W / 12.0;
  const double half = 0.5 * theta;
  const double cot = std::cos(half) / std::sin(half);
  return Eigen::Matrix3d::Identity() - 0.5 * W +
         (1.0 - half * cot) / (theta * theta) * W * W;
}

Eigen::Isometry3d se3_exp(const Vector6d& xi) {
  const Eigen::Vector3d rho = xi.head<3>();
  const Eigen::Vector3d phi = xi.tail<3>();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = so3_exp(phi);
  T.translation() = so3_left_jacobian(phi) * rho;
  return T;
}

Vector6d se3_log(const Eigen::Isometry3d& T) {
  const Eigen::Vector3d phi = so3_log(T.linear());
  Vector6d xi;
  xi.head<3>() = so3_left_jacobian_inverse(phi) * T.translation();
  xi.tail<3>() = phi;
  return xi;
}

Eigen::Isometry3d interpolate(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, double s) {
  const Eigen::Quaterniond qa(a.linear());
  const Eigen::Quaterniond qb(b.linear());
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = qa.slerp(s, qb).normalized().toRotationMatrix();
  T.translation() = (1.0 - s) * a.translation() + s * b.translation();
  return T;
}

double rotation_angle(const Eigen::Matrix3d& R) { return so3_log(R).norm(); }

std::array<double, 7> to_tum(const Eigen::Isometry3d& T) {
  Eigen::Quaterniond q(T.linear());
  q.normalize();
  const Eigen::Vector3d t = T.translation();
  return {t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()};
}

Eigen::Isometry3d from_tum(const std::array<double, 7>& v) {
  Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);  // Eigen's constructor takes w first
  q.normalize();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = q.toRotationMatrix();
  T.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return T;
}

bool is_finite(const Eigen::Isometry3d& T) { return T.matrix().allFinite(); }

bool is_rigid(const Eigen::Matrix4d& M, double tolerance) {
  if (!M.allFinite()) return false;
  const Eigen::Matrix3d R = M.topLeftCorner<3, 3>();
  const bool bottom = M.row(3).isApprox(Eigen::RowVector4d(0, 0, 0, 1), tolerance) &&
                      std::abs(M(3, 3) - 1.0) < tolerance;
  return bottom && (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() <
                       tolerance && std::abs(R.determinant() - 1.0) < tolerance;
}

Eigen::Isometry3d orthonormalise(const Eigen::Matrix4d& M) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(M.topLeftCorner<3, 3>(),
                                        Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d R = svd.matrixU() * svd.matrixV().transpose();
  if (R.determinant() < 0.0) {
    Eigen::Matrix3d U = svd.matrixU();
    U.col(2) *= -1.0;
    R = U * svd.matrixV().transpose();
  }
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = R;
  T.translation() = M.topRightCorner<3, 1>();
  return T;
}

}  // namespace fslam::core

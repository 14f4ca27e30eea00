#include "fslam/core/geometry/se3.hpp"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

namespace fslam::core {
namespace {

Vector6d random_twist(std::mt19937& rng, double scale) {
  std::uniform_real_distribution<double> u(-scale, scale);
  Vector6d xi;
  for (int i = 0; i < 6; ++i) xi[i] = u(rng);
  return xi;
}

TEST(Se3, ExpLogRoundTrip) {
  std::mt19937 rng(7);
  for (int k = 0; k < 200; ++k) {
    const Vector6d xi = random_twist(rng, 1.5);  // angles up to ~2.6 rad
    const Vector6d back = se3_log(se3_exp(xi));
    EXPECT_LT((back - xi).norm(), 1e-9) << xi.transpose();
  }
}

TEST(Se3, SmallAndNearPiAngles) {
  Vector6d xi = Vector6d::Zero();
  xi << 0.1, -0.2, 0.3, 1e-12, 0.0, 0.0;
  EXPECT_LT((se3_log(se3_exp(xi)) - xi).norm(), 1e-12);
  const Eigen::Vector3d phi(0.0, M_PI - 1e-7, 0.0);
  EXPECT_NEAR(so3_log(so3_exp(phi)).norm(), M_PI - 1e-7, 1e-6);
}

TEST(Se3, LeftJacobianMatchesFiniteDifference) {
  // d/dt exp(phi + t * delta) * exp(phi)^T at t = 0 equals hat(J_l(phi) * delta).
  const Eigen::Vector3d phi(0.3, -0.7, 0.4);
  const Eigen::Vector3d delta(0.2, 0.1, -0.5);
  const double h = 1e-6;
  const Eigen::Matrix3d dR = (so3_exp(phi + h * delta) - so3_exp(phi - h * delta)) / (2 * h);
  const Eigen::Matrix3d omega_hat = dR * so3_exp(phi).transpose();
  const Eigen::Vector3d omega(omega_hat(2, 1), omega_hat(0, 2), omega_hat(1, 0));
  EXPECT_LT((omega - so3_left_jacobian(phi) * delta).norm(), 1e-8);
  EXPECT_LT((so3_left_jacobian(phi) * so3_left_jacobian_inverse(phi) -
             Eigen::Matrix3d::Identity()).norm(), 1e-12);
}

TEST(Se3, InterpolationEndsAndMidpoint) {
  std::mt19937 rng(3);
  const Eigen::Isometry3d a = se3_exp(random_twist(rng, 1.0));
  const Eigen::Isometry3d b = se3_exp(random_twist(rng, 1.0));
  EXPECT_TRUE(interpolate(a, b, 0.0).isApprox(a, 1e-12));
  EXPECT_TRUE(interpolate(a, b, 1.0).isApprox(b, 1e-12));
  // Rotation of the midpoint is halfway along the geodesic.
  const Eigen::Isometry3d m = interpolate(a, b, 0.5);
  const double total = rotation_angle(a.linear().transpose() * b.linear());
  EXPECT_NEAR(rotation_angle(a.linear().transpose() * m.linear()), 0.5 * total, 1e-9);
  EXPECT_TRUE(m.translation().isApprox(0.5 * (a.translation() + b.translation())));
}

TEST(Se3, TumOrderRoundTrip) {
  const Eigen::Isometry3d T = from_tum({1.0, 2.0, 3.0, 0.0, 0.0, std::sin(0.25), std::cos(0.25)});
  // qz = sin(theta/2) -> rotation by 0.5 rad about z.
  EXPECT_NEAR(rotation_angle(T.linear()), 0.5, 1e-12);
  EXPECT_NEAR(T.linear()(1, 0), std::sin(0.5), 1e-12);
  const auto tum = to_tum(T);
  EXPECT_DOUBLE_EQ(tum[0], 1.0);
  EXPECT_NEAR(tum[5], std::sin(0.25), 1e-12);
  EXPECT_NEAR(tum[6], std::cos(0.25), 1e-12);
}

TEST(Se3, RigidityChecks) {
  Eigen::Matrix4d M = se3_exp((Vector6d() << 1, 2, 3, 0.1, 0.2, 0.3).finished()).matrix();
  EXPECT_TRUE(is_rigid(M));
  M(0, 0) += 0.01;
  EXPECT_FALSE(is_rigid(M));
  EXPECT_TRUE(is_rigid(orthonormalise(M).matrix()));
  M(1, 1) = std::nan("");
  EXPECT_FALSE(is_rigid(M));
}

}  // namespace
}  // namespace fslam::core

// The keyframe rules (paper eq. keyframe_crit and the mapper's mapping keyframe) on poses with a
// known motion between them.
#include "fslam/core/tracking/keyframe_policy.hpp"

#include <cmath>

#include <gtest/gtest.h>

namespace fslam::core {
namespace {

constexpr double kDeg = M_PI / 180.0;

// A camera-to-world pose: rotation `angle` about `axis`, then at `t` (metres).
Eigen::Isometry3d pose(double angle, const Eigen::Vector3d& axis, const Eigen::Vector3d& t) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  T.translation() = t;
  return T;
}

TEST(KeyframePolicy, MotionIsTheCameraCentreDistanceAndTheRelativeRotationAngle) {
  const Eigen::Isometry3d T_k = pose(0.7, {0.2, 1.0, -0.3}, {1.0, -2.0, 0.5});
  // 4 cm along a diagonal and 2.5 degrees about another axis, applied in the world frame.
  const Eigen::Vector3d step = 0.04 * Eigen::Vector3d(1.0, 2.0, -2.0) / 3.0;
  Eigen::Isometry3d T_c = T_k;
  T_c.linear() = Eigen::AngleAxisd(2.5 * kDeg, Eigen::Vector3d(1.0, 0.0, 1.0).normalized()) * T_k.linear();
  T_c.translation() += step;
  const PoseMotion m = pose_motion(T_k, T_c);
  EXPECT_NEAR(m.translation, 0.04, 1e-12);         // metres
  EXPECT_NEAR(m.rotation, 2.5 * kDeg, 1e-12);      // radians
  const PoseMotion back = pose_motion(T_c, T_k);  // the same motion either way
  EXPECT_NEAR(back.translation, m.translation, 1e-12);
  EXPECT_NEAR(back.rotation, m.rotation, 1e-12);
  // Near a half turn the angle stays exact (the quaternion form, not acos of the trace).
  const PoseMotion half = pose_motion(T_k, pose(M_PI - 1e-6, {0.0, 0.0, 1.0}, {0.0, 0.0, 0.0}) * T_k);
  EXPECT_NEAR(half.rotation, M_PI - 1e-6, 1e-9);
}

TEST(KeyframePolicy, TrackerKeyframeWhenAnyThresholdIsExceeded) {
  const KeyframeConfig config;  // 5 cm, 3 degrees, 2 cm RMS
  EXPECT_FALSE(is_keyframe(config, {0.049, 2.9 * kDeg}, 0.019));
  EXPECT_TRUE(is_keyframe(config, {0.051, 0.0}, 0.0));
  EXPECT_TRUE(is_keyframe(config, {0.0, 3.1 * kDeg}, 0.0));
  EXPECT_TRUE(is_keyframe(config, {0.0, 0.0}, 0.021));
}

TEST(KeyframePolicy, MappingKeyframeFromTheSameMeasure) {
  // The mapper's defaults: 15 cm or 9 degrees from the last mapping keyframe.
  EXPECT_FALSE(is_mapping_keyframe({0.149, 8.9 * kDeg}, 0.15, 9.0));
  EXPECT_TRUE(is_mapping_keyframe({0.151, 0.0}, 0.15, 9.0));
  EXPECT_TRUE(is_mapping_keyframe({0.0, 9.1 * kDeg}, 0.15, 9.0));
  const Eigen::Isometry3d T_k = pose(0.3, {1.0, 0.0, 0.0}, {0.0, 0.0, 0.0});
  const Eigen::Isometry3d T_c = pose(0.3 + 10.0 * kDeg, {1.0, 0.0, 0.0}, {0.0, 0.0, 0.0});
  EXPECT_TRUE(is_mapping_keyframe(pose_motion(T_k, T_c), 0.15, 9.0));
  EXPECT_FALSE(is_mapping_keyframe(pose_motion(T_k, T_c), 0.15, 11.0));
}

}  // namespace
}  // namespace fslam::core

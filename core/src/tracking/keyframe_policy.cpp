#include "fslam/core/tracking/keyframe_policy.hpp"

#include <cmath>

#include "fslam/core/error.hpp"
#include "fslam/core/geometry/se3.hpp"

namespace fslam::core {
namespace {
constexpr double kDegToRad = M_PI / 180.0;
}  // namespace

bool KeyframeConfig::is_valid(std::string* why) const {
  if (!(translation > 0.0)) return fail(why, "keyframe.translation must be > 0 m");
  if (!(rotation_deg > 0.0)) return fail(why, "keyframe.rotation_deg must be > 0");
  if (!(rms_residual > 0.0)) return fail(why, "keyframe.rms_residual must be > 0 m");
  return true;
}

PoseMotion pose_motion(const Eigen::Isometry3d& T_world_reference, const Eigen::Isometry3d& T_world_current) {
  PoseMotion m;
  m.translation = (T_world_current.translation() - T_world_reference.translation()).norm();
  m.rotation = rotation_angle(T_world_current.linear() * T_world_reference.linear().transpose());
  return m;
}

// Eq. keyframe_crit: ||t_c - t_k|| > tau_t or angle(R_c R_k^T) > tau_r or sigma_gicp > tau_sigma.
bool is_keyframe(const KeyframeConfig& config, const PoseMotion& motion, double rms_residual) {
  return motion.translation > config.translation || motion.rotation > config.rotation_deg * kDegToRad ||
         rms_residual > config.rms_residual;
}

double motion_in_thresholds(const PoseMotion& motion, double translation, double rotation_deg) {
  return motion.translation / translation + motion.rotation / (rotation_deg * kDegToRad);
}

bool is_mapping_keyframe(const PoseMotion& motion, double min_translation, double min_rotation_deg) {
  return motion.translation >= min_translation || motion.rotation * 180.0 / M_PI >= min_rotation_deg;
}

}  // namespace fslam::core

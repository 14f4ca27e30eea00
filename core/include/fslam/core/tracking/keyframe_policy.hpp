// The keyframe rules, in one place and with one measure of motion: the tracker's keyframe
// (paper eq. keyframe_crit: a new keyframe grows the map) and the mapper's mapping keyframe (a
// keyframe far enough from the last mapping keyframe prunes with the mapping percentile of eq.
// pruning_set). Both measure a pose's motion from a reference pose as the translation
// ||t_c - t_k|| and the rotation angle(R_c R_k^T).
#pragma once

#include <string>

#include <Eigen/Geometry>

namespace fslam::core {

// Eq. keyframe_crit: a keyframe when translation > tau_t, or rotation > tau_r, or the RMS GICP
// residual > tau_sigma, measured against the last keyframe.
struct KeyframeConfig {
  double translation = 0.05;    // tau_t, metres
  double rotation_deg = 3.0;    // tau_r, degrees
  double rms_residual = 0.02;   // tau_sigma, metres
  bool is_valid(std::string* why = nullptr) const;
};

// How far a camera moved from a reference pose.
struct PoseMotion {
  double translation = 0.0;  // ||t_c - t_k||, metres
  double rotation = 0.0;     // angle(R_c R_k^T), radians in [0, pi]
};

// The motion of T_world_current from T_world_reference (both camera-to-world).
PoseMotion pose_motion(const Eigen::Isometry3d& T_world_reference, const Eigen::Isometry3d& T_world_current);

// A motion in units of a translation (metres) and a rotation (degrees) threshold, summed: below 1
// for a motion well inside both, 2 at both thresholds. Ranks keyframes by redundancy.
double motion_in_thresholds(const PoseMotion& motion, double translation, double rotation_deg);

// Eq. keyframe_crit for a frame that moved `motion` from the last keyframe and registered with
// RMS residual `rms_residual` (metres).
bool is_keyframe(const KeyframeConfig& config, const PoseMotion& motion, double rms_residual);

// A mapping keyframe: moved at least `min_translation` metres or `min_rotation_deg` degrees from
// the last mapping keyframe (MapperConfig::mapping_keyframe_translation, _rotation_deg).
bool is_mapping_keyframe(const PoseMotion& motion, double min_translation, double min_rotation_deg);

}  // namespace fslam::core

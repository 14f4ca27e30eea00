// The keyframe rules, in one place and with one measure of motion: the tracker's keyframe
// (paper eq. keyframe_crit: a new keyframe grows the map) and the mapper's mapping keyframe (a
// keyframe far enough from the last mapping keyframe prunes with the mapping percentile of eq.
// pruning_set). Both measure a pose's motion from a reference pose as the translation
// ||t_c - t_k|| and the rotation angle(R_c R_k^T).
#pragma once

#include <cmath>
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

// A revisit (the mapper's stored keyframes, MapperConfig::revisit_*; relocalisation's described
// ones, RelocaliserConfig::revisit_*): T_world_current within both `translation` (metres) and
// `rotation_deg` of a kept keyframe's pose. The kept keyframe in [begin, end) it revisits, the
// nearest in threshold units (motion_in_thresholds), or `end` when none is (or a threshold is 0).
// pose_of(keyframe) gives a keyframe's camera-to-world pose.
template <typename It, typename PoseOf>
It find_revisited(It begin, It end, const Eigen::Isometry3d& T_world_current, double translation,
                  double rotation_deg, const PoseOf& pose_of) {
  It revisited = end;
  if (!(translation > 0.0 && rotation_deg > 0.0)) return end;
  double best = 2.0;  // a motion inside both thresholds scores below 2
  for (It it = begin; it != end; ++it) {
    const PoseMotion m = pose_motion(pose_of(*it), T_world_current);
    if (m.translation >= translation || m.rotation >= rotation_deg * M_PI / 180.0) continue;
    const double score = motion_in_thresholds(m, translation, rotation_deg);
    if (score < best) best = score, revisited = it;
  }
  return revisited;
}

}  // namespace fslam::core

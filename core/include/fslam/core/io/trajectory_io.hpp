// Camera trajectories in TUM format: "timestamp tx ty tz qx qy qz qw", camera-to-world.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Geometry>

namespace fslam::core {

struct StampedPose {
  double timestamp = 0.0;          // seconds
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
};
using Trajectory = std::vector<StampedPose>;

// Reads a TUM trajectory ('#' comments and blank lines skipped, spaces, tabs or commas between
// fields). Rejects lines with too few fields, non-numbers, non-finite values and quaternions far
// from unit norm, naming the file and line.
bool read_tum_trajectory(const std::string& path, Trajectory* trajectory, std::string* why);
bool write_tum_trajectory(const std::string& path, const Trajectory& trajectory, std::string* why);

// The pose whose timestamp is nearest to `t`, or nullptr when none is within max_difference
// seconds (the TUM association tolerance by default).
const StampedPose* nearest_pose(const Trajectory& trajectory, double t, double max_difference = 0.02);
// Not on a temporary: the pointer would dangle (`fslam track --loop-closure` read freed memory
// that way, found by ASan).
const StampedPose* nearest_pose(Trajectory&& trajectory, double t, double max_difference = 0.02) = delete;

}  // namespace fslam::core

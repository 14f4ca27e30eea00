// `fslam stream --rosbag2 DIR`: a rosbag2 recording (sqlite3 storage) of a ROS 2 RGB-D camera as a
// dataset, so that it plays to the server like any recorded sequence (docs/ros2.md).
#pragma once

#include <memory>
#include <string>

#include "fslam/core/dataset/dataset.hpp"

namespace fslam::cli {

// Frames of the bag: colour (sensor_msgs/Image rgb8 / bgr8 / mono8 or CompressedImage jpeg / png)
// paired with depth (Image 16UC1 / 32FC1) by header stamp within `tolerance_ms`, intrinsics from
// the first usable CameraInfo. `topics`: "colour,depth,camera_info" ROS names, or empty to pick
// them by type (depth: the Image topic whose name holds "depth"). Null with `why` otherwise.
std::unique_ptr<core::Dataset> open_rosbag2_dataset(const std::string& folder, const std::string& topics,
                                                    double tolerance_ms, std::string* why);

}  // namespace fslam::cli

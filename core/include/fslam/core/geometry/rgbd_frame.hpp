// One RGB-D observation as every stage of the pipeline sees it.
#pragma once

#include <cstdint>
#include <optional>

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/pinhole_camera.hpp"

namespace fslam::core {

struct RgbdFrame {
  std::int64_t id = 0;     // frame number in its source (file number, or index in the dataset)
  double timestamp = 0.0;  // seconds
  cv::Mat colour;          // [H, W] CV_8UC3, RGB order
  cv::Mat depth;           // [H, W] CV_32FC1, metres along the optical axis; 0 = missing
  PinholeCamera camera;    // intrinsics of `depth` (and of `colour` when registered)
  std::optional<Eigen::Isometry3d> T_world_camera_gt;  // ground truth, camera-to-world
};

}  // namespace fslam::core

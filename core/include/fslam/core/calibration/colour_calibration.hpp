// Estimating the colour sensor of an RGB-D camera (ColourCamera) from a posed recording: the
// colour camera's focal length, principal point and offset from the depth camera are the ones
// under which the colours that two views see at the same depth points agree best. Needs depth
// camera poses (ground truth or a tracked trajectory) and textured surfaces seen from several
// viewpoints; docs/datasets.md has the measured values for 7-Scenes.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/colour_camera.hpp"
#include "fslam/core/geometry/pinhole_camera.hpp"

namespace fslam::core {

struct ColourCalibrationConfig {
  int pixel_stride = 4;            // depth pixels sampled every pixel_stride in u and v
  int blur_radius = 2;             // box blur half-size (pixels) of the grey images: a wider basin
  double residual_cap = 30.0;      // grey levels; larger differences (occlusions, highlights) count as this
  double min_depth = 0.3;          // metres; depth samples outside are not used
  double max_depth = 6.0;
  int max_iterations = 80;         // pattern-search sweeps
  double final_focal_step = 0.25;  // pixels; the search ends when the focal step falls below this
  bool is_valid(std::string* why = nullptr) const;
};

// One view: the raw (unregistered) colour image, depth in metres and the depth camera's pose.
struct ColourCalibrationView {
  cv::Mat colour;  // [H, W] CV_8UC3
  cv::Mat depth;   // [H, W] CV_32FC1 metres, 0 = missing
  Eigen::Isometry3d T_world_depth = Eigen::Isometry3d::Identity();
};

struct ColourCalibrationPair {
  ColourCalibrationView a, b;
};

struct ColourCalibrationResult {
  ColourCamera camera;
  double initial_cost = 0.0;  // mean capped grey-level difference under the initial camera
  double final_cost = 0.0;    // ... under the estimate
  std::size_t samples = 0;    // depth samples of the first views, over all pairs
  int evaluations = 0;
};

// Estimates fx (fy keeps the initial aspect ratio fy / fx), cx, cy, tx and ty from `initial`
// (tz is kept: a forward offset of millimetres changes nothing visible) by a pattern search on
// the mean capped difference between the grey levels pair.a and pair.b show at pair.a's depth
// points. Fails on bad input or when the pairs share no visible samples.
bool calibrate_colour_camera(const std::vector<ColourCalibrationPair>& pairs,
                             const PinholeCamera& depth_camera, const ColourCamera& initial,
                             const ColourCalibrationConfig& config, ColourCalibrationResult* result,
                             std::string* why);

}  // namespace fslam::core

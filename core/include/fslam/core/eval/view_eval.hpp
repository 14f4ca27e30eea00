// Rendering quality of a map at given views: render each frame's pose, then PSNR and SSIM of the
// colour (8-bit, as written to disk) and depth L1 of the expected and the median depth against
// the sensor's (docs/evaluation.md, "Rendering").
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/rgbd_frame.hpp"
#include "fslam/core/map/gaussian_map.hpp"
#include "fslam/core/render/rasterizer.hpp"

namespace fslam::core {

// One rendered view against its frame.
struct ViewScore {
  double psnr_db = 0.0;
  double ssim = 0.0;
  // Expected camera-plane depth D (eq. blending with the planar depth), the depth the losses
  // train; and the median depth. Pixels with valid sensor depth; holes count fully.
  double depth_l1_cm = 0.0;
  double depth_l1_median_cm = 0.0;
  double depth_missing_fraction = 0.0;  // valid sensor pixels the render left without depth
};

// Means over a set of views (all 0 for none).
struct ViewScores {
  std::vector<ViewScore> views;
  ViewScore mean() const;
};

// [H, W] CV_8UC3 RGB of a [3, H, W] colour in [0, 1] (rounded, clamped), the image PSNR and SSIM
// score.
cv::Mat colour_to_rgb8(const PlanarImage& colour);

// Renders `map` at T_world_camera with the frame's camera and scores it against the frame.
// rendered (optional): the render, for pictures of the view.
bool evaluate_view(const Rasterizer& rasterizer, const GaussianMap& map, const RgbdFrame& frame,
                   const Eigen::Isometry3d& T_world_camera, const RenderSettings& settings,
                   ViewScore* score, std::string* why, RenderResult* rendered = nullptr);

}  // namespace fslam::core

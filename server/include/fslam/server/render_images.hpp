// Turning renderer outputs into 8-bit images: for files (fslam run, fslam render) and for render
// results on the wire (wire.hpp).
#pragma once

#include <cstdint>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "fslam/core/eval/view_eval.hpp"
#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/render/rasterizer.hpp"

#include "fslam/core/math/unproject.hpp"
#include "fslam/core/render/planar_image.hpp"

namespace fslam::server {

// [3, H, W] colour in [0, 1] -> CV_8UC3 RGB: core's (the image the held-out scores are of).
using core::colour_to_rgb8;
// One plane of a PlanarImage as CV_32FC1.
cv::Mat plane_to_mat(const core::PlanarImage& image, int channel);
// Depth in metres -> turbo colour map over [0, max_depth], black where missing.
cv::Mat depth_to_rgb8(const cv::Mat& depth_m, double max_depth);
// Normals of a depth image, shown as 127.5 (1 - n) (camera frame, facing the camera).
cv::Mat normals_to_rgb8(const core::PlanarImage& depth, const core::math::Intrinsics& intrinsics);
// [1, H, W] in [0, 1] -> grey CV_8UC3.
cv::Mat opacity_to_rgb8(const core::PlanarImage& alpha);

}  // namespace fslam::server

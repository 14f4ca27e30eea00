// Turning renderer outputs into 8-bit images: for files (fslam run, fslam render) and for render
// results on the wire (the server).
#pragma once

#include <cstdint>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/render/rasterizer.hpp"

#include "fslam/core/math/unproject.hpp"
#include "fslam/core/render/planar_image.hpp"

namespace fslam::server {

// [3, H, W] colour in [0, 1] -> CV_8UC3 RGB.
cv::Mat colour_to_rgb8(const core::PlanarImage& colour);
// One plane of a PlanarImage as CV_32FC1.
cv::Mat plane_to_mat(const core::PlanarImage& image, int channel);
// Depth in metres -> turbo colour map over [0, max_depth], black where missing.
cv::Mat depth_to_rgb8(const cv::Mat& depth_m, double max_depth);
// Normals of a depth image, shown as 127.5 (1 - n) (camera frame, facing the camera).
cv::Mat normals_to_rgb8(const core::PlanarImage& depth, const core::math::Intrinsics& intrinsics);
// [1, H, W] in [0, 1] -> grey CV_8UC3.
cv::Mat opacity_to_rgb8(const core::PlanarImage& alpha);

// One channel of a render result on the wire (proto CHANNEL_* bits).
struct ChannelImage {
  std::uint32_t channel = 0;  // one CHANNEL_* bit
  cv::Mat image;              // CV_8UC3 RGB, CV_16UC1 depth, or CV_8UC1 opacity
};
// The requested channels in bit order: colour RGB8; depth as expected camera-plane depth divided
// by opacity (0 where opacity < 0.5 or beyond 16 bits) times depth_scale, 16-bit; normals of
// the median depth as normals_to_rgb8 draws them; opacity 8-bit.
std::vector<ChannelImage> render_channels(const core::RenderResult& rendered,
                                          const core::PinholeCamera& camera,
                                          std::uint32_t channels, float depth_scale);
// PNG bytes of a CV_8UC1 / CV_8UC3 (RGB) / CV_16UC1 image; false when encoding fails.
bool encode_png(const cv::Mat& image, std::vector<std::uint8_t>* bytes);

}  // namespace fslam::server

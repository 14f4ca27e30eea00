#include "fslam/core/eval/view_eval.hpp"

#include <algorithm>
#include <cmath>

#include <opencv2/core.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/eval/image_metrics.hpp"

namespace fslam::core {
namespace {

cv::Mat plane_of(const PlanarImage& image, int channel) {
  cv::Mat out(image.height, image.width, CV_32FC1);
  std::copy(image.plane(channel), image.plane(channel) + image.pixels(), out.ptr<float>());
  return out;
}

}  // namespace

ViewScore ViewScores::mean() const {
  ViewScore m;
  if (views.empty()) return m;
  for (const ViewScore& v : views) {
    m.psnr_db += v.psnr_db;
    m.ssim += v.ssim;
    m.depth_l1_cm += v.depth_l1_cm;
    m.depth_l1_median_cm += v.depth_l1_median_cm;
    m.depth_missing_fraction += v.depth_missing_fraction;
  }
  const double n = static_cast<double>(views.size());
  m.psnr_db /= n;
  m.ssim /= n;
  m.depth_l1_cm /= n;
  m.depth_l1_median_cm /= n;
  m.depth_missing_fraction /= n;
  return m;
}

cv::Mat colour_to_rgb8(const PlanarImage& colour) {
  cv::Mat out(colour.height, colour.width, CV_8UC3);
  for (int v = 0; v < colour.height; ++v)
    for (int u = 0; u < colour.width; ++u)
      for (int c = 0; c < 3; ++c)
        out.at<cv::Vec3b>(v, u)[c] = cv::saturate_cast<uchar>(
            std::lround(255.0f * std::clamp(colour.at(c, v, u), 0.f, 1.f)));
  return out;
}

bool evaluate_view(const Rasterizer& rasterizer, const GaussianMap& map, const RgbdFrame& frame,
                   const Eigen::Isometry3d& T_world_camera, const RenderSettings& settings,
                   ViewScore* score, std::string* why, RenderResult* rendered) {
  RenderView view;
  view.camera = frame.camera;
  view.T_camera_world = T_world_camera.inverse();
  RenderResult own;
  RenderResult& r = rendered != nullptr ? *rendered : own;
  if (!rasterizer.forward(map, view, settings, &r, why)) return false;
  const cv::Mat rgb = colour_to_rgb8(r.colour);
  const ImageMetricsConfig config;
  DepthL1Result depth, depth_median;
  ViewScore s;
  if (!compute_psnr(rgb, frame.colour, config, &s.psnr_db, why) ||
      !compute_ssim(rgb, frame.colour, config, &s.ssim, why) ||
      !compute_depth_l1(plane_of(r.depth, 0), frame.depth, cv::Mat(), &depth, why) ||
      !compute_depth_l1(plane_of(r.median_depth, 0), frame.depth, cv::Mat(), &depth_median, why)) {
    return fail(why, "metrics of frame " + std::to_string(frame.id) + ": " + (why ? *why : ""));
  }
  s.depth_l1_cm = depth.l1_cm;
  s.depth_l1_median_cm = depth_median.l1_cm;
  s.depth_missing_fraction = static_cast<double>(depth.missing_rendered) /
                             static_cast<double>(std::max<std::size_t>(1, depth.valid_pixels));
  *score = s;
  return true;
}

}  // namespace fslam::core

#include "fslam/server/render_images.hpp"

#include <algorithm>
#include <cmath>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/core/mapping/image_losses.hpp"

namespace fslam::server {

cv::Mat plane_to_mat(const core::PlanarImage& image, int channel) {
  cv::Mat out(image.height, image.width, CV_32FC1);
  std::copy(image.plane(channel), image.plane(channel) + image.pixels(), out.ptr<float>());
  return out;
}

cv::Mat depth_to_rgb8(const cv::Mat& depth_m, double max_depth) {
  cv::Mat scaled;
  depth_m.convertTo(scaled, CV_8U, 255.0 / max_depth);
  cv::Mat coloured;
  cv::applyColorMap(scaled, coloured, cv::COLORMAP_TURBO);
  cv::cvtColor(coloured, coloured, cv::COLOR_BGR2RGB);
  coloured.setTo(cv::Scalar(0, 0, 0), depth_m <= 0.0f);
  return coloured;
}

cv::Mat normals_to_rgb8(const core::PlanarImage& depth, const core::math::Intrinsics& intrinsics) {
  core::PlanarImage normals;
  std::string why;
  core::depth_to_normals(depth, intrinsics, &normals, &why);
  cv::Mat out(depth.height, depth.width, CV_8UC3, cv::Scalar(0, 0, 0));
  if (normals.empty()) return out;
  for (int v = 0; v < normals.height; ++v)
    for (int u = 0; u < normals.width; ++u)
      for (int c = 0; c < 3; ++c)
        out.at<cv::Vec3b>(v, u)[c] =
            cv::saturate_cast<uchar>(std::lround(127.5f * (1.0f - normals.at(c, v, u))));
  return out;
}

cv::Mat opacity_to_rgb8(const core::PlanarImage& alpha) {
  cv::Mat grey;
  plane_to_mat(alpha, 0).convertTo(grey, CV_8U, 255.0);
  cv::Mat out;
  cv::cvtColor(grey, out, cv::COLOR_GRAY2RGB);
  return out;
}

}  // namespace fslam::server

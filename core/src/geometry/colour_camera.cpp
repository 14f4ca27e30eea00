#include "fslam/core/geometry/colour_camera.hpp"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/io/text_tables.hpp"

namespace fslam::core {

bool ColourCamera::parse(const std::string& text, ColourCamera* out, std::string* why) {
  const std::string usage = "colour camera '" + text + "': ";
  std::vector<double> v;
  std::string reason;
  if (!parse_number_list(text, &v, &reason)) return fail(why, usage + reason);
  if (v.size() != 7)
    return fail(why, usage + "expected fx,fy,cx,cy,tx,ty,tz (7 numbers), found " +
                         std::to_string(v.size()));
  ColourCamera c;
  c.camera.fx = v[0];
  c.camera.fy = v[1];
  c.camera.cx = v[2];
  c.camera.cy = v[3];
  c.t_colour_depth = {v[4], v[5], v[6]};
  if (!c.is_valid(&reason)) return fail(why, usage + reason);
  *out = c;
  return true;
}

std::string ColourCamera::to_string() const {
  // Hundredths of a pixel and tenths of a millimetre: finer than any calibration.
  std::ostringstream text;
  text << std::fixed << std::setprecision(2) << camera.fx << ',' << camera.fy << ',' << camera.cx
       << ',' << camera.cy << std::setprecision(4) << ',' << t_colour_depth.x() << ','
       << t_colour_depth.y() << ',' << t_colour_depth.z();
  return text.str();
}

bool ColourCamera::is_valid(std::string* why) const {
  if (!(std::isfinite(camera.fx) && std::isfinite(camera.fy) && camera.fx > 0.0 && camera.fy > 0.0))
    return fail(why, "focal lengths must be positive and finite");
  if (!(std::isfinite(camera.cx) && std::isfinite(camera.cy)))
    return fail(why, "principal point must be finite");
  if (!t_colour_depth.allFinite()) return fail(why, "translation must be finite");
  if (camera.width > 0 || camera.height > 0) return camera.is_valid(why);
  return true;
}

bool register_colour_to_depth(const cv::Mat& colour, const cv::Mat& depth,
                              const PinholeCamera& depth_camera, const ColourCamera& colour_camera,
                              cv::Mat* registered, std::string* why) {
  if (colour.empty() || colour.type() != CV_8UC3)
    return fail(why, "colour registration: colour must be a non-empty 8-bit 3-channel image");
  if (depth.empty() || depth.type() != CV_32FC1)
    return fail(why, "colour registration: depth must be a non-empty 32-bit float image");
  std::string reason;
  if (!depth_camera.is_valid(&reason)) return fail(why, "colour registration: depth camera: " + reason);
  if (depth.cols != depth_camera.width || depth.rows != depth_camera.height)
    return fail(why, "colour registration: depth image is not the depth camera's size");
  if (!colour_camera.is_valid(&reason)) return fail(why, "colour registration: " + reason);
  const PinholeCamera& c = colour_camera.camera;
  if ((c.width > 0 || c.height > 0) && (colour.cols != c.width || colour.rows != c.height))
    return fail(why, "colour registration: colour image is " + std::to_string(colour.cols) + "x" +
                         std::to_string(colour.rows) + " but the colour camera is " +
                         std::to_string(c.width) + "x" + std::to_string(c.height));

  // Pixels without depth are placed at the frame's median depth: the surfaces around a hole are
  // far closer to it than to infinity, where the sensors' offset would be ignored. The median of
  // every 4th pixel in u and v is as good a guess and 16x cheaper.
  constexpr int kMedianStride = 4;
  std::vector<float> valid;  // metres
  valid.reserve(depth.total() / (kMedianStride * kMedianStride) + 1);
  for (int v = 0; v < depth.rows; v += kMedianStride) {
    const float* z_row = depth.ptr<float>(v);
    for (int u = 0; u < depth.cols; u += kMedianStride)
      if (std::isfinite(z_row[u]) && z_row[u] > 0.0f) valid.push_back(z_row[u]);
  }
  float fill = 0.0f;  // 0: no depth at all, rays to infinity
  if (!valid.empty()) {
    std::nth_element(valid.begin(), valid.begin() + valid.size() / 2, valid.end());
    fill = valid[valid.size() / 2];
  }
  // p_colour = p_depth + t, then the colour pinhole: u_c = fx (x z + tx) / (z + tz) + cx with
  // (x, y) the depth pixel's ray at z = 1, precomputed per column and row.
  const float fx = static_cast<float>(c.fx), fy = static_cast<float>(c.fy);
  const float cx = static_cast<float>(c.cx), cy = static_cast<float>(c.cy);
  const float tx = static_cast<float>(colour_camera.t_colour_depth.x());
  const float ty = static_cast<float>(colour_camera.t_colour_depth.y());
  const float tz = static_cast<float>(colour_camera.t_colour_depth.z());
  std::vector<float> ray_x(static_cast<std::size_t>(depth.cols));
  for (int u = 0; u < depth.cols; ++u)
    ray_x[static_cast<std::size_t>(u)] =
        static_cast<float>((u - depth_camera.cx) / depth_camera.fx);
  cv::Mat map_u(depth.size(), CV_32FC1), map_v(depth.size(), CV_32FC1);
  for (int v = 0; v < depth.rows; ++v) {
    const float* z_row = depth.ptr<float>(v);  // [W] metres
    float* mu = map_u.ptr<float>(v);
    float* mv = map_v.ptr<float>(v);
    const float y = static_cast<float>((v - depth_camera.cy) / depth_camera.fy);
    for (int u = 0; u < depth.cols; ++u) {
      const float x = ray_x[static_cast<std::size_t>(u)];
      const float z = std::isfinite(z_row[u]) && z_row[u] > 0.0f ? z_row[u] : fill;
      const float zc = z + tz;
      if (z > 0.0f && zc > 0.0f) {
        const float inv = 1.0f / zc;
        mu[u] = fx * (x * z + tx) * inv + cx;
        mv[u] = fy * (y * z + ty) * inv + cy;
      } else {  // the direction alone
        mu[u] = fx * x + cx;
        mv[u] = fy * y + cy;
      }
    }
  }
  cv::Mat out;
  cv::remap(colour, out, map_u, map_v, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  *registered = out;
  return true;
}

}  // namespace fslam::core

#include "fslam/core/calibration/colour_calibration.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include <opencv2/imgproc.hpp>

#include "fslam/core/error.hpp"

namespace fslam::core {

namespace {

// The five estimated numbers: focal length fx, principal point, and the in-plane translation.
using Parameters = std::array<double, 5>;  // fx, cx, cy (pixels), tx, ty (metres)

ColourCamera camera_of(const Parameters& p, const ColourCamera& initial) {
  ColourCamera c = initial;
  const double aspect = initial.camera.fy / initial.camera.fx;
  c.camera.fx = p[0];
  c.camera.fy = p[0] * aspect;
  c.camera.cx = p[1];
  c.camera.cy = p[2];
  c.t_colour_depth.x() = p[3];
  c.t_colour_depth.y() = p[4];
  return c;
}

// A pair prepared once: blurred grey images and a's depth points in both depth frames.
struct PreparedPair {
  cv::Mat grey_a, grey_b;                  // [H, W] CV_32FC1
  std::vector<Eigen::Vector3d> points_a;   // depth frame of a, metres
  std::vector<Eigen::Vector3d> points_b;   // the same points in the depth frame of b
};

cv::Mat blurred_grey(const cv::Mat& colour, int radius) {
  cv::Mat grey, out;
  cv::cvtColor(colour, grey, cv::COLOR_RGB2GRAY);
  grey.convertTo(out, CV_32F);
  if (radius > 0) cv::blur(out, out, cv::Size(2 * radius + 1, 2 * radius + 1));
  return out;
}

// Bilinear grey level at (u, v); false outside the image.
bool sample(const cv::Mat& grey, double u, double v, double* value) {
  if (!(u >= 0.0 && v >= 0.0 && u < grey.cols - 1 && v < grey.rows - 1)) return false;
  const int u0 = static_cast<int>(u), v0 = static_cast<int>(v);
  const double a = u - u0, b = v - v0;
  const float* r0 = grey.ptr<float>(v0);
  const float* r1 = grey.ptr<float>(v0 + 1);
  *value = (1 - b) * ((1 - a) * r0[u0] + a * r0[u0 + 1]) + b * ((1 - a) * r1[u0] + a * r1[u0 + 1]);
  return true;
}

// Where a depth-frame point lands in the colour image; false behind the colour camera.
bool project(const ColourCamera& c, const Eigen::Vector3d& p_depth, double* u, double* v) {
  const Eigen::Vector3d p = p_depth + c.t_colour_depth;
  if (!(p.z() > 0.0)) return false;
  const Eigen::Vector2d pixel = c.camera.project(p);
  *u = pixel.x();
  *v = pixel.y();
  return true;
}

// Mean over samples seen by both views of min(|I_a - I_b|, cap); +inf when none is.
double cost(const std::vector<PreparedPair>& pairs, const ColourCamera& camera, double cap) {
  double sum = 0.0;
  std::size_t count = 0;
  for (const PreparedPair& pair : pairs) {
    for (std::size_t i = 0; i < pair.points_a.size(); ++i) {
      double ua, va, ub, vb, ia, ib;
      if (!project(camera, pair.points_a[i], &ua, &va) ||
          !project(camera, pair.points_b[i], &ub, &vb) || !sample(pair.grey_a, ua, va, &ia) ||
          !sample(pair.grey_b, ub, vb, &ib))
        continue;
      sum += std::min(std::abs(ia - ib), cap);
      ++count;
    }
  }
  return count > 0 ? sum / static_cast<double>(count) : std::numeric_limits<double>::infinity();
}

bool check_view(const ColourCalibrationView& view, const PinholeCamera& depth_camera,
                std::string* why) {
  if (view.colour.empty() || view.colour.type() != CV_8UC3)
    return fail(why, "colour calibration: colour images must be 8-bit 3-channel");
  if (view.depth.type() != CV_32FC1 || view.depth.cols != depth_camera.width ||
      view.depth.rows != depth_camera.height)
    return fail(why, "colour calibration: depth images must be float metres of the depth camera's size");
  if (!view.T_world_depth.matrix().allFinite())
    return fail(why, "colour calibration: a pose is not finite");
  return true;
}

}  // namespace

bool ColourCalibrationConfig::is_valid(std::string* why) const {
  if (pixel_stride < 1) return fail(why, "pixel_stride must be >= 1");
  if (blur_radius < 0) return fail(why, "blur_radius must be >= 0");
  if (!(residual_cap > 0.0)) return fail(why, "residual_cap must be > 0");
  if (!(min_depth > 0.0 && max_depth > min_depth)) return fail(why, "need 0 < min_depth < max_depth");
  if (max_iterations < 1) return fail(why, "max_iterations must be >= 1");
  if (!(final_focal_step > 0.0)) return fail(why, "final_focal_step must be > 0");
  return true;
}

bool calibrate_colour_camera(const std::vector<ColourCalibrationPair>& pairs,
                             const PinholeCamera& depth_camera, const ColourCamera& initial,
                             const ColourCalibrationConfig& config, ColourCalibrationResult* result,
                             std::string* why) {
  std::string reason;
  if (!config.is_valid(&reason)) return fail(why, "colour calibration: " + reason);
  if (!depth_camera.is_valid(&reason)) return fail(why, "colour calibration: depth camera: " + reason);
  if (!initial.is_valid(&reason)) return fail(why, "colour calibration: initial camera: " + reason);
  if (pairs.empty()) return fail(why, "colour calibration: no view pairs");

  std::vector<PreparedPair> prepared(pairs.size());
  std::size_t samples = 0;
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const ColourCalibrationPair& in = pairs[k];
    if (!check_view(in.a, depth_camera, why) || !check_view(in.b, depth_camera, why)) return false;
    PreparedPair& out = prepared[k];
    out.grey_a = blurred_grey(in.a.colour, config.blur_radius);
    out.grey_b = blurred_grey(in.b.colour, config.blur_radius);
    const Eigen::Isometry3d T_b_a = in.b.T_world_depth.inverse() * in.a.T_world_depth;
    for (int v = 0; v < in.a.depth.rows; v += config.pixel_stride) {
      const float* row = in.a.depth.ptr<float>(v);  // [W] metres
      for (int u = 0; u < in.a.depth.cols; u += config.pixel_stride) {
        const double z = row[u];
        if (!(z > config.min_depth && z < config.max_depth)) continue;
        const Eigen::Vector3d p = depth_camera.unproject({static_cast<double>(u), static_cast<double>(v)}, z);
        out.points_a.push_back(p);
        out.points_b.push_back(T_b_a * p);
      }
    }
    samples += out.points_a.size();
  }

  Parameters p = {initial.camera.fx, initial.camera.cx, initial.camera.cy,
                  initial.t_colour_depth.x(), initial.t_colour_depth.y()};
  // Initial steps: a few percent of the focal length, ~1 % of the image, 2 cm.
  Parameters step = {0.02 * initial.camera.fx, 8.0, 8.0, 0.02, 0.02};
  int evaluations = 1;
  const double initial_cost = cost(prepared, camera_of(p, initial), config.residual_cap);
  if (!std::isfinite(initial_cost))
    return fail(why, "colour calibration: no depth sample is seen in both views of any pair");
  double best = initial_cost;
  // Compass (pattern) search: try +-step on each number in turn, keep every improvement, halve
  // the steps when a sweep improves nothing. The cost is piecewise smooth but noisy, which
  // derivative-free search tolerates.
  for (int sweep = 0; sweep < config.max_iterations && step[0] >= config.final_focal_step; ++sweep) {
    bool improved = false;
    for (std::size_t k = 0; k < p.size(); ++k) {
      for (const double sign : {1.0, -1.0}) {
        Parameters q = p;
        q[k] += sign * step[k];
        if (!(q[0] > 0.0)) continue;
        const double c = cost(prepared, camera_of(q, initial), config.residual_cap);
        ++evaluations;
        if (c < best) {
          best = c;
          p = q;
          improved = true;
        }
      }
    }
    if (!improved)
      for (double& s : step) s *= 0.5;
  }
  result->camera = camera_of(p, initial);
  result->initial_cost = initial_cost;
  result->final_cost = best;
  result->samples = samples;
  result->evaluations = evaluations;
  return true;
}

}  // namespace fslam::core

#include "fslam/core/tracking/point_features.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <vector>

namespace fslam::core {
namespace {

// Bilinear sample of every channel of `latent` at frame pixel uv (clamped at the borders).
void sample_latent(const PlanarImage& latent, const PinholeCamera& camera,
                   const Eigen::Vector2d& uv, float* f) {
  const double sx = static_cast<double>(latent.width) / camera.width;
  const double sy = static_cast<double>(latent.height) / camera.height;
  const double x = std::clamp((uv.x() + 0.5) * sx - 0.5, 0.0, latent.width - 1.0);
  const double y = std::clamp((uv.y() + 0.5) * sy - 0.5, 0.0, latent.height - 1.0);
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  const int x1 = std::min(x0 + 1, latent.width - 1), y1 = std::min(y0 + 1, latent.height - 1);
  const float tx = static_cast<float>(x - x0), ty = static_cast<float>(y - y0);
  const std::size_t w = static_cast<std::size_t>(latent.width);
  const std::size_t i00 = y0 * w + x0, i01 = y0 * w + x1, i10 = y1 * w + x0, i11 = y1 * w + x1;
  const float* plane = latent.data.data();
  for (int c = 0; c < latent.channels; ++c, plane += latent.pixels()) {
    f[c] = (1 - ty) * ((1 - tx) * plane[i00] + tx * plane[i01]) +
           ty * ((1 - tx) * plane[i10] + tx * plane[i11]);
  }
}

}  // namespace

void sample_point_features(const PlanarImage& latent, const PinholeCamera& camera,
                           GaussianPoints* points, bool gradient) {
  const int d = latent.channels;
  const std::size_t dn = static_cast<std::size_t>(d);
  points->feature_dim = d;
  points->features.assign(points->size() * dn, 0.0f);
  points->feature_spread.assign(points->size(), 0.0f);
  points->feature_gradient.assign(gradient ? points->size() * dn * 3 : 0, 0.0f);
  // One latent cell in frame pixels along u and v.
  const Eigen::Vector2d cell(static_cast<double>(camera.width) / latent.width,
                             static_cast<double>(camera.height) / latent.height);
  const Eigen::Vector2d steps[4] = {
      {cell.x(), 0.0}, {-cell.x(), 0.0}, {0.0, cell.y()}, {0.0, -cell.y()}};
  std::vector<float> neighbours(4 * dn);
  for (std::size_t i = 0; i < points->size(); ++i) {
    const Eigen::Vector3d p = points->means[i].cast<double>();
    if (!(p.z() > 0)) continue;
    const Eigen::Vector2d uv = camera.project(p);
    float* f = &points->features[i * dn];
    sample_latent(latent, camera, uv, f);
    // The spread: mean of ||f(uv + step) - f(uv)||^2 over the four one-cell steps.
    double spread = 0.0;
    for (int k = 0; k < 4; ++k) {
      float* g = &neighbours[k * dn];
      sample_latent(latent, camera, uv + steps[k], g);
      for (int c = 0; c < d; ++c) spread += (g[c] - f[c]) * (g[c] - f[c]);
    }
    points->feature_spread[i] = static_cast<float>(spread / 4.0);
    if (!gradient) continue;
    // d f / d X = (d f / d uv) (d uv / d X): central differences over one cell each way, through
    // the pinhole projection's Jacobian at the point (pixels per metre).
    const double iz = 1.0 / p.z();
    const double du_dx = camera.fx * iz, du_dz = -camera.fx * p.x() * iz * iz;
    const double dv_dy = camera.fy * iz, dv_dz = -camera.fy * p.y() * iz * iz;
    float* G = &points->feature_gradient[i * dn * 3];
    for (int c = 0; c < d; ++c) {
      const double gu = (neighbours[c] - neighbours[dn + c]) / (2.0 * cell.x());
      const double gv = (neighbours[2 * dn + c] - neighbours[3 * dn + c]) / (2.0 * cell.y());
      G[3 * c + 0] = static_cast<float>(gu * du_dx);
      G[3 * c + 1] = static_cast<float>(gv * dv_dy);
      G[3 * c + 2] = static_cast<float>(gu * du_dz + gv * dv_dz);
    }
  }
}

bool depth_sees(const PinholeCamera& camera, const cv::Mat& depth, const Eigen::Isometry3d& T_camera_world,
                const Eigen::Vector3f& point_world, float max_depth_difference, Eigen::Vector2d* uv) {
  assert(depth.type() == CV_32FC1);
  const Eigen::Vector3d p = T_camera_world * point_world.cast<double>();
  if (!(p.z() > 0)) return false;
  const Eigen::Vector2d pixel = camera.project(p);
  // The pixel holding the projection, tested in floating point before any conversion to int.
  if (!(pixel.x() >= -0.5 && pixel.x() < depth.cols - 0.5 && pixel.y() >= -0.5 && pixel.y() < depth.rows - 0.5))
    return false;
  const float z = depth.at<float>(static_cast<int>(std::floor(pixel.y() + 0.5)),
                                  static_cast<int>(std::floor(pixel.x() + 0.5)));
  if (!(z > 0.0f) || !(std::abs(z - p.z()) <= max_depth_difference)) return false;
  if (uv != nullptr) *uv = pixel;
  return true;
}

std::size_t refresh_map_features(const PlanarImage& latent, const PinholeCamera& camera,
                                 const cv::Mat& depth, const Eigen::Isometry3d& T_world_camera,
                                 float max_depth_difference, LocalMap* map) {
  assert(depth.type() == CV_32FC1);
  if (map->feature_dim() != latent.channels || latent.empty()) return 0;
  const Eigen::Isometry3d T_camera_world = T_world_camera.inverse();
  std::size_t refreshed = 0;
  map->update_features([&](const TargetPoint& point, float* feature) {
    Eigen::Vector2d uv;
    if (!depth_sees(camera, depth, T_camera_world, point.mean, max_depth_difference, &uv)) return;
    sample_latent(latent, camera, uv, feature);
    ++refreshed;
  });
  return refreshed;
}

}  // namespace fslam::core

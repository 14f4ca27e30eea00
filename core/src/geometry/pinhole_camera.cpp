#include "fslam/core/geometry/pinhole_camera.hpp"

#include <cmath>
#include <sstream>

namespace fslam::core {

bool PinholeCamera::is_valid(std::string* why) const {
  auto fail = [&](const std::string& message) {
    if (why) *why = message;
    return false;
  };
  if (!(std::isfinite(fx) && std::isfinite(fy) && fx > 0.0 && fy > 0.0)) {
    std::ostringstream s;
    s << "focal lengths must be positive and finite (fx=" << fx << ", fy=" << fy << ")";
    return fail(s.str());
  }
  if (width <= 0 || height <= 0) {
    std::ostringstream s;
    s << "image size must be positive (" << width << "x" << height << ")";
    return fail(s.str());
  }
  if (!(std::isfinite(cx) && std::isfinite(cy) && cx >= 0.0 && cy >= 0.0 && cx < width &&
        cy < height)) {
    std::ostringstream s;
    s << "principal point (" << cx << ", " << cy << ") lies outside the " << width << "x"
      << height << " image";
    return fail(s.str());
  }
  return true;
}

Eigen::Matrix3d PinholeCamera::K() const {
  Eigen::Matrix3d k;
  k << fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0;
  return k;
}

Eigen::Vector2d PinholeCamera::project(const Eigen::Vector3d& p) const {
  return {fx * p.x() / p.z() + cx, fy * p.y() / p.z() + cy};
}

Eigen::Vector3d PinholeCamera::unproject(const Eigen::Vector2d& pixel, double depth) const {
  return {(pixel.x() - cx) * depth / fx, (pixel.y() - cy) * depth / fy, depth};
}

bool PinholeCamera::contains(const Eigen::Vector2d& pixel) const {
  return pixel.x() >= -0.5 && pixel.y() >= -0.5 && pixel.x() < width - 0.5 &&
         pixel.y() < height - 0.5;
}

PinholeCamera PinholeCamera::scaled(double factor) const {
  // Pixel centres sit at integers, so the principal point maps as (c + 0.5) * s - 0.5.
  PinholeCamera c = *this;
  c.fx *= factor;
  c.fy *= factor;
  c.cx = (cx + 0.5) * factor - 0.5;
  c.cy = (cy + 0.5) * factor - 0.5;
  c.width = static_cast<int>(std::lround(width * factor));
  c.height = static_cast<int>(std::lround(height * factor));
  return c;
}

math::Intrinsics PinholeCamera::intrinsics() const {
  return {static_cast<float>(fx), static_cast<float>(fy), static_cast<float>(cx),
          static_cast<float>(cy)};
}

}  // namespace fslam::core

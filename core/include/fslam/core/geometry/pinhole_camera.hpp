// Pinhole camera model: intrinsics in pixels plus the image size they belong to.
#pragma once

#include <string>

#include <Eigen/Core>

#include "fslam/core/math/unproject.hpp"

namespace fslam::core {

struct PinholeCamera {
  double fx = 0.0;  // focal length, pixels
  double fy = 0.0;
  double cx = 0.0;  // principal point, pixels (pixel centres at integers)
  double cy = 0.0;
  int width = 0;    // image size, pixels
  int height = 0;

  // Positive finite focal lengths, positive size, principal point inside the image.
  bool is_valid(std::string* why = nullptr) const;

  Eigen::Matrix3d K() const;
  // Camera-frame point -> pixel; the point must have z > 0.
  Eigen::Vector2d project(const Eigen::Vector3d& p_camera) const;
  // Pixel and depth (metres) -> camera-frame point.
  Eigen::Vector3d unproject(const Eigen::Vector2d& pixel, double depth) const;
  bool contains(const Eigen::Vector2d& pixel) const;
  // The same camera for an image resized by `factor` (0.5 halves it).
  PinholeCamera scaled(double factor) const;
  math::Intrinsics intrinsics() const;
};

}  // namespace fslam::core

// The colour sensor of an RGB-D camera whose colour images are not registered to its depth
// images (Kinect v1 recordings such as 7-Scenes): the colour images' own pinhole intrinsics and
// where the colour sensor sits in the depth camera's frame. Registering resamples each colour
// image onto the depth camera's pixels, so that everything downstream sees one camera.
#pragma once

#include <string>

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/pinhole_camera.hpp"

namespace fslam::core {

struct ColourCamera {
  // Intrinsics of the colour images; width/height 0 means "the colour images' size".
  PinholeCamera camera;
  // A point p in the depth camera's frame is at p + t in the colour camera's frame (metres).
  // No rotation: the two sensors of a structured-light camera are mounted parallel, and a
  // rotation of a fraction of a degree is absorbed by the principal point.
  Eigen::Vector3d t_colour_depth = Eigen::Vector3d::Zero();

  // "fx,fy,cx,cy,tx,ty,tz" (commas or spaces; pixels and metres), the form to_string() writes.
  static bool parse(const std::string& text, ColourCamera* out, std::string* why);
  std::string to_string() const;
  // Positive finite focal lengths, finite principal point and translation.
  bool is_valid(std::string* why = nullptr) const;
};

// Resamples `colour` (CV_8UC3, the colour camera's images) onto the pixels of `depth` (CV_32FC1
// metres, 0 = missing, taken with `depth_camera`): a pixel with depth looks up where its 3D
// point projects in the colour image; a pixel without depth takes the frame's median depth (the
// ray's direction alone when the frame has no depth). Bilinear, borders replicated. Fails on empty or mistyped images and invalid cameras.
bool register_colour_to_depth(const cv::Mat& colour, const cv::Mat& depth,
                              const PinholeCamera& depth_camera, const ColourCamera& colour_camera,
                              cv::Mat* registered, std::string* why);

}  // namespace fslam::core

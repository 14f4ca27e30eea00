// Depth-to-point math, plain data (the tracker's preprocessing and the losses' normals use it).
#pragma once

#include "fslam/core/math/host_device.hpp"

namespace fslam::core::math {

// Plain-data pinhole intrinsics usable in device code (no Eigen, no OpenCV).
struct Intrinsics {
  float fx, fy, cx, cy;  // pixels
};

// A depth sample is valid when finite and inside (min_depth, max_depth) metres; 0 marks missing.
FSLAM_HD bool depth_is_valid(float z, float min_depth, float max_depth) {
  return z == z && z > min_depth && z < max_depth;  // z == z rejects NaN without <cmath>
}

// Back-projects pixel (u, v) at depth z (metres) into the camera frame:
// X = z * K^-1 [u, v, 1]^T, pixel centres at integer coordinates.
FSLAM_HD void unproject_pixel(const Intrinsics& k, float u, float v, float z, float* xyz) {
  xyz[0] = (u - k.cx) * z / k.fx;
  xyz[1] = (v - k.cy) * z / k.fy;
  xyz[2] = z;
}

// Unprojects one pixel of a row-major depth image into out[3 * i]; invalid pixels become NaN so
// that the output stays organised (index i = v * width + u).
FSLAM_HD void unproject_depth_pixel(const Intrinsics& k, const float* depth, int width, int i,
                                    float min_depth, float max_depth, float* out) {
  const float z = depth[i];
  float* p = out + 3 * i;
  if (!depth_is_valid(z, min_depth, max_depth)) {
    const float nan = __builtin_nanf("");
    p[0] = p[1] = p[2] = nan;
    return;
  }
  unproject_pixel(k, static_cast<float>(i % width), static_cast<float>(i / width), z, p);
}

}  // namespace fslam::core::math

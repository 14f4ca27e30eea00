// A feature map whose objects are known, for segmentation tests: three panels of Gaussians on
// z = 2 m seen from the origin by a 160x120 camera, the left and right ones touching with
// different latents, the far one with the left one's latent but 10 cm apart in space.
#pragma once

#include <cmath>
#include <random>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/map/gaussian_map.hpp"

namespace fslam::test {

constexpr int kPanelFeatureDim = 8;
inline const core::PinholeCamera kPanelCamera{200.0, 200.0, 79.5, 59.5, 160, 120};  // looks down +z

// Panel of Gaussians x in [x0, x1), y in [-0.3, 0.3), 1 cm apart, on the plane z (metres),
// flat discs facing the camera, latent `base` plus noise of 0.05 per channel (no latent when the
// map has feature_dim 0).
inline void add_panel(core::GaussianMap* map, float x0, float x1, const std::vector<float>& base,
                      std::mt19937* rng, float z = 2.0f) {
  std::normal_distribution<float> noise(0.0f, 0.05f);
  for (float x = x0; x < x1 - 1e-6f; x += 0.01f)
    for (float y = -0.3f; y < 0.3f - 1e-6f; y += 0.01f) {
      const float mean[3] = {x + 0.005f, y + 0.005f, z};
      const float rotation[4] = {1, 0, 0, 0};
      const float log_scale[3] = {std::log(0.007f), std::log(0.007f), std::log(0.001f)};
      const float sh[3] = {0.5f, 0.5f, 0.5f};
      std::vector<float> f(base);
      for (float& v : f) v += noise(*rng);
      map->push_back(mean, rotation, log_scale, 4.0f, sh, map->feature_dim > 0 ? f.data() : nullptr);
    }
}

// The three panels, in the order left, right, far.
inline core::GaussianMap panel_map(int feature_dim = kPanelFeatureDim) {
  core::GaussianMap map;
  map.sh_degree = 0;
  map.feature_dim = feature_dim;
  std::mt19937 rng(7);
  std::vector<float> a(kPanelFeatureDim, 0.0f), b(kPanelFeatureDim, 0.0f);
  a[0] = 1.0f;
  a[3] = -0.5f;
  b[1] = 1.0f;
  b[5] = 0.7f;
  add_panel(&map, -0.5f, 0.0f, a, &rng);
  add_panel(&map, 0.0f, 0.5f, b, &rng);
  add_panel(&map, 0.6f, 0.75f, a, &rng);
  return map;
}

// Ground truth per pixel from the origin: 1 left, 2 right, 3 far, 0 elsewhere: the panel whose
// extent holds the pixel centre (edges at u = 29.5, 79.5, 129.5, 139.5, 154.5 and v = 29.5,
// 89.5); `shift` pixels to the left for a camera moved shift / 100 m along +x.
inline cv::Mat panel_truth(int shift = 0) {
  cv::Mat t(120, 160, CV_32SC1, cv::Scalar(0));
  for (int v = 30; v <= 89; ++v)
    for (int u = 30; u <= 154; ++u) {
      const int id = u <= 79 ? 1 : u <= 129 ? 2 : u >= 140 ? 3 : 0;
      if (u - shift >= 0) t.at<int>(v, u - shift) = id;
    }
  return t;
}

}  // namespace fslam::test

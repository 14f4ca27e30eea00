#include "fslam/core/features/feature_pyramid.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>

namespace fslam::core {

int feature_dim(const std::vector<FeatureLevelShape>& shapes) {
  int d = 0;
  for (const auto& s : shapes) d += s.channels;
  return d;
}

int FeaturePyramid::dim() const {
  int d = 0;
  for (const auto& l : levels) d += l.shape.channels;
  return d;
}

std::vector<FeatureLevelShape> FeaturePyramid::shapes() const {
  std::vector<FeatureLevelShape> s;
  s.reserve(levels.size());
  for (const auto& l : levels) s.push_back(l.shape);
  return s;
}

void sample_features(const FeaturePyramid& pyramid, float u, float v, float* out) {
  assert(pyramid.image_width > 0 && pyramid.image_height > 0);
  for (const auto& level : pyramid.levels) {
    const int W = level.shape.width, H = level.shape.height, C = level.shape.channels;
    assert(W > 0 && H > 0 && level.data.size() == static_cast<std::size_t>(C) * H * W);
    // Half-pixel-centre mapping: frame and level cover the same extent.
    const float x = std::clamp((u + 0.5f) * W / pyramid.image_width - 0.5f, 0.0f, W - 1.0f);
    const float y = std::clamp((v + 0.5f) * H / pyramid.image_height - 0.5f, 0.0f, H - 1.0f);
    const int x0 = std::min(static_cast<int>(x), W - 1), y0 = std::min(static_cast<int>(y), H - 1);
    const int x1 = std::min(x0 + 1, W - 1), y1 = std::min(y0 + 1, H - 1);
    const float fx = x - x0, fy = y - y0;
    const float w00 = (1 - fx) * (1 - fy), w01 = fx * (1 - fy), w10 = (1 - fx) * fy, w11 = fx * fy;
    const std::size_t row0 = static_cast<std::size_t>(y0) * W, row1 = static_cast<std::size_t>(y1) * W;
    const std::size_t i00 = row0 + x0, i01 = row0 + x1, i10 = row1 + x0, i11 = row1 + x1;
    const std::size_t plane = static_cast<std::size_t>(H) * W;
    const float* p = level.data.data();
    for (int c = 0; c < C; ++c, p += plane)
      *out++ = w00 * p[i00] + w01 * p[i01] + w10 * p[i10] + w11 * p[i11];
  }
}

std::vector<float> sample_features(const FeaturePyramid& pyramid, float u, float v) {
  std::vector<float> out(static_cast<std::size_t>(pyramid.dim()));
  sample_features(pyramid, u, v, out.data());
  return out;
}

}  // namespace fslam::core

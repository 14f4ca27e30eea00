#include "fslam/core/features/feature_observation.hpp"

#include <algorithm>
#include <cmath>
#include <random>

#include "fslam/core/error.hpp"

namespace fslam::core {

void FeatureObservation::samples(const std::vector<float>& mean, const std::vector<float>& std,
                                 std::vector<float>* u) const {
  const std::size_t C = static_cast<std::size_t>(channels);
  u->resize(size() * C);
  for (std::size_t k = 0; k < size(); ++k)
    for (std::size_t c = 0; c < C; ++c)
      (*u)[k * C + c] = mean[c] + std[c] * kCodeStep * static_cast<float>(codes[k * C + c]);
}

bool observe_features(const FeaturePyramid& pyramid, int width, int height, int count,
                      std::uint32_t seed, const std::vector<float>& mean, const std::vector<float>& std,
                      FeatureObservation* out, std::string* why) {
  if (pyramid.levels.empty() || pyramid.image_width <= 0 || pyramid.image_height <= 0) {
    return fail(why, "features: no encoded frame");
  }
  if (width < 1 || height < 1 || count < 1) return fail(why, "features: observation size and count must be >= 1");
  const int C = pyramid.dim();
  if (static_cast<int>(mean.size()) != C || static_cast<int>(std.size()) != C) {
    return fail(why, "features: normalisation has " + std::to_string(mean.size()) + " channels, the pyramid " +
                         std::to_string(C));
  }
  // nx x ny cells of about equal area, nx / ny the image's aspect.
  const double aspect = static_cast<double>(width) / height;
  const int nx = std::clamp(static_cast<int>(std::lround(std::sqrt(count * aspect))), 1, width);
  const int ny = std::clamp(static_cast<int>(std::lround(static_cast<double>(count) / nx)), 1, height);
  out->width = width;
  out->height = height;
  out->channels = C;
  out->pixels.clear();
  out->pixels.reserve(static_cast<std::size_t>(nx) * ny);
  std::mt19937 rng(seed);
  for (int j = 0; j < ny; ++j) {
    const int y0 = j * height / ny, y1 = std::max(y0 + 1, (j + 1) * height / ny);
    for (int i = 0; i < nx; ++i) {
      const int x0 = i * width / nx, x1 = std::max(x0 + 1, (i + 1) * width / nx);
      const int x = std::uniform_int_distribution<int>(x0, x1 - 1)(rng);
      const int y = std::uniform_int_distribution<int>(y0, y1 - 1)(rng);
      out->pixels.push_back(y * width + x);
    }
  }
  out->codes.resize(out->pixels.size() * static_cast<std::size_t>(C));
  const float sx = static_cast<float>(pyramid.image_width) / static_cast<float>(width);
  const float sy = static_cast<float>(pyramid.image_height) / static_cast<float>(height);
  std::vector<float> u(static_cast<std::size_t>(C));
  for (std::size_t k = 0; k < out->pixels.size(); ++k) {
    const int x = out->pixels[k] % width, y = out->pixels[k] / width;
    sample_features(pyramid, (static_cast<float>(x) + 0.5f) * sx - 0.5f, (static_cast<float>(y) + 0.5f) * sy - 0.5f,
                    u.data());
    for (int c = 0; c < C; ++c) {
      const float z = (u[c] - mean[c]) / std[c] / FeatureObservation::kCodeStep;
      const float q = std::isfinite(z) ? std::clamp(std::round(z), -127.0f, 127.0f) : 0.0f;
      out->codes[k * static_cast<std::size_t>(C) + c] = static_cast<std::int8_t>(q);
    }
  }
  return true;
}

}  // namespace fslam::core

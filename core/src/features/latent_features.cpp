#include "fslam/core/features/latent_features.hpp"

#include <algorithm>
#include <cmath>

#include "fslam/core/error.hpp"

namespace fslam::core {

bool LatentFeaturesConfig::is_valid(std::string* why) const {
  if (!enabled()) return true;
  if (!encoder.is_valid(why)) return false;
  if (grid_step < 1) return fail(why, "features: grid_step must be >= 1");
  return true;
}

std::unique_ptr<LatentFeatures> LatentFeatures::create(const LatentFeaturesConfig& config,
                                                       std::string* why) {
  if (!config.enabled()) {
    fail(why, "features: no autoencoder weights (features.autoencoder_path); make them with "
              "deploy/make_builtin_autoencoder.sh or fslam train-autoencoder");
    return nullptr;
  }
  if (!config.is_valid(why)) return nullptr;
  std::unique_ptr<FeatureEncoder> encoder = make_feature_encoder(config.encoder, why);
  if (!encoder) return nullptr;
  FeatureAutoencoder autoencoder;
  std::string reason;
  if (!autoencoder.load(config.autoencoder_path, encoder->level_shapes(), &reason)) {
    fail(why, "features: " + reason);
    return nullptr;
  }
  return std::make_unique<LatentFeatures>(std::move(encoder), std::move(autoencoder), config.grid_step);
}

LatentFeatures::LatentFeatures(std::unique_ptr<FeatureEncoder> encoder, FeatureAutoencoder autoencoder,
                               int grid_step)
    : encoder_(std::move(encoder)), autoencoder_(std::move(autoencoder)), grid_step_(grid_step) {}

std::string LatentFeatures::describe() const {
  return encoder_->describe() + "; autoencoder " + std::to_string(autoencoder_.input_dim()) + " -> " +
         std::to_string(autoencoder_.latent_dim());
}

bool LatentFeatures::encode(const cv::Mat& rgb, FeaturePyramid* pyramid, std::string* why) {
  return encoder_->encode(rgb, pyramid, why);
}

bool LatentFeatures::latent_image(const cv::Mat& rgb, int width, int height, PlanarImage* out,
                                  std::string* why) {
  return encode(rgb, &pyramid_, why) && latent_image(pyramid_, width, height, out, why);
}

bool LatentFeatures::latent_image(const FeaturePyramid& pyramid, int width, int height,
                                  PlanarImage* out, std::string* why) {
  if (width <= 0 || height <= 0) return fail(why, "features: empty target size");
  if (pyramid.levels.empty() || pyramid.image_width <= 0 || pyramid.image_height <= 0) {
    return fail(why, "features: no encoded frame");
  }
  // The coarse grid: every grid_step-th target pixel, plus the last row and column.
  auto axis = [&](int n) {
    std::vector<int> at;
    for (int k = 0; k < n; k += grid_step_) at.push_back(k);
    if (at.back() != n - 1) at.push_back(n - 1);
    return at;
  };
  const std::vector<int> xs = axis(width), ys = axis(height);
  const int gw = static_cast<int>(xs.size()), gh = static_cast<int>(ys.size());
  const int c = autoencoder_.input_dim(), d = autoencoder_.latent_dim();
  u_.resize(static_cast<std::size_t>(gw) * gh * c);
  f_.resize(static_cast<std::size_t>(gw) * gh * d);
  const float sx = static_cast<float>(pyramid.image_width) / static_cast<float>(width);
  const float sy = static_cast<float>(pyramid.image_height) / static_cast<float>(height);
  for (int j = 0; j < gh; ++j)
    for (int i = 0; i < gw; ++i) {
      // Target pixel centre -> frame pixel coordinates (centres at integers).
      const float u = (static_cast<float>(xs[i]) + 0.5f) * sx - 0.5f;
      const float v = (static_cast<float>(ys[j]) + 0.5f) * sy - 0.5f;
      sample_features(pyramid, u, v, &u_[(static_cast<std::size_t>(j) * gw + i) * c]);
    }
  autoencoder_.encode(u_.data(), gw * gh, f_.data());  // f_i = phi(u_i)
  // Bilinear between grid samples.
  *out = PlanarImage(width, height, d);
  int j = 0;
  for (int y = 0; y < height; ++y) {
    while (j + 1 < gh - 1 && ys[j + 1] <= y) ++j;
    const int j1 = std::min(j + 1, gh - 1);
    const float ty = ys[j1] == ys[j] ? 0.0f : static_cast<float>(y - ys[j]) / static_cast<float>(ys[j1] - ys[j]);
    int i = 0;
    for (int x = 0; x < width; ++x) {
      while (i + 1 < gw - 1 && xs[i + 1] <= x) ++i;
      const int i1 = std::min(i + 1, gw - 1);
      const float tx = xs[i1] == xs[i] ? 0.0f : static_cast<float>(x - xs[i]) / static_cast<float>(xs[i1] - xs[i]);
      const float* f00 = &f_[(static_cast<std::size_t>(j) * gw + i) * d];
      const float* f01 = &f_[(static_cast<std::size_t>(j) * gw + i1) * d];
      const float* f10 = &f_[(static_cast<std::size_t>(j1) * gw + i) * d];
      const float* f11 = &f_[(static_cast<std::size_t>(j1) * gw + i1) * d];
      for (int k = 0; k < d; ++k) {
        out->at(k, y, x) = (1 - ty) * ((1 - tx) * f00[k] + tx * f01[k]) + ty * ((1 - tx) * f10[k] + tx * f11[k]);
      }
    }
  }
  return true;
}

}  // namespace fslam::core

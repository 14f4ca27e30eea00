// The image encoder's observation at a keyframe's sample pixels: the target of L_feat through the
// decoder heads (paper eq. modeling_losses, ||F_hat - F_obs||_1, F_hat the rendered latent decoded
// by phi^(l) back to the encoder's levels). K pixels of one image (the mapper's training image)
// on a jittered grid; each pixel's C channels of u (sample_features) standardised by the
// autoencoder's input normalisation and kept as int8 in steps of kCodeStep standard deviations:
// 352 B a sample instead of 1.4 kB, for a quantisation error of 1/64 standard deviation on average
// (the heads' reconstruction error is ~20x that, docs/features_autoencoder.md).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "fslam/core/features/feature_pyramid.hpp"

namespace fslam::core {

struct FeatureObservation {
  static constexpr float kCodeStep = 1.0f / 16.0f;  // standard deviations per code; +-7.9 kept
  int width = 0, height = 0;         // the image `pixels` index
  int channels = 0;                  // C
  std::vector<std::int32_t> pixels;  // y * width + x, one per sample
  std::vector<std::int8_t> codes;    // [K, C]

  std::size_t size() const { return pixels.size(); }
  bool empty() const { return pixels.empty(); }
  std::size_t bytes() const { return pixels.size() * sizeof(std::int32_t) + codes.size(); }
  // The samples in encoder units, [K, C]: mean_c + std_c * code * kCodeStep.
  void samples(const std::vector<float>& mean, const std::vector<float>& std, std::vector<float>* u) const;
};

// `count` pixels of a width x height image on a jittered grid (one at random in each cell, seeded),
// each with u sampled from `pyramid` at the pixel's centre (pixel centres map onto the encoded
// frame as PinholeCamera::scaled does) and coded against mean / std [C]. False + why for an empty
// pyramid, a size or count below 1, or a normalisation of the wrong length.
bool observe_features(const FeaturePyramid& pyramid, int width, int height, int count,
                      std::uint32_t seed, const std::vector<float>& mean, const std::vector<float>& std,
                      FeatureObservation* out, std::string* why);

}  // namespace fslam::core

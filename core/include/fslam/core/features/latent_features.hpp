// Per-pixel latents of a frame (paper sec. "Online Feature Rasterization"): the image encoder's
// pyramid sampled bilinearly at each pixel (u_i) and compressed by the autoencoder's joint
// encoder phi to the D channels the Gaussians carry. The mapper's feature loss compares the
// rendered latent image with this one (eq. modeling_losses, L_feat).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "fslam/core/features/feature_autoencoder.hpp"
#include "fslam/core/features/feature_encoder.hpp"
#include "fslam/core/render/planar_image.hpp"

namespace fslam::core {

struct LatentFeaturesConfig {
  FeatureEncoderConfig encoder;
  std::string autoencoder_path;  // weights from `fslam train-autoencoder`; empty = features off
  // phi runs on a grid this many target pixels apart and the latents are interpolated between:
  // phi costs about 24k multiply-adds per sample, and the encoder's finest level is 4 input
  // pixels per cell anyway.
  int grid_step = 2;
  bool enabled() const { return !autoencoder_path.empty(); }
  bool is_valid(std::string* why = nullptr) const;
};

class LatentFeatures {
 public:
  // nullptr + why for a bad config, an encoder that cannot start, or weights that do not fit
  // the encoder.
  static std::unique_ptr<LatentFeatures> create(const LatentFeaturesConfig& config, std::string* why);
  LatentFeatures(std::unique_ptr<FeatureEncoder> encoder, FeatureAutoencoder autoencoder, int grid_step);

  int dim() const { return autoencoder_.latent_dim(); }
  // The image encoder's pyramid of a frame: the costly part (a frame is encoded once, and each
  // user computes the latent at its own resolution from it). rgb: [H, W] CV_8UC3 RGB.
  bool encode(const cv::Mat& rgb, FeaturePyramid* pyramid, std::string* why);
  // out: [D, height, width], the latent of the encoded frame resized to width x height (pixel
  // centres map as PinholeCamera::scaled does): phi on a grid, interpolated between.
  bool latent_image(const FeaturePyramid& pyramid, int width, int height, PlanarImage* out,
                    std::string* why);
  // encode, then latent_image.
  bool latent_image(const cv::Mat& rgb, int width, int height, PlanarImage* out, std::string* why);
  std::string describe() const;
  // The pretrained autoencoder (never trained here): phi for the latents, the heads for the
  // decoded L_feat (the mapper trains its own copy's LoRA online).
  const FeatureAutoencoder& autoencoder() const { return autoencoder_; }
  // None of the calls is thread-safe: each thread keeps its own LatentFeatures.

 private:
  std::unique_ptr<FeatureEncoder> encoder_;
  FeatureAutoencoder autoencoder_;
  int grid_step_;
  FeaturePyramid pyramid_;    // the last frame of latent_image(rgb, ...)
  std::vector<float> u_, f_;  // [N, C] samples and [N, D] latents of the coarse grid
};

}  // namespace fslam::core

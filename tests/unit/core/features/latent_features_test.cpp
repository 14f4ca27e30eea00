// Per-pixel latents: the encoder's pyramid through phi on a grid, interpolated between.
#include <cmath>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "fslam/core/features/latent_features.hpp"
#include "fslam/core/pipeline/slam_pipeline.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

// Left half red cloth, right half blue plaster: two surfaces any encoder should tell apart.
cv::Mat two_halves() {
  cv::Mat rgb(240, 320, CV_8UC3);
  std::mt19937 rng(4);
  std::normal_distribution<float> n(0.0f, 6.0f);
  for (int v = 0; v < rgb.rows; ++v)
    for (int u = 0; u < rgb.cols; ++u) {
      const bool left = u < rgb.cols / 2;
      const float stripe = left ? 30.0f * ((u / 4) % 2) : 0.0f;
      const cv::Vec3f base = left ? cv::Vec3f(190, 40, 40) : cv::Vec3f(60, 80, 200);
      for (int c = 0; c < 3; ++c)
        rgb.at<cv::Vec3b>(v, u)[c] = cv::saturate_cast<uchar>(base[c] + stripe + n(rng));
    }
  return rgb;
}

LatentFeaturesConfig small_config() {
  LatentFeaturesConfig config;
  config.encoder.builtin.input_width = 256;
  config.encoder.builtin.input_height = 256;
  return config;
}

// Weights for the builtin encoder at 256x256, briefly pretrained on the test image.
std::string make_weights(const LatentFeaturesConfig& config) {
  std::string why;
  auto encoder = make_feature_encoder(config.encoder, &why);
  EXPECT_NE(encoder, nullptr) << why;
  FeaturePyramid pyramid;
  EXPECT_TRUE(encoder->encode(two_halves(), &pyramid, &why)) << why;
  FeatureAutoencoder ae;
  AutoencoderPretrainOptions options;
  options.steps = 150;
  options.batch = 64;
  options.pixels_per_image = 1000;
  AutoencoderPretrainStats stats;
  EXPECT_TRUE(pretrain_autoencoder({pyramid}, options, &ae, nullptr, &stats, &why)) << why;
  const std::string path = (test::fresh_temp_dir("latent") / "w.fae").string();
  EXPECT_TRUE(ae.save(path, &why)) << why;
  return path;
}

TEST(LatentFeatures, LatentImageIsPhiOfThePyramidOnTheGrid) {
  LatentFeaturesConfig config = small_config();
  config.autoencoder_path = make_weights(config);
  config.grid_step = 2;
  std::string why;
  auto latents = LatentFeatures::create(config, &why);
  ASSERT_NE(latents, nullptr) << why;
  const cv::Mat rgb = two_halves();
  PlanarImage image;
  ASSERT_TRUE(latents->latent_image(rgb, 80, 60, &image, &why)) << why;
  ASSERT_EQ(image.channels, 16);
  ASSERT_EQ(image.width, 80);
  ASSERT_EQ(image.height, 60);
  for (float v : image.data) ASSERT_TRUE(std::isfinite(v));

  // At a grid node the latent is exactly phi(u) of the pyramid sample at that pixel's centre.
  auto encoder = make_feature_encoder(config.encoder, &why);
  FeaturePyramid pyramid;
  ASSERT_TRUE(encoder->encode(rgb, &pyramid, &why)) << why;
  FeatureAutoencoder ae;
  ASSERT_TRUE(ae.load(config.autoencoder_path, &why)) << why;
  const int x = 20, y = 30;  // even: a grid node
  const std::vector<float> u = sample_features(pyramid, (x + 0.5f) * 4.0f - 0.5f, (y + 0.5f) * 4.0f - 0.5f);
  std::vector<float> f(16);
  ae.encode(u.data(), 1, f.data());
  for (int c = 0; c < 16; ++c) EXPECT_NEAR(image.at(c, y, x), f[c], 1e-5f) << "channel " << c;

  // The two surfaces are told apart: away from the boundary's halo (the coarse level pools over
  // ~12 latent pixels here) and the border, every latent is nearer its own half's mean latent.
  auto mean_of = [&](int x0, int x1) {
    std::vector<double> m(16, 0.0);
    int n = 0;
    for (int y = 12; y < 48; ++y)
      for (int x = x0; x < x1; ++x, ++n)
        for (int c = 0; c < 16; ++c) m[c] += image.at(c, y, x);
    for (double& v : m) v /= n;
    return m;
  };
  const std::vector<double> left = mean_of(12, 28), right = mean_of(52, 68);
  auto nearer_own = [&](int x, int y, bool is_left) {
    double dl = 0, dr = 0;
    for (int c = 0; c < 16; ++c) {
      dl += std::pow(image.at(c, y, x) - left[c], 2);
      dr += std::pow(image.at(c, y, x) - right[c], 2);
    }
    return is_left ? dl < dr : dr < dl;
  };
  int right_side = 0, total = 0;
  for (int y = 12; y < 48; ++y)
    for (int x = 12; x < 68; ++x) {
      if (x >= 28 && x < 52) continue;  // the boundary's halo
      right_side += nearer_own(x, y, x < 40) ? 1 : 0;
      ++total;
    }
  EXPECT_GE(right_side, total * 98 / 100) << right_side << " of " << total;
}

TEST(LatentFeatures, MissingOrMismatchedWeightsAreClearErrors) {
  LatentFeaturesConfig config = small_config();
  std::string why;
  EXPECT_EQ(LatentFeatures::create(config, &why), nullptr);
  EXPECT_NE(why.find("autoencoder_path"), std::string::npos) << why;
  config.autoencoder_path = "/nonexistent/w.fae";
  EXPECT_EQ(LatentFeatures::create(config, &why), nullptr);
  EXPECT_FALSE(why.empty());
  // Weights for other level channels than the builtin encoder's.
  FeatureAutoencoderConfig other;
  other.level_channels = {8, 4, 2};
  const std::string path = (test::fresh_temp_dir("mismatch") / "w.fae").string();
  ASSERT_TRUE(FeatureAutoencoder(other).save(path, &why)) << why;
  config.autoencoder_path = path;
  EXPECT_EQ(LatentFeatures::create(config, &why), nullptr);
  EXPECT_NE(why.find("features:"), std::string::npos) << why;
}

// The live pipeline tracks with the frame's latent (eq. feat_gicp) when features are on: the
// first keyframe's points reach the tracker's local map with their latents, and the encoder's
// time is reported; with track_with_features off the local map carries no features. (Here and
// not in a pipeline test file: it needs this file's image and weights.)
TEST(LatentFeatures, SlamPipelineTracksWithTheFramesLatent) {
  const LatentFeaturesConfig features = [] {
    LatentFeaturesConfig c = small_config();
    c.autoencoder_path = make_weights(c);
    return c;
  }();
  RgbdFrame frame;
  frame.colour = two_halves();
  frame.camera = {250.0, 250.0, 159.5, 119.5, 320, 240};
  frame.depth = cv::Mat(240, 320, CV_32FC1);
  for (int v = 0; v < 240; ++v)  // a floor tilting away, so every lattice cell has depth
    for (int u = 0; u < 320; ++u) frame.depth.at<float>(v, u) = 1.0f + 0.004f * static_cast<float>(v);
  for (const bool on : {true, false}) {
    PipelineConfig config;
    config.features = features;
    config.track_with_features = on;
    std::string why;
    auto mapping_features = LatentFeatures::create(features, &why);
    ASSERT_NE(mapping_features, nullptr) << why;
    config.mapper.feature_dim = mapping_features->dim();
    SlamPipeline pipeline(config, make_cpu_rasterizer(), std::move(mapping_features));
    TrackingResult result;
    ASSERT_TRUE(pipeline.process_frame(frame, &result, &why)) << why;
    ASSERT_TRUE(result.keyframe);
    EXPECT_GT(pipeline.tracker().local_map().size(), 1000u);
    if (on) {
      EXPECT_EQ(pipeline.tracker().local_map().feature_dim(), 16);
      EXPECT_GT(result.timings.features_ms, 0.0);
    } else {
      EXPECT_EQ(pipeline.tracker().local_map().feature_dim(), 0);
      EXPECT_EQ(result.timings.features_ms, 0.0);
    }
    pipeline.finish();
  }
}

}  // namespace
}  // namespace fslam::core

// The onnx backend against the tiny models tests/unit/core/features/make_test_onnx_models.py
// writes at build time (their outputs are block means of the normalised input, scaled per
// channel, so the expected pyramid is computed here exactly).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include <opencv2/core.hpp>

#include "fslam/core/features/feature_encoder.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

fs::path model(const std::string& name) { return fs::path(FSLAM_TEST_ONNX_DIR) / name; }

#define REQUIRE_TEST_MODEL(name)                                                         \
  do {                                                                                   \
    if (!fs::exists(model(name)))                                                        \
      GTEST_SKIP() << "test model " << model(name)                                       \
                   << " was not generated (needs /usr/bin/python3 with python3-onnx at " \
                      "configure time; see tests/CMakeLists.txt)";                       \
  } while (0)

FeatureEncoderConfig onnx_config(const std::string& name) {
  FeatureEncoderConfig config;
  config.backend = FeatureBackend::onnx;
  config.onnx.model_path = model(name).string();
  config.onnx.input_width = 32;
  config.onnx.input_height = 32;
  return config;
}

cv::Mat random_rgb(int w, int h, int seed) {
  cv::Mat img(h, w, CV_8UC3);
  cv::RNG rng(seed);
  rng.fill(img, cv::RNG::UNIFORM, 0, 256);
  return img;
}

// The tiny model's output channel c at (y, x) of a level pooled over `pool` x `pool` blocks:
// (c + 1) * block mean of normalised network channel c % 3 + 0.25 c.
float expected(const cv::Mat& rgb32, const OnnxFeatureConfig& cfg, int pool, int c, int y, int x) {
  const int net_channel = c % 3;
  const int src = cfg.colour_order == ColourOrder::rgb ? net_channel : 2 - net_channel;
  double sum = 0;
  for (int dy = 0; dy < pool; ++dy)
    for (int dx = 0; dx < pool; ++dx) {
      const double p = rgb32.at<cv::Vec3b>(y * pool + dy, x * pool + dx)[src];
      sum += (p / 255.0 - cfg.mean[src]) / cfg.std[src];
    }
  return static_cast<float>((c + 1) * sum / (pool * pool) + 0.25 * c);
}

void expect_pyramid(const FeaturePyramid& p, const cv::Mat& rgb32, const OnnxFeatureConfig& cfg) {
  ASSERT_EQ(p.levels.size(), 3u);
  const int pools[3] = {8, 4, 2};  // coarsest first
  for (int l = 0; l < 3; ++l) {
    const FeatureLevel& level = p.levels[l];
    for (int c = 0; c < level.shape.channels; ++c)
      for (int y = 0; y < level.shape.height; ++y)
        for (int x = 0; x < level.shape.width; ++x)
          ASSERT_NEAR(level.at(c, y, x), expected(rgb32, cfg, pools[l], c, y, x), 2e-4f)
              << "level " << l << " channel " << c << " at (" << x << ", " << y << ")";
  }
}

TEST(OnnxEncoder, MissingModelFileIsAClearError) {
  FeatureEncoderConfig config;
  config.backend = FeatureBackend::onnx;
  std::string why;
  EXPECT_FALSE(config.is_valid(&why));
  EXPECT_NE(why.find("model_path is required"), std::string::npos) << why;
  config.onnx.model_path = "/nonexistent/encoder.onnx";
  EXPECT_EQ(make_feature_encoder(config, &why), nullptr);
  EXPECT_NE(why.find("/nonexistent/encoder.onnx"), std::string::npos) << why;
  EXPECT_NE(why.find("not a readable file"), std::string::npos) << why;
}

TEST(OnnxEncoder, UnreadableModelIsAClearError) {
  const fs::path dir = test::fresh_temp_dir("onnx");
  std::ofstream(dir / "garbage.onnx") << "this is not a protobuf";
  FeatureEncoderConfig config;
  config.backend = FeatureBackend::onnx;
  config.onnx.model_path = (dir / "garbage.onnx").string();
  std::string why;
  EXPECT_EQ(make_feature_encoder(config, &why), nullptr);
  EXPECT_NE(why.find("not a valid ONNX protobuf"), std::string::npos) << why;  // onnx_check.hpp
}

TEST(OnnxEncoder, ConfigValidation) {
  FeatureEncoderConfig config = onnx_config("tiny_pyramid.onnx");
  std::string why;
  EXPECT_TRUE(config.is_valid(&why)) << why;
  config.onnx.std[1] = 0.0f;
  EXPECT_FALSE(config.is_valid(&why));
  EXPECT_NE(why.find("std"), std::string::npos) << why;
  config = onnx_config("tiny_pyramid.onnx");
  config.onnx.output_names = {"a", "b"};
  EXPECT_FALSE(config.is_valid(&why));
  config.onnx.output_names = {"a", "b", "a"};
  EXPECT_FALSE(config.is_valid(&why));
  config.onnx.output_names = {"a", "b", "c"};
  EXPECT_TRUE(config.is_valid(&why)) << why;
  config.onnx.input_width = 0;
  EXPECT_FALSE(config.is_valid(&why));
}

TEST(OnnxEncoder, ShapesAreOrderedCoarsestFirst) {
  REQUIRE_TEST_MODEL("tiny_pyramid.onnx");
  std::string why;
  auto encoder = make_feature_encoder(onnx_config("tiny_pyramid.onnx"), &why);
  ASSERT_NE(encoder, nullptr) << why;
  // The graph lists mid, fine, coarse; the pyramid is coarse, mid, fine.
  const std::vector<FeatureLevelShape> shapes = {{8, 4, 4}, {4, 8, 8}, {2, 16, 16}};
  EXPECT_EQ(encoder->level_shapes(), shapes);
  EXPECT_EQ(encoder->dim(), 14);
  EXPECT_NE(encoder->describe().find("[8, 4, 4], [4, 8, 8], [2, 16, 16]"), std::string::npos)
      << encoder->describe();
}

TEST(OnnxEncoder, NormalisesAndAssemblesThePyramid) {
  REQUIRE_TEST_MODEL("tiny_pyramid.onnx");
  FeatureEncoderConfig config = onnx_config("tiny_pyramid.onnx");
  config.onnx.mean = {0.1f, 0.5f, 0.9f};
  config.onnx.std = {0.5f, 0.25f, 2.0f};
  std::string why;
  auto encoder = make_feature_encoder(config, &why);
  ASSERT_NE(encoder, nullptr) << why;
  const cv::Mat rgb = random_rgb(32, 32, 7);
  FeaturePyramid p;
  ASSERT_TRUE(encoder->encode(rgb, &p, &why)) << why;
  EXPECT_EQ(p.image_width, 32);
  EXPECT_EQ(p.image_height, 32);
  EXPECT_EQ(p.shapes(), encoder->level_shapes());
  expect_pyramid(p, rgb, config.onnx);
}

TEST(OnnxEncoder, BgrColourOrderSwapsTheInputChannels) {
  REQUIRE_TEST_MODEL("tiny_pyramid.onnx");
  FeatureEncoderConfig config = onnx_config("tiny_pyramid.onnx");
  config.onnx.colour_order = ColourOrder::bgr;
  config.onnx.mean = {0.2f, 0.4f, 0.6f};  // still RGB order
  std::string why;
  auto encoder = make_feature_encoder(config, &why);
  ASSERT_NE(encoder, nullptr) << why;
  const cv::Mat rgb = random_rgb(32, 32, 8);
  FeaturePyramid p;
  ASSERT_TRUE(encoder->encode(rgb, &p, &why)) << why;
  expect_pyramid(p, rgb, config.onnx);
}

TEST(OnnxEncoder, ResizesTheFrameToTheInputSize) {
  REQUIRE_TEST_MODEL("tiny_pyramid.onnx");
  FeatureEncoderConfig config = onnx_config("tiny_pyramid.onnx");
  std::string why;
  auto encoder = make_feature_encoder(config, &why);
  ASSERT_NE(encoder, nullptr) << why;
  // A 64x64 frame of 2x2 constant blocks shrinks exactly onto the 32x32 frame of the blocks.
  const cv::Mat rgb32 = random_rgb(32, 32, 9);
  cv::Mat rgb64(64, 64, CV_8UC3);
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 64; ++x) rgb64.at<cv::Vec3b>(y, x) = rgb32.at<cv::Vec3b>(y / 2, x / 2);
  FeaturePyramid p;
  ASSERT_TRUE(encoder->encode(rgb64, &p, &why)) << why;
  EXPECT_EQ(p.image_width, 64);
  expect_pyramid(p, rgb32, config.onnx);
}

TEST(OnnxEncoder, NamedOutputsInAnyOrder) {
  REQUIRE_TEST_MODEL("tiny_pyramid.onnx");
  FeatureEncoderConfig config = onnx_config("tiny_pyramid.onnx");
  config.onnx.output_names = {"fine_feats", "coarse_feats", "mid_feats"};
  std::string why;
  auto encoder = make_feature_encoder(config, &why);
  ASSERT_NE(encoder, nullptr) << why;
  const cv::Mat rgb = random_rgb(32, 32, 10);
  FeaturePyramid p;
  ASSERT_TRUE(encoder->encode(rgb, &p, &why)) << why;
  expect_pyramid(p, rgb, config.onnx);

  config.onnx.output_names = {"fine_feats", "coarse_feats", "no_such_output"};
  EXPECT_EQ(make_feature_encoder(config, &why), nullptr);
  EXPECT_NE(why.find("no output named 'no_such_output'"), std::string::npos) << why;
}

TEST(OnnxEncoder, WrongOutputCountIsAClearError) {
  REQUIRE_TEST_MODEL("two_outputs.onnx");
  std::string why;
  EXPECT_EQ(make_feature_encoder(onnx_config("two_outputs.onnx"), &why), nullptr);
  EXPECT_NE(why.find("has 2 outputs"), std::string::npos) << why;
  EXPECT_NE(why.find("expected 3"), std::string::npos) << why;
}

TEST(OnnxEncoder, WrongOutputShapeIsAClearError) {
  REQUIRE_TEST_MODEL("flat_output.onnx");
  std::string why;
  EXPECT_EQ(make_feature_encoder(onnx_config("flat_output.onnx"), &why), nullptr);
  EXPECT_NE(why.find("'coarse_feats' has shape [1, 128]"), std::string::npos) << why;
  EXPECT_NE(why.find("[1, C, H, W]"), std::string::npos) << why;
}

TEST(OnnxEncoder, RejectsImagesThatAreNotRgb8) {
  REQUIRE_TEST_MODEL("tiny_pyramid.onnx");
  std::string why;
  auto encoder = make_feature_encoder(onnx_config("tiny_pyramid.onnx"), &why);
  ASSERT_NE(encoder, nullptr) << why;
  FeaturePyramid p;
  EXPECT_FALSE(encoder->encode(cv::Mat(), &p, &why));
  EXPECT_FALSE(encoder->encode(cv::Mat(32, 32, CV_32FC3, cv::Scalar::all(0)), &p, &why));
  EXPECT_NE(why.find("8-bit 3-channel"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::core

#include "fslam/core/features/feature_pyramid.hpp"

#include <gtest/gtest.h>

#include <vector>

namespace fslam::core {
namespace {

// A pyramid for an 8x4 frame: level 0 [2, 2, 4] (half resolution), level 1 [1, 4, 8] (full).
// Values are distinct and not linear in x or y, so a wrong weight or index shows.
FeaturePyramid make_pyramid() {
  FeaturePyramid p;
  p.image_width = 8;
  p.image_height = 4;
  p.levels.resize(2);
  p.levels[0].resize({2, 2, 4});
  p.levels[1].resize({1, 4, 8});
  for (auto& level : p.levels)
    for (std::size_t i = 0; i < level.data.size(); ++i)
      level.data[i] = static_cast<float>((i * 37) % 23) + 0.5f * static_cast<float>(i % 3);
  return p;
}

TEST(FeaturePyramid, DimIsTheSumOfChannels) {
  const FeaturePyramid p = make_pyramid();
  EXPECT_EQ(p.dim(), 3);
  EXPECT_EQ(feature_dim({{256, 64, 64}, {64, 128, 128}, {32, 256, 256}}), 352);
  EXPECT_EQ(p.shapes()[0], (FeatureLevelShape{2, 2, 4}));
  EXPECT_EQ(p.levels[0].at(1, 1, 2), p.levels[0].data[(1 * 2 + 1) * 4 + 2]);
}

TEST(FeaturePyramid, ExactAtPixelCentres) {
  const FeaturePyramid p = make_pyramid();
  const auto& full = p.levels[1];
  // (u, v) = (3, 2) is the centre of full-resolution pixel (3, 2).
  const std::vector<float> s = sample_features(p, 3.0f, 2.0f);
  ASSERT_EQ(s.size(), 3u);
  EXPECT_FLOAT_EQ(s[2], full.at(0, 2, 3));
  // On the half-resolution level, u = 2.5 maps to x = (2.5 + 0.5) * 4 / 8 - 0.5 = 1 and
  // v = 0.5 to y = (0.5 + 0.5) * 2 / 4 - 0.5 = 0: the centre of level pixel (1, 0).
  const std::vector<float> h = sample_features(p, 2.5f, 0.5f);
  EXPECT_FLOAT_EQ(h[0], p.levels[0].at(0, 0, 1));
  EXPECT_FLOAT_EQ(h[1], p.levels[0].at(1, 0, 1));
}

TEST(FeaturePyramid, BilinearBetweenCentres) {
  const FeaturePyramid p = make_pyramid();
  const auto& half = p.levels[0];
  const auto& full = p.levels[1];
  // Full level: halfway between pixels (3, 2) and (4, 2), a quarter of the way to row 3.
  const std::vector<float> s = sample_features(p, 3.5f, 2.25f);
  const float top = 0.5f * (full.at(0, 2, 3) + full.at(0, 2, 4));
  const float bottom = 0.5f * (full.at(0, 3, 3) + full.at(0, 3, 4));
  EXPECT_NEAR(s[2], 0.75f * top + 0.25f * bottom, 1e-5f);
  // Half level at (u, v) = (3, 1.5): x = 1.25, y = 0.5.
  const std::vector<float> h = sample_features(p, 3.0f, 1.5f);
  for (int c = 0; c < 2; ++c) {
    const float row0 = 0.75f * half.at(c, 0, 1) + 0.25f * half.at(c, 0, 2);
    const float row1 = 0.75f * half.at(c, 1, 1) + 0.25f * half.at(c, 1, 2);
    EXPECT_NEAR(h[c], 0.5f * row0 + 0.5f * row1, 1e-5f) << "channel " << c;
  }
}

TEST(FeaturePyramid, ClampedAtBorders) {
  const FeaturePyramid p = make_pyramid();
  const auto& half = p.levels[0];
  const auto& full = p.levels[1];
  // The frame's corner pixel centre (0, 0) lies outside the half level's outermost centres.
  std::vector<float> s = sample_features(p, 0.0f, 0.0f);
  EXPECT_FLOAT_EQ(s[0], half.at(0, 0, 0));
  EXPECT_FLOAT_EQ(s[2], full.at(0, 0, 0));
  // Far outside: the nearest border pixel.
  s = sample_features(p, 100.0f, -7.0f);
  EXPECT_FLOAT_EQ(s[1], half.at(1, 0, 3));
  EXPECT_FLOAT_EQ(s[2], full.at(0, 0, 7));
  // Outside along one axis only: clamped in x, bilinear in y.
  s = sample_features(p, -3.0f, 1.5f);
  EXPECT_NEAR(s[2], 0.5f * (full.at(0, 1, 0) + full.at(0, 2, 0)), 1e-5f);
  // The pointer form writes the same values.
  std::vector<float> out(3, -1.0f);
  sample_features(p, 5.2f, 2.7f, out.data());
  EXPECT_EQ(out, sample_features(p, 5.2f, 2.7f));
}

}  // namespace
}  // namespace fslam::core

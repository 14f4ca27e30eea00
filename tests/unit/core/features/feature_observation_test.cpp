// The decoded L_feat's target: sample pixels on a jittered grid, u coded in 1/16 standard
// deviations.
#include <algorithm>
#include <cmath>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "fslam/core/features/feature_observation.hpp"

namespace fslam::core {
namespace {

// Two levels (3 channels at 8x6, 2 channels at 16x12) of smooth values over a 32x24 frame.
FeaturePyramid smooth_pyramid() {
  FeaturePyramid p;
  p.image_width = 32;
  p.image_height = 24;
  const FeatureLevelShape shapes[2] = {{3, 6, 8}, {2, 12, 16}};
  for (const FeatureLevelShape& s : shapes) {
    FeatureLevel level;
    level.resize(s);
    for (int c = 0; c < s.channels; ++c)
      for (int y = 0; y < s.height; ++y)
        for (int x = 0; x < s.width; ++x)
          level.channel(c)[y * s.width + x] = 2.0f * std::sin(0.4f * x + 0.9f * c) + 0.3f * y - 1.0f;
    p.levels.push_back(std::move(level));
  }
  return p;
}

TEST(FeatureObservation, CodesEachSampleWithinHalfAStepOfItsChannelSpread) {
  const FeaturePyramid p = smooth_pyramid();
  const std::vector<float> mean = {0.5f, -0.2f, 0.0f, 1.0f, 0.1f}, spread = {1.5f, 2.0f, 0.8f, 1.0f, 3.0f};
  FeatureObservation obs;
  std::string why;
  ASSERT_TRUE(observe_features(p, 40, 30, 120, 7, mean, spread, &obs, &why)) << why;
  // One pixel per cell of a 13x9 grid (aspect 4:3), each inside the image and distinct.
  EXPECT_NEAR(static_cast<double>(obs.size()), 120.0, 10.0);
  EXPECT_EQ(obs.channels, 5);
  EXPECT_EQ(obs.codes.size(), obs.size() * 5);
  std::set<int> distinct(obs.pixels.begin(), obs.pixels.end());
  EXPECT_EQ(distinct.size(), obs.size());
  for (int px : obs.pixels) EXPECT_TRUE(px >= 0 && px < 40 * 30);
  // Spread over the image: every quarter holds about a quarter of the samples.
  int quarters[4] = {};
  for (int px : obs.pixels) ++quarters[(px % 40 >= 20) + 2 * (px / 40 >= 15)];
  for (int q : quarters) EXPECT_NEAR(q, static_cast<double>(obs.size()) / 4, 6.0);
  std::vector<float> u;
  obs.samples(mean, spread, &u);
  ASSERT_EQ(u.size(), obs.size() * 5);
  for (std::size_t k = 0; k < obs.size(); ++k) {
    const int x = obs.pixels[k] % 40, y = obs.pixels[k] / 40;
    const std::vector<float> exact = sample_features(p, (x + 0.5f) * 32 / 40 - 0.5f, (y + 0.5f) * 24 / 30 - 0.5f);
    for (int c = 0; c < 5; ++c) {
      EXPECT_LE(std::abs(u[k * 5 + c] - exact[c]), 0.5f * FeatureObservation::kCodeStep * spread[c] + 1e-5f)
          << "sample " << k << " channel " << c;
    }
  }
  // The same seed gives the same pixels; another seed other pixels.
  FeatureObservation again, other;
  ASSERT_TRUE(observe_features(p, 40, 30, 120, 7, mean, spread, &again, &why));
  ASSERT_TRUE(observe_features(p, 40, 30, 120, 8, mean, spread, &other, &why));
  EXPECT_EQ(again.pixels, obs.pixels);
  EXPECT_NE(other.pixels, obs.pixels);
}

TEST(FeatureObservation, ClampsOutliersAndRefusesBadInput) {
  FeaturePyramid p = smooth_pyramid();
  p.levels[0].data[0] = 1e6f;
  p.levels[1].data[0] = std::nanf("");
  const std::vector<float> mean(5, 0.0f), spread(5, 1.0f);
  FeatureObservation obs;
  std::string why;
  ASSERT_TRUE(observe_features(p, 32, 24, 768, 1, mean, spread, &obs, &why)) << why;  // every pixel
  for (std::int8_t code : obs.codes) EXPECT_GE(code, -127);
  EXPECT_FALSE(observe_features(FeaturePyramid{}, 32, 24, 10, 1, mean, spread, &obs, &why));
  EXPECT_FALSE(observe_features(p, 0, 24, 10, 1, mean, spread, &obs, &why));
  EXPECT_FALSE(observe_features(p, 32, 24, 0, 1, mean, spread, &obs, &why));
  EXPECT_FALSE(observe_features(p, 32, 24, 10, 1, std::vector<float>(4, 0.0f), spread, &obs, &why));
  EXPECT_NE(why.find("channels"), std::string::npos);
}

}  // namespace
}  // namespace fslam::core

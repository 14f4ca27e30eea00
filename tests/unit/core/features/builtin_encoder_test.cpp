// The builtin descriptor pyramid: the three-level contract, determinism, and that it separates
// regions of different colour or texture while staying smooth within one.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>

#include "fslam/core/features/feature_encoder.hpp"

namespace fslam::core {
namespace {

std::unique_ptr<FeatureEncoder> builtin(int w = 1024, int h = 1024) {
  FeatureEncoderConfig config;
  config.builtin.input_width = w;
  config.builtin.input_height = h;
  std::string why;
  auto encoder = make_feature_encoder(config, &why);
  EXPECT_NE(encoder, nullptr) << why;
  return encoder;
}

FeaturePyramid encode(FeatureEncoder& encoder, const cv::Mat& rgb) {
  FeaturePyramid p;
  std::string why;
  EXPECT_TRUE(encoder.encode(rgb, &p, &why)) << why;
  return p;
}

// A 640x480 frame whose left half is painted by `left` and right half by `right`; each returns
// the RGB colour at (x, y). A little deterministic noise, like a camera's.
using Paint = std::function<cv::Vec3f(int x, int y)>;
cv::Mat two_regions(const Paint& left, const Paint& right) {
  cv::Mat img(480, 640, CV_8UC3);
  cv::RNG rng(3);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      const cv::Vec3f c = x < img.cols / 2 ? left(x, y) : right(x, y);
      for (int k = 0; k < 3; ++k)
        img.at<cv::Vec3b>(y, x)[k] = cv::saturate_cast<uchar>(c[k] + rng.gaussian(2.0));
    }
  return img;
}

Paint flat(cv::Vec3f c) {
  return [c](int, int) { return c; };
}
// Stripes of `period` pixels across x (vertical stripes) or y, between colours a and b.
Paint stripes(cv::Vec3f a, cv::Vec3f b, int period, bool vertical) {
  return [=](int x, int y) { return ((vertical ? x : y) / (period / 2)) % 2 ? a : b; };
}

// Root-mean-square difference per channel of the sampled vectors u_i, so that thresholds do
// not depend on the number of channels.
double distance(const std::vector<float>& a, const std::vector<float>& b) {
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += (a[i] - b[i]) * (a[i] - b[i]);
  return std::sqrt(s / a.size());
}

// Points well inside the left (side -1) or right (+1) half of the 640x480 two-region frame, at
// least 100 px from the boundary and the frame border.
std::vector<cv::Point2f> region_points(int side) {
  std::vector<cv::Point2f> pts;
  for (float dx : {120.0f, 160.0f, 200.0f})
    for (float y : {180.0f, 240.0f, 300.0f}) pts.emplace_back(320.0f + side * dx, y);
  return pts;
}

struct Separation {
  double within = 0;  // largest distance between two points of one region
  double across = 0;  // smallest distance between points of different regions
};

Separation separation(const FeaturePyramid& p) {
  Separation s;
  s.across = 1e30;
  const auto left = region_points(-1), right = region_points(1);
  for (const auto* region : {&left, &right})
    for (const auto& a : *region)
      for (const auto& b : *region)
        s.within = std::max(s.within, distance(sample_features(p, a.x, a.y),
                                               sample_features(p, b.x, b.y)));
  for (const auto& a : left)
    for (const auto& b : right)
      s.across = std::min(s.across, distance(sample_features(p, a.x, a.y),
                                             sample_features(p, b.x, b.y)));
  return s;
}

TEST(BuiltinEncoder, ThePapersThreeLevels) {
  auto encoder = builtin();
  ASSERT_NE(encoder, nullptr);
  const std::vector<FeatureLevelShape> expected = {{256, 64, 64}, {64, 128, 128}, {32, 256, 256}};
  EXPECT_EQ(encoder->level_shapes(), expected);
  EXPECT_EQ(encoder->dim(), 352);
  const FeaturePyramid p = encode(*encoder, cv::Mat(480, 640, CV_8UC3, cv::Scalar(90, 120, 30)));
  EXPECT_EQ(p.shapes(), expected);
  EXPECT_EQ(p.image_width, 640);
  EXPECT_EQ(p.image_height, 480);
  const auto names = builtin_feature_channel_names();
  ASSERT_EQ(names.size(), 3u);
  for (int l = 0; l < 3; ++l) EXPECT_EQ(static_cast<int>(names[l].size()), expected[l].channels);
  EXPECT_EQ(names[2][0], "L@4");
  EXPECT_EQ(names[2][12], "E0/2@4");  // stride-2 energy pooled over sigma ~ 4 input px
}

TEST(BuiltinEncoder, LevelSizesFollowTheInputSize) {
  auto encoder = builtin(512, 256);
  ASSERT_NE(encoder, nullptr);
  const std::vector<FeatureLevelShape> expected = {{256, 16, 32}, {64, 32, 64}, {32, 64, 128}};
  EXPECT_EQ(encoder->level_shapes(), expected);
  EXPECT_EQ(encode(*encoder, cv::Mat(100, 70, CV_8UC3, cv::Scalar::all(7))).shapes(), expected);

  FeatureEncoderConfig config;
  config.builtin.input_width = 1000;  // not a multiple of 16
  std::string why;
  EXPECT_EQ(make_feature_encoder(config, &why), nullptr);
  EXPECT_NE(why.find("multiples of 16"), std::string::npos) << why;
}

TEST(BuiltinEncoder, DeterministicAndFinite) {
  cv::Mat noise(480, 640, CV_8UC3);
  cv::RNG(11).fill(noise, cv::RNG::UNIFORM, 0, 256);
  auto a = builtin(), b = builtin();
  const FeaturePyramid pa = encode(*a, noise), pa2 = encode(*a, noise), pb = encode(*b, noise);
  for (int l = 0; l < 3; ++l) {
    EXPECT_EQ(pa.levels[l].data, pa2.levels[l].data) << "level " << l;
    EXPECT_EQ(pa.levels[l].data, pb.levels[l].data) << "level " << l;
    for (float v : pa.levels[l].data) ASSERT_TRUE(std::isfinite(v));
  }
  // OpenCV's thread count does not change a bit.
  const int threads = cv::getNumThreads();
  cv::setNumThreads(1);
  const FeaturePyramid serial = encode(*a, noise);
  cv::setNumThreads(threads);
  for (int l = 0; l < 3; ++l) EXPECT_EQ(pa.levels[l].data, serial.levels[l].data) << "level " << l;
  // Saturated frames stay finite.
  for (double v : {0.0, 255.0})
    for (const auto& level : encode(*a, cv::Mat(48, 64, CV_8UC3, cv::Scalar::all(v))).levels)
      for (float x : level.data) ASSERT_TRUE(std::isfinite(x));
}

TEST(BuiltinEncoder, ConstantColourGivesConstantFeatures) {
  auto encoder = builtin();
  for (const cv::Scalar& colour : {cv::Scalar(0, 0, 0), cv::Scalar(200, 40, 90),
                                  cv::Scalar(255, 255, 255), cv::Scalar(30, 180, 220)}) {
    const FeaturePyramid p = encode(*encoder, cv::Mat(480, 640, CV_8UC3, colour));
    for (int l = 0; l < 3; ++l)
      for (int c = 0; c < p.levels[l].shape.channels; ++c) {
        const cv::Mat ch(p.levels[l].shape.height, p.levels[l].shape.width, CV_32FC1,
                         const_cast<float*>(p.levels[l].channel(c)));
        double lo, hi;
        cv::minMaxLoc(ch, &lo, &hi);
        // Whole level, borders included: the filters replicate the border.
        ASSERT_LT(hi - lo, 1e-3) << "level " << l << " channel " << c << " colour " << colour;
      }
  }
}

const cv::Vec3f kRed(190, 60, 50), kBlue(60, 80, 190), kGrey(128, 128, 128);
const cv::Vec3f kDark(88, 88, 88), kLight(168, 168, 168);  // mean kGrey

// Regions that differ in colour only, in texture only, or in texture orientation only are
// farther apart across the boundary than any two points within a region: by at least 3x in the
// RMS per-channel distance of the whole 352-vector.
TEST(BuiltinEncoder, SeparatesColourAndTexture) {
  auto encoder = builtin();
  struct Case {
    const char* what;
    cv::Mat image;
  };
  const Case cases[] = {
      {"red vs blue", two_regions(flat(kRed), flat(kBlue))},
      {"8 px stripes vs flat grey of the same mean",
       two_regions(stripes(kDark, kLight, 8, true), flat(kGrey))},
      {"vertical vs horizontal 8 px stripes",
       two_regions(stripes(kDark, kLight, 8, true), stripes(kDark, kLight, 8, false))},
      {"4 px vs 12 px stripes",
       two_regions(stripes(kDark, kLight, 4, true), stripes(kDark, kLight, 12, true))},
  };
  for (const Case& c : cases) {
    const Separation s = separation(encode(*encoder, c.image));
    EXPECT_GT(s.across, 3.0 * s.within) << c.what << ": across " << s.across << " within "
                                        << s.within;
  }
}

// Stripes 12 px wide are regions of their own at the fine level (its cells are 2.5 px), so
// fine vs coarse stripes separate at the coarse level, whose channels are texture statistics.
TEST(BuiltinEncoder, CoarseLevelSeparatesTextureScales) {
  auto encoder = builtin();
  FeaturePyramid p = encode(*encoder, two_regions(stripes(kDark, kLight, 6, true),
                                                  stripes(kDark, kLight, 24, true)));
  p.levels.resize(1);  // the coarse level alone
  const Separation s = separation(p);
  EXPECT_GT(s.across, 3.0 * s.within) << "across " << s.across << " within " << s.within;
}

// A 10% gain moves every point's features less than a region change: under 0.2x the step
// between regions of different colour, and under 0.6x the step between a striped and a flat
// region (texture energies scale with contrast; docs/features.md).
TEST(BuiltinEncoder, BrightnessChangeMovesFeaturesLessThanARegionChange) {
  auto encoder = builtin();
  struct Case {
    cv::Mat image;
    double bound;
  };
  const Case cases[] = {{two_regions(flat(kRed), flat(kBlue)), 0.2},
                        {two_regions(stripes(kDark, kLight, 8, true), flat(kGrey)), 0.6}};
  for (const Case& c : cases) {
    cv::Mat brighter;
    c.image.convertTo(brighter, CV_8UC3, 1.1);
    const FeaturePyramid p = encode(*encoder, c.image), q = encode(*encoder, brighter);
    const double across = separation(p).across;
    for (int side : {-1, 1})
      for (const auto& pt : region_points(side)) {
        const double moved = distance(sample_features(p, pt.x, pt.y),
                                      sample_features(q, pt.x, pt.y));
        EXPECT_LT(moved, c.bound * across) << "at (" << pt.x << ", " << pt.y << ")";
      }
  }
}

TEST(BuiltinEncoder, RejectsImagesThatAreNotRgb8) {
  auto encoder = builtin();
  FeaturePyramid p;
  std::string why;
  EXPECT_FALSE(encoder->encode(cv::Mat(), &p, &why));
  EXPECT_FALSE(encoder->encode(cv::Mat(10, 10, CV_8UC1, cv::Scalar(0)), &p, &why));
  EXPECT_NE(why.find("8-bit 3-channel"), std::string::npos) << why;
}

TEST(FeatureEncoderConfig, BackendNames) {
  FeatureBackend b;
  std::string why;
  EXPECT_TRUE(parse_feature_backend("onnx", &b, &why));
  EXPECT_EQ(b, FeatureBackend::onnx);
  EXPECT_STREQ(to_string(b), "onnx");
  EXPECT_TRUE(parse_feature_backend("builtin", &b, &why));
  EXPECT_EQ(b, FeatureBackend::builtin);
  EXPECT_FALSE(parse_feature_backend("dino", &b, &why));
  EXPECT_NE(why.find("dino"), std::string::npos);
  EXPECT_TRUE(FeatureEncoderConfig().is_valid(&why)) << why;  // builtin needs no model file
}

}  // namespace
}  // namespace fslam::core

// The grounding detector's plumbing (tokens, pre-processing, output decoding, thresholds) on a
// tiny ONNX model generated at test time: whatever it sees, it answers one box scoring 0.98 and
// one scoring 0.02.
#include "fslam/server/grounding.hpp"

#include <cmath>
#include <filesystem>

#include <gtest/gtest.h>

#include "grounding_model.hpp"
#include "test_support.hpp"

namespace fslam::server {
namespace {

TEST(Grounding, SplitsLowerCasedWordsAndPunctuation) {
  EXPECT_EQ(split_tokens("  The LEFT panel. "), (std::vector<std::string>{"the", "left", "panel", "."}));
  EXPECT_EQ(split_tokens("red,cup"), (std::vector<std::string>{"red", ",", "cup"}));
  EXPECT_TRUE(split_tokens(" \t").empty());
}

class GroundingModel : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string why;
    model_ = test::make_grounding_model(test::fresh_temp_dir("model").string(), 64, 0.25, 0.5, 0.3,
                                        0.4, &why);
    if (model_.empty()) GTEST_SKIP() << why;
  }
  GroundingConfig config() const {
    GroundingConfig c;
    c.model = model_;
    c.input_size = 64;
    return c;
  }
  std::string model_;
};

TEST_F(GroundingModel, KeepsExactlyTheHighScoringBoxInPixels) {
  GroundingDetector detector;
  std::string why;
  ASSERT_TRUE(detector.load(config(), &why)) << why;
  // vocabulary: [PAD] [UNK] the left right panel .
  EXPECT_EQ(detector.token_ids("The left cup."), (std::vector<float>{2, 3, 1, 6}));
  const cv::Mat view(120, 160, CV_8UC3, cv::Scalar(90, 120, 150));
  // Two texts of different lengths in a row: the network takes any token count.
  for (const char* text : {"the left panel", "panel"}) {
    std::vector<GroundedBox> boxes;
    ASSERT_TRUE(detector.detect(view, text, &boxes, &why)) << why;
    ASSERT_EQ(boxes.size(), 1u) << text;
    // (cx, cy, w, h) = (0.25, 0.5, 0.3, 0.4) of a 160 x 120 view.
    EXPECT_NEAR(boxes[0].u0, 16.0, 1e-3);
    EXPECT_NEAR(boxes[0].u1, 64.0, 1e-3);
    EXPECT_NEAR(boxes[0].v0, 36.0, 1e-3);
    EXPECT_NEAR(boxes[0].v1, 84.0, 1e-3);
    EXPECT_NEAR(boxes[0].score, 1.0 / (1.0 + std::exp(-4.0)), 1e-4);
  }
  std::vector<GroundedBox> boxes;
  EXPECT_FALSE(detector.detect(view, "   ", &boxes, &why));
  EXPECT_NE(why.find("no words"), std::string::npos) << why;
}

TEST_F(GroundingModel, ThresholdDropsBoxesScoringLess) {
  GroundingConfig c = config();
  c.box_threshold = 0.99f;
  GroundingDetector detector;
  std::string why;
  ASSERT_TRUE(detector.load(c, &why)) << why;
  std::vector<GroundedBox> boxes;
  ASSERT_TRUE(detector.detect(cv::Mat(60, 80, CV_8UC3, cv::Scalar(0)), "panel", &boxes, &why)) << why;
  EXPECT_TRUE(boxes.empty());
}

TEST_F(GroundingModel, MissingFilesAreClearErrors) {
  GroundingDetector detector;
  std::string why;
  GroundingConfig c = config();
  c.model = model_ + ".absent";
  EXPECT_FALSE(detector.load(c, &why));
  EXPECT_NE(why.find("vocabulary"), std::string::npos) << why;
  std::filesystem::copy_file(model_ + ".vocab.txt", c.model + ".vocab.txt");
  EXPECT_FALSE(detector.load(c, &why));
  EXPECT_NE(why.find(c.model), std::string::npos) << why;
  std::vector<GroundedBox> boxes;
  EXPECT_FALSE(detector.detect(cv::Mat(8, 8, CV_8UC3), "panel", &boxes, &why));
  EXPECT_NE(why.find("no model"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::server

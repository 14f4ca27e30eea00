#include "fslam/core/io/image_io.hpp"

#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "test_support.hpp"

namespace fslam::core {
namespace {

TEST(ImageIo, DepthRoundTripAndInvalidCodes) {
  const auto dir = test::fresh_temp_dir("depth");
  cv::Mat raw(4, 5, CV_16UC1, cv::Scalar(5000));
  raw.at<std::uint16_t>(1, 2) = 0;
  raw.at<std::uint16_t>(2, 3) = 65535;
  raw.at<std::uint16_t>(3, 4) = 12345;
  std::string why;
  const auto path = (dir / "d.png").string();
  ASSERT_TRUE(write_image(path, raw, &why)) << why;
  cv::Mat metres;
  ASSERT_TRUE(read_depth_image(path, 5000.0, &metres, &why)) << why;
  ASSERT_EQ(metres.type(), CV_32FC1);
  EXPECT_FLOAT_EQ(metres.at<float>(0, 0), 1.0f);
  EXPECT_FLOAT_EQ(metres.at<float>(1, 2), 0.0f);
  EXPECT_FLOAT_EQ(metres.at<float>(2, 3), 0.0f);
  EXPECT_NEAR(metres.at<float>(3, 4), 2.469f, 1e-6);
  // And back to 16-bit without loss.
  const cv::Mat again = depth_to_u16(metres, 5000.0);
  EXPECT_EQ(again.at<std::uint16_t>(3, 4), 12345);
  EXPECT_EQ(again.at<std::uint16_t>(2, 3), 0);
}

TEST(ImageIo, ColourIsRgbOrder) {
  const auto dir = test::fresh_temp_dir("colour");
  cv::Mat rgb(2, 3, CV_8UC3, cv::Scalar(10, 20, 30));
  std::string why;
  ASSERT_TRUE(write_image((dir / "c.png").string(), rgb, &why)) << why;
  cv::Mat back;
  ASSERT_TRUE(read_colour_image((dir / "c.png").string(), &back, &why)) << why;
  EXPECT_EQ(back.at<cv::Vec3b>(1, 2), cv::Vec3b(10, 20, 30));
}

TEST(ImageIo, ErrorsNameTheFile) {
  const auto dir = test::fresh_temp_dir("errors");
  std::string why;
  cv::Mat m;
  EXPECT_FALSE(read_colour_image((dir / "nope.png").string(), &m, &why));
  EXPECT_NE(why.find("nope.png"), std::string::npos) << why;
  std::ofstream((dir / "junk.png").string()) << "not a png";
  EXPECT_FALSE(read_depth_image((dir / "junk.png").string(), 1000.0, &m, &why));
  EXPECT_NE(why.find("junk.png"), std::string::npos) << why;
  cv::Mat rgb(2, 2, CV_8UC3, cv::Scalar::all(1));
  ASSERT_TRUE(write_image((dir / "rgb.png").string(), rgb, &why));
  EXPECT_FALSE(read_depth_image((dir / "rgb.png").string(), 1000.0, &m, &why));
  EXPECT_NE(why.find("one channel"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::core

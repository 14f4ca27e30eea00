#include <cmath>

#include <gtest/gtest.h>

#include "fslam/core/compute/backend.hpp"

namespace fslam::core {
namespace {

TEST(CpuBackend, UnprojectsValidPixelsAndMarksMissing) {
  PinholeCamera cam{500.0, 400.0, 2.0, 1.0, 5, 3};
  cv::Mat depth(3, 5, CV_32FC1, cv::Scalar(2.0f));
  depth.at<float>(0, 0) = 0.0f;
  depth.at<float>(1, 1) = std::nanf("");
  depth.at<float>(2, 4) = 50.0f;  // beyond max_depth
  auto backend = make_cpu_backend();
  std::vector<float> points;
  std::string why;
  ASSERT_TRUE(backend->unproject_depth(depth, cam, DepthRange{}, &points, &why)) << why;
  ASSERT_EQ(points.size(), 45u);
  EXPECT_TRUE(std::isnan(points[0]));
  EXPECT_TRUE(std::isnan(points[3 * 6]));
  EXPECT_TRUE(std::isnan(points[3 * 14]));
  // Pixel (u=4, v=0) at 2 m: x = (4 - 2) * 2 / 500, y = (0 - 1) * 2 / 400.
  EXPECT_FLOAT_EQ(points[3 * 4 + 0], 0.008f);
  EXPECT_FLOAT_EQ(points[3 * 4 + 1], -0.005f);
  EXPECT_FLOAT_EQ(points[3 * 4 + 2], 2.0f);
}

TEST(CpuBackend, RejectsBadInput) {
  auto backend = make_cpu_backend();
  std::vector<float> points;
  std::string why;
  cv::Mat depth(3, 5, CV_32FC1, cv::Scalar(1.0f));
  EXPECT_FALSE(backend->unproject_depth(depth, PinholeCamera{0, 0, 0, 0, 5, 3}, {}, &points, &why));
  EXPECT_NE(why.find("intrinsics"), std::string::npos) << why;
  EXPECT_FALSE(backend->unproject_depth(depth, PinholeCamera{1, 1, 1, 1, 6, 3}, {}, &points, &why));
  EXPECT_NE(why.find("5x3"), std::string::npos) << why;
  EXPECT_FALSE(backend->unproject_depth(cv::Mat(3, 5, CV_16UC1), PinholeCamera{1, 1, 1, 1, 5, 3},
                                        {}, &points, &why));
}

}  // namespace
}  // namespace fslam::core

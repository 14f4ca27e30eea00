// The client's own 16-bit depth PNG writer: any PNG decoder (here OpenCV's, as the server
// uses) reads back exactly the values written, byte order and extremes included.
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "../../../client/src/depth_png.hpp"

namespace fslam::client {
namespace {

TEST(DepthPng, DecodesToTheExactValuesWritten) {
  const int w = 37, h = 23;  // odd sizes: no row padding assumptions
  std::vector<std::uint16_t> depth(static_cast<std::size_t>(w) * h);
  std::mt19937 rng(4);
  std::uniform_int_distribution<int> value(0, 65535);
  for (auto& d : depth) d = static_cast<std::uint16_t>(value(rng));
  depth[0] = 0;
  depth[1] = 65535;
  depth[2] = 0x0102;  // distinguishes byte orders
  std::vector<std::uint8_t> png;
  std::string why;
  ASSERT_TRUE(encode_depth_png(depth.data(), w, h, &png, &why)) << why;
  const cv::Mat back = cv::imdecode(png, cv::IMREAD_UNCHANGED);
  ASSERT_EQ(back.type(), CV_16UC1);
  ASSERT_EQ(back.cols, w);
  ASSERT_EQ(back.rows, h);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) ASSERT_EQ(back.at<std::uint16_t>(v, u), depth[v * w + u]) << u << "," << v;
}

TEST(DepthPng, CompressesASmoothDepthImage) {
  const int w = 640, h = 480;
  std::vector<std::uint16_t> depth(static_cast<std::size_t>(w) * h);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) depth[v * w + u] = static_cast<std::uint16_t>(1500 + u / 4 + v / 8);
  std::vector<std::uint8_t> png;
  std::string why;
  ASSERT_TRUE(encode_depth_png(depth.data(), w, h, &png, &why)) << why;
  EXPECT_LT(png.size(), depth.size() * 2 / 4);  // under a quarter of the raw bytes
}

}  // namespace
}  // namespace fslam::client

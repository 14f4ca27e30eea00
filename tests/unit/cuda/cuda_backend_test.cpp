// GPU parity: the CUDA backend runs the same math as the CPU backend, so results must agree
// bit for bit up to float rounding. Skips where no GPU is usable.
#include "fslam/cuda/cuda_backend.hpp"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

namespace fslam::cuda {
namespace {

TEST(CudaBackend, UnprojectMatchesCpu) {
  std::string why;
  auto gpu = make_cuda_backend(0, &why);
  if (!gpu) {
    GTEST_SKIP() << "no usable GPU: " << why;
  }
  core::PinholeCamera cam{525.0, 525.0, 319.5, 239.5, 640, 480};
  cv::Mat depth(480, 640, CV_32FC1);
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> d(0.0f, 12.0f);
  for (int v = 0; v < depth.rows; ++v)
    for (int u = 0; u < depth.cols; ++u) depth.at<float>(v, u) = (u + v) % 17 ? d(rng) : 0.0f;
  std::vector<float> a, b;
  ASSERT_TRUE(core::make_cpu_backend()->unproject_depth(depth, cam, {}, &a, &why)) << why;
  ASSERT_TRUE(gpu->unproject_depth(depth, cam, {}, &b, &why)) << why;
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (std::isnan(a[i])) {
      EXPECT_TRUE(std::isnan(b[i])) << i;
    } else {
      EXPECT_NEAR(a[i], b[i], 1e-6f * std::max(1.0f, std::abs(a[i]))) << i;
    }
  }
}

TEST(CudaBackend, NoDeviceIsReportedNotFatal) {
  std::string why;
  const int n = usable_device_count(&why);
  if (n == 0) {
    EXPECT_FALSE(why.empty());
  }
  EXPECT_FALSE(make_cuda_backend(n + 3, &why));
  EXPECT_FALSE(why.empty());
}

// The rasteriser's own factory refuses a device that does not exist (its renders and gradients
// are checked with every other backend's in tests/unit/server/rasterizer_backends_test.cpp).
TEST(CudaBackend, RasterizerOnANonexistentDeviceIsAnError) {
  std::string why;
  EXPECT_FALSE(make_cuda_rasterizer(-1, &why));
  EXPECT_FALSE(why.empty());
  const int n = usable_device_count(&why);
  why.clear();
  EXPECT_FALSE(make_cuda_rasterizer(n + 3, &why));
  EXPECT_FALSE(why.empty());
}

}  // namespace
}  // namespace fslam::cuda

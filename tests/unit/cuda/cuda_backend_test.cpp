// The CUDA backend's device handling (its rasteriser's renders and gradients are checked with
// every other backend's in tests/unit/server/rasterizer_backends_test.cpp).
#include "fslam/cuda/cuda_backend.hpp"

#include <gtest/gtest.h>

namespace fslam::cuda {
namespace {

TEST(CudaBackend, NoDeviceIsReportedNotFatal) {
  std::string why;
  const int n = usable_device_count(&why);
  if (n == 0) {
    EXPECT_FALSE(why.empty());
  }
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

#include "launchers.hpp"

namespace fslam::cuda {
namespace {

// One thread per pixel, running the same math as the CPU backend (core/math/unproject.hpp).
__global__ void unproject_depth_kernel(core::math::Intrinsics k, const float* __restrict__ depth,
                                       int width, int n, float min_depth, float max_depth,
                                       float* __restrict__ points) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  core::math::unproject_depth_pixel(k, depth, width, i, min_depth, max_depth, points);
}

}  // namespace

cudaError_t unproject_depth_fwd(const core::math::Intrinsics& k, const float* depth, int width,
                                int height, float min_depth, float max_depth, float* points,
                                cudaStream_t stream) {
  const int n = width * height;
  if (n <= 0) return cudaSuccess;
  constexpr int kBlock = 256;
  unproject_depth_kernel<<<(n + kBlock - 1) / kBlock, kBlock, 0, stream>>>(
      k, depth, width, n, min_depth, max_depth, points);
  return cudaGetLastError();
}

}  // namespace fslam::cuda

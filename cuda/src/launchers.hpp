// Plain-data boundary between host code and kernels: no Eigen, no OpenCV here.
#pragma once

#include <cuda_runtime.h>

#include "fslam/core/math/unproject.hpp"

namespace fslam::cuda {

// depth: [height * width] float metres (device); points: [height * width * 3] float (device).
// Returns the launch status; zero pixels is a no-op.
cudaError_t unproject_depth_fwd(const core::math::Intrinsics& k, const float* depth, int width,
                                int height, float min_depth, float max_depth, float* points,
                                cudaStream_t stream);

}  // namespace fslam::cuda

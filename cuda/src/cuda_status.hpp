// A CUDA status as text for error messages.
#pragma once

#include <string>

#include <cuda_runtime.h>

namespace fslam::cuda {

// "cudaErrorX: description".
inline std::string describe(cudaError_t status) {
  return std::string(cudaGetErrorName(status)) + ": " + cudaGetErrorString(status);
}

}  // namespace fslam::cuda

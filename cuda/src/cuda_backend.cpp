#include "fslam/cuda/cuda_backend.hpp"

#include "cuda_status.hpp"

namespace fslam::cuda {

int usable_device_count(std::string* why) {
  int count = 0;
  const cudaError_t status = cudaGetDeviceCount(&count);
  if (status != cudaSuccess) {
    if (why) *why = describe(status);
    return 0;
  }
  if (count == 0 && why) *why = "no CUDA device found";
  return count;
}

}  // namespace fslam::cuda

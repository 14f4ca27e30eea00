// The CUDA implementation of core's ComputeBackend. Only server/'s backend factory includes this.
#pragma once

#include <memory>
#include <string>

#include "fslam/core/compute/backend.hpp"
#include "fslam/core/render/rasterizer.hpp"

namespace fslam::cuda {

// Number of usable CUDA devices; 0 with `why` set when there is none (no driver, no device).
int usable_device_count(std::string* why);

// A backend on `device`; nullptr with `why` when that device cannot be used.
std::unique_ptr<core::ComputeBackend> make_cuda_backend(int device, std::string* why);

// The CUDA rasteriser on `device` (forward only: backward() fails with the reason, mapping uses
// the CPU rasteriser); nullptr with `why` when that device cannot be used.
std::unique_ptr<core::Rasterizer> make_cuda_rasterizer(int device, std::string* why);

}  // namespace fslam::cuda

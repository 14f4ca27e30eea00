// The CUDA backend: its devices and its rasteriser. Only server/'s backend factory (and the CUDA
// tests and benchmark) include this.
#pragma once

#include <memory>
#include <string>

#include "fslam/core/render/rasterizer.hpp"

namespace fslam::cuda {

// Number of usable CUDA devices; 0 with `why` set when there is none (no driver, no device).
int usable_device_count(std::string* why);

// The CUDA rasteriser on `device` (forward only: backward() fails with the reason, mapping uses
// the CPU rasteriser); nullptr with `why` when that device cannot be used.
std::unique_ptr<core::Rasterizer> make_cuda_rasterizer(int device, std::string* why);

}  // namespace fslam::cuda

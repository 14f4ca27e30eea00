// The one place that chooses a compute backend (design.md: compute.backend: auto|cpu|cuda): the
// rasteriser, the one operation with a CPU and a CUDA implementation.
#pragma once

#include <memory>
#include <string>

#include "fslam/core/render/rasterizer.hpp"

namespace fslam::server {

// The CUDA backends this binary was built with: "cuda" or "" (CPU only).
bool cuda_compiled_in();

// What a rasteriser is for: kRender needs forward() only (render and segmentation queries,
// fslam render, segment-eval); kMapping needs backward() too (the mapper).
enum class RasterUse { kRender, kMapping };

// The rasteriser for `choice` (auto, cpu, cuda) and `use`. "cuda" requires a usable GPU (else a
// configuration error that says why). "auto" takes the GPU for kRender when one is usable (else
// the CPU, with a notice), and the CPU for kMapping: the CUDA backward pass is checked against the
// CPU's, but the mapper on it has not run end to end on a GPU yet, so mapping on it is opt-in.
std::unique_ptr<core::Rasterizer> make_rasterizer(const std::string& choice, RasterUse use, std::string* notice,
                                                  std::string* why);

}  // namespace fslam::server

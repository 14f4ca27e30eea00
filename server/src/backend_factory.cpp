#include "fslam/server/backend_factory.hpp"

#include "fslam/core/build_config.hpp"
#if FSLAM_HAVE_CUDA
#include "fslam/cuda/cuda_backend.hpp"
#endif

namespace fslam::server {

bool cuda_compiled_in() { return FSLAM_HAVE_CUDA != 0; }

std::unique_ptr<core::Rasterizer> make_rasterizer(const std::string& choice, RasterUse use, std::string* notice,
                                                  std::string* why) {
  if (choice != "auto" && choice != "cpu" && choice != "cuda") {
    if (why) *why = "compute.backend must be auto, cpu or cuda, got '" + choice + "'";
    return nullptr;
  }
  if (choice == "cpu") return core::make_cpu_rasterizer();
  if (use == RasterUse::kMapping && choice == "auto") {
    if (notice) *notice = "mapping rasteriser: CPU (CUDA mapping is opt-in: --backend cuda; docs/mapping.md)";
    return core::make_cpu_rasterizer();
  }
#if FSLAM_HAVE_CUDA
  std::string reason;
  if (auto rasterizer = cuda::make_cuda_rasterizer(0, &reason)) return rasterizer;
  if (choice == "cuda") {
    if (why) *why = "compute.backend is cuda but no GPU is usable (" + reason + ")";
    return nullptr;
  }
  if (notice) *notice = "rasteriser: no usable GPU (" + reason + "); using the CPU rasteriser";
#else
  if (choice == "cuda") {
    if (why) *why = "compute.backend is cuda but this build has no CUDA backend (configure with -DFSLAM_WITH_CUDA=ON)";
    return nullptr;
  }
  if (notice) *notice = "rasteriser: CUDA not compiled in; using the CPU rasteriser";
#endif
  return core::make_cpu_rasterizer();
}

}  // namespace fslam::server

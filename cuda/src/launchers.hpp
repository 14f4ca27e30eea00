// Plain-data boundary between host code and kernels: no Eigen, no OpenCV here. One launcher per
// pipeline stage and direction, each defined in the kernel file of its name (<stage>_fwd.cu /
// <stage>_bwd.cu, binning.cu), as the CPU rasteriser's stage headers in core/render.
#pragma once

#include <cstdint>

#include <cuda_runtime.h>

#include "fslam/core/math/splat_math.hpp"

#include "device_buffer.hpp"

namespace fslam::cuda {

// ---------------------------------------------------------------- rasteriser
constexpr int kRasterTile = 16;           // pixels per tile side, as the CPU rasteriser's kTileSize
constexpr int kMaxFeatureChannels = 64;   // D the compositing kernels hold per pixel

// project_fwd.cu. Projects every Gaussian of `scene` (device pointers; radius 0 = culled): its tile rectangle
// ([N, 4]), the number of tiles it touches and whether it is visible (1) at all.
cudaError_t project_fwd(const core::math::SplatScene<float>& scene, const core::math::SplatCamera<float>& cam,
                        int tile_size, int tiles_x, int tiles_y, core::math::ProjectedGaussian<float>* projected,
                        int* rect, std::uint32_t* touched, std::uint8_t* visible, cudaStream_t stream);

// Device memory of the binning, kept between renders.
struct BinBuffers {
  DeviceBuffer<std::uint32_t> offsets, ids, sorted_ids;
  DeviceBuffer<unsigned long long> keys, sorted_keys;
  DeviceBuffer<unsigned char> scratch;
  DeviceBuffer<uint2> ranges;  // [tiles] begin, end into sorted_ids
};

// binning.cu. Bins the projected Gaussians into per-tile lists sorted front to back by the depth of the mean,
// ties by id: the order of the CPU's render_impl::bin_to_tiles. On return buffers->ranges and
// buffers->sorted_ids hold the lists and *entries their total length. Synchronises `stream` once
// (to size the lists).
cudaError_t bin_fwd(int count, const core::math::ProjectedGaussian<float>* projected, const int* rect,
                    const std::uint32_t* touched, int tiles_x, int tiles_y, BinBuffers* buffers,
                    std::uint32_t* entries, cudaStream_t stream);

// composite_fwd.cu. Composites the depth-sorted tile lists into `out` (device planes, all set; features [D, H, W]);
// per pixel the list index where it ended (the list's length when it did not) and of its median
// splat (-1 none); counters[0] += pairs evaluated, counters[1] += blended.
cudaError_t composite_fwd(const core::math::ProjectedGaussian<float>* projected, const uint2* tile_ranges,
                          const std::uint32_t* tile_ids, const float* features, int feature_dim, int width,
                          int height, int tiles_x, int tiles_y, const float background[3],
                          const core::math::RasterOutputs<float>& out, std::int32_t* pixel_end,
                          std::int32_t* pixel_median, unsigned long long* counters, cudaStream_t stream);

// composite_bwd.cu. Backward of the compositing: adds each Gaussian's 2D gradient into accum [N, math::kGrad2dFixed + D]
// (zeroed by the caller), from the forward's outputs, per-pixel ends and medians.
cudaError_t composite_bwd(const core::math::ProjectedGaussian<float>* projected, const uint2* tile_ranges,
                          const std::uint32_t* tile_ids, const float* features, int feature_dim, int width,
                          int height, int tiles_x, int tiles_y, const float background[3],
                          const core::math::RasterOutputs<float>& out, const std::int32_t* pixel_end,
                          const std::int32_t* pixel_median, const core::math::RasterOutputGrads<float>& grads, float* accum,
                          cudaStream_t stream);

// project_bwd.cu. Backward of the projection: out [N, 11 + 3K + D + 2] per Gaussian (mean, rotation, log-scale,
// opacity logit, SH, features, importance rgb and feature), zero for culled ones.
cudaError_t project_bwd(const core::math::SplatScene<float>& scene, const core::math::SplatCamera<float>& cam,
                        const core::math::ProjectedGaussian<float>* projected, const float* accum, int feature_dim,
                        float* out, cudaStream_t stream);

}  // namespace fslam::cuda

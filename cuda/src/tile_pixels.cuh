// Device helpers the compositing kernels share (composite_fwd.cu, composite_bwd.cu): a block is
// one 16x16 tile, a thread one pixel, and the tile's depth-sorted list is read in batches
// through shared memory. Internal to cuda/src; host code never includes it.
#pragma once

#include <cstdint>

#include <cuda_runtime.h>

#include "fslam/core/math/splat_math.hpp"

namespace fslam::cuda::tile {

namespace math = core::math;

// Whether pixel (px, py) is a pair the CPU rasteriser evaluates: in the splat's row range and
// row span (its loops run over exactly those), so both passes see the same pairs.
__device__ inline bool in_footprint(const math::ProjectedGaussian<float>& g, int px, int py) {
  int y0, y1, x0, x1;
  math::splat_row_range(g, &y0, &y1);
  if (py < y0 || py >= y1) return false;
  return math::splat_row_span(g, static_cast<float>(py), &x0, &x1) && px >= x0 && px < x1;
}

// A compositing thread's pixel: one block per tile, one thread per pixel, and the tile's list.
struct TilePixel {
  int px, py, rank;
  bool inside;                // the pixel lies in the image (edge tiles overhang it)
  std::uint32_t begin, end;   // the tile's depth-sorted list in the sorted ids
};

template <int kTile>
__device__ TilePixel tile_pixel(const uint2* __restrict__ tile_ranges, int tiles_x, int width, int height) {
  TilePixel t;
  const int tile = blockIdx.x;
  t.px = (tile % tiles_x) * kTile + static_cast<int>(threadIdx.x);
  t.py = (tile / tiles_x) * kTile + static_cast<int>(threadIdx.y);
  t.rank = static_cast<int>(threadIdx.y) * kTile + static_cast<int>(threadIdx.x);
  t.inside = t.px < width && t.py < height;
  t.begin = tile_ranges[tile].x;
  t.end = tile_ranges[tile].y;
  return t;
}

// Loads the list entries [first, first + kBatch) into shared memory, one per thread, then waits
// for the block; returns how many were loaded.
template <int kBatch>
__device__ int load_batch(const TilePixel& t, std::uint32_t first, const std::uint32_t* __restrict__ tile_ids,
                          const math::ProjectedGaussian<float>* __restrict__ projected,
                          math::ProjectedGaussian<float>* batch, std::uint32_t* batch_ids) {
  const std::uint32_t mine = first + static_cast<std::uint32_t>(t.rank);
  if (mine < t.end) {
    batch_ids[t.rank] = tile_ids[mine];
    batch[t.rank] = projected[batch_ids[t.rank]];
  }
  __syncthreads();
  return static_cast<int>(min(static_cast<std::uint32_t>(kBatch), t.end - first));
}

}  // namespace fslam::cuda::tile

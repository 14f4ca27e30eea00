// The CPU rasteriser's tile layout and the state its stages share: what the forward pass keeps
// for the backward pass, and the gradient views the backward pass adds into. Internal to
// core/render and its tests; users go through fslam/core/render/rasterizer.hpp.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include "fslam/core/math/lanes.hpp"
#include "fslam/core/math/splat_math.hpp"

namespace fslam::core::render_impl {

constexpr int kTileSize = 16;                  // pixels per tile side
// The compositing loops run the shared per-pixel math on kLanes pixels of a tile row at once
// (simd::Lanes): a tile row is kChunksPerRow chunks, a tile kChunks.
constexpr int kLanes = 8;
constexpr int kChunksPerRow = kTileSize / kLanes;
constexpr int kChunks = kTileSize * kChunksPerRow;
constexpr int kTilePixels = kTileSize * kTileSize;
template <typename T>
using PixelLanes = simd::Lanes<T, kLanes>;

using math::kGrad2dFixed;
using math::RasterOutputGrads;
using math::RasterOutputs;
using math::SplatScene;

// Gradients w.r.t. the scene's parameters (same shapes), accumulated (+=) by the backward pass.
template <typename T>
struct SceneGrads {
  T* means = nullptr;
  T* rotations = nullptr;
  T* log_scales = nullptr;
  T* opacity_logits = nullptr;
  T* sh = nullptr;
  T* features = nullptr;
  T* importance_rgb = nullptr;      // [N] sum over pixels of |dL_rgb / dalpha_i(x)| (eq. importance)
  T* importance_feature = nullptr;  // [N] the same for the feature loss (eq. sem_importance)
};

// What the backward pass needs from the forward pass.
template <typename T>
struct RasterState {
  int width = 0, height = 0, tiles_x = 0, tiles_y = 0;
  std::vector<math::ProjectedGaussian<T>> projected;  // [N]
  std::vector<std::uint32_t> tile_offsets;            // [tiles + 1] into tile_ids
  std::vector<std::uint32_t> tile_ids;                // Gaussian ids, front to back per tile
  std::vector<std::int32_t> pixel_end;     // [H * W] exclusive end of the pixel's splats (tile list)
  std::vector<std::int32_t> pixel_median;  // [H * W] tile-list index of the median splat, -1 none
  std::size_t visible = 0;
  std::uint64_t evaluated_pairs = 0;  // splat-pixel pairs whose alpha was computed
  std::uint64_t blend_steps = 0;      // splat-pixel pairs composited (alpha >= 1/255)
  // Scratch kept with the state so that a reused state (CpuRasterizer pools them) allocates
  // nothing per call: [N, 4] tile rectangles of project_fwd; the backward pass's 2D gradient of
  // each tile-list entry ([tile_ids.size(), kGrad2dFixed + D]: math::pack_gradient_2d, then D
  // features) and the entries grouped by Gaussian ([N + 1] offsets into [tile_ids.size()]).
  std::vector<int> rect;
  mutable std::vector<T> entry_grads;
  mutable std::vector<std::uint32_t> entry_offsets, entry_order;
};

// One tile's pixel window in the image: [x0, x1) x [y0, y1), clipped at the image's edge.
struct TileWindow {
  int x0, y0, x1, y1;
};

inline TileWindow tile_window(int tile, int tiles_x, int width, int height) {
  const int x0 = (tile % tiles_x) * kTileSize, y0 = (tile / tiles_x) * kTileSize;
  return {x0, y0, std::min(width, x0 + kTileSize), std::min(height, y0 + kTileSize)};
}

}  // namespace fslam::core::render_impl

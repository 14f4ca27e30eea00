// Compositing, forward (paper eq. blending with the camera-plane depth D_i(x)): each tile's list
// front to back over its pixels, kLanes pixels of a row at once. The CUDA sibling is
// cuda/src/composite_fwd.cu (one thread per pixel over the same lists). Internal to core/render
// and its tests.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include "fslam/core/math/host_device.hpp"
#include "fslam/core/math/lanes.hpp"
#include "fslam/core/math/splat_math.hpp"
#include "fslam/core/render/raster_state.hpp"

namespace fslam::core::render_impl {

// Per-pixel compositing state of one tile in chunks of kLanes pixels of a row, advanced splat by
// splat (front to back) over the chunks each splat's footprint covers: every pixel still sees
// its splats in depth order. One per worker, reused across its tiles.
template <typename T>
struct ForwardTile {
  using L = PixelLanes<T>;
  using M = typename L::Mask;
  explicit ForwardTile(int channels)
      : C(channels), trans(kChunks), acc(static_cast<std::size_t>(kChunks) * channels), done(kChunks),
        has_median(kChunks), median(kTilePixels), end_index(kTilePixels), median_index(kTilePixels) {}
  int C;                       // composited channels: colour 3, depth, features D
  TileWindow win{};
  std::vector<L> trans, acc;   // [kChunks], [kChunks, C]
  std::vector<M> done, has_median;
  std::vector<T> median;       // [kTilePixels]
  std::vector<std::int32_t> end_index, median_index;
  int active = 0;              // pixels of the tile still compositing
  std::uint64_t evaluated = 0, blended = 0;
};

// Resets the tile's state for a list of `count` splats: pixels outside the image are done from
// the start.
template <typename T>
FSLAM_HD_INLINE void begin_forward_tile(const TileWindow& win, std::uint32_t count, ForwardTile<T>* tile) {
  using L = PixelLanes<T>;
  using M = typename L::Mask;
  ForwardTile<T>& s = *tile;
  s.win = win;
  std::fill(s.trans.begin(), s.trans.end(), L(T(1)));
  std::fill(s.acc.begin(), s.acc.end(), L(T(0)));
  std::fill(s.median.begin(), s.median.end(), T(0));
  std::fill(s.end_index.begin(), s.end_index.end(), static_cast<std::int32_t>(count));
  std::fill(s.median_index.begin(), s.median_index.end(), -1);
  const L lane = L::iota(T(0));
  for (int k = 0; k < kChunks; ++k) {
    const int row = win.y0 + k / kChunksPerRow;
    const L px = lane + T(win.x0 + (k % kChunksPerRow) * kLanes);
    s.done[k] = row < win.y1 ? px >= L(T(win.x1)) : (lane >= L(T(0)));
    s.has_median[k] = M::none();
  }
  s.active = (win.x1 - win.x0) * (win.y1 - win.y0);
}

// One chunk's step of splat g, the j-th of the tile's list (f: its D features): alpha, the end
// of pixels whose transmittance falls below kTransmittanceMin, the blend and the median.
template <typename T>
FSLAM_HD_INLINE void composite_chunk_forward(const math::ProjectedGaussian<T>& g, const T* f, int D, std::uint32_t j, int k,
                             int first, const PixelLanes<T>& px, const PixelLanes<T>& lpy,
                             const typename PixelLanes<T>::Mask& live, ForwardTile<T>* tile) {
  using L = PixelLanes<T>;
  using M = typename L::Mask;
  ForwardTile<T>& s = *tile;
  s.evaluated += simd::count(live);
  L gauss;
  const L alpha = select(live, math::splat_alpha(g, px, lpy, &gauss), L(T(0)));
  const M hit = alpha > L(T(0));
  if (!simd::any(hit)) return;
  const L Tr = s.trans[k];
  const L next = Tr * (T(1) - alpha);
  const M stop = hit & (next < L(T(math::kTransmittanceMin)));
  if (simd::any(stop)) {
    s.done[k] |= stop;
    for (unsigned b = simd::bits(stop); b != 0; b &= b - 1) {
      s.end_index[first + __builtin_ctz(b)] = static_cast<std::int32_t>(j);
      --s.active;
    }
  }
  const M blend = hit & ~stop;
  if (!simd::any(blend)) return;
  s.blended += simd::count(blend);
  const L w = select(blend, alpha * Tr, L(T(0)));
  const L d = math::splat_planar_depth(g, px, lpy);
  L* a = s.acc.data() + static_cast<std::size_t>(k) * s.C;
  a[0] += w * g.colour[0];
  a[1] += w * g.colour[1];
  a[2] += w * g.colour[2];
  a[3] += w * d;
  for (int c = 0; c < D; ++c) a[4 + c] += w * f[c];
  const M med = blend & ~s.has_median[k] & (next < L(T(0.5)));
  if (simd::any(med)) {
    s.has_median[k] |= med;
    for (unsigned b = simd::bits(med); b != 0; b &= b - 1) {
      const int i = __builtin_ctz(b);
      s.median_index[first + i] = static_cast<std::int32_t>(j);
      s.median[first + i] = d[i];
    }
  }
  s.trans[k] = select(blend, next, Tr);
}

// Splat g (the j-th of the tile's list) over the tile's pixels it covers: its row range, each
// row's span (math::splat_row_range, splat_row_span), the chunks the span touches.
template <typename T>
FSLAM_HD_INLINE void composite_splat_forward(const math::ProjectedGaussian<T>& g, const T* f, int D, std::uint32_t j,
                             ForwardTile<T>* tile) {
  using L = PixelLanes<T>;
  using M = typename L::Mask;
  const TileWindow& win = tile->win;
  const L lane = L::iota(T(0));
  int gy0, gy1;
  math::splat_row_range(g, &gy0, &gy1);
  gy0 = std::max(win.y0, gy0);
  gy1 = std::min(win.y1, gy1);
  for (int py = gy0; py < gy1; ++py) {
    int sx0, sx1;
    if (!math::splat_row_span(g, T(py), &sx0, &sx1)) continue;
    sx0 = std::max(sx0, win.x0);
    sx1 = std::min(sx1, win.x1);
    if (sx0 >= sx1) continue;
    const int ly = py - win.y0;
    const L lpy = L(T(py));
    for (int kc = (sx0 - win.x0) / kLanes; kc <= (sx1 - 1 - win.x0) / kLanes; ++kc) {
      const int k = ly * kChunksPerRow + kc;
      const int first = ly * kTileSize + kc * kLanes;  // tile pixel of lane 0
      const L px = lane + T(win.x0 + kc * kLanes);
      const M live = (px >= L(T(sx0))) & (px < L(T(sx1))) & ~tile->done[k];
      if (!simd::any(live)) continue;
      composite_chunk_forward(g, f, D, j, k, first, px, lpy, live, tile);
    }
  }
}

// Writes the tile's pixels: colour over the background, depth, alpha, median depth, features,
// and each pixel's list end and median index for the backward pass.
template <typename T>
FSLAM_HD_INLINE void write_forward_tile(const ForwardTile<T>& s, int W, std::size_t plane, int D, const T background[3],
                        RasterState<T>* state, const RasterOutputs<T>& out) {
  using L = PixelLanes<T>;
  RasterState<T>& st = *state;
  const TileWindow& win = s.win;
  for (int py = win.y0; py < win.y1; ++py) {
    for (int px = win.x0; px < win.x1; ++px) {
      const int lp = (py - win.y0) * kTileSize + (px - win.x0);
      const int k = lp / kLanes, i = lp % kLanes;
      const std::size_t pix = static_cast<std::size_t>(py) * W + px;
      const L* a = s.acc.data() + static_cast<std::size_t>(k) * s.C;
      const T tr = s.trans[k][i];
      st.pixel_end[pix] = s.end_index[lp];
      st.pixel_median[pix] = s.median_index[lp];
      for (int c = 0; c < 3; ++c) out.colour[c * plane + pix] = a[c][i] + tr * background[c];
      out.depth[pix] = a[3][i];
      out.alpha[pix] = T(1) - tr;
      if (out.median_depth != nullptr) out.median_depth[pix] = s.median[lp];
      if (out.features != nullptr)
        for (int c = 0; c < D; ++c) out.features[c * plane + pix] = a[4 + c][i];
    }
  }
}

// Composites every tile of the binned state (project_fwd, bin_to_tiles) into `out`, D feature
// channels (0: none), and records the pairs evaluated and blended.
template <typename T>
void composite_fwd(const SplatScene<T>& scene, int D, const T background[3], RasterState<T>* state,
                   const RasterOutputs<T>& out) {
  RasterState<T>& st = *state;
  const int W = st.width, H = st.height;
  const std::size_t plane = static_cast<std::size_t>(W) * H;
  st.pixel_end.assign(plane, 0);
  st.pixel_median.assign(plane, -1);
  const int tiles = st.tiles_x * st.tiles_y;
  tbb::enumerable_thread_specific<std::uint64_t> evaluated(0), blended(0);
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles), [&](const auto& r) {
    ForwardTile<T> tile(4 + D);
    for (int t = r.begin(); t != r.end(); ++t) {
      const std::uint32_t begin = st.tile_offsets[t], count = st.tile_offsets[t + 1] - begin;
      begin_forward_tile(tile_window(t, st.tiles_x, W, H), count, &tile);
      for (std::uint32_t j = 0; j < count && tile.active > 0; ++j) {
        const std::uint32_t id = st.tile_ids[begin + j];
        const T* f = D > 0 ? scene.features + static_cast<std::size_t>(id) * scene.feature_dim : nullptr;
        composite_splat_forward(st.projected[id], f, D, j, &tile);
      }
      write_forward_tile(tile, W, plane, D, background, state, out);
    }
    evaluated.local() += tile.evaluated;
    blended.local() += tile.blended;
  });
  st.evaluated_pairs = 0;
  st.blend_steps = 0;
  for (std::uint64_t s : evaluated) st.evaluated_pairs += s;
  for (std::uint64_t s : blended) st.blend_steps += s;
}

}  // namespace fslam::core::render_impl

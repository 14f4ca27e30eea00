// Compositing, backward (paper: per-splat backward parallelization). Each tile is processed
// splat by splat (outer loop) over its pixels (inner loop, kLanes pixels of a row at once),
// rolling each pixel's transmittance and prefix sums forward: the state at the start of every
// block of P splats is the checkpoint T*_{kP} of eq. transmittance_ckpt, and T_i is recovered
// from it as in eq. transmittance_recover. Each splat's gradient over a tile goes to its own row
// of the tile list (no atomics, no locks), and project_bwd sums a Gaussian's rows in tile order:
// the sum's order does not depend on which thread ran which tile, so the gradients are the same
// bit for bit on every run and at any thread count. The CUDA sibling is cuda/src/composite_bwd.cu.
// Internal to core/render and its tests.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "fslam/core/math/host_device.hpp"
#include "fslam/core/math/lanes.hpp"
#include "fslam/core/math/splat_math.hpp"
#include "fslam/core/render/raster_state.hpp"

namespace fslam::core::render_impl {

// What the backward pass reads of the forward pass and the loss, per rendered pixel.
template <typename T>
struct CompositeBwdInputs {
  const T* background;           // [3]
  RasterOutputs<T> out;          // the forward's outputs
  RasterOutputGrads<T> grad_out; // dL/d(outputs); null planes are zero
  int W, H, D;                   // image size, rendered feature channels
  bool feature_grads;            // grad_out.features given and D > 0
};

// One tile's per-pixel state in chunks of kLanes pixels of a row, reused across a worker's tiles.
template <typename T>
struct BackwardTile {
  using L = PixelLanes<T>;
  BackwardTile(int channels_, int grad_channels_, int D)
      : channels(channels_), grad_channels(grad_channels_), trans(kChunks),
        prefix(static_cast<std::size_t>(kChunks) * channels_), total(static_cast<std::size_t>(kChunks) * channels_),
        pixel_grads(static_cast<std::size_t>(kChunks) * grad_channels_), g_background(kChunks),
        g_alpha_out(kChunks), g_median(kChunks), pixel_end(kChunks), pixel_median(kChunks),
        feature_grad(static_cast<std::size_t>(D)) {}
  int channels;       // colour 3, depth 1, features D: the prefix sums per pixel
  int grad_channels;  // the output gradients the inner loop reads: colour 3, depth, then D features
  int x0 = 0, y0 = 0, tw = 0, th = 0;  // the tile's first pixel and its size inside the image
  std::vector<L> trans, prefix, total, pixel_grads;
  std::vector<L> g_background, g_alpha_out, g_median;
  // Per chunk, as lanes of T: the exclusive end of each pixel's splats in the tile list and
  // the list index of its median splat (-1: none), exact in T for any tile list.
  std::vector<L> pixel_end, pixel_median;
  std::vector<L> feature_grad;  // one splat's dL/df, per lane
};

// Loads one pixel's T_final, final composited values without the background, and output
// gradients into its lane; returns the pixel's list end.
template <typename T>
FSLAM_HD_INLINE int load_backward_pixel(const CompositeBwdInputs<T>& in, const RasterState<T>& st, int lx, int ly,
                        BackwardTile<T>* tile) {
  using L = PixelLanes<T>;
  BackwardTile<T>& s = *tile;
  const std::size_t plane = static_cast<std::size_t>(in.W) * in.H;
  const RasterOutputs<T>& out = in.out;
  const RasterOutputGrads<T>& grad_out = in.grad_out;
  const T* background = in.background;
  const int D = in.D;
  const int lp = ly * kTileSize + lx;
  const int k = lp / kLanes, i = lp % kLanes;
  const std::size_t pix = static_cast<std::size_t>(s.y0 + ly) * in.W + s.x0 + lx;
  const T t_final = T(1) - out.alpha[pix];
  L* tot = s.total.data() + static_cast<std::size_t>(k) * s.channels;
  for (int c = 0; c < 3; ++c) tot[c].v[i] = out.colour[c * plane + pix] - t_final * background[c];
  tot[3].v[i] = out.depth[pix];
  for (int c = 0; c < D; ++c) tot[4 + c].v[i] = out.features[c * plane + pix];
  L* gp = s.pixel_grads.data() + static_cast<std::size_t>(k) * s.grad_channels;
  T gc[3];
  for (int c = 0; c < 3; ++c) gp[c].v[i] = gc[c] = grad_out.colour ? grad_out.colour[c * plane + pix] : T(0);
  gp[3].v[i] = grad_out.depth ? grad_out.depth[pix] : T(0);
  if (in.feature_grads)
    for (int c = 0; c < D; ++c) gp[4 + c].v[i] = grad_out.features[c * plane + pix];
  // The parts of dL/dalpha_i that do not depend on splat i, times (1 - alpha_i): the
  // background seen through the pixel (a colour term) and the accumulated opacity.
  T gb = T(0);
  for (int c = 0; c < 3; ++c) gb -= gc[c] * background[c] * t_final;
  s.g_background[k].v[i] = gb;
  s.g_alpha_out[k].v[i] = grad_out.alpha != nullptr ? grad_out.alpha[pix] * t_final : T(0);
  const int median = grad_out.median_depth != nullptr ? st.pixel_median[pix] : -1;
  s.g_median[k].v[i] = median >= 0 ? grad_out.median_depth[pix] : T(0);
  s.pixel_end[k].v[i] = T(st.pixel_end[pix]);
  s.pixel_median[k].v[i] = T(median);
  return st.pixel_end[pix];
}

// Resets the tile's state and loads its pixels (those outside the image end before the first
// splat); returns the largest list end of its pixels.
template <typename T>
FSLAM_HD_INLINE int begin_backward_tile(const CompositeBwdInputs<T>& in, const RasterState<T>& st, int t, BackwardTile<T>* tile) {
  using L = PixelLanes<T>;
  BackwardTile<T>& s = *tile;
  const TileWindow win = tile_window(t, st.tiles_x, in.W, in.H);
  s.x0 = win.x0;
  s.y0 = win.y0;
  s.tw = win.x1 - win.x0;
  s.th = win.y1 - win.y0;
  std::fill(s.trans.begin(), s.trans.end(), L(T(1)));
  std::fill(s.prefix.begin(), s.prefix.end(), L(T(0)));
  std::fill(s.total.begin(), s.total.end(), L(T(0)));
  std::fill(s.pixel_grads.begin(), s.pixel_grads.end(), L(T(0)));
  std::fill(s.g_background.begin(), s.g_background.end(), L(T(0)));
  std::fill(s.g_alpha_out.begin(), s.g_alpha_out.end(), L(T(0)));
  std::fill(s.g_median.begin(), s.g_median.end(), L(T(0)));
  std::fill(s.pixel_end.begin(), s.pixel_end.end(), L(T(0)));
  std::fill(s.pixel_median.begin(), s.pixel_median.end(), L(T(-1)));
  int max_end = 0;
  for (int ly = 0; ly < s.th; ++ly)
    for (int lx = 0; lx < s.tw; ++lx) max_end = std::max(max_end, load_backward_pixel(in, st, lx, ly, tile));
  return max_end;
}

// Splat g, the j-th of the tile's list (f: its features), over the pixels it covers that have
// not ended before it: each pair through math::splat_pair_backward, its 2D gradient summed per
// lane into pg, imp_rgb, imp_feat and tile->feature_grad. Returns whether any pair had alpha > 0.
template <typename T>
FSLAM_HD_INLINE bool splat_backward_over_tile(const CompositeBwdInputs<T>& in, const math::ProjectedGaussian<T>& g, const T* f,
                              int j, BackwardTile<T>* tile, math::ProjectedGradient<PixelLanes<T>>* pg,
                              PixelLanes<T>* imp_rgb, PixelLanes<T>* imp_feat) {
  using L = PixelLanes<T>;
  using M = typename L::Mask;
  BackwardTile<T>& s = *tile;
  const L lane = L::iota(T(0));
  const L lj = L(T(j));
  bool touched = false;
  int ry0, ry1;
  math::splat_row_range(g, &ry0, &ry1);
  const int gy0 = std::max(0, ry0 - s.y0);
  const int gy1 = std::min(s.th, ry1 - s.y0);
  for (int ly = gy0; ly < gy1; ++ly) {
    int sx0, sx1;
    if (!math::splat_row_span(g, T(s.y0 + ly), &sx0, &sx1)) continue;
    sx0 = std::max(sx0 - s.x0, 0);
    sx1 = std::min(sx1 - s.x0, s.tw);
    if (sx0 >= sx1) continue;
    const L py = L(T(s.y0 + ly));
    for (int kc = sx0 / kLanes; kc <= (sx1 - 1) / kLanes; ++kc) {
      const int k = ly * kChunksPerRow + kc;
      const L lx = lane + T(kc * kLanes);
      const M live = (lx >= L(T(sx0))) & (lx < L(T(sx1))) & (lj < s.pixel_end[k]);
      if (!simd::any(live)) continue;
      const L px = lx + T(s.x0);
      L gauss;
      const L alpha = select(live, math::splat_alpha(g, px, py, &gauss), L(T(0)));
      if (!simd::any(alpha > L(T(0)))) continue;
      gauss = select(live, gauss, L(T(0)));
      touched = true;
      const L gm = select(live & (s.pixel_median[k] == lj), s.g_median[k], L(T(0)));
      math::splat_pair_backward(g, f, in.D, in.feature_grads, px, py, alpha, gauss,
                                s.total.data() + static_cast<std::size_t>(k) * s.channels,
                                s.pixel_grads.data() + static_cast<std::size_t>(k) * s.grad_channels,
                                s.g_background[k], s.g_alpha_out[k], gm, &s.trans[k],
                                s.prefix.data() + static_cast<std::size_t>(k) * s.channels, pg,
                                s.feature_grad.data(), imp_rgb, imp_feat);
    }
  }
  return touched;
}

// Writes one splat's lane sums over a tile to its tile-list row `a` ([kGrad2dFixed + D]).
template <typename T>
FSLAM_HD_INLINE void write_splat_gradient(const math::ProjectedGradient<PixelLanes<T>>& pg, const PixelLanes<T>& imp_rgb,
                        const PixelLanes<T>& imp_feat, const std::vector<PixelLanes<T>>& feature_grad, int D,
                        T* a) {
  math::ProjectedGradient<T> sum_pg;
  sum_pg.u = simd::sum(pg.u);
  sum_pg.v = simd::sum(pg.v);
  for (int k = 0; k < 3; ++k) sum_pg.conic[k] = simd::sum(pg.conic[k]);
  sum_pg.opacity = simd::sum(pg.opacity);
  sum_pg.depth = simd::sum(pg.depth);
  for (int k = 0; k < 2; ++k) sum_pg.plane[k] = simd::sum(pg.plane[k]);
  for (int k = 0; k < 3; ++k) sum_pg.colour[k] = simd::sum(pg.colour[k]);
  T packed[kGrad2dFixed];
  math::pack_gradient_2d(sum_pg, simd::sum(imp_rgb), simd::sum(imp_feat), packed);
  for (int k = 0; k < kGrad2dFixed; ++k) a[k] = packed[k];
  for (int c = 0; c < D; ++c) a[kGrad2dFixed + c] = simd::sum(feature_grad[c]);
}

// Backward of composite_fwd: each splat's 2D gradient over each of its tiles into
// st.entry_grads ([tile_ids.size(), kGrad2dFixed + D], one row per tile-list entry, every row
// written here; zero where the splat adds nothing); project_bwd sums them per Gaussian.
template <typename T>
void composite_bwd(const SplatScene<T>& scene, const CompositeBwdInputs<T>& in, const RasterState<T>& st) {
  using L = PixelLanes<T>;
  const int D = in.D;
  const std::size_t stride = static_cast<std::size_t>(kGrad2dFixed + D);
  const int channels = 4 + D;
  const int grad_channels = 4 + (in.feature_grads ? D : 0);
  st.entry_grads.resize(st.tile_ids.size() * stride);
  const int tiles = st.tiles_x * st.tiles_y;
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles), [&](const auto& r) {
    BackwardTile<T> tile(channels, grad_channels, D);
    for (int t = r.begin(); t != r.end(); ++t) {
      const std::uint32_t begin = st.tile_offsets[t], end = st.tile_offsets[t + 1];
      if (begin == end) continue;
      T* rows = st.entry_grads.data() + begin * stride;
      const int max_end = begin_backward_tile(in, st, t, &tile);
      for (int j = 0; j < max_end; ++j) {
        T* row = rows + static_cast<std::size_t>(j) * stride;
        const std::uint32_t id = st.tile_ids[begin + j];
        const T* f = D > 0 ? scene.features + static_cast<std::size_t>(id) * scene.feature_dim : nullptr;
        math::ProjectedGradient<L> pg{};
        L imp_rgb(T(0)), imp_feat(T(0));
        std::fill(tile.feature_grad.begin(), tile.feature_grad.end(), L(T(0)));
        if (!splat_backward_over_tile(in, st.projected[id], f, j, &tile, &pg, &imp_rgb, &imp_feat)) {
          std::fill(row, row + stride, T(0));
          continue;
        }
        write_splat_gradient(pg, imp_rgb, imp_feat, tile.feature_grad, D, row);
      }
      // Splats behind every pixel's end add nothing.
      std::fill(rows + static_cast<std::size_t>(max_end) * stride, rows + (end - begin) * stride, T(0));
    }
  });
}

}  // namespace fslam::core::render_impl

// The CPU rasteriser's algorithm, templated on the scalar so that tests run it in double as the
// finite-difference reference: project -> bin to 16x16 tiles -> depth sort -> composite
// (paper eq. blending, proj), and the per-splat backward (paper: per-splat backward
// parallelization, eq. transmittance_ckpt / transmittance_recover).
// Internal to core/render and its tests; users go through fslam/core/render/rasterizer.hpp.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include "fslam/core/error.hpp"
#include "fslam/core/math/lanes.hpp"
#include "fslam/core/math/splat_math.hpp"
#include "fslam/core/render/rasterizer.hpp"

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
  // nothing per call: [N, 4] tile rectangles of project_and_bin, and the backward pass's
  // per-thread [N, kGrad2dFixed + D] gradient buffers.
  std::vector<int> rect;
  mutable tbb::enumerable_thread_specific<std::vector<T>> thread_grads;
};

// The float views of a GaussianMap and a RenderView that the CPU backend and the benchmark use.
inline SplatScene<float> splat_scene(const GaussianMap& map) {
  return math::splat_scene_of<float>(map, map.size(), map.sh_degree, map.feature_dim, !map.filter_3d.empty());
}

inline math::SplatCamera<float> splat_camera(const RenderView& view, float near_plane) {
  math::SplatCamera<float> cam{};
  const Eigen::Matrix3d R = view.T_camera_world.rotation();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cam.R[3 * r + c] = static_cast<float>(R(r, c));
    cam.t[r] = static_cast<float>(view.T_camera_world.translation()[r]);
  }
  cam.fx = static_cast<float>(view.camera.fx);
  cam.fy = static_cast<float>(view.camera.fy);
  cam.cx = static_cast<float>(view.camera.cx);
  cam.cy = static_cast<float>(view.camera.cy);
  cam.near_plane = near_plane;
  cam.width = view.camera.width;
  cam.height = view.camera.height;
  return cam;
}

// The renderer's camera for a view, or false with `why` when the view or settings are invalid.
inline bool render_camera(const RenderView& view, const RenderSettings& settings,
               math::SplatCamera<float>* cam, std::string* why) {
  std::string reason;
  if (!view.camera.is_valid(&reason)) return fail(why, "render view: " + reason);
  if (!view.T_camera_world.matrix().allFinite()) return fail(why, "render view: non-finite pose");
  if (!(settings.near_plane > 0.0f)) return fail(why, "render settings: near plane must be > 0");
  *cam = splat_camera(view, settings.near_plane);
  return true;
}

// The checks every rasteriser's backward() makes: a valid view, a forward state, output
// gradients (empty = zero) shaped like the outputs. Sets the camera and the rendered feature
// channels D.
inline bool check_backward_inputs(const GaussianMap& map, const RenderView& view, const RenderSettings& settings,
                                  const RenderResult& result, const RenderGradients& output_grads,
                                  math::SplatCamera<float>* cam, int* D, std::string* why) {
  if (!render_camera(view, settings, cam, why)) return false;
  if (!result.backward_state) return fail(why, "backward: no forward state");
  *D = settings.features ? map.feature_dim : 0;
  const auto check = [&](const PlanarImage& g, const PlanarImage& like, const char* name) {
    if (g.empty() || g.same_shape(like)) return true;
    return fail(why, std::string("backward: gradient of ") + name + " has the wrong shape");
  };
  return check(output_grads.colour, result.colour, "colour") && check(output_grads.depth, result.depth, "depth") &&
         check(output_grads.median_depth, result.median_depth, "median depth") &&
         check(output_grads.alpha, result.alpha, "alpha") &&
         (*D == 0 || check(output_grads.features, result.features, "features"));
}

// Bins the projected Gaussians (st.projected, radius 0 = culled) into depth-sorted tile lists
// given each one's tile rectangle (rect: [N, 4], splat_tile_rect). The CUDA rasteriser's bin_fwd
// keeps this order (depth of the mean, ties by id) so that both composite the same lists.
template <typename T>
void bin_to_tiles(const std::vector<int>& rect, RasterState<T>* state) {
  RasterState<T>& st = *state;
  const std::size_t n = st.projected.size();
  const int tiles = st.tiles_x * st.tiles_y;
  st.tile_offsets.assign(tiles + 1, 0);
  st.visible = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (st.projected[i].radius == 0) continue;
    ++st.visible;
    for (int ty = rect[4 * i + 1]; ty < rect[4 * i + 3]; ++ty)
      for (int tx = rect[4 * i]; tx < rect[4 * i + 2]; ++tx) ++st.tile_offsets[ty * st.tiles_x + tx + 1];
  }
  for (int t = 0; t < tiles; ++t) st.tile_offsets[t + 1] += st.tile_offsets[t];
  st.tile_ids.resize(st.tile_offsets[tiles]);
  std::vector<std::uint32_t> cursor(st.tile_offsets.begin(), st.tile_offsets.end() - 1);
  for (std::size_t i = 0; i < n; ++i) {
    if (st.projected[i].radius == 0) continue;
    for (int ty = rect[4 * i + 1]; ty < rect[4 * i + 3]; ++ty)
      for (int tx = rect[4 * i]; tx < rect[4 * i + 2]; ++tx)
        st.tile_ids[cursor[ty * st.tiles_x + tx]++] = static_cast<std::uint32_t>(i);
  }
  // Front to back by the depth of the mean; ties by id so that the order is deterministic.
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles), [&](const auto& r) {
    for (int t = r.begin(); t != r.end(); ++t) {
      std::sort(st.tile_ids.begin() + st.tile_offsets[t], st.tile_ids.begin() + st.tile_offsets[t + 1],
                [&](std::uint32_t a, std::uint32_t b) {
                  const T da = st.projected[a].depth, db = st.projected[b].depth;
                  return da < db || (da == db && a < b);
                });
    }
  });
}

// Projects every Gaussian and bins them into depth-sorted tile lists.
template <typename T>
void project_and_bin(const SplatScene<T>& scene, const math::SplatCamera<T>& cam,
                     RasterState<T>* state) {
  RasterState<T>& st = *state;
  st.width = cam.width;
  st.height = cam.height;
  st.tiles_x = (cam.width + kTileSize - 1) / kTileSize;
  st.tiles_y = (cam.height + kTileSize - 1) / kTileSize;
  const std::size_t n = scene.count;
  st.projected.assign(n, math::ProjectedGaussian<T>{});
  std::vector<int>& rect = st.rect;  // [N, 4] tile x0, y0, x1, y1 (exclusive)
  rect.assign(4 * n, 0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n), [&](const auto& r) {
    for (std::size_t i = r.begin(); i != r.end(); ++i) {
      math::ProjectionTerms<T> terms;
      math::ProjectedGaussian<T>& pg = st.projected[i];
      if (!math::project_gaussian(scene.means + 3 * i, scene.rotations + 4 * i,
                                  scene.log_scales + 3 * i, scene.opacity_logits[i],
                                  scene.filter(i), scene.sh + i * scene.sh_stride(),
                                  scene.sh_degree, cam, &pg, &terms)) {
        pg.radius = 0;
        continue;
      }
      math::splat_tile_rect(pg, kTileSize, st.tiles_x, st.tiles_y, &rect[4 * i]);
    }
  });
  bin_to_tiles(rect, state);
}

// Forward pass (eq. blending with the camera-plane depth D_i(x)).
template <typename T>
void rasterize_forward(const SplatScene<T>& scene, const math::SplatCamera<T>& cam,
                       const T background[3], bool render_features, RasterState<T>* state,
                       const RasterOutputs<T>& out) {
  using L = PixelLanes<T>;
  using M = typename L::Mask;
  project_and_bin(scene, cam, state);
  RasterState<T>& st = *state;
  const int W = cam.width, H = cam.height, D = render_features ? scene.feature_dim : 0;
  const int C = 4 + D;  // composited channels: colour 3, depth, features D
  const std::size_t plane = static_cast<std::size_t>(W) * H;
  st.pixel_end.assign(plane, 0);
  st.pixel_median.assign(plane, -1);
  const int tiles = st.tiles_x * st.tiles_y;
  tbb::enumerable_thread_specific<std::uint64_t> evaluated(0), blended(0);
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles), [&](const auto& r) {
    // Per-pixel compositing state of one tile in chunks of kLanes pixels of a row, advanced
    // splat by splat (front to back) over the chunks each splat's footprint covers: every pixel
    // still sees its splats in depth order.
    std::vector<L> trans(kChunks), acc(static_cast<std::size_t>(kChunks) * C);
    std::vector<M> done(kChunks), has_median(kChunks);
    std::vector<T> median(kTilePixels);
    std::vector<std::int32_t> end_index(kTilePixels), median_index(kTilePixels);
    const L lane = L::iota(T(0));
    std::uint64_t& eval_count = evaluated.local();
    std::uint64_t& blend_count = blended.local();
    for (int t = r.begin(); t != r.end(); ++t) {
      const int tx = t % st.tiles_x, ty = t / st.tiles_x;
      const int x0 = tx * kTileSize, y0 = ty * kTileSize;
      const int x1 = std::min(W, x0 + kTileSize), y1 = std::min(H, y0 + kTileSize);
      const std::uint32_t begin = st.tile_offsets[t], count = st.tile_offsets[t + 1] - begin;
      std::fill(trans.begin(), trans.end(), L(T(1)));
      std::fill(acc.begin(), acc.end(), L(T(0)));
      std::fill(median.begin(), median.end(), T(0));
      std::fill(end_index.begin(), end_index.end(), static_cast<std::int32_t>(count));
      std::fill(median_index.begin(), median_index.end(), -1);
      for (int k = 0; k < kChunks; ++k) {
        // Pixels outside the image are done from the start.
        const int row = y0 + k / kChunksPerRow;
        const L px = lane + T(x0 + (k % kChunksPerRow) * kLanes);
        done[k] = row < y1 ? px >= L(T(x1)) : (lane >= L(T(0)));
        has_median[k] = M::none();
      }
      int active = (x1 - x0) * (y1 - y0);
      for (std::uint32_t j = 0; j < count && active > 0; ++j) {
        const std::uint32_t id = st.tile_ids[begin + j];
        const math::ProjectedGaussian<T>& g = st.projected[id];
        const T* f = D > 0 ? scene.features + static_cast<std::size_t>(id) * scene.feature_dim : nullptr;
        int gy0, gy1;
        math::splat_row_range(g, &gy0, &gy1);
        gy0 = std::max(y0, gy0);
        gy1 = std::min(y1, gy1);
        for (int py = gy0; py < gy1; ++py) {
          int sx0, sx1;
          if (!math::splat_row_span(g, T(py), &sx0, &sx1)) continue;
          sx0 = std::max(sx0, x0);
          sx1 = std::min(sx1, x1);
          if (sx0 >= sx1) continue;
          const int ly = py - y0;
          const L lpy = L(T(py));
          for (int kc = (sx0 - x0) / kLanes; kc <= (sx1 - 1 - x0) / kLanes; ++kc) {
            const int k = ly * kChunksPerRow + kc;
            const int first = ly * kTileSize + kc * kLanes;  // tile pixel of lane 0
            const L px = lane + T(x0 + kc * kLanes);
            const M live = (px >= L(T(sx0))) & (px < L(T(sx1))) & ~done[k];
            if (!simd::any(live)) continue;
            eval_count += simd::count(live);
            L gauss;
            const L alpha = select(live, math::splat_alpha(g, px, lpy, &gauss), L(T(0)));
            const M hit = alpha > L(T(0));
            if (!simd::any(hit)) continue;
            const L Tr = trans[k];
            const L next = Tr * (T(1) - alpha);
            const M stop = hit & (next < L(T(math::kTransmittanceMin)));
            if (simd::any(stop)) {
              done[k] |= stop;
              for (unsigned b = simd::bits(stop); b != 0; b &= b - 1) {
                end_index[first + __builtin_ctz(b)] = static_cast<std::int32_t>(j);
                --active;
              }
            }
            const M blend = hit & ~stop;
            if (!simd::any(blend)) continue;
            blend_count += simd::count(blend);
            const L w = select(blend, alpha * Tr, L(T(0)));
            const L d = math::splat_planar_depth(g, px, lpy);
            L* a = acc.data() + static_cast<std::size_t>(k) * C;
            a[0] += w * g.colour[0];
            a[1] += w * g.colour[1];
            a[2] += w * g.colour[2];
            a[3] += w * d;
            for (int c = 0; c < D; ++c) a[4 + c] += w * f[c];
            const M med = blend & ~has_median[k] & (next < L(T(0.5)));
            if (simd::any(med)) {
              has_median[k] |= med;
              for (unsigned b = simd::bits(med); b != 0; b &= b - 1) {
                const int i = __builtin_ctz(b);
                median_index[first + i] = static_cast<std::int32_t>(j);
                median[first + i] = d[i];
              }
            }
            trans[k] = select(blend, next, Tr);
          }
        }
      }
      for (int py = y0; py < y1; ++py) {
        for (int px = x0; px < x1; ++px) {
          const int lp = (py - y0) * kTileSize + (px - x0);
          const int k = lp / kLanes, i = lp % kLanes;
          const std::size_t pix = static_cast<std::size_t>(py) * W + px;
          const L* a = acc.data() + static_cast<std::size_t>(k) * C;
          const T tr = trans[k][i];
          st.pixel_end[pix] = end_index[lp];
          st.pixel_median[pix] = median_index[lp];
          for (int c = 0; c < 3; ++c) out.colour[c * plane + pix] = a[c][i] + tr * background[c];
          out.depth[pix] = a[3][i];
          out.alpha[pix] = T(1) - tr;
          if (out.median_depth != nullptr) out.median_depth[pix] = median[lp];
          if (out.features != nullptr)
            for (int c = 0; c < D; ++c) out.features[c * plane + pix] = a[4 + c][i];
        }
      }
    }
  });
  st.evaluated_pairs = 0;
  st.blend_steps = 0;
  for (std::uint64_t s : evaluated) st.evaluated_pairs += s;
  for (std::uint64_t s : blended) st.blend_steps += s;
}

// Per-Gaussian 2D gradients as one thread accumulates them: [N, kGrad2dFixed + D]
// (math::pack_gradient_2d, then D features).

// Backward pass. Each tile is processed splat by splat (outer loop) over its pixels (inner loop,
// kLanes pixels of a row at once), rolling each pixel's transmittance and prefix sums forward:
// the state at the start of every block of P splats is the checkpoint T*_{kP} of eq.
// transmittance_ckpt, and T_i is recovered from it as in eq. transmittance_recover. Gradients go
// to the worker thread's own buffer (no atomics, no locks) and the buffers are reduced once at
// the end.
template <typename T>
void rasterize_backward(const SplatScene<T>& scene, const math::SplatCamera<T>& cam,
                        const T background[3], bool render_features, const RasterState<T>& st,
                        const RasterOutputs<T>& out, const RasterOutputGrads<T>& grad_out,
                        const SceneGrads<T>& grads) {
  using L = PixelLanes<T>;
  using M = typename L::Mask;
  const int W = cam.width, H = cam.height, D = render_features ? scene.feature_dim : 0;
  const std::size_t plane = static_cast<std::size_t>(W) * H;
  const std::size_t n = scene.count;
  const int stride = kGrad2dFixed + D;
  const int channels = 4 + D;  // colour 3, depth 1, features D: the prefix sums per pixel
  // Per chunk of a tile, the output gradients the inner loop reads: colour 3, depth, then D
  // features (absent ones are zero).
  const bool feature_grads = grad_out.features != nullptr && D > 0;
  const int grad_channels = 4 + (feature_grads ? D : 0);
  auto& buffers = st.thread_grads;
  for (std::vector<T>& b : buffers) b.assign(n * stride, T(0));
  const int tiles = st.tiles_x * st.tiles_y;
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles), [&](const auto& r) {
    bool existed = false;
    std::vector<T>& acc = buffers.local(existed);
    if (!existed) acc.assign(n * stride, T(0));
    std::vector<L> trans(kChunks), prefix(static_cast<std::size_t>(kChunks) * channels);
    std::vector<L> total(static_cast<std::size_t>(kChunks) * channels);
    std::vector<L> pixel_grads(static_cast<std::size_t>(kChunks) * grad_channels);
    std::vector<L> g_background(kChunks), g_alpha_out(kChunks), g_median(kChunks);
    // Per chunk, as lanes of T: the exclusive end of each pixel's splats in the tile list and
    // the list index of its median splat (-1: none), exact in T for any tile list.
    std::vector<L> pixel_end(kChunks), pixel_median(kChunks);
    std::vector<L> feature_grad(static_cast<std::size_t>(D));  // one splat's dL/df, per lane
    const L lane = L::iota(T(0));
    for (int t = r.begin(); t != r.end(); ++t) {
      const int tx = t % st.tiles_x, ty = t / st.tiles_x;
      const std::uint32_t begin = st.tile_offsets[t], end = st.tile_offsets[t + 1];
      if (begin == end) continue;
      const int x0 = tx * kTileSize, y0 = ty * kTileSize;
      const int tw = std::min(W, x0 + kTileSize) - x0, th = std::min(H, y0 + kTileSize) - y0;
      // Per pixel: T_final, the final composited values without the background, and the
      // output gradients; pixels outside the image end before the first splat.
      std::fill(trans.begin(), trans.end(), L(T(1)));
      std::fill(prefix.begin(), prefix.end(), L(T(0)));
      std::fill(total.begin(), total.end(), L(T(0)));
      std::fill(pixel_grads.begin(), pixel_grads.end(), L(T(0)));
      std::fill(g_background.begin(), g_background.end(), L(T(0)));
      std::fill(g_alpha_out.begin(), g_alpha_out.end(), L(T(0)));
      std::fill(g_median.begin(), g_median.end(), L(T(0)));
      std::fill(pixel_end.begin(), pixel_end.end(), L(T(0)));
      std::fill(pixel_median.begin(), pixel_median.end(), L(T(-1)));
      int max_end = 0;
      for (int ly = 0; ly < th; ++ly)
        for (int lx = 0; lx < tw; ++lx) {
          const int lp = ly * kTileSize + lx;
          const int k = lp / kLanes, i = lp % kLanes;
          const std::size_t pix = static_cast<std::size_t>(y0 + ly) * W + x0 + lx;
          const T t_final = T(1) - out.alpha[pix];
          L* tot = total.data() + static_cast<std::size_t>(k) * channels;
          for (int c = 0; c < 3; ++c) tot[c].v[i] = out.colour[c * plane + pix] - t_final * background[c];
          tot[3].v[i] = out.depth[pix];
          for (int c = 0; c < D; ++c) tot[4 + c].v[i] = out.features[c * plane + pix];
          L* gp = pixel_grads.data() + static_cast<std::size_t>(k) * grad_channels;
          T gc[3];
          for (int c = 0; c < 3; ++c) gp[c].v[i] = gc[c] = grad_out.colour ? grad_out.colour[c * plane + pix] : T(0);
          gp[3].v[i] = grad_out.depth ? grad_out.depth[pix] : T(0);
          if (feature_grads)
            for (int c = 0; c < D; ++c) gp[4 + c].v[i] = grad_out.features[c * plane + pix];
          // The parts of dL/dalpha_i that do not depend on splat i, times (1 - alpha_i): the
          // background seen through the pixel (a colour term) and the accumulated opacity.
          T gb = T(0);
          for (int c = 0; c < 3; ++c) gb -= gc[c] * background[c] * t_final;
          g_background[k].v[i] = gb;
          g_alpha_out[k].v[i] = grad_out.alpha != nullptr ? grad_out.alpha[pix] * t_final : T(0);
          const int median = grad_out.median_depth != nullptr ? st.pixel_median[pix] : -1;
          g_median[k].v[i] = median >= 0 ? grad_out.median_depth[pix] : T(0);
          pixel_end[k].v[i] = T(st.pixel_end[pix]);
          pixel_median[k].v[i] = T(median);
          max_end = std::max(max_end, st.pixel_end[pix]);
        }
      for (int j = 0; j < max_end; ++j) {
        const std::uint32_t id = st.tile_ids[begin + j];
        const math::ProjectedGaussian<T>& g = st.projected[id];
        const T* f = D > 0 ? scene.features + static_cast<std::size_t>(id) * scene.feature_dim
                           : nullptr;
        const L lj = L(T(j));
        math::ProjectedGradient<L> pg{};
        L imp_rgb(T(0)), imp_feat(T(0));
        std::fill(feature_grad.begin(), feature_grad.end(), L(T(0)));
        bool touched = false;
        int ry0, ry1;
        math::splat_row_range(g, &ry0, &ry1);
        const int gy0 = std::max(0, ry0 - y0);
        const int gy1 = std::min(th, ry1 - y0);
        for (int ly = gy0; ly < gy1; ++ly) {
          int sx0, sx1;
          if (!math::splat_row_span(g, T(y0 + ly), &sx0, &sx1)) continue;
          sx0 = std::max(sx0 - x0, 0);
          sx1 = std::min(sx1 - x0, tw);
          if (sx0 >= sx1) continue;
          const L py = L(T(y0 + ly));
          for (int kc = sx0 / kLanes; kc <= (sx1 - 1) / kLanes; ++kc) {
            const int k = ly * kChunksPerRow + kc;
            const L lx = lane + T(kc * kLanes);
            const M live = (lx >= L(T(sx0))) & (lx < L(T(sx1))) & (lj < pixel_end[k]);
            if (!simd::any(live)) continue;
            const L px = lx + T(x0);
            L gauss;
            const L alpha = select(live, math::splat_alpha(g, px, py, &gauss), L(T(0)));
            if (!simd::any(alpha > L(T(0)))) continue;
            gauss = select(live, gauss, L(T(0)));
            touched = true;
            const L gm = select(live & (pixel_median[k] == lj), g_median[k], L(T(0)));
            math::splat_pair_backward(g, f, D, feature_grads, px, py, alpha, gauss,
                                      total.data() + static_cast<std::size_t>(k) * channels,
                                      pixel_grads.data() + static_cast<std::size_t>(k) * grad_channels,
                                      g_background[k], g_alpha_out[k], gm, &trans[k],
                                      prefix.data() + static_cast<std::size_t>(k) * channels, &pg,
                                      feature_grad.data(), &imp_rgb, &imp_feat);
          }
        }
        if (!touched) continue;
        math::ProjectedGradient<T> sum_pg;
        sum_pg.u = simd::sum(pg.u);
        sum_pg.v = simd::sum(pg.v);
        for (int k = 0; k < 3; ++k) sum_pg.conic[k] = simd::sum(pg.conic[k]);
        sum_pg.opacity = simd::sum(pg.opacity);
        sum_pg.depth = simd::sum(pg.depth);
        for (int k = 0; k < 2; ++k) sum_pg.plane[k] = simd::sum(pg.plane[k]);
        for (int k = 0; k < 3; ++k) sum_pg.colour[k] = simd::sum(pg.colour[k]);
        T* a = acc.data() + static_cast<std::size_t>(id) * stride;
        T packed[kGrad2dFixed];
        math::pack_gradient_2d(sum_pg, simd::sum(imp_rgb), simd::sum(imp_feat), packed);
        for (int k = 0; k < kGrad2dFixed; ++k) a[k] += packed[k];
        for (int c = 0; c < D; ++c) a[kGrad2dFixed + c] += simd::sum(feature_grad[c]);
      }
    }
  });

  // Reduce the thread buffers once, then chain each Gaussian's 2D gradient to its parameters.
  std::vector<std::vector<T>*> parts;
  for (auto& b : buffers) parts.push_back(&b);
  const int sh_stride = scene.sh_stride();
  const int K = (scene.sh_degree + 1) * (scene.sh_degree + 1);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n), [&](const auto& r) {
    std::vector<T> sum(stride);
    for (std::size_t i = r.begin(); i != r.end(); ++i) {
      if (st.projected[i].radius == 0) continue;
      std::fill(sum.begin(), sum.end(), T(0));
      for (const std::vector<T>* part : parts)
        for (int k = 0; k < stride; ++k) sum[k] += (*part)[i * stride + k];
      const math::ProjectedGradient<T> pg = math::unpack_gradient_2d(sum.data());
      math::ProjectedGaussian<T> projected;
      math::ProjectionTerms<T> terms;
      math::project_gaussian(scene.means + 3 * i, scene.rotations + 4 * i, scene.log_scales + 3 * i,
                             scene.opacity_logits[i], scene.filter(i), scene.sh + i * sh_stride,
                             scene.sh_degree, cam, &projected, &terms);
      math::GaussianParamGradient<T> pgrad;
      math::project_gaussian_backward(scene.rotations + 4 * i, scene.filter(i),
                                      scene.sh + i * sh_stride, scene.sh_degree, cam, projected,
                                      terms, pg, &pgrad);
      for (int k = 0; k < 3; ++k) grads.means[3 * i + k] += pgrad.mean[k];
      for (int k = 0; k < 4; ++k) grads.rotations[4 * i + k] += pgrad.quat[k];
      for (int k = 0; k < 3; ++k) grads.log_scales[3 * i + k] += pgrad.log_scale[k];
      grads.opacity_logits[i] += pgrad.opacity_logit;
      for (int k = 0; k < 3 * K; ++k) grads.sh[i * sh_stride + k] += pgrad.sh[k];
      if (grads.features != nullptr)
        for (int c = 0; c < D; ++c)
          grads.features[i * scene.feature_dim + c] += sum[kGrad2dFixed + c];
      if (grads.importance_rgb != nullptr) grads.importance_rgb[i] += sum[12];
      if (grads.importance_feature != nullptr) grads.importance_feature[i] += sum[13];
    }
  });
}

// The straightforward reference: every pixel walks every visible Gaussian, globally sorted by
// depth, with no tiles. Same per-pixel math and order, so it must equal rasterize_forward; it is
// the baseline of the throughput benchmark. Returns the splat-pixel pairs evaluated.
template <typename T>
std::uint64_t rasterize_reference(const SplatScene<T>& scene, const math::SplatCamera<T>& cam,
                                  const T background[3], const RasterOutputs<T>& out) {
  const std::size_t n = scene.count;
  std::vector<math::ProjectedGaussian<T>> projected(n);
  std::vector<std::uint32_t> order;
  for (std::size_t i = 0; i < n; ++i) {
    math::ProjectionTerms<T> terms;
    if (math::project_gaussian(scene.means + 3 * i, scene.rotations + 4 * i,
                               scene.log_scales + 3 * i, scene.opacity_logits[i], scene.filter(i),
                               scene.sh + i * scene.sh_stride(), scene.sh_degree, cam,
                               &projected[i], &terms)) {
      order.push_back(static_cast<std::uint32_t>(i));
    }
  }
  std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
    return projected[a].depth < projected[b].depth ||
           (projected[a].depth == projected[b].depth && a < b);
  });
  const int W = cam.width, H = cam.height, D = scene.feature_dim;
  const std::size_t plane = static_cast<std::size_t>(W) * H;
  std::uint64_t steps = 0;
  std::vector<T> feat(static_cast<std::size_t>(D));
  for (int py = 0; py < H; ++py) {
    for (int px = 0; px < W; ++px) {
      const std::size_t pix = static_cast<std::size_t>(py) * W + px;
      T Tr = T(1), colour[3] = {T(0), T(0), T(0)}, depth = T(0), median = T(0);
      bool has_median = false;
      std::fill(feat.begin(), feat.end(), T(0));
      for (std::uint32_t id : order) {
        const math::ProjectedGaussian<T>& g = projected[id];
        ++steps;
        T gauss;
        const T alpha = math::splat_alpha(g, T(px), T(py), &gauss);
        if (alpha == T(0)) continue;
        const T next = Tr * (T(1) - alpha);
        if (next < T(math::kTransmittanceMin)) break;
        const T w = alpha * Tr;
        const T d = math::splat_planar_depth(g, T(px), T(py));
        for (int c = 0; c < 3; ++c) colour[c] += w * g.colour[c];
        depth += w * d;
        for (int c = 0; c < D; ++c) feat[c] += w * scene.features[static_cast<std::size_t>(id) * D + c];
        if (!has_median && next < T(0.5)) {
          has_median = true;
          median = d;
        }
        Tr = next;
      }
      for (int c = 0; c < 3; ++c) out.colour[c * plane + pix] = colour[c] + Tr * background[c];
      out.depth[pix] = depth;
      out.alpha[pix] = T(1) - Tr;
      if (out.median_depth != nullptr) out.median_depth[pix] = median;
      if (out.features != nullptr)
        for (int c = 0; c < D; ++c) out.features[c * plane + pix] = feat[c];
    }
  }
  return steps;
}

}  // namespace fslam::core::render_impl

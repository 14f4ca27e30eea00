// Compositing, backward (paper eq. transmittance_recover): per pixel over the forward's lists,
// each splat-pixel pair through core's math::splat_pair_backward, summed per Gaussian with atomics.
#include "launchers.hpp"
#include "tile_pixels.cuh"

namespace fslam::cuda {
namespace {

namespace math = core::math;
using tile::in_footprint;
using tile::load_batch;
using tile::tile_pixel;
using tile::TilePixel;

// The backward pass per pixel, front to back over the same lists as the forward pass, each
// splat-pixel pair through the shared math::splat_pair_backward (paper eq. transmittance_recover);
// a pair's contribution to its Gaussian's 2D gradient is added with atomics (summation order is
// not fixed, unlike the CPU's per-thread buffers).
template <int kTile>
__global__ void composite_bwd_kernel(const math::ProjectedGaussian<float>* __restrict__ projected,
                                     const uint2* __restrict__ tile_ranges, const std::uint32_t* __restrict__ tile_ids,
                                     const float* __restrict__ features, int feature_dim, int width, int height,
                                     int tiles_x, float3 background, math::RasterOutputs<float> out,
                                     const std::int32_t* __restrict__ pixel_end,
                                     const std::int32_t* __restrict__ pixel_median, math::RasterOutputGrads<float> grads,
                                     float* __restrict__ accum) {
  constexpr int kBatch = kTile * kTile;
  __shared__ math::ProjectedGaussian<float> batch[kBatch];
  __shared__ std::uint32_t batch_ids[kBatch];
  const TilePixel t = tile_pixel<kTile>(tile_ranges, tiles_x, width, height);
  const int px = t.px, py = t.py;
  const bool inside = t.inside;
  const std::uint32_t begin = t.begin, end = t.end;
  const int D = feature_dim;
  const bool feature_grads = grads.features != nullptr && D > 0;
  const long plane = static_cast<long>(width) * height, pix = static_cast<long>(py) * width + px;
  float tot[4 + kMaxFeatureChannels], gp[4 + kMaxFeatureChannels], pre[4 + kMaxFeatureChannels];
  float fg[kMaxFeatureChannels];
  float trans = 1.0f, g_background = 0.0f, g_alpha_out = 0.0f;
  std::int32_t last = 0, median = -1;
  for (int c = 0; c < 4 + D; ++c) tot[c] = gp[c] = pre[c] = 0.0f;
  if (inside) {
    const float t_final = 1.0f - out.alpha[pix];
    const float bg[3] = {background.x, background.y, background.z};
    for (int c = 0; c < 3; ++c) {
      tot[c] = out.colour[c * plane + pix] - t_final * bg[c];
      gp[c] = grads.colour != nullptr ? grads.colour[c * plane + pix] : 0.0f;
      g_background -= gp[c] * bg[c] * t_final;
    }
    tot[3] = out.depth[pix];
    gp[3] = grads.depth != nullptr ? grads.depth[pix] : 0.0f;
    for (int c = 0; c < D; ++c) {
      tot[4 + c] = out.features[c * plane + pix];
      if (feature_grads) gp[4 + c] = grads.features[c * plane + pix];
    }
    g_alpha_out = grads.alpha != nullptr ? grads.alpha[pix] * t_final : 0.0f;
    last = pixel_end[pix];
    median = grads.median_depth != nullptr ? pixel_median[pix] : -1;
  }
  const int stride = math::kGrad2dFixed + D;
  for (std::uint32_t first = begin; first < end; first += kBatch) {
    const int offset = static_cast<int>(first - begin);
    if (__syncthreads_count(offset < last ? 1 : 0) == 0) break;  // every pixel is past its end
    const int n = load_batch<kBatch>(t, first, tile_ids, projected, batch, batch_ids);
    for (int k = 0; k < n && offset + k < last; ++k) {
      const math::ProjectedGaussian<float>& g = batch[k];
      if (!in_footprint(g, px, py)) continue;
      float gauss;
      const float alpha = math::splat_alpha(g, static_cast<float>(px), static_cast<float>(py), &gauss);
      if (alpha == 0.0f) continue;
      const std::uint32_t id = batch_ids[k];
      const float* f = features + static_cast<long>(id) * feature_dim;
      math::ProjectedGradient<float> pg{};
      for (int c = 0; c < D; ++c) fg[c] = 0.0f;
      float imp_rgb = 0.0f, imp_feat = 0.0f;
      const float g_median = median == offset + k ? grads.median_depth[pix] : 0.0f;
      math::splat_pair_backward(g, f, D, feature_grads, static_cast<float>(px), static_cast<float>(py), alpha, gauss,
                                tot, gp, g_background, g_alpha_out, g_median, &trans, pre, &pg, fg, &imp_rgb,
                                &imp_feat);
      float* a = accum + static_cast<long>(id) * stride;
      float values[math::kGrad2dFixed];
      math::pack_gradient_2d(pg, imp_rgb, imp_feat, values);
      for (int c = 0; c < math::kGrad2dFixed; ++c) atomicAdd(&a[c], values[c]);
      if (feature_grads)
        for (int c = 0; c < D; ++c) atomicAdd(&a[math::kGrad2dFixed + c], fg[c]);
    }
  }
}

}  // namespace

cudaError_t composite_bwd(const core::math::ProjectedGaussian<float>* projected, const uint2* tile_ranges,
                          const std::uint32_t* tile_ids, const float* features, int feature_dim, int width,
                          int height, int tiles_x, int tiles_y, const float background[3],
                          const core::math::RasterOutputs<float>& out, const std::int32_t* pixel_end,
                          const std::int32_t* pixel_median, const core::math::RasterOutputGrads<float>& grads, float* accum,
                          cudaStream_t stream) {
  if (feature_dim < 0 || feature_dim > kMaxFeatureChannels) return cudaErrorInvalidValue;
  const int tiles = tiles_x * tiles_y;
  if (tiles <= 0) return cudaSuccess;
  const dim3 block(kRasterTile, kRasterTile);
  composite_bwd_kernel<kRasterTile><<<tiles, block, 0, stream>>>(
      projected, tile_ranges, tile_ids, features, feature_dim, width, height, tiles_x,
      make_float3(background[0], background[1], background[2]), out, pixel_end, pixel_median, grads, accum);
  return cudaGetLastError();
}

}  // namespace fslam::cuda

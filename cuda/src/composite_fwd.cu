// Compositing, forward (paper eq. blending): one block per 16x16 tile, one thread per pixel,
// running core's per-pixel math (fslam/core/math/compositing.hpp) over the binned lists.
#include "launchers.hpp"
#include "tile_pixels.cuh"

namespace fslam::cuda {
namespace {

namespace math = core::math;
using tile::in_footprint;
using tile::load_batch;
using tile::tile_pixel;
using tile::TilePixel;

// Each pixel composites its tile's list front to back exactly as the CPU's per-splat loop does
// per pixel: the row range and span decide which pairs are evaluated, splat_alpha the weight,
// kTransmittanceMin ends the pixel, the first transmittance below 0.5 gives the median depth.
template <int kTile>
__global__ void composite_kernel(const math::ProjectedGaussian<float>* __restrict__ projected,
                                 const uint2* __restrict__ tile_ranges,
                                 const std::uint32_t* __restrict__ tile_ids, const float* __restrict__ features,
                                 int feature_dim, int width, int height, int tiles_x, float3 background,
                                 math::RasterOutputs<float> out, std::int32_t* __restrict__ pixel_end,
                                 std::int32_t* __restrict__ pixel_median, unsigned long long* __restrict__ counters) {
  constexpr int kBatch = kTile * kTile;
  __shared__ math::ProjectedGaussian<float> batch[kBatch];
  __shared__ std::uint32_t batch_ids[kBatch];
  const TilePixel t = tile_pixel<kTile>(tile_ranges, tiles_x, width, height);
  const int px = t.px, py = t.py;
  const bool inside = t.inside;
  const std::uint32_t begin = t.begin, end = t.end;
  bool done = !inside;
  float trans = 1.0f, acc[4 + kMaxFeatureChannels];
  const int channels = 4 + feature_dim;
  for (int c = 0; c < channels; ++c) acc[c] = 0.0f;
  float median = 0.0f;
  bool has_median = false;
  std::int32_t end_index = static_cast<std::int32_t>(end - begin), median_index = -1;
  unsigned long long evaluated = 0, blended = 0;
  for (std::uint32_t first = begin; first < end; first += kBatch) {
    if (__syncthreads_count(done ? 1 : 0) == kBatch) break;  // every pixel of the tile has ended
    const int n = load_batch<kBatch>(t, first, tile_ids, projected, batch, batch_ids);
    for (int k = 0; k < n && !done; ++k) {
      const math::ProjectedGaussian<float>& g = batch[k];
      if (!in_footprint(g, px, py)) continue;
      ++evaluated;
      float gauss;
      const float alpha = math::splat_alpha(g, static_cast<float>(px), static_cast<float>(py), &gauss);
      if (alpha == 0.0f) continue;
      const float next = trans * (1.0f - alpha);
      if (next < math::kTransmittanceMin) {
        end_index = static_cast<std::int32_t>(first - begin) + k;
        done = true;
        break;
      }
      ++blended;
      const float w = alpha * trans;
      const float d = math::splat_planar_depth(g, static_cast<float>(px), static_cast<float>(py));
      acc[0] += w * g.colour[0];
      acc[1] += w * g.colour[1];
      acc[2] += w * g.colour[2];
      acc[3] += w * d;
      const float* f = features + static_cast<long>(batch_ids[k]) * feature_dim;
      for (int c = 0; c < feature_dim; ++c) acc[4 + c] += w * f[c];
      if (!has_median && next < 0.5f) {
        has_median = true;
        median = d;
        median_index = static_cast<std::int32_t>(first - begin) + k;
      }
      trans = next;
    }
  }
  if (!inside) return;
  const long plane = static_cast<long>(width) * height, pix = static_cast<long>(py) * width + px;
  out.colour[pix] = acc[0] + trans * background.x;
  out.colour[plane + pix] = acc[1] + trans * background.y;
  out.colour[2 * plane + pix] = acc[2] + trans * background.z;
  out.depth[pix] = acc[3];
  out.median_depth[pix] = median;
  out.alpha[pix] = 1.0f - trans;
  for (int c = 0; c < feature_dim; ++c) out.features[c * plane + pix] = acc[4 + c];
  pixel_end[pix] = end_index;
  pixel_median[pix] = median_index;
  atomicAdd(&counters[0], evaluated);
  atomicAdd(&counters[1], blended);
}

}  // namespace

cudaError_t composite_fwd(const core::math::ProjectedGaussian<float>* projected, const uint2* tile_ranges,
                          const std::uint32_t* tile_ids, const float* features, int feature_dim, int width,
                          int height, int tiles_x, int tiles_y, const float background[3],
                          const core::math::RasterOutputs<float>& out, std::int32_t* pixel_end,
                          std::int32_t* pixel_median, unsigned long long* counters, cudaStream_t stream) {
  if (feature_dim < 0 || feature_dim > kMaxFeatureChannels) return cudaErrorInvalidValue;
  const int tiles = tiles_x * tiles_y;
  if (tiles <= 0) return cudaSuccess;
  const dim3 block(kRasterTile, kRasterTile);
  composite_kernel<kRasterTile><<<tiles, block, 0, stream>>>(
      projected, tile_ranges, tile_ids, features, feature_dim, width, height, tiles_x,
      make_float3(background[0], background[1], background[2]), out, pixel_end, pixel_median, counters);
  return cudaGetLastError();
}

}  // namespace fslam::cuda

// The forward rasteriser's kernels: projection (one thread per Gaussian) and compositing (one
// block per 16x16 tile, one thread per pixel), running core's math (fslam/core/math/splat_math.hpp,
// paper eq. proj and blending) so the CPU tests exercise the same code.
#include <cub/cub.cuh>

#include "launchers.hpp"

namespace fslam::cuda {
namespace {

namespace math = core::math;

__global__ void project_kernel(math::SplatScene<float> scene, math::SplatCamera<float> cam, int tile_size,
                               int tiles_x, int tiles_y, math::ProjectedGaussian<float>* __restrict__ projected,
                               int* __restrict__ rect, std::uint32_t* __restrict__ touched,
                               std::uint8_t* __restrict__ visible) {
  const std::size_t i = static_cast<std::size_t>(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= scene.count) return;
  math::ProjectionTerms<float> terms;
  math::ProjectedGaussian<float> pg;
  if (!math::project_gaussian(scene.means + 3 * i, scene.rotations + 4 * i, scene.log_scales + 3 * i,
                              scene.opacity_logits[i], scene.filter(i), scene.sh + i * scene.sh_stride(),
                              scene.sh_degree, cam, &pg, &terms)) {
    pg.radius = 0;
  }
  projected[i] = pg;
  int* r = rect + 4 * i;
  if (pg.radius > 0) {
    math::splat_tile_rect(pg, tile_size, tiles_x, tiles_y, r);
  } else {
    r[0] = r[1] = r[2] = r[3] = 0;
  }
  const int w = r[2] - r[0], h = r[3] - r[1];
  touched[i] = w > 0 && h > 0 ? static_cast<std::uint32_t>(w * h) : 0u;
  visible[i] = pg.radius > 0 ? 1 : 0;
}

// One key per (Gaussian, tile) pair: tile in the high 32 bits, the depth's bits in the low 32 (a
// positive float's bits order like the float). Written in id order, so a stable sort keeps ties
// by id.
__global__ void duplicate_kernel(int count, const math::ProjectedGaussian<float>* __restrict__ projected,
                                 const int* __restrict__ rect, const std::uint32_t* __restrict__ touched,
                                 const std::uint32_t* __restrict__ offsets, int tiles_x,
                                 unsigned long long* __restrict__ keys, std::uint32_t* __restrict__ ids) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= count || touched[i] == 0) return;
  const unsigned long long depth = __float_as_uint(projected[i].depth);
  std::uint32_t k = offsets[i];
  const int* r = rect + 4 * i;
  for (int ty = r[1]; ty < r[3]; ++ty)
    for (int tx = r[0]; tx < r[2]; ++tx) {
      keys[k] = (static_cast<unsigned long long>(ty * tiles_x + tx) << 32) | depth;
      ids[k] = static_cast<std::uint32_t>(i);
      ++k;
    }
}

// Each tile's [begin, end) in the sorted keys; tiles without entries keep {0, 0}.
__global__ void ranges_kernel(std::uint32_t entries, const unsigned long long* __restrict__ keys,
                              uint2* __restrict__ ranges) {
  const std::uint32_t j = blockIdx.x * blockDim.x + threadIdx.x;
  if (j >= entries) return;
  const unsigned tile = static_cast<unsigned>(keys[j] >> 32);
  if (j == 0 || static_cast<unsigned>(keys[j - 1] >> 32) != tile) ranges[tile].x = j;
  if (j + 1 == entries || static_cast<unsigned>(keys[j + 1] >> 32) != tile) ranges[tile].y = j + 1;
}

// Whether pixel (px, py) is a pair the CPU rasteriser evaluates: in the splat's row range and
// row span (its loops run over exactly those), so both passes see the same pairs.
__device__ bool in_footprint(const math::ProjectedGaussian<float>& g, int px, int py) {
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

// Chains each Gaussian's summed 2D gradient to its parameters (math::project_gaussian_backward):
// out [N, P] with P = 11 + 3K + D + 2: mean 3, rotation 4, log-scale 3, opacity logit, SH [K, 3],
// features D, importance rgb and feature.
__global__ void project_bwd_kernel(math::SplatScene<float> scene, math::SplatCamera<float> cam,
                                   const math::ProjectedGaussian<float>* __restrict__ projected,
                                   const float* __restrict__ accum, int D, float* __restrict__ out) {
  const std::size_t i = static_cast<std::size_t>(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= scene.count) return;
  const int K = (scene.sh_degree + 1) * (scene.sh_degree + 1);
  const int P = 11 + 3 * K + D + 2, stride = math::kGrad2dFixed + D;
  float* o = out + i * P;
  for (int k = 0; k < P; ++k) o[k] = 0.0f;
  if (projected[i].radius == 0) return;
  const float* a = accum + i * stride;
  const math::ProjectedGradient<float> pg = math::unpack_gradient_2d(a);
  math::ProjectedGaussian<float> again;
  math::ProjectionTerms<float> terms;
  math::project_gaussian(scene.means + 3 * i, scene.rotations + 4 * i, scene.log_scales + 3 * i,
                         scene.opacity_logits[i], scene.filter(i), scene.sh + i * scene.sh_stride(), scene.sh_degree,
                         cam, &again, &terms);
  math::GaussianParamGradient<float> pgrad;
  math::project_gaussian_backward(scene.rotations + 4 * i, scene.filter(i), scene.sh + i * scene.sh_stride(),
                                  scene.sh_degree, cam, again, terms, pg, &pgrad);
  for (int k = 0; k < 3; ++k) o[k] = pgrad.mean[k];
  for (int k = 0; k < 4; ++k) o[3 + k] = pgrad.quat[k];
  for (int k = 0; k < 3; ++k) o[7 + k] = pgrad.log_scale[k];
  o[10] = pgrad.opacity_logit;
  for (int k = 0; k < 3 * K; ++k) o[11 + k] = pgrad.sh[k];
  for (int c = 0; c < D; ++c) o[11 + 3 * K + c] = a[math::kGrad2dFixed + c];
  o[11 + 3 * K + D] = a[12];
  o[12 + 3 * K + D] = a[13];
}

}  // namespace

cudaError_t project_fwd(const core::math::SplatScene<float>& scene, const core::math::SplatCamera<float>& cam,
                        int tile_size, int tiles_x, int tiles_y, core::math::ProjectedGaussian<float>* projected,
                        int* rect, std::uint32_t* touched, std::uint8_t* visible, cudaStream_t stream) {
  if (scene.count == 0) return cudaSuccess;
  constexpr int kBlock = 128;
  const unsigned blocks = static_cast<unsigned>((scene.count + kBlock - 1) / kBlock);
  project_kernel<<<blocks, kBlock, 0, stream>>>(scene, cam, tile_size, tiles_x, tiles_y, projected, rect, touched,
                                                visible);
  return cudaGetLastError();
}

cudaError_t bin_fwd(int count, const core::math::ProjectedGaussian<float>* projected, const int* rect,
                    const std::uint32_t* touched, int tiles_x, int tiles_y, BinBuffers* buffers,
                    std::uint32_t* entries, cudaStream_t stream) {
  const int tiles = tiles_x * tiles_y;
  *entries = 0;
  cudaError_t status = buffers->ranges.resize(static_cast<std::size_t>(std::max(tiles, 1)));
  if (status == cudaSuccess) status = cudaMemsetAsync(buffers->ranges.data(), 0, tiles * sizeof(uint2), stream);
  if (status != cudaSuccess || count == 0) return status;
  // Where each Gaussian's pairs start: an exclusive scan of the tiles it touches.
  status = buffers->offsets.resize(static_cast<std::size_t>(count));
  std::size_t scratch = 0;
  if (status == cudaSuccess) {
    status = cub::DeviceScan::ExclusiveSum(nullptr, scratch, touched, buffers->offsets.data(), count, stream);
  }
  if (status == cudaSuccess) status = buffers->scratch.resize(std::max<std::size_t>(scratch, 1));
  if (status == cudaSuccess) {
    status = cub::DeviceScan::ExclusiveSum(buffers->scratch.data(), scratch, touched, buffers->offsets.data(),
                                           count, stream);
  }
  std::uint32_t last[2] = {0, 0};
  if (status == cudaSuccess) {
    status = cudaMemcpyAsync(&last[0], buffers->offsets.data() + count - 1, sizeof(std::uint32_t),
                             cudaMemcpyDeviceToHost, stream);
  }
  if (status == cudaSuccess) {
    status = cudaMemcpyAsync(&last[1], touched + count - 1, sizeof(std::uint32_t), cudaMemcpyDeviceToHost, stream);
  }
  if (status == cudaSuccess) status = cudaStreamSynchronize(stream);
  if (status != cudaSuccess) return status;
  const std::uint32_t n = last[0] + last[1];
  *entries = n;
  if (n == 0) return cudaSuccess;
  status = buffers->keys.resize(n);
  if (status == cudaSuccess) status = buffers->sorted_keys.resize(n);
  if (status == cudaSuccess) status = buffers->ids.resize(n);
  if (status == cudaSuccess) status = buffers->sorted_ids.resize(n);
  if (status != cudaSuccess) return status;
  constexpr int kBlock = 256;
  duplicate_kernel<<<(count + kBlock - 1) / kBlock, kBlock, 0, stream>>>(
      count, projected, rect, touched, buffers->offsets.data(), tiles_x, buffers->keys.data(), buffers->ids.data());
  status = cudaGetLastError();
  // A stable radix sort over the depth bits and as many tile bits as there are tiles.
  int tile_bits = 1;
  while ((1 << tile_bits) < tiles) ++tile_bits;
  if (status == cudaSuccess) {
    status = cub::DeviceRadixSort::SortPairs(nullptr, scratch, buffers->keys.data(), buffers->sorted_keys.data(),
                                             buffers->ids.data(), buffers->sorted_ids.data(), n, 0, 32 + tile_bits,
                                             stream);
  }
  if (status == cudaSuccess) status = buffers->scratch.resize(std::max<std::size_t>(scratch, 1));
  if (status == cudaSuccess) {
    status = cub::DeviceRadixSort::SortPairs(buffers->scratch.data(), scratch, buffers->keys.data(),
                                             buffers->sorted_keys.data(), buffers->ids.data(),
                                             buffers->sorted_ids.data(), n, 0, 32 + tile_bits, stream);
  }
  if (status != cudaSuccess) return status;
  ranges_kernel<<<(n + kBlock - 1) / kBlock, kBlock, 0, stream>>>(n, buffers->sorted_keys.data(),
                                                                 buffers->ranges.data());
  return cudaGetLastError();
}

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

cudaError_t project_bwd(const core::math::SplatScene<float>& scene, const core::math::SplatCamera<float>& cam,
                        const core::math::ProjectedGaussian<float>* projected, const float* accum, int feature_dim,
                        float* out, cudaStream_t stream) {
  if (scene.count == 0) return cudaSuccess;
  constexpr int kBlock = 128;
  const unsigned blocks = static_cast<unsigned>((scene.count + kBlock - 1) / kBlock);
  project_bwd_kernel<<<blocks, kBlock, 0, stream>>>(scene, cam, projected, accum, feature_dim, out);
  return cudaGetLastError();
}

}  // namespace fslam::cuda

// Binning: each visible Gaussian's (tile, depth) pairs, an exclusive scan and a stable radix sort
// (CUB) into per-tile lists front to back, ties by id, as the CPU's render_impl::bin_to_tiles.
#include <algorithm>

#include <cub/cub.cuh>

#include "launchers.hpp"

namespace fslam::cuda {
namespace {

namespace math = core::math;

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

}  // namespace

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

}  // namespace fslam::cuda

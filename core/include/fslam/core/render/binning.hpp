// Binning: the projected Gaussians into per-tile lists, front to back by the depth of the mean,
// ties by id. The CUDA sibling is cuda/src/binning.cu (a scan and a stable radix sort in the same
// order). Internal to core/render and its tests.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "fslam/core/render/raster_state.hpp"

namespace fslam::core::render_impl {

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

}  // namespace fslam::core::render_impl

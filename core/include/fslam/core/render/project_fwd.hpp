// Projection, forward (paper eq. proj): every Gaussian through math::project_gaussian, in
// parallel, with the tile rectangle it covers. The CUDA sibling is cuda/src/project_fwd.cu.
// Internal to core/render and its tests.
#pragma once

#include <cstddef>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "fslam/core/math/splat_math.hpp"
#include "fslam/core/render/raster_state.hpp"

namespace fslam::core::render_impl {

// Sets the state's image and tile grid for `cam`, projects every Gaussian into st.projected
// (radius 0 = culled) and writes each visible one's tile rectangle into st.rect ([N, 4] tile x0,
// y0, x1, y1, exclusive; math::splat_tile_rect).
template <typename T>
void project_fwd(const SplatScene<T>& scene, const math::SplatCamera<T>& cam, RasterState<T>* state) {
  RasterState<T>& st = *state;
  st.width = cam.width;
  st.height = cam.height;
  st.tiles_x = (cam.width + kTileSize - 1) / kTileSize;
  st.tiles_y = (cam.height + kTileSize - 1) / kTileSize;
  const std::size_t n = scene.count;
  st.projected.assign(n, math::ProjectedGaussian<T>{});
  std::vector<int>& rect = st.rect;
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
}

}  // namespace fslam::core::render_impl

// Projection, backward: the per-tile 2D gradients of composite_bwd summed once per Gaussian, in
// tile order, then chained to its parameters through math::project_gaussian_backward. The CUDA sibling is
// cuda/src/project_bwd.cu. Internal to core/render and its tests.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "fslam/core/math/splat_math.hpp"
#include "fslam/core/render/raster_state.hpp"

namespace fslam::core::render_impl {

// Orders the tile-list entries by Gaussian, keeping tile order within one (a counting sort):
// Gaussian i's entries are st.entry_order[st.entry_offsets[i] .. st.entry_offsets[i + 1]).
template <typename T>
void group_entries_by_gaussian(std::size_t n, const RasterState<T>& st) {
  std::vector<std::uint32_t>& offsets = st.entry_offsets;
  offsets.assign(n + 1, 0);
  for (const std::uint32_t id : st.tile_ids) ++offsets[id + 1];
  for (std::size_t i = 0; i < n; ++i) offsets[i + 1] += offsets[i];
  st.entry_order.resize(st.tile_ids.size());
  // offsets[i] is Gaussian i's cursor, from its start to its end (i + 1's start); shifted by one
  // Gaussian afterwards, so that no cursor array is allocated per call.
  for (std::uint32_t e = 0; e < st.tile_ids.size(); ++e) st.entry_order[offsets[st.tile_ids[e]]++] = e;
  for (std::size_t i = n; i > 0; --i) offsets[i] = offsets[i - 1];
  offsets[0] = 0;
}

// Adds (+=) to `grads` each visible Gaussian's parameter gradients from the sum of its rows of
// st.entry_grads ([tile_ids.size(), kGrad2dFixed + D]), re-projecting it for the forward's terms.
template <typename T>
void project_bwd(const SplatScene<T>& scene, const math::SplatCamera<T>& cam, int D, const RasterState<T>& st,
                 const SceneGrads<T>& grads) {
  const std::size_t n = scene.count;
  const std::size_t stride = static_cast<std::size_t>(kGrad2dFixed + D);
  group_entries_by_gaussian(n, st);
  const int sh_stride = scene.sh_stride();
  const int K = (scene.sh_degree + 1) * (scene.sh_degree + 1);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n), [&](const auto& r) {
    std::vector<T> sum(stride);
    for (std::size_t i = r.begin(); i != r.end(); ++i) {
      if (st.projected[i].radius == 0) continue;
      std::fill(sum.begin(), sum.end(), T(0));
      for (std::uint32_t k = st.entry_offsets[i]; k != st.entry_offsets[i + 1]; ++k) {
        const T* row = st.entry_grads.data() + st.entry_order[k] * stride;
        for (std::size_t c = 0; c < stride; ++c) sum[c] += row[c];
      }
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

}  // namespace fslam::core::render_impl

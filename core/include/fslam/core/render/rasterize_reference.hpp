// The straightforward reference of the CPU rasteriser: no tiles, no lanes. Internal to
// core/render, its tests and the rasteriser benchmark.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "fslam/core/math/splat_math.hpp"

namespace fslam::core::render_impl {

// The straightforward reference: every pixel walks every visible Gaussian, globally sorted by
// depth, with no tiles. Same per-pixel math and order, so it must equal rasterize_forward; it is
// the baseline of the throughput benchmark. Returns the splat-pixel pairs evaluated.
template <typename T>
std::uint64_t rasterize_reference(const math::SplatScene<T>& scene, const math::SplatCamera<T>& cam,
                                  const T background[3], const math::RasterOutputs<T>& out) {
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

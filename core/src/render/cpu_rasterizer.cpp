#include <cmath>
#include <memory>
#include <mutex>
#include <vector>

#include "fslam/core/error.hpp"
#include "fslam/core/render/rasterize_impl.hpp"
#include "fslam/core/render/rasterizer.hpp"

namespace fslam::core {

namespace {
struct CpuBackwardState final : RenderBackwardState {
  render_impl::RasterState<float> raster;
};

// Forward states handed back when their result is dropped, so that the mapper's render per step
// reuses its buffers instead of faulting fresh pages in (measured: page faults and zeroing were
// ~13 % of a mapping run's time). Bounded in count and in the pixels a kept state holds.
class StatePool {
 public:
  static std::shared_ptr<CpuBackwardState> acquire(const std::shared_ptr<StatePool>& pool) {
    std::unique_ptr<CpuBackwardState> state;
    {
      std::lock_guard<std::mutex> lock(pool->mutex_);
      if (!pool->free_.empty()) {
        state = std::move(pool->free_.back());
        pool->free_.pop_back();
      }
    }
    if (!state) state = std::make_unique<CpuBackwardState>();
    return std::shared_ptr<CpuBackwardState>(state.release(), [weak = std::weak_ptr<StatePool>(pool)](CpuBackwardState* s) {
      std::unique_ptr<CpuBackwardState> owned(s);
      const std::shared_ptr<StatePool> p = weak.lock();
      if (!p || owned->raster.pixel_end.capacity() > kMaxPooledPixels) return;
      std::lock_guard<std::mutex> lock(p->mutex_);
      if (p->free_.size() < kMaxPooled) p->free_.push_back(std::move(owned));
    });
  }

 private:
  static constexpr std::size_t kMaxPooled = 4;
  static constexpr std::size_t kMaxPooledPixels = 2'000'000;
  std::mutex mutex_;
  std::vector<std::unique_ptr<CpuBackwardState>> free_;
};
}  // namespace

double RenderStats::mean_splats_per_pixel() const {
  return pixels > 0 ? static_cast<double>(blend_steps) / static_cast<double>(pixels) : 0.0;
}

void GaussianGradients::reset(const GaussianMap& map) {
  const std::size_t n = map.size();
  means.assign(3 * n, 0.0f);
  rotations.assign(4 * n, 0.0f);
  log_scales.assign(3 * n, 0.0f);
  opacity_logits.assign(n, 0.0f);
  sh.assign(n * static_cast<std::size_t>(map.sh_per_gaussian()), 0.0f);
  features.assign(n * static_cast<std::size_t>(map.feature_dim), 0.0f);
  importance_rgb.assign(n, 0.0f);
  importance_feature.assign(n, 0.0f);
}

namespace {

class CpuRasterizer final : public Rasterizer {
 public:
  std::string name() const override { return "cpu"; }

  bool forward(const GaussianMap& map, const RenderView& view, const RenderSettings& settings,
               RenderResult* result, std::string* why) const override {
    math::SplatCamera<float> cam;
    if (!render_impl::render_camera(view, settings, &cam, why)) return false;
    std::string reason;
    if (!map.is_consistent(&reason)) return fail(why, "map: " + reason);
    const int W = cam.width, H = cam.height;
    const int D = settings.features ? map.feature_dim : 0;
    result->colour = PlanarImage(W, H, 3);
    result->depth = PlanarImage(W, H, 1);
    result->median_depth = PlanarImage(W, H, 1);
    result->alpha = PlanarImage(W, H, 1);
    result->features = D > 0 ? PlanarImage(W, H, D) : PlanarImage();
    std::shared_ptr<CpuBackwardState> state = StatePool::acquire(pool_);
    render_impl::RasterOutputs<float> out;
    out.colour = result->colour.data.data();
    out.depth = result->depth.data.data();
    out.median_depth = result->median_depth.data.data();
    out.alpha = result->alpha.data.data();
    out.features = D > 0 ? result->features.data.data() : nullptr;
    render_impl::rasterize_forward(render_impl::splat_scene(map), cam, settings.background.data(), D > 0,
                                   &state->raster, out);
    result->visible.resize(map.size());
    for (std::size_t i = 0; i < map.size(); ++i) {
      result->visible[i] = state->raster.projected[i].radius > 0 ? 1 : 0;
    }
    result->stats.gaussians = map.size();
    result->stats.pixels = static_cast<std::size_t>(W) * H;
    result->stats.visible = state->raster.visible;
    result->stats.tile_entries = state->raster.tile_ids.size();
    result->stats.blend_steps = state->raster.blend_steps;
    result->stats.evaluated_pairs = state->raster.evaluated_pairs;
    result->backward_state = std::move(state);
    return true;
  }

  bool backward(const GaussianMap& map, const RenderView& view, const RenderSettings& settings,
                const RenderResult& result, const RenderGradients& output_grads,
                GaussianGradients* grads, std::string* why) const override {
    math::SplatCamera<float> cam;
    int D = 0;
    if (!render_impl::check_backward_inputs(map, view, settings, result, output_grads, &cam, &D, why)) return false;
    const auto* state = dynamic_cast<const CpuBackwardState*>(result.backward_state.get());
    if (state == nullptr) return fail(why, "backward: the result is not from the CPU rasteriser's forward pass");
    const auto& st = state->raster;
    if (st.projected.size() != map.size() || st.width != cam.width || st.height != cam.height) {
      return fail(why, "backward: the forward pass was for another map or view");
    }
    if (grads->opacity_logits.size() != map.size()) grads->reset(map);
    render_impl::RasterOutputs<float> out;
    out.colour = const_cast<float*>(result.colour.data.data());
    out.depth = const_cast<float*>(result.depth.data.data());
    out.median_depth = const_cast<float*>(result.median_depth.data.data());
    out.alpha = const_cast<float*>(result.alpha.data.data());
    out.features = D > 0 ? const_cast<float*>(result.features.data.data()) : nullptr;
    auto ptr = [](const PlanarImage& g) { return g.empty() ? nullptr : g.data.data(); };
    render_impl::RasterOutputGrads<float> gout;
    gout.colour = ptr(output_grads.colour);
    gout.depth = ptr(output_grads.depth);
    gout.median_depth = ptr(output_grads.median_depth);
    gout.alpha = ptr(output_grads.alpha);
    gout.features = D > 0 ? ptr(output_grads.features) : nullptr;
    render_impl::SceneGrads<float> g;
    g.means = grads->means.data();
    g.rotations = grads->rotations.data();
    g.log_scales = grads->log_scales.data();
    g.opacity_logits = grads->opacity_logits.data();
    g.sh = grads->sh.data();
    g.features = D > 0 ? grads->features.data() : nullptr;
    g.importance_rgb = grads->importance_rgb.data();
    g.importance_feature = grads->importance_feature.data();
    render_impl::rasterize_backward(render_impl::splat_scene(map), cam, settings.background.data(), D > 0, st, out,
                                    gout, g);
    return true;
  }

 private:
  std::shared_ptr<StatePool> pool_ = std::make_shared<StatePool>();
};

}  // namespace

std::unique_ptr<Rasterizer> make_cpu_rasterizer() { return std::make_unique<CpuRasterizer>(); }

}  // namespace fslam::core

// The CUDA rasteriser: projection, binning, the depth sort, compositing and the backward pass on
// the GPU with core's math, in the CPU rasteriser's order (depth of the mean, ties by id), so both
// composite the same lists and differ only by float rounding and the backward's summation order.
#include <algorithm>
#include <mutex>

#include "fslam/core/error.hpp"
#include "fslam/core/render/rasterize_impl.hpp"
#include "fslam/cuda/cuda_backend.hpp"

#include "cuda_status.hpp"
#include "device_buffer.hpp"
#include "launchers.hpp"

namespace fslam::cuda {
namespace {

namespace math = core::math;
namespace render_impl = core::render_impl;
static_assert(kRasterTile == render_impl::kTileSize, "CPU and CUDA tiles must match");

template <typename T>
cudaError_t upload(DeviceBuffer<T>* buffer, const std::vector<T>& host, cudaStream_t stream) {
  cudaError_t status = buffer->resize(std::max<std::size_t>(host.size(), 1));
  if (status == cudaSuccess && !host.empty()) {
    status = cudaMemcpyAsync(buffer->data(), host.data(), host.size() * sizeof(T), cudaMemcpyHostToDevice, stream);
  }
  return status;
}

// What one forward pass leaves on the device for its backward pass.
struct CudaBackwardState final : core::RenderBackwardState {
  std::size_t count = 0;
  int width = 0, height = 0, tiles_x = 0, tiles_y = 0, feature_dim = 0;
  DeviceBuffer<float> means, rotations, log_scales, opacity_logits, sh, filter_3d, features;
  DeviceBuffer<math::ProjectedGaussian<float>> projected;
  DeviceBuffer<int> rect;
  DeviceBuffer<std::uint32_t> touched;
  DeviceBuffer<std::uint8_t> visible;
  BinBuffers bins;
  DeviceBuffer<float> outputs;  // colour 3, depth, median depth, alpha, then D feature planes
  DeviceBuffer<std::int32_t> pixel_end, pixel_median;
  DeviceBuffer<unsigned long long> counters;
  bool has_filter = false;
  int sh_degree = 0;

  math::SplatScene<float> scene() const {
    return math::splat_scene_of<float>(*this, count, sh_degree, feature_dim, has_filter);
  }
  math::RasterOutputs<float> planes() {
    const std::size_t plane = static_cast<std::size_t>(width) * height;
    math::RasterOutputs<float> out;
    out.colour = outputs.data();
    out.depth = out.colour + 3 * plane;
    out.median_depth = out.depth + plane;
    out.alpha = out.median_depth + plane;
    out.features = out.alpha + plane;
    return out;
  }
};

class CudaRasterizer final : public core::Rasterizer {
 public:
  CudaRasterizer(int device, cudaStream_t stream) : device_(device), stream_(stream) {}
  ~CudaRasterizer() override { cudaStreamDestroy(stream_); }
  std::string name() const override { return "cuda:" + std::to_string(device_); }

  bool forward(const core::GaussianMap& map, const core::RenderView& view, const core::RenderSettings& settings,
               core::RenderResult* result, std::string* why) const override {
    math::SplatCamera<float> cam;
    if (!render_impl::render_camera(view, settings, &cam, why)) return false;
    std::string reason;
    if (!map.is_consistent(&reason)) return core::fail(why, "map: " + reason);
    const int D = settings.features ? map.feature_dim : 0;
    if (D > kMaxFeatureChannels) {
      return core::fail(why, "the CUDA rasteriser renders at most " + std::to_string(kMaxFeatureChannels) +
                                 " feature channels (the map has " + std::to_string(D) + ")");
    }
    const std::lock_guard<std::mutex> lock(mutex_);  // one pass at a time on this stream
    cudaError_t status = cudaSetDevice(device_);
    if (status == cudaSuccess) status = render(map, cam, settings, D, result);
    if (status != cudaSuccess) return core::fail(why, "CUDA render failed (" + describe(status) + ")");
    return true;
  }

  bool backward(const core::GaussianMap& map, const core::RenderView& view, const core::RenderSettings& settings,
                const core::RenderResult& result, const core::RenderGradients& output_grads,
                core::GaussianGradients* grads, std::string* why) const override {
    math::SplatCamera<float> cam;
    int D = 0;
    if (!render_impl::check_backward_inputs(map, view, settings, result, output_grads, &cam, &D, why)) return false;
    auto* state = const_cast<CudaBackwardState*>(dynamic_cast<const CudaBackwardState*>(result.backward_state.get()));
    if (state == nullptr) return core::fail(why, "backward: the result is not from the CUDA rasteriser's forward pass");
    if (state->count != map.size() || state->width != cam.width || state->height != cam.height ||
        state->feature_dim != D) {
      return core::fail(why, "backward: the forward pass was for another map or view");
    }
    if (grads->opacity_logits.size() != map.size()) grads->reset(map);
    const std::lock_guard<std::mutex> lock(mutex_);
    cudaError_t status = cudaSetDevice(device_);
    if (status == cudaSuccess) status = gradients(map, cam, settings, output_grads, state, grads);
    if (status != cudaSuccess) return core::fail(why, "CUDA backward failed (" + describe(status) + ")");
    return true;
  }

 private:
  cudaError_t render(const core::GaussianMap& map, const math::SplatCamera<float>& cam,
                     const core::RenderSettings& settings, int D, core::RenderResult* result) const {
    auto state = std::make_shared<CudaBackwardState>();
    CudaBackwardState& st = *state;
    const std::size_t n = map.size(), slots = std::max<std::size_t>(n, 1);
    st.count = n;
    st.width = cam.width;
    st.height = cam.height;
    st.tiles_x = (cam.width + kRasterTile - 1) / kRasterTile;
    st.tiles_y = (cam.height + kRasterTile - 1) / kRasterTile;
    st.feature_dim = D;
    st.has_filter = !map.filter_3d.empty();
    st.sh_degree = map.sh_degree;
    cudaError_t status = upload(&st.means, map.means, stream_);
    if (status == cudaSuccess) status = upload(&st.rotations, map.rotations, stream_);
    if (status == cudaSuccess) status = upload(&st.log_scales, map.log_scales, stream_);
    if (status == cudaSuccess) status = upload(&st.opacity_logits, map.opacity_logits, stream_);
    if (status == cudaSuccess) status = upload(&st.sh, map.sh, stream_);
    if (status == cudaSuccess) status = upload(&st.filter_3d, map.filter_3d, stream_);
    if (status == cudaSuccess && D > 0) status = upload(&st.features, map.features, stream_);
    if (status == cudaSuccess) status = st.projected.resize(slots);
    if (status == cudaSuccess) status = st.rect.resize(4 * slots);
    if (status == cudaSuccess) status = st.touched.resize(slots);
    if (status == cudaSuccess) status = st.visible.resize(slots);
    const math::SplatScene<float> scene = st.scene();
    if (status == cudaSuccess) {
      status = project_fwd(scene, cam, kRasterTile, st.tiles_x, st.tiles_y, st.projected.data(), st.rect.data(),
                           st.touched.data(), st.visible.data(), stream_);
    }
    std::uint32_t entries = 0;
    if (status == cudaSuccess) {
      status = bin_fwd(static_cast<int>(n), st.projected.data(), st.rect.data(), st.touched.data(), st.tiles_x,
                       st.tiles_y, &st.bins, &entries, stream_);
    }
    const int W = cam.width, H = cam.height;
    const std::size_t plane = static_cast<std::size_t>(W) * H;
    if (status == cudaSuccess) status = st.outputs.resize(plane * (6 + static_cast<std::size_t>(D)));
    if (status == cudaSuccess) status = st.pixel_end.resize(std::max<std::size_t>(plane, 1));
    if (status == cudaSuccess) status = st.pixel_median.resize(std::max<std::size_t>(plane, 1));
    if (status == cudaSuccess) status = st.counters.resize(2);
    if (status == cudaSuccess) {
      status = cudaMemsetAsync(st.counters.data(), 0, 2 * sizeof(unsigned long long), stream_);
    }
    const math::RasterOutputs<float> out = st.planes();
    if (status == cudaSuccess) {
      status = composite_fwd(st.projected.data(), st.bins.ranges.data(), st.bins.sorted_ids.data(), scene.features,
                             D, W, H, st.tiles_x, st.tiles_y, settings.background.data(), out, st.pixel_end.data(),
                             st.pixel_median.data(), st.counters.data(), stream_);
    }
    result->colour = core::PlanarImage(W, H, 3);
    result->depth = core::PlanarImage(W, H, 1);
    result->median_depth = core::PlanarImage(W, H, 1);
    result->alpha = core::PlanarImage(W, H, 1);
    result->features = D > 0 ? core::PlanarImage(W, H, D) : core::PlanarImage();
    result->visible.assign(n, 0);
    unsigned long long counters[2] = {0, 0};
    const auto copy_back = [&](void* host, const void* device, std::size_t bytes) {
      if (status == cudaSuccess && bytes > 0) {
        status = cudaMemcpyAsync(host, device, bytes, cudaMemcpyDeviceToHost, stream_);
      }
    };
    copy_back(result->colour.data.data(), out.colour, 3 * plane * sizeof(float));
    copy_back(result->depth.data.data(), out.depth, plane * sizeof(float));
    copy_back(result->median_depth.data.data(), out.median_depth, plane * sizeof(float));
    copy_back(result->alpha.data.data(), out.alpha, plane * sizeof(float));
    copy_back(result->features.data.data(), out.features, static_cast<std::size_t>(D) * plane * sizeof(float));
    copy_back(result->visible.data(), st.visible.data(), n);
    copy_back(counters, st.counters.data(), sizeof(counters));
    if (status == cudaSuccess) status = cudaStreamSynchronize(stream_);
    if (status != cudaSuccess) return status;
    result->stats.gaussians = n;
    result->stats.pixels = plane;
    result->stats.visible = static_cast<std::size_t>(std::count(result->visible.begin(), result->visible.end(), 1));
    result->stats.tile_entries = entries;
    result->stats.evaluated_pairs = counters[0];
    result->stats.blend_steps = counters[1];
    result->backward_state = std::move(state);
    return cudaSuccess;
  }

  cudaError_t gradients(const core::GaussianMap& map, const math::SplatCamera<float>& cam,
                        const core::RenderSettings& settings, const core::RenderGradients& output_grads,
                        CudaBackwardState* st, core::GaussianGradients* grads) const {
    const int D = st->feature_dim;
    const std::size_t n = st->count;
    if (n == 0) return cudaSuccess;
    // The output gradients on the device (empty images are zero gradients).
    DeviceBuffer<float> g_colour, g_depth, g_median, g_alpha, g_features;
    math::RasterOutputGrads<float> view;
    cudaError_t status = cudaSuccess;
    const auto put = [&](DeviceBuffer<float>* buffer, const core::PlanarImage& image, const float** pointer) {
      if (status != cudaSuccess || image.empty()) return;
      status = upload(buffer, image.data, stream_);
      *pointer = buffer->data();
    };
    put(&g_colour, output_grads.colour, &view.colour);
    put(&g_depth, output_grads.depth, &view.depth);
    put(&g_median, output_grads.median_depth, &view.median_depth);
    put(&g_alpha, output_grads.alpha, &view.alpha);
    if (D > 0) put(&g_features, output_grads.features, &view.features);
    const int stride = math::kGrad2dFixed + D;
    const int K = (map.sh_degree + 1) * (map.sh_degree + 1);
    const int P = 11 + 3 * K + D + 2;
    DeviceBuffer<float> accum, per_gaussian;
    if (status == cudaSuccess) status = accum.resize(n * stride);
    if (status == cudaSuccess) status = cudaMemsetAsync(accum.data(), 0, n * stride * sizeof(float), stream_);
    if (status == cudaSuccess) status = per_gaussian.resize(n * P);
    const math::SplatScene<float> scene = st->scene();
    if (status == cudaSuccess) {
      status = composite_bwd(st->projected.data(), st->bins.ranges.data(), st->bins.sorted_ids.data(), scene.features,
                             D, st->width, st->height, st->tiles_x, st->tiles_y, settings.background.data(),
                             st->planes(), st->pixel_end.data(), st->pixel_median.data(), view, accum.data(), stream_);
    }
    if (status == cudaSuccess) status = project_bwd(scene, cam, st->projected.data(), accum.data(), D, per_gaussian.data(), stream_);
    std::vector<float> host(n * P);
    if (status == cudaSuccess) {
      status = cudaMemcpyAsync(host.data(), per_gaussian.data(), host.size() * sizeof(float), cudaMemcpyDeviceToHost,
                               stream_);
    }
    if (status == cudaSuccess) status = cudaStreamSynchronize(stream_);
    if (status != cudaSuccess) return status;
    const int sh_stride = 3 * K;
    for (std::size_t i = 0; i < n; ++i) {
      const float* o = &host[i * P];
      for (int k = 0; k < 3; ++k) grads->means[3 * i + k] += o[k];
      for (int k = 0; k < 4; ++k) grads->rotations[4 * i + k] += o[3 + k];
      for (int k = 0; k < 3; ++k) grads->log_scales[3 * i + k] += o[7 + k];
      grads->opacity_logits[i] += o[10];
      for (int k = 0; k < sh_stride; ++k) grads->sh[i * sh_stride + k] += o[11 + k];
      for (int c = 0; c < D; ++c) grads->features[i * map.feature_dim + c] += o[11 + sh_stride + c];
      grads->importance_rgb[i] += o[11 + sh_stride + D];
      grads->importance_feature[i] += o[12 + sh_stride + D];
    }
    return cudaSuccess;
  }

  int device_;
  cudaStream_t stream_;
  mutable std::mutex mutex_;
};

}  // namespace

std::unique_ptr<core::Rasterizer> make_cuda_rasterizer(int device, std::string* why) {
  std::string reason;
  const int count = usable_device_count(&reason);
  if (device < 0 || device >= count) {
    core::fail(why, count == 0 ? reason
                               : "CUDA device " + std::to_string(device) + " does not exist (" +
                                     std::to_string(count) + " found)");
    return nullptr;
  }
  cudaStream_t stream = nullptr;
  cudaError_t status = cudaSetDevice(device);
  if (status == cudaSuccess) status = cudaStreamCreateWithFlags(&stream, cudaStreamNonBlocking);
  if (status != cudaSuccess) {
    core::fail(why, describe(status));
    return nullptr;
  }
  return std::make_unique<CudaRasterizer>(device, stream);
}

}  // namespace fslam::cuda

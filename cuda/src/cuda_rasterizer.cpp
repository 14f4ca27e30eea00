// The CUDA rasteriser: projection, binning, the depth sort and compositing on the GPU with core's
// math, in the CPU rasteriser's order (depth of the mean, ties by id), so both composite the same
// lists. Forward only: gradients (mapping) run on the CPU.
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
    const std::lock_guard<std::mutex> lock(mutex_);  // one render at a time on this stream
    cudaError_t status = cudaSetDevice(device_);
    if (status == cudaSuccess) status = render(map, cam, settings, D, result);
    if (status != cudaSuccess) return core::fail(why, "CUDA render failed (" + describe(status) + ")");
    return true;
  }

  bool backward(const core::GaussianMap&, const core::RenderView&, const core::RenderSettings&,
                const core::RenderResult&, const core::RenderGradients&, core::GaussianGradients*,
                std::string* why) const override {
    return core::fail(why, "the CUDA rasteriser renders only (no backward pass yet); mapping uses the CPU rasteriser");
  }

 private:
  cudaError_t render(const core::GaussianMap& map, const math::SplatCamera<float>& cam,
                     const core::RenderSettings& settings, int D, core::RenderResult* result) const {
    const std::size_t n = map.size(), slots = std::max<std::size_t>(n, 1);
    const int W = cam.width, H = cam.height;
    const int tiles_x = (W + kRasterTile - 1) / kRasterTile, tiles_y = (H + kRasterTile - 1) / kRasterTile;
    cudaError_t status = upload(&means_, map.means, stream_);
    if (status == cudaSuccess) status = upload(&rotations_, map.rotations, stream_);
    if (status == cudaSuccess) status = upload(&log_scales_, map.log_scales, stream_);
    if (status == cudaSuccess) status = upload(&opacity_logits_, map.opacity_logits, stream_);
    if (status == cudaSuccess) status = upload(&sh_, map.sh, stream_);
    if (status == cudaSuccess) status = upload(&filter_3d_, map.filter_3d, stream_);
    if (status == cudaSuccess && D > 0) status = upload(&features_, map.features, stream_);
    if (status == cudaSuccess) status = projected_.resize(slots);
    if (status == cudaSuccess) status = rect_.resize(4 * slots);
    if (status == cudaSuccess) status = touched_.resize(slots);
    if (status == cudaSuccess) status = visible_.resize(slots);
    math::SplatScene<float> scene;
    scene.count = n;
    scene.means = means_.data();
    scene.rotations = rotations_.data();
    scene.log_scales = log_scales_.data();
    scene.opacity_logits = opacity_logits_.data();
    scene.sh = sh_.data();
    scene.features = D > 0 ? features_.data() : nullptr;
    scene.filter_3d = map.filter_3d.empty() ? nullptr : filter_3d_.data();
    scene.sh_degree = map.sh_degree;
    scene.feature_dim = D;
    if (status == cudaSuccess) {
      status = project_fwd(scene, cam, kRasterTile, tiles_x, tiles_y, projected_.data(), rect_.data(),
                           touched_.data(), visible_.data(), stream_);
    }
    std::uint32_t entries = 0;
    if (status == cudaSuccess) {
      status = bin_fwd(static_cast<int>(n), projected_.data(), rect_.data(), touched_.data(), tiles_x, tiles_y,
                       &bins_, &entries, stream_);
    }
    const std::size_t plane = static_cast<std::size_t>(W) * H;
    if (status == cudaSuccess) status = outputs_.resize(plane * (6 + static_cast<std::size_t>(D)));
    if (status == cudaSuccess) status = counters_.resize(2);
    if (status == cudaSuccess) {
      status = cudaMemsetAsync(counters_.data(), 0, 2 * sizeof(unsigned long long), stream_);
    }
    math::RasterOutputs<float> out;
    out.colour = outputs_.data();
    out.depth = out.colour + 3 * plane;
    out.median_depth = out.depth + plane;
    out.alpha = out.median_depth + plane;
    out.features = out.alpha + plane;
    if (status == cudaSuccess) {
      status = composite_fwd(projected_.data(), bins_.ranges.data(), bins_.sorted_ids.data(), scene.features, D, W,
                             H, tiles_x, tiles_y, settings.background.data(), out, counters_.data(), stream_);
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
    copy_back(result->visible.data(), visible_.data(), n);
    copy_back(counters, counters_.data(), sizeof(counters));
    if (status == cudaSuccess) status = cudaStreamSynchronize(stream_);
    if (status != cudaSuccess) return status;
    result->stats.gaussians = n;
    result->stats.pixels = plane;
    result->stats.visible = static_cast<std::size_t>(std::count(result->visible.begin(), result->visible.end(), 1));
    result->stats.tile_entries = entries;
    result->stats.evaluated_pairs = counters[0];
    result->stats.blend_steps = counters[1];
    result->backward_state = nullptr;
    return cudaSuccess;
  }

  int device_;
  cudaStream_t stream_;
  mutable std::mutex mutex_;
  // Device copies of the map and the render's buffers, grown as needed and reused.
  mutable DeviceBuffer<float> means_, rotations_, log_scales_, opacity_logits_, sh_, filter_3d_, features_;
  mutable DeviceBuffer<math::ProjectedGaussian<float>> projected_;
  mutable DeviceBuffer<int> rect_;
  mutable DeviceBuffer<std::uint32_t> touched_;
  mutable DeviceBuffer<std::uint8_t> visible_;
  mutable BinBuffers bins_;
  mutable DeviceBuffer<float> outputs_;
  mutable DeviceBuffer<unsigned long long> counters_;
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

#include "fslam/cuda/cuda_backend.hpp"

#include "cuda_status.hpp"
#include "device_buffer.hpp"
#include "launchers.hpp"

namespace fslam::cuda {
namespace {

class CudaBackend final : public core::ComputeBackend {
 public:
  CudaBackend(int device, cudaStream_t stream) : device_(device), stream_(stream) {}
  ~CudaBackend() override { cudaStreamDestroy(stream_); }

  std::string name() const override { return "cuda:" + std::to_string(device_); }

  bool unproject_depth(const cv::Mat& depth, const core::PinholeCamera& camera,
                       const core::DepthRange& range, std::vector<float>* points,
                       std::string* why) override {
    if (!core::check_unproject_inputs(depth, camera, why)) return false;
    const cv::Mat d = depth.isContinuous() ? depth : depth.clone();
    const std::size_t n = d.total();
    cudaError_t status = cudaSetDevice(device_);
    if (status == cudaSuccess) status = depth_.resize(n);
    if (status == cudaSuccess) status = points_.resize(3 * n);
    if (status == cudaSuccess)
      status = cudaMemcpyAsync(depth_.data(), d.ptr<float>(), n * sizeof(float),
                               cudaMemcpyHostToDevice, stream_);
    if (status == cudaSuccess)
      status = unproject_depth_fwd(camera.intrinsics(), depth_.data(), d.cols, d.rows,
                                   range.min_depth, range.max_depth, points_.data(), stream_);
    points->resize(3 * n);
    if (status == cudaSuccess)
      status = cudaMemcpyAsync(points->data(), points_.data(), 3 * n * sizeof(float),
                               cudaMemcpyDeviceToHost, stream_);
    if (status == cudaSuccess) status = cudaStreamSynchronize(stream_);
    if (status != cudaSuccess) {
      if (why) *why = "CUDA unproject_depth failed (" + describe(status) + ")";
      return false;
    }
    return true;
  }

 private:
  int device_;
  cudaStream_t stream_;
  DeviceBuffer<float> depth_;   // [H * W] metres
  DeviceBuffer<float> points_;  // [H * W * 3] camera frame
};

}  // namespace

int usable_device_count(std::string* why) {
  int count = 0;
  const cudaError_t status = cudaGetDeviceCount(&count);
  if (status != cudaSuccess) {
    if (why) *why = describe(status);
    return 0;
  }
  if (count == 0 && why) *why = "no CUDA device found";
  return count;
}

std::unique_ptr<core::ComputeBackend> make_cuda_backend(int device, std::string* why) {
  std::string reason;
  const int count = usable_device_count(&reason);
  if (device < 0 || device >= count) {
    if (why)
      *why = count == 0 ? reason
                        : "CUDA device " + std::to_string(device) + " does not exist (" +
                              std::to_string(count) + " found)";
    return nullptr;
  }
  cudaStream_t stream = nullptr;
  cudaError_t status = cudaSetDevice(device);
  if (status == cudaSuccess) status = cudaStreamCreateWithFlags(&stream, cudaStreamNonBlocking);
  if (status != cudaSuccess) {
    if (why) *why = describe(status);
    return nullptr;
  }
  return std::make_unique<CudaBackend>(device, stream);
}

}  // namespace fslam::cuda

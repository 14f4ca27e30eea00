#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "fslam/core/compute/backend.hpp"
#include "fslam/core/math/unproject.hpp"

namespace fslam::core {

bool check_unproject_inputs(const cv::Mat& depth, const PinholeCamera& camera, std::string* why) {
  if (depth.empty() || depth.type() != CV_32FC1) {
    if (why) *why = "depth must be a non-empty CV_32FC1 image in metres";
    return false;
  }
  std::string reason;
  if (!camera.is_valid(&reason)) {
    if (why) *why = "bad intrinsics: " + reason;
    return false;
  }
  if (depth.cols != camera.width || depth.rows != camera.height) {
    if (why)
      *why = "depth is " + std::to_string(depth.cols) + "x" + std::to_string(depth.rows) +
             " but the camera is " + std::to_string(camera.width) + "x" +
             std::to_string(camera.height);
    return false;
  }
  return true;
}

namespace {

class CpuBackend final : public ComputeBackend {
 public:
  std::string name() const override { return "cpu"; }

  bool unproject_depth(const cv::Mat& depth, const PinholeCamera& camera, const DepthRange& range,
                       std::vector<float>* points, std::string* why) override {
    if (!check_unproject_inputs(depth, camera, why)) return false;
    const cv::Mat d = depth.isContinuous() ? depth : depth.clone();
    const int width = d.cols;
    const math::Intrinsics k = camera.intrinsics();
    points->resize(static_cast<std::size_t>(d.total()) * 3);
    const float* src = d.ptr<float>();
    float* dst = points->data();
    tbb::parallel_for(tbb::blocked_range<int>(0, d.rows), [&](const tbb::blocked_range<int>& r) {
      for (int v = r.begin(); v < r.end(); ++v)
        for (int u = 0; u < width; ++u)
          math::unproject_depth_pixel(k, src, width, v * width + u, range.min_depth,
                                      range.max_depth, dst);
    });
    return true;
  }
};

}  // namespace

std::unique_ptr<ComputeBackend> make_cpu_backend() { return std::make_unique<CpuBackend>(); }

}  // namespace fslam::core

// Coarse per-frame compute operations with a CPU implementation here and a CUDA one in cuda/.
// Both run the same host/device math (fslam/core/math), so CPU tests exercise the GPU's math.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/pinhole_camera.hpp"

namespace fslam::core {

struct DepthRange {
  float min_depth = 0.1f;  // metres; samples at or below are missing
  float max_depth = 10.0f; // metres; samples at or beyond are missing
};

class ComputeBackend {
 public:
  virtual ~ComputeBackend() = default;
  virtual std::string name() const = 0;

  // depth: [H, W] CV_32FC1 metres -> points: [H * W * 3] float, camera frame, row-major pixel
  // order, NaN where the depth is missing or outside `range`. False with `why` on bad input.
  virtual bool unproject_depth(const cv::Mat& depth, const PinholeCamera& camera,
                               const DepthRange& range, std::vector<float>* points,
                               std::string* why) = 0;
};

// The CPU backend (TBB over rows).
std::unique_ptr<ComputeBackend> make_cpu_backend();

// Shared input validation for every backend's unproject_depth.
bool check_unproject_inputs(const cv::Mat& depth, const PinholeCamera& camera, std::string* why);

}  // namespace fslam::core

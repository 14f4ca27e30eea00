// A check of a relative pose that needs no ground truth: frame a's depth samples, moved into
// frame b by T_b_a and projected, against frame b's own depth where they land. A pose that is
// right leaves only sensor noise and occlusion edges; a pose off by a few centimetres shows as a
// larger median |dz| and fewer samples within `inlier_distance` (docs/evaluation.md, "Depth
// agreement"). `fslam eval --dataset` scores every step of an estimate and of the ground truth.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "fslam/core/eval/ate.hpp"
#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::core {

struct DepthAgreementConfig {
  int stride = 4;                 // pixels between samples of frame a, both axes
  double inlier_distance = 0.05;  // m; |dz| below it counts as agreeing
};
bool validate(const DepthAgreementConfig& config, std::string* why);

struct DepthAgreement {
  std::size_t samples = 0;       // samples of a with depth that land on a pixel of b with depth
  double median_abs_m = 0.0;     // median |z_b(pixel) - z of the moved sample|, metres
  double inlier_fraction = 0.0;  // share of `samples` with |dz| < inlier_distance
};

// Both depths CV_32FC1 in metres (0 or non-finite = missing), the camera's size. Fails on a
// wrong type or size, an invalid camera or config, or when no sample lands on depth in b.
bool depth_agreement(const cv::Mat& depth_a, const cv::Mat& depth_b, const PinholeCamera& camera,
                     const Eigen::Isometry3d& T_b_a, const DepthAgreementConfig& config,
                     DepthAgreement* result, std::string* why);

class Dataset;

// One step of a trajectory scored both ways: the same two frames under the ground truth's and
// under the estimate's relative pose.
struct DepthAgreementStep {
  std::int64_t frame_a = 0;  // RgbdFrame::id of the two frames
  std::int64_t frame_b = 0;
  DepthAgreement ground_truth;
  DepthAgreement estimate;
};

// Steps (k, k + delta) over the poses `association` pairs between `gt` and `est`, in time order;
// each pose's frame is the dataset's frame at the estimate's timestamp (within the association's
// max_difference). Fails when a frame is missing or unreadable, or no step can be scored.
// `progress(done, total)` is called after each step when given.
bool depth_agreement_steps(const Dataset& dataset, const Trajectory& gt, const Trajectory& est,
                           const AssociationConfig& association, std::size_t delta,
                           const DepthAgreementConfig& config,
                           std::vector<DepthAgreementStep>* steps, std::string* why,
                           const std::function<void(std::size_t, std::size_t)>& progress = {});

}  // namespace fslam::core

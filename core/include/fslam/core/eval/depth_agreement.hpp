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

// The signed residuals z_b(pixel) - z of the moved sample (agreeing samples only: |dz| under
// inlier_distance), binned by the pixel of b they land on (a cols x rows grid over the image) and
// by z_b. Over many steps a wrong pose averages out while a sensor's depth distortion, fixed to
// the pixel and growing with depth, stays: the median per cell then maps it (docs/evaluation.md,
// "Residual grid"). Bins: below depth_edges[0], between consecutive edges, above the last.
struct DepthResidualGrid {
  int cols = 8;
  int rows = 6;
  std::vector<double> depth_edges = {1.0, 1.5, 2.0, 2.5, 3.0};  // metres, increasing
  std::vector<std::vector<float>> cells;  // [(bin * rows + row) * cols + col]: metres, filled by add

  int bins() const { return static_cast<int>(depth_edges.size()) + 1; }
  // Adds one residual dz (metres) of a sample landing at pixel (u, v) of a width x height image
  // with depth z_b.
  void add(int u, int v, int width, int height, double z_b, double dz);
  // The median of a cell, metres; NaN with fewer than min_samples.
  double median(int bin, int row, int col, std::size_t min_samples) const;
  std::size_t count(int bin, int row, int col) const;

 private:
  std::size_t index(int bin, int row, int col) const {
    return static_cast<std::size_t>((bin * rows + row) * cols + col);
  }
};

bool validate(const DepthResidualGrid& grid, std::string* why);

// Both depths CV_32FC1 in metres (0 or non-finite = missing), the camera's size. Fails on a
// wrong type or size, an invalid camera or config, or when no sample lands on depth in b.
// grid (optional): the step's signed residuals are added to it.
bool depth_agreement(const cv::Mat& depth_a, const cv::Mat& depth_b, const PinholeCamera& camera,
                     const Eigen::Isometry3d& T_b_a, const DepthAgreementConfig& config,
                     DepthAgreement* result, std::string* why, DepthResidualGrid* grid = nullptr);

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
// `progress(done, total)` is called after each step when given. gt_residuals / est_residuals
// (optional): every step's signed residuals under each side's poses.
bool depth_agreement_steps(const Dataset& dataset, const Trajectory& gt, const Trajectory& est,
                           const AssociationConfig& association, std::size_t delta,
                           const DepthAgreementConfig& config,
                           std::vector<DepthAgreementStep>* steps, std::string* why,
                           const std::function<void(std::size_t, std::size_t)>& progress = {},
                           DepthResidualGrid* gt_residuals = nullptr,
                           DepthResidualGrid* est_residuals = nullptr);

}  // namespace fslam::core

// Absolute trajectory error (ATE) as the TUM RGB-D benchmark's evaluate_ate.py computes it:
// greedy timestamp association, closed-form alignment of the estimate onto the ground truth,
// statistics of the per-pose translational error. docs/evaluation.md states the protocol.
#pragma once

#include <cstddef>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::core {

// Summary of a list of errors with numpy's conventions: population standard deviation (ddof 0),
// the median of an even count is the mean of the two middle values.
struct ErrorStats {
  std::size_t count = 0;
  double rmse = 0.0;    // sqrt(mean(e^2))
  double mean = 0.0;
  double median = 0.0;
  double std = 0.0;     // sqrt(mean((e - mean)^2))
  double min = 0.0;
  double max = 0.0;
};
// All zero for an empty list.
ErrorStats summarize_errors(const std::vector<double>& errors);

// TUM associate.py parameters (fslam/core/geometry/associate.hpp implements the algorithm).
struct AssociationConfig {
  double max_difference = 0.02;  // seconds; a pair needs |t_gt - (t_est + offset)| < this
  double offset = 0.0;           // seconds added to every estimate timestamp
};
bool validate(const AssociationConfig& config, std::string* why);

// One-to-one (gt index, est index) pairs by greedy timestamp association, in gt-time order.
std::vector<std::pair<std::size_t, std::size_t>> associate_trajectories(
    const Trajectory& gt, const Trajectory& est, const AssociationConfig& config);

// How the estimate is mapped onto the ground truth before errors are taken.
enum class Alignment {
  kSE3,   // rotation + translation (Horn / Umeyama without scale): RGB-D and stereo
  kSim3,  // rotation + translation + scale (Umeyama with scale): monocular
};
const char* to_string(Alignment alignment);

struct AteConfig {
  AssociationConfig association;
  Alignment alignment = Alignment::kSE3;
};
bool validate(const AteConfig& config, std::string* why);

struct AteResult {
  Alignment alignment = Alignment::kSE3;
  std::size_t pairs = 0;  // associated poses, all of which enter the statistics
  double rmse = 0.0;      // metres, sqrt(mean(e^2)); never report `mean` as RMSE
  double mean = 0.0;      // metres
  double median = 0.0;    // metres
  double std = 0.0;       // metres, population standard deviation
  double min = 0.0;       // metres
  double max = 0.0;       // metres
  // Alignment: p_gt ~ T_gt_est * (scale * p_est). scale is 1 under SE(3).
  double scale = 1.0;
  Eigen::Isometry3d T_gt_est = Eigen::Isometry3d::Identity();
  std::vector<std::size_t> gt_indices;       // [pairs] into the gt trajectory, gt-time order
  std::vector<std::size_t> est_indices;      // [pairs] into the estimate
  std::vector<Eigen::Vector3d> est_aligned;  // [pairs] aligned estimate positions, gt world, metres
  std::vector<double> errors;                // [pairs] metres, |aligned est - gt|
};

// Associates, aligns (closed form over all pairs) and measures. Fails on an invalid config,
// non-finite poses or timestamps, or fewer than 3 associated pairs (alignment undetermined).
bool compute_ate(const Trajectory& gt, const Trajectory& est, const AteConfig& config,
                 AteResult* result, std::string* why);

// Closed-form least-squares alignment (Umeyama 1991; Horn 1987 without scale) of the columns
// of `source` onto `destination` ([3, N] each, N >= 3): destination ~ T * (scale * source).
// Reflections are excluded (det R = +1).
void align_points(const Eigen::Matrix3Xd& source, const Eigen::Matrix3Xd& destination,
                  Alignment alignment, Eigen::Isometry3d* T, double* scale);

}  // namespace fslam::core

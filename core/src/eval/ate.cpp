#include "fslam/core/eval/ate.hpp"

#include "fslam/core/error.hpp"

#include <algorithm>
#include <cmath>

#include "fslam/core/geometry/associate.hpp"
#include "fslam/core/geometry/se3.hpp"

namespace fslam::core {
namespace {

// Index of the first pose with a non-finite timestamp or transform, or size() when all are finite.
std::size_t first_non_finite(const Trajectory& trajectory) {
  for (std::size_t i = 0; i < trajectory.size(); ++i)
    if (!std::isfinite(trajectory[i].timestamp) || !is_finite(trajectory[i].T_world_camera))
      return i;
  return trajectory.size();
}

std::vector<double> timestamps(const Trajectory& trajectory) {
  std::vector<double> stamps(trajectory.size());
  for (std::size_t i = 0; i < trajectory.size(); ++i) stamps[i] = trajectory[i].timestamp;
  return stamps;
}

}  // namespace

ErrorStats summarize_errors(const std::vector<double>& errors) {
  ErrorStats s;
  s.count = errors.size();
  if (errors.empty()) return s;
  const double n = static_cast<double>(errors.size());
  double sum = 0.0, sum_sq = 0.0;
  for (double e : errors) {
    sum += e;
    sum_sq += e * e;
  }
  s.mean = sum / n;
  s.rmse = std::sqrt(sum_sq / n);
  double var = 0.0;  // two-pass: sum_sq / n - mean^2 cancels badly for tight distributions
  for (double e : errors) var += (e - s.mean) * (e - s.mean);
  s.std = std::sqrt(var / n);
  std::vector<double> sorted = errors;
  std::sort(sorted.begin(), sorted.end());
  const std::size_t mid = sorted.size() / 2;
  s.median = sorted.size() % 2 ? sorted[mid] : 0.5 * (sorted[mid - 1] + sorted[mid]);
  s.min = sorted.front();
  s.max = sorted.back();
  return s;
}

bool validate(const AssociationConfig& config, std::string* why) {
  if (!(config.max_difference > 0.0) || !std::isfinite(config.max_difference))
    return fail(why, "association max_difference must be a positive number of seconds, got " +
                         std::to_string(config.max_difference));
  if (!std::isfinite(config.offset)) return fail(why, "association offset must be finite");
  return true;
}

std::vector<std::pair<std::size_t, std::size_t>> associate_trajectories(
    const Trajectory& gt, const Trajectory& est, const AssociationConfig& config) {
  // evaluate_ate.py: associate(first_list = gt, second_list = est, offset, max_difference).
  return associate_timestamps(timestamps(gt), timestamps(est), config.offset,
                              config.max_difference);
}

const char* to_string(Alignment alignment) {
  switch (alignment) {
    case Alignment::kSE3: return "SE(3)";
    case Alignment::kSim3: return "Sim(3)";
  }
  return "unknown";
}

bool validate(const AteConfig& config, std::string* why) {
  if (config.alignment != Alignment::kSE3 && config.alignment != Alignment::kSim3)
    return fail(why, "unknown ATE alignment");
  return validate(config.association, why);
}

void align_points(const Eigen::Matrix3Xd& source, const Eigen::Matrix3Xd& destination,
                  Alignment alignment, Eigen::Isometry3d* T, double* scale) {
  // Eigen::umeyama returns [c R, t; 0 1] with S = diag(1, 1, -1) when det(U) det(V) < 0, the same
  // reflection guard as evaluate_ate.py's align().
  const Eigen::Matrix4d M =
      Eigen::umeyama(source, destination, alignment == Alignment::kSim3);
  const Eigen::Matrix3d cR = M.topLeftCorner<3, 3>();
  const double c = alignment == Alignment::kSim3 ? std::cbrt(cR.determinant()) : 1.0;
  T->setIdentity();
  T->linear() = cR / c;
  T->translation() = M.topRightCorner<3, 1>();
  *scale = c;
}

bool compute_ate(const Trajectory& gt, const Trajectory& est, const AteConfig& config,
                 AteResult* result, std::string* why) {
  if (!validate(config, why)) return false;
  if (const std::size_t i = first_non_finite(gt); i < gt.size())
    return fail(why, "ground-truth pose " + std::to_string(i) + " is not finite");
  if (const std::size_t i = first_non_finite(est); i < est.size())
    return fail(why, "estimated pose " + std::to_string(i) + " is not finite");

  const auto matches = associate_trajectories(gt, est, config.association);
  if (matches.size() < 3)
    return fail(why, "only " + std::to_string(matches.size()) +
                         " poses associated (need 3 to align; ground truth has " +
                         std::to_string(gt.size()) + ", estimate " + std::to_string(est.size()) +
                         ", max difference " + std::to_string(config.association.max_difference) +
                         " s): are the timestamps in the same clock?");

  const auto n = static_cast<Eigen::Index>(matches.size());
  Eigen::Matrix3Xd p_gt(3, n), p_est(3, n);
  AteResult r;
  r.alignment = config.alignment;
  r.pairs = matches.size();
  r.gt_indices.reserve(matches.size());
  r.est_indices.reserve(matches.size());
  for (Eigen::Index k = 0; k < n; ++k) {
    const auto [i, j] = matches[static_cast<std::size_t>(k)];
    p_gt.col(k) = gt[i].T_world_camera.translation();
    p_est.col(k) = est[j].T_world_camera.translation();
    r.gt_indices.push_back(i);
    r.est_indices.push_back(j);
  }

  align_points(p_est, p_gt, config.alignment, &r.T_gt_est, &r.scale);

  r.est_aligned.resize(matches.size());
  r.errors.resize(matches.size());
  for (Eigen::Index k = 0; k < n; ++k) {
    const auto s = static_cast<std::size_t>(k);
    r.est_aligned[s] = r.T_gt_est * (r.scale * p_est.col(k));
    r.errors[s] = (r.est_aligned[s] - p_gt.col(k)).norm();
  }
  const ErrorStats stats = summarize_errors(r.errors);
  r.rmse = stats.rmse;
  r.mean = stats.mean;
  r.median = stats.median;
  r.std = stats.std;
  r.min = stats.min;
  r.max = stats.max;
  *result = std::move(r);
  return true;
}

}  // namespace fslam::core

#include "fslam/core/eval/depth_agreement.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <utility>
#include <vector>

#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/eval/percentile.hpp"
#include "fslam/core/geometry/rgbd_frame.hpp"

namespace fslam::core {

bool validate(const DepthAgreementConfig& config, std::string* why) {
  if (config.stride < 1) {
    if (why) *why = "depth agreement: stride must be >= 1";
    return false;
  }
  if (!(config.inlier_distance > 0.0) || !std::isfinite(config.inlier_distance)) {
    if (why) *why = "depth agreement: inlier_distance must be positive and finite";
    return false;
  }
  return true;
}

namespace {

bool check_depth(const cv::Mat& depth, const PinholeCamera& camera, const char* name,
                 std::string* why) {
  if (depth.type() != CV_32FC1 || depth.cols != camera.width || depth.rows != camera.height) {
    if (why)
      *why = std::string("depth agreement: depth of frame ") + name + " must be CV_32FC1 of " +
             std::to_string(camera.width) + "x" + std::to_string(camera.height) + " (got " +
             std::to_string(depth.cols) + "x" + std::to_string(depth.rows) + ", type " +
             std::to_string(depth.type()) + ")";
    return false;
  }
  return true;
}

bool has_depth(float z) { return std::isfinite(z) && z > 0.0f; }

}  // namespace

bool validate(const DepthResidualGrid& grid, std::string* why) {
  if (grid.cols < 1 || grid.rows < 1) {
    if (why) *why = "depth residual grid: cols and rows must be >= 1";
    return false;
  }
  for (std::size_t i = 0; i < grid.depth_edges.size(); ++i) {
    if (!std::isfinite(grid.depth_edges[i]) || (i > 0 && !(grid.depth_edges[i] > grid.depth_edges[i - 1]))) {
      if (why) *why = "depth residual grid: depth_edges must be finite and increasing";
      return false;
    }
  }
  return true;
}

void DepthResidualGrid::add(int u, int v, int width, int height, double z_b, double dz) {
  if (cells.empty()) cells.resize(static_cast<std::size_t>(bins() * rows * cols));
  const int bin = static_cast<int>(std::upper_bound(depth_edges.begin(), depth_edges.end(), z_b) -
                                   depth_edges.begin());
  const int col = std::clamp(u * cols / width, 0, cols - 1);
  const int row = std::clamp(v * rows / height, 0, rows - 1);
  cells[index(bin, row, col)].push_back(static_cast<float>(dz));
}

std::size_t DepthResidualGrid::count(int bin, int row, int col) const {
  if (cells.empty()) return 0;
  return cells[index(bin, row, col)].size();
}

double DepthResidualGrid::median(int bin, int row, int col, std::size_t min_samples) const {
  if (count(bin, row, col) < std::max<std::size_t>(min_samples, 1))
    return std::numeric_limits<double>::quiet_NaN();
  const std::vector<float>& c = cells[index(bin, row, col)];
  return percentile(std::vector<double>(c.begin(), c.end()), 0.5);
}

bool depth_agreement(const cv::Mat& depth_a, const cv::Mat& depth_b, const PinholeCamera& camera,
                     const Eigen::Isometry3d& T_b_a, const DepthAgreementConfig& config,
                     DepthAgreement* result, std::string* why, DepthResidualGrid* grid) {
  if (!validate(config, why)) return false;
  std::string camera_why;
  if (!camera.is_valid(&camera_why)) {
    if (why) *why = "depth agreement: " + camera_why;
    return false;
  }
  if (!check_depth(depth_a, camera, "a", why) || !check_depth(depth_b, camera, "b", why))
    return false;
  if (!T_b_a.matrix().allFinite()) {
    if (why) *why = "depth agreement: the relative pose is not finite";
    return false;
  }
  if (grid != nullptr && !validate(*grid, why)) return false;

  std::vector<double> residuals;
  residuals.reserve(static_cast<std::size_t>(camera.width / config.stride + 1) *
                    static_cast<std::size_t>(camera.height / config.stride + 1));
  for (int v = 0; v < camera.height; v += config.stride) {
    const float* row = depth_a.ptr<float>(v);
    for (int u = 0; u < camera.width; u += config.stride) {
      if (!has_depth(row[u])) continue;
      const Eigen::Vector3d p_b = T_b_a * camera.unproject(Eigen::Vector2d(u, v), row[u]);
      if (!(p_b.z() > 0.0)) continue;
      const Eigen::Vector2d pixel = camera.project(p_b);
      const int ub = static_cast<int>(std::lround(pixel.x()));
      const int vb = static_cast<int>(std::lround(pixel.y()));
      if (ub < 0 || vb < 0 || ub >= camera.width || vb >= camera.height) continue;
      const float z_b = depth_b.at<float>(vb, ub);
      if (!has_depth(z_b)) continue;
      const double dz = static_cast<double>(z_b) - p_b.z();
      residuals.push_back(std::abs(dz));
      if (grid != nullptr && std::abs(dz) < config.inlier_distance)
        grid->add(ub, vb, camera.width, camera.height, z_b, dz);
    }
  }
  if (residuals.empty()) {
    if (why) *why = "depth agreement: no sample of frame a lands on depth in frame b";
    return false;
  }
  const std::size_t inliers = static_cast<std::size_t>(
      std::count_if(residuals.begin(), residuals.end(),
                    [&](double r) { return r < config.inlier_distance; }));
  result->samples = residuals.size();
  result->median_abs_m = percentile(std::move(residuals), 0.5);
  result->inlier_fraction = static_cast<double>(inliers) / static_cast<double>(result->samples);
  return true;
}

bool depth_agreement_steps(const Dataset& dataset, const Trajectory& gt, const Trajectory& est,
                           const AssociationConfig& association, std::size_t delta,
                           const DepthAgreementConfig& config,
                           std::vector<DepthAgreementStep>* steps, std::string* why,
                           const std::function<void(std::size_t, std::size_t)>& progress,
                           DepthResidualGrid* gt_residuals, DepthResidualGrid* est_residuals) {
  steps->clear();
  if (delta < 1) {
    if (why) *why = "depth agreement: the step must be >= 1 frame";
    return false;
  }
  if (!validate(config, why) || !validate(association, why)) return false;
  Trajectory stamps(dataset.size());  // the dataset's frame times (poses unused)
  for (std::size_t i = 0; i < stamps.size(); ++i) stamps[i].timestamp = dataset.timestamp(i);

  const auto pairs = associate_trajectories(gt, est, association);
  if (pairs.size() <= delta) {
    if (why)
      *why = "depth agreement: " + std::to_string(pairs.size()) +
             " associated poses, too few for a step of " + std::to_string(delta);
    return false;
  }
  std::vector<std::size_t> frames(pairs.size());
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const double t = est[pairs[k].second].timestamp;
    const StampedPose* frame = nearest_pose(stamps, t, association.max_difference);
    if (frame == nullptr) {
      if (why)
        *why = "depth agreement: the dataset has no frame within " +
               std::to_string(association.max_difference) + " s of the estimate's pose at t = " +
               std::to_string(t) + " s (is it the dataset the estimate was made from?)";
      return false;
    }
    frames[k] = static_cast<std::size_t>(frame - stamps.data());
  }

  std::map<std::size_t, RgbdFrame> loaded;  // the frames the next steps still need
  const auto frame = [&](std::size_t index) -> const RgbdFrame* {
    auto it = loaded.find(index);
    if (it != loaded.end()) return &it->second;
    RgbdFrame f;
    if (!dataset.load(index, &f, why)) return nullptr;
    return &loaded.emplace(index, std::move(f)).first->second;
  };
  const std::size_t total = pairs.size() - delta;
  for (std::size_t k = 0; k < total; ++k) {
    const RgbdFrame* a = frame(frames[k]);
    const RgbdFrame* b = a ? frame(frames[k + delta]) : nullptr;
    if (!b) return false;
    const auto relative = [&](const Trajectory& t, std::size_t i, std::size_t j) {
      return t[j].T_world_camera.inverse() * t[i].T_world_camera;  // T_b_a
    };
    DepthAgreementStep step;
    step.frame_a = a->id;
    step.frame_b = b->id;
    if (!depth_agreement(a->depth, b->depth, a->camera,
                         relative(gt, pairs[k].first, pairs[k + delta].first), config,
                         &step.ground_truth, why, gt_residuals) ||
        !depth_agreement(a->depth, b->depth, a->camera,
                         relative(est, pairs[k].second, pairs[k + delta].second), config,
                         &step.estimate, why, est_residuals)) {
      if (why) *why += " (frames " + std::to_string(a->id) + " -> " + std::to_string(b->id) + ")";
      return false;
    }
    steps->push_back(step);
    loaded.erase(loaded.begin(), loaded.lower_bound(std::min(frames[k], frames[k + 1])));
    if (progress) progress(k + 1, total);
  }
  return true;
}

}  // namespace fslam::core

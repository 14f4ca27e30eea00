// The feature graph both segmentation modes work on (private to core/segmentation): the
// Gaussians taking part, their standardised latents, and spatial neighbour queries over them.
#pragma once

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <flann/flann.hpp>

#include "fslam/core/segmentation/feature_graph.hpp"

namespace fslam::core::segmentation_detail {

inline float sigmoid(float x) { return 1.0f / (1.0f + std::exp(-x)); }

// For each of the `count` points (rows of xyz in `points`, the points `index` was built on), the
// rows of its `knn` nearest other points within `radius`.
std::vector<std::vector<int>> knn_within(const flann::Index<flann::L2<float>>& index,
                                         const std::vector<float>& points, int knn, float radius);

// Every Gaussian's `knn` nearest Gaussians of any opacity within `max_neighbour_distance`.
std::vector<std::vector<int>> spatial_neighbours(const GaussianMap& map, const FeatureGraphConfig& config);

// False with `why` when the map's feature array does not match it or carries no features.
bool check_features(const GaussianMap& map, std::string* why);

// The Gaussians taking part, their standardised latents and a k-d tree over their means.
class FeatureSpace {
 public:
  FeatureSpace(const GaussianMap& map, const FeatureGraphConfig& config) : map_(map), config_(config) {
    for (std::size_t i = 0; i < map.size(); ++i)
      if (sigmoid(map.opacity_logits[i]) >= config.min_opacity) active_.push_back(static_cast<int>(i));
    d_ = map.feature_dim;
    // Latents have no fixed scale: centre them per channel and divide by one spread for all
    // channels (the RMS of the channels' standard deviations). A per-channel scale would blow
    // up channels that carry only noise.
    mean_.assign(static_cast<std::size_t>(d_), 0.0f);
    inv_std_.assign(static_cast<std::size_t>(d_), 1.0f);
    if (active_.empty() || d_ == 0) return;
    std::vector<double> sum(d_, 0.0), sum2(d_, 0.0);
    for (int i : active_)
      for (int c = 0; c < d_; ++c) {
        const double f = map.features[static_cast<std::size_t>(i) * d_ + c];
        sum[c] += f;
        sum2[c] += f * f;
      }
    const double n = static_cast<double>(active_.size());
    double variance = 0.0;
    for (int c = 0; c < d_; ++c) {
      mean_[c] = static_cast<float>(sum[c] / n);
      variance += std::max(0.0, sum2[c] / n - (sum[c] / n) * (sum[c] / n)) / d_;
    }
    inv_std_.assign(static_cast<std::size_t>(d_), static_cast<float>(1.0 / std::max(std::sqrt(variance), 1e-6)));
    z_.resize(map.size() * static_cast<std::size_t>(d_));
    for (std::size_t i = 0; i < map.size(); ++i) standardise(&map.features[i * d_], &z_[i * d_]);
    points_.resize(active_.size() * 3);
    for (std::size_t k = 0; k < active_.size(); ++k)
      for (int a = 0; a < 3; ++a) points_[k * 3 + a] = map.means[static_cast<std::size_t>(active_[k]) * 3 + a];
    index_ = std::make_unique<flann::Index<flann::L2<float>>>(
        flann::Matrix<float>(points_.data(), active_.size(), 3), flann::KDTreeSingleIndexParams(10));
    index_->buildIndex();
  }

  const std::vector<int>& active() const { return active_; }
  int dim() const { return d_; }
  void standardise(const float* f, float* z) const {
    for (int c = 0; c < d_; ++c) z[c] = (f[c] - mean_[c]) * inv_std_[c];
  }
  const float* z(int i) const { return &z_[static_cast<std::size_t>(i) * d_]; }
  // RMS difference of two standardised latents.
  float distance(const float* a, const float* b) const {
    float s = 0;
    for (int c = 0; c < d_; ++c) s += (a[c] - b[c]) * (a[c] - b[c]);
    return std::sqrt(s / static_cast<float>(d_));
  }
  bool alike(int i, int j) const { return distance(z(i), z(j)) < config_.feature_threshold; }

  // Spatial neighbours (map indices) of every map index: k nearest within the radius.
  std::vector<std::vector<int>> neighbours() const {
    std::vector<std::vector<int>> out(map_.size());
    if (active_.empty()) return out;
    const std::vector<std::vector<int>> rows =
        knn_within(*index_, points_, config_.knn, config_.max_neighbour_distance);
    for (std::size_t q = 0; q < rows.size(); ++q)
      for (int other : rows[q]) {
        out[static_cast<std::size_t>(active_[q])].push_back(active_[static_cast<std::size_t>(other)]);
      }
    return out;
  }

  // Active map indices within `radius` of `p` (world frame, metres), nearest first.
  std::vector<int> within(const Eigen::Vector3f& p, float radius) const {
    std::vector<int> out;
    if (active_.empty()) return out;
    float q[3] = {p.x(), p.y(), p.z()};
    std::vector<std::vector<int>> idx;
    std::vector<std::vector<float>> d2;
    flann::SearchParams params(flann::FLANN_CHECKS_UNLIMITED);
    params.sorted = true;
    index_->radiusSearch(flann::Matrix<float>(q, 1, 3), idx, d2, radius * radius, params);
    for (int k : idx[0]) out.push_back(active_[static_cast<std::size_t>(k)]);
    return out;
  }

 private:
  const GaussianMap& map_;
  FeatureGraphConfig config_;
  std::vector<int> active_;  // map indices
  int d_ = 0;
  std::vector<float> mean_, inv_std_, z_, points_;
  std::unique_ptr<flann::Index<flann::L2<float>>> index_;
};

}  // namespace fslam::core::segmentation_detail

// A static GICP target: Gaussian points in a FLANN KD-tree, with LocalMap's search interface
// (eq. correspondence). For frame-to-frame registration and tests; the tracker's incremental
// model is LocalMap.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "fslam/core/tracking/gaussian_points.hpp"
#include "fslam/core/tracking/local_map.hpp"

namespace fslam::core {

// Exact radius-bounded nearest neighbour over a fixed set of Gaussian points (eq. correspondence).
class KdTreeTarget {
 public:
  KdTreeTarget();
  ~KdTreeTarget();
  KdTreeTarget(KdTreeTarget&&) noexcept;
  KdTreeTarget& operator=(KdTreeTarget&&) noexcept;
  KdTreeTarget(const KdTreeTarget&) = delete;
  KdTreeTarget& operator=(const KdTreeTarget&) = delete;

  // Replaces the stored points by `points_target` (target frame) and builds the tree. Missing
  // opacities read as 1. Points are stored in a spatial order, not the input order
  // (input_index maps back). Returns false with `why` when the set is inconsistent (then empty).
  bool build(const GaussianPoints& points_target, std::string* why = nullptr);

  // Nearest stored point to `query` (target frame) within `max_distance` metres, inclusive;
  // nullptr if none. Exact search. Thread-safe for concurrent readers (FLANN allocates one
  // 3-float scratch vector per query; nothing else is allocated).
  const TargetPoint* nearest(const Eigen::Vector3f& query, float max_distance,
                             float* squared_distance = nullptr) const;

  std::size_t size() const { return points_.size(); }
  bool empty() const { return points_.empty(); }
  const TargetPoint& point(std::size_t i) const { return points_[i]; }  // stored order
  // Index in the GaussianPoints given to build() of a point this target returned.
  std::size_t input_index(const TargetPoint& p) const;
  int feature_dim() const { return feature_dim_; }
  const float* feature(const TargetPoint& p) const { return features_.data() + p.feature_offset; }
  void clear();

 private:
  struct Index;  // the FLANN tree, kept out of this header

  std::vector<TargetPoint> points_;         // [N] target frame, Morton order; the tree indexes
                                            // their means in place
  std::vector<std::uint32_t> input_index_;  // [N] position in build()'s input
  std::vector<float> features_;             // [N * feature_dim_], rows in points_ order
  int feature_dim_ = 0;
  std::unique_ptr<Index> index_;
};

}  // namespace fslam::core

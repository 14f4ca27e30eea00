// The tracker's local target model: Gaussian points of recent keyframes in world coordinates,
// kept incrementally in a voxel hash (never an index rebuilt over the whole map per frame), with
// nearest-neighbour search for eq. correspondence.
#pragma once

#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Geometry>

#include "fslam/core/tracking/gaussian_points.hpp"

namespace fslam::core {

struct LocalMapConfig {
  float voxel_size = 0.1f;          // metres, hash cell edge; >= max correspondence distance
  float min_point_distance = 0.01f; // metres; a new point closer than this to a stored one is
                                    // not inserted (keeps density bounded)
  int max_points_per_voxel = 27;
  float radius = 4.0f;              // metres; voxels farther than this from the latest keyframe
                                    // camera are dropped after each insertion
  bool is_valid(std::string* why = nullptr) const;
};

// A stored target point: mean, covariance, opacity and feature row, all in world coordinates.
struct TargetPoint {
  Eigen::Vector3f mean;
  Eigen::Matrix3f covariance;
  float opacity = 1.0f;
  std::uint32_t feature_offset = 0;  // index into LocalMap::features(), valid if feature_dim > 0
};

class LocalMap {
 public:
  explicit LocalMap(const LocalMapConfig& config = {});

  // Adds a keyframe's points (already in world coordinates) and drops voxels outside `radius`
  // of `camera_position_world`. Returns the number of points actually inserted.
  std::size_t insert(const GaussianPoints& points_world, const Eigen::Vector3f& camera_position_world);

  // Nearest stored point to `query` (world) within `max_distance` metres; nullptr if none.
  // Searches the query's voxel and its 26 neighbours. Thread-safe for concurrent readers.
  const TargetPoint* nearest(const Eigen::Vector3f& query, float max_distance,
                             float* squared_distance = nullptr) const;

  std::size_t size() const { return size_; }
  std::size_t voxel_count() const { return voxels_.size(); }
  int feature_dim() const { return feature_dim_; }
  const float* feature(const TargetPoint& p) const { return features_.data() + p.feature_offset; }
  void clear();
  // Every stored point, for inspection, tests and visualisation.
  GaussianPoints points() const;

 private:
  struct VoxelKey {
    std::int32_t x, y, z;
    bool operator==(const VoxelKey& o) const { return x == o.x && y == o.y && z == o.z; }
  };
  struct VoxelKeyHash {
    std::size_t operator()(const VoxelKey& k) const;
  };
  VoxelKey key_of(const Eigen::Vector3f& p) const;

  LocalMapConfig config_;
  std::unordered_map<VoxelKey, std::vector<TargetPoint>, VoxelKeyHash> voxels_;
  std::vector<float> features_;  // rows of feature_dim_, referenced by TargetPoint::feature_offset
  int feature_dim_ = 0;
  std::size_t size_ = 0;
};

}  // namespace fslam::core

// The tracker's local target model: Gaussian points of recent keyframes in world coordinates,
// kept incrementally in a voxel hash (never an index rebuilt over the whole map per frame), with
// nearest-neighbour search for eq. correspondence.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "fslam/core/tracking/gaussian_points.hpp"

namespace fslam::core {

struct LocalMapConfig {
  float voxel_size = 0.1f;          // metres, hash cell edge; >= max correspondence distance
  float min_point_distance = 0.01f; // metres; a new point closer than this to a stored one is
                                    // not inserted (keeps density bounded)
  bool fuse = true;  // ... but fused into that stored point (product of the two Gaussians), so
                     // repeated observations average the sensor noise out; off: the first stays
  int max_points_per_voxel = 27;
  // Metres; voxels farther than this from the latest keyframe camera are dropped after each
  // insertion. The preprocess max_depth (6 m): what the camera can see stays. At 4 m (the default
  // until 2026-12-06) the synthetic hall's camera, turning to look back down it, slid 33-40 cm
  // against a map that had dropped what it saw 4-6 m away, and loop closure removed less of the
  // ring's drift (seeds 1, 2: 22, 46 % of the ATE against 64, 50 %; docs/tracking.md).
  float radius = 6.0f;
  bool is_valid(std::string* why = nullptr) const;
};

// What a point LocalMap::insert stores is: a depth observation (a keyframe's point, or a map
// Gaussian that is to be fused as one) or a map Gaussian held where the mapper put it: an
// observation fused into one adds its information (the covariance shrinks) but leaves the mean.
enum class PointOrigin : std::uint8_t { observation, map_gaussian };

// A stored target point: mean, covariance, opacity and feature row, all in world coordinates.
struct TargetPoint {
  Eigen::Vector3f mean;
  Eigen::Matrix3f covariance;
  float opacity = 1.0f;
  std::uint32_t feature_offset = 0;  // index into LocalMap::features(), valid if feature_dim > 0
  PointOrigin origin = PointOrigin::observation;
};

class LocalMap {
 public:
  explicit LocalMap(const LocalMapConfig& config = {});

  // Adds a keyframe's points (already in world coordinates) and drops voxels outside `radius`
  // of `camera_position_world`. Returns the number of points actually inserted. With `fuse`, a
  // point within min_point_distance of a stored one updates it instead (mean and covariance;
  // opacity and feature row stay, refresh_point_features renews those); a stored map Gaussian
  // keeps its mean and takes only the observation's information. `origins`: one per point
  // (empty: all observations).
  // The map's feature_dim is set by the first insertion into an empty map; a later insertion
  // with another feature_dim (features present vs absent included) is a programming error that
  // is not fatal: the map drops every feature and tracks on geometry alone until it is empty.
  std::size_t insert(const GaussianPoints& points_world, const Eigen::Vector3f& camera_position_world,
                     const std::vector<PointOrigin>& origins = {});

  // Nearest stored point to `query` (world) within `max_distance` metres; nullptr if none.
  // Searches the query's voxel and its 26 neighbours, so `max_distance` is clamped to
  // voxel_size (beyond it the result would not be exact). Thread-safe for concurrent readers.
  // The pointer stays valid until the next insert() or clear().
  const TargetPoint* nearest(const Eigen::Vector3f& query, float max_distance,
                             float* squared_distance = nullptr) const;

  // Whether later insertions fuse a point into a stored one within min_point_distance (true) or
  // drop it (false); what is stored stays as it is.
  void set_fuse(bool fuse) { config_.fuse = fuse; }
  std::size_t size() const { return size_; }
  std::size_t voxel_count() const { return voxels_.size(); }
  int feature_dim() const { return feature_dim_; }
  const float* feature(const TargetPoint& p) const { return features_.data() + p.feature_offset; }
  // Feature rows held, live and dead (dropped voxels); compaction keeps it at most 2x size().
  std::size_t feature_rows_stored() const {
    return feature_dim_ > 0 ? features_.size() / static_cast<std::size_t>(feature_dim_) : 0;
  }
  // Calls visit(const TargetPoint&, float* feature) with each stored point and its writable
  // feature row ([feature_dim]); nothing when the map has no features. Not safe beside readers.
  template <typename Visit>
  void update_features(Visit&& visit) {
    if (feature_dim_ == 0) return;
    for (const Voxel& voxel : voxels_)
      for (const TargetPoint& p : voxel.points) visit(p, features_.data() + p.feature_offset);
  }
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
  // A voxel's points, with their means also in a padded structure-of-arrays block that
  // nearest() scans in vector lanes.
  struct Voxel {
    VoxelKey key;
    std::uint32_t count = 0;          // points.size(), kept beside the block nearest() scans
    std::uint32_t capacity = 0;       // lanes per coordinate block, a multiple of 4
    std::vector<float> xyz;           // [3, capacity] metres, world: x | y | z; far past the points
    std::vector<TargetPoint> points;  // [count <= max_points_per_voxel], the same order
  };
  // Open addressing with linear probing: no per-lookup modulo or node chasing (nearest() looks
  // up a few voxels per query, ~200k queries per frame).
  struct Slot {
    VoxelKey key;
    std::uint32_t voxel;  // index into voxels_, kEmptySlot when free
  };
  static constexpr std::uint32_t kEmptySlot = 0xFFFFFFFFu;

  VoxelKey key_of(const Eigen::Vector3f& p) const;
  std::size_t home_slot(const VoxelKey& key) const;
  const Voxel* find_voxel(const VoxelKey& key) const;
  Voxel& find_or_add_voxel(const VoxelKey& key);
  void rebuild_table(std::size_t min_voxels);
  void add_point(Voxel* voxel, const TargetPoint& point) const;
  // Fuses the observation (mean, covariance) into `stored` (a map Gaussian: the covariance
  // only); false when it could not (the fused mean lies in a full voxel or the covariances are
  // singular), leaving `stored` as it was.
  bool fuse_into(const TargetPoint* stored, const Eigen::Vector3f& mean,
                 const Eigen::Matrix3f& covariance);
  void drop_voxels_outside(const Eigen::Vector3f& centre_world);
  void compact_features();

  LocalMapConfig config_;
  std::vector<Voxel> voxels_;    // in insertion order, dropped ones compacted away
  std::vector<Slot> table_;      // power-of-two size, at most half full
  int table_shift_ = 64;         // 64 - log2(table_.size()), for Fibonacci hashing
  std::vector<float> features_;  // rows of feature_dim_, referenced by TargetPoint::feature_offset
  int feature_dim_ = 0;
  std::size_t dead_feature_rows_ = 0;  // rows of dropped voxels still in features_
  float inv_voxel_size_ = 0.0f;        // 1 / voxel_size, 1/m
  std::size_t size_ = 0;
};

}  // namespace fslam::core

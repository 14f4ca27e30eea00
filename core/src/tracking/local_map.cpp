#include "fslam/core/tracking/local_map.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>

#include "fslam/core/error.hpp"

namespace fslam::core {

namespace {

// Vector lanes of the per-voxel mean blocks: capacities are rounded up to this, and the
// distance loop in nearest() runs over whole lanes.
constexpr std::uint32_t kLanes = 4;
// The padding lanes' coordinate, metres: finite (squared distances stay ordinary floats, ~1e30)
// and too far to ever be a nearest neighbour.
constexpr float kFarAway = 1e15f;
// Distances computed per pass of nearest()'s scan (a stack buffer).
constexpr std::uint32_t kScanBlock = 64;

// Slack on the voxel-box lower bound of the pruned neighbour search, in voxel edges: key_of's
// floor(p / voxel_size) can put a point a float ulp of p outside its voxel, so a box is skipped
// only when it is farther than the best distance by more than this. 1e-3 edges covers the
// rounding of coordinates up to about 8000 voxel edges (800 m at 0.1 m) from the origin.
constexpr float kBoxSlackEdges = 1e-3f;

std::uint32_t round_up_lanes(std::size_t n) {
  return static_cast<std::uint32_t>((n + kLanes - 1) / kLanes * kLanes);
}

// The hash table is sized to the voxels actually held (at most half full, at least this many
// voxels' worth), not to the reservation below: a compact table stays in cache.
constexpr std::size_t kMinTableVoxels = 1024;

// Voxels a map of this config typically holds (a few surfaces crossing the ball of `radius`),
// reserved up front so the first keyframes do not reallocate.
std::size_t initial_voxel_capacity(const LocalMapConfig& config) {
  const double cells_across = 2.0 * config.radius / config.voxel_size;
  const double estimate = 4.0 * cells_across * cells_across;
  return static_cast<std::size_t>(std::clamp(estimate, 1024.0, 32768.0));
}

}  // namespace

bool LocalMapConfig::is_valid(std::string* why) const {
  if (!(std::isfinite(voxel_size) && voxel_size > 0.0f))
    return fail(
        why, "voxel_size must be positive and finite (metres), got " + std::to_string(voxel_size));
  if (!(min_point_distance >= 0.0f && min_point_distance <= voxel_size))
    return fail(why,
                "min_point_distance must be in [0, voxel_size = " + std::to_string(voxel_size) +
                    "] metres, got " + std::to_string(min_point_distance));
  if (max_points_per_voxel < 1)
    return fail(why, "max_points_per_voxel must be at least 1, got " +
                         std::to_string(max_points_per_voxel));
  if (!(std::isfinite(radius) && radius >= voxel_size))
    return fail(why, "radius must be finite and at least voxel_size = " +
                         std::to_string(voxel_size) + " (metres), got " + std::to_string(radius));
  return true;
}

// The large-primes XOR hash of Teschner et al. (2003), as in KISS-ICP's voxel map.
std::size_t LocalMap::VoxelKeyHash::operator()(const VoxelKey& k) const {
  return static_cast<std::size_t>((static_cast<std::uint32_t>(k.x) * 73856093u) ^
                                  (static_cast<std::uint32_t>(k.y) * 19349669u) ^
                                  (static_cast<std::uint32_t>(k.z) * 83492791u));
}

LocalMap::LocalMap(const LocalMapConfig& config)
    : config_(config), inv_voxel_size_(1.0f / config.voxel_size) {
  assert(config.is_valid());
  voxels_.reserve(initial_voxel_capacity(config));
  rebuild_table(kMinTableVoxels);
}

LocalMap::VoxelKey LocalMap::key_of(const Eigen::Vector3f& p) const {
  return {static_cast<std::int32_t>(std::floor(p.x() * inv_voxel_size_)),
          static_cast<std::int32_t>(std::floor(p.y() * inv_voxel_size_)),
          static_cast<std::int32_t>(std::floor(p.z() * inv_voxel_size_))};
}

// Fibonacci hashing of the XOR hash: its top bits pick the slot, so that neighbouring voxels,
// whose XOR hashes differ in few low bits, spread over the table.
inline std::size_t LocalMap::home_slot(const VoxelKey& key) const {
  const std::uint64_t h = static_cast<std::uint64_t>(VoxelKeyHash{}(key));
  return static_cast<std::size_t>((h * 0x9E3779B97F4A7C15ull) >> table_shift_);
}

inline const LocalMap::Voxel* LocalMap::find_voxel(const VoxelKey& key) const {
  const std::size_t mask = table_.size() - 1;
  for (std::size_t s = home_slot(key);; s = (s + 1) & mask) {
    const Slot& slot = table_[s];
    if (slot.voxel == kEmptySlot) return nullptr;
    if (slot.key == key) return &voxels_[slot.voxel];
  }
}

LocalMap::Voxel& LocalMap::find_or_add_voxel(const VoxelKey& key) {
  if (2 * (voxels_.size() + 1) > table_.size()) rebuild_table(2 * (voxels_.size() + 1));
  const std::size_t mask = table_.size() - 1;
  std::size_t s = home_slot(key);
  for (; table_[s].voxel != kEmptySlot; s = (s + 1) & mask)
    if (table_[s].key == key) return voxels_[table_[s].voxel];
  table_[s] = {key, static_cast<std::uint32_t>(voxels_.size())};
  Voxel& voxel = voxels_.emplace_back();
  voxel.key = key;
  return voxel;
}

// A table of at least twice `min_voxels` slots (load <= 1/2 keeps probe runs short), refilled
// from voxels_.
void LocalMap::rebuild_table(std::size_t min_voxels) {
  std::size_t size = 16;
  int bits = 4;
  while (size < 2 * min_voxels) {
    size *= 2;
    ++bits;
  }
  table_.assign(size, Slot{{0, 0, 0}, kEmptySlot});
  table_shift_ = 64 - bits;
  const std::size_t mask = size - 1;
  for (std::size_t i = 0; i < voxels_.size(); ++i) {
    std::size_t s = home_slot(voxels_[i].key);
    while (table_[s].voxel != kEmptySlot) s = (s + 1) & mask;
    table_[s] = {voxels_[i].key, static_cast<std::uint32_t>(i)};
  }
}

// Appends `point` to the voxel, growing its mean block (doubling, up to max_points_per_voxel).
void LocalMap::add_point(Voxel* voxel, const TargetPoint& point) const {
  const std::size_t n = voxel->points.size();
  if (n == voxel->capacity) {
    const std::uint32_t limit =
        round_up_lanes(static_cast<std::size_t>(config_.max_points_per_voxel));
    const std::uint32_t capacity = std::min(limit, std::max(kLanes, 2 * voxel->capacity));
    std::vector<float> xyz(3 * static_cast<std::size_t>(capacity), kFarAway);
    for (int a = 0; a < 3; ++a)
      std::copy_n(voxel->xyz.begin() + a * voxel->capacity, n, xyz.begin() + a * capacity);
    voxel->xyz.swap(xyz);
    voxel->capacity = capacity;
  }
  for (int a = 0; a < 3; ++a) voxel->xyz[a * voxel->capacity + n] = point.mean[a];
  voxel->points.push_back(point);
  voxel->count = static_cast<std::uint32_t>(voxel->points.size());
}

const TargetPoint* LocalMap::nearest(const Eigen::Vector3f& query, float max_distance,
                                     float* squared_distance) const {
  if (size_ == 0 || !(max_distance >= 0.0f) || !query.allFinite()) return nullptr;
  const float r = std::min(max_distance, config_.voxel_size);
  float best = r * r;
  const TargetPoint* found = nullptr;
  // Distances over whole lanes (a loop the compiler vectorises), reduced to their minimum as
  // integers: the bits of non-negative floats order like the floats, and an integer minimum
  // vectorises where a float one would need -ffast-math. The index is searched for only when
  // the block beats the best so far, which most neighbour voxels do not.
  const float qx = query.x(), qy = query.y(), qz = query.z();
  auto scan = [&](const Voxel& voxel) {
    const std::size_t lanes = round_up_lanes(voxel.count);
    std::int32_t bits[kScanBlock];  // bit patterns of squared distances, m^2
    for (std::size_t base = 0; base < lanes; base += kScanBlock) {
      const float* x = voxel.xyz.data() + base;
      const float* y = x + voxel.capacity;
      const float* z = y + voxel.capacity;
      const std::size_t m = std::min<std::size_t>(kScanBlock, lanes - base);
      std::int32_t lowest = std::numeric_limits<std::int32_t>::max();
      for (std::size_t i = 0; i < m; ++i) {
        const float dx = x[i] - qx, dy = y[i] - qy, dz = z[i] - qz;
        const float d2 = dx * dx + dy * dy + dz * dz;
        std::memcpy(&bits[i], &d2, sizeof d2);
        lowest = std::min(lowest, bits[i]);
      }
      float lowest_d2;
      std::memcpy(&lowest_d2, &lowest, sizeof lowest_d2);
      if (!(lowest_d2 <= best)) continue;
      std::size_t i = 0;
      while (bits[i] != lowest) ++i;
      best = lowest_d2;
      found = &voxel.points[base + i];
    }
  };

  const VoxelKey c = key_of(query);
  if (const Voxel* own = find_voxel(c)) scan(*own);

  // Eq. correspondence over the 26 neighbours, visiting a neighbour only when its box can hold a
  // point closer than the best so far: gap[a][0 | 1 | 2] is the squared distance from the query
  // to the neighbour layer at offset -1 | 0 | +1 along axis a.
  float gap[3][3];
  const std::int32_t ck[3] = {c.x, c.y, c.z};
  const float slack = kBoxSlackEdges * config_.voxel_size;
  for (int a = 0; a < 3; ++a) {
    const float lower = query[a] - static_cast<float>(ck[a]) * config_.voxel_size - slack;
    const float upper = static_cast<float>(ck[a] + 1) * config_.voxel_size - query[a] - slack;
    gap[a][0] = lower > 0.0f ? lower * lower : 0.0f;
    gap[a][1] = 0.0f;
    gap[a][2] = upper > 0.0f ? upper * upper : 0.0f;
  }
  for (int dx = -1; dx <= 1; ++dx) {
    const float gx = gap[0][dx + 1];
    if (gx > best) continue;
    for (int dy = -1; dy <= 1; ++dy) {
      const float gxy = gx + gap[1][dy + 1];
      if (gxy > best) continue;
      for (int dz = -1; dz <= 1; ++dz) {
        if ((dx == 0 && dy == 0 && dz == 0) || gxy + gap[2][dz + 1] > best) continue;
        if (const Voxel* v = find_voxel({c.x + dx, c.y + dy, c.z + dz})) scan(*v);
      }
    }
  }
  if (found && squared_distance) *squared_distance = best;
  return found;
}

std::size_t LocalMap::insert(const GaussianPoints& points_world, const Eigen::Vector3f& camera_position_world,
                             const std::vector<PointOrigin>& origins) {
  assert(origins.empty() || origins.size() == points_world.size());
  assert(points_world.covariances.size() == points_world.size());
  assert(points_world.opacities.empty() || points_world.opacities.size() == points_world.size());
  assert(!points_world.has_features() ||
         points_world.features.size() ==
             points_world.size() * static_cast<std::size_t>(points_world.feature_dim));
  const int incoming_dim = points_world.has_features() ? points_world.feature_dim : 0;
  if (size_ == 0) {
    features_.clear();
    dead_feature_rows_ = 0;
    feature_dim_ = incoming_dim;
  } else if (incoming_dim != feature_dim_) {
    // Documented in the header: a feature_dim mismatch drops the map's features.
    features_.clear();
    features_.shrink_to_fit();
    dead_feature_rows_ = 0;
    feature_dim_ = 0;
  }
  const bool store_features = feature_dim_ > 0;
  const std::size_t dim = static_cast<std::size_t>(feature_dim_);
  if (store_features) features_.reserve(features_.size() + points_world.size() * dim);

  const float min_distance = config_.min_point_distance;
  const std::size_t max_per_voxel = static_cast<std::size_t>(config_.max_points_per_voxel);
  std::size_t inserted = 0;
  for (std::size_t i = 0; i < points_world.size(); ++i) {
    const Eigen::Vector3f& mean = points_world.means[i];
    if (!mean.allFinite()) continue;
    // Thinning: the new point must keep min_point_distance to every stored point, new ones too.
    if (min_distance > 0.0f) {
      if (const TargetPoint* stored = nearest(mean, min_distance)) {
        if (config_.fuse) fuse_into(stored, mean, points_world.covariances[i]);
        continue;
      }
    }
    Voxel& voxel = find_or_add_voxel(key_of(mean));
    if (voxel.points.size() >= max_per_voxel) continue;
    TargetPoint p;
    p.mean = mean;
    p.covariance = points_world.covariances[i];
    p.opacity = points_world.has_opacities() ? points_world.opacities[i] : 1.0f;
    p.origin = origins.empty() ? PointOrigin::observation : origins[i];
    if (store_features) {
      assert(features_.size() <= std::numeric_limits<std::uint32_t>::max() - dim);
      p.feature_offset = static_cast<std::uint32_t>(features_.size());
      const float* row = points_world.feature(i);
      features_.insert(features_.end(), row, row + dim);
    }
    add_point(&voxel, p);
    ++inserted;
    ++size_;  // nearest() above must see this point when thinning the next one
  }
  drop_voxels_outside(camera_position_world);
  return inserted;
}

bool LocalMap::fuse_into(const TargetPoint* stored, const Eigen::Vector3f& mean,
                         const Eigen::Matrix3f& covariance) {
  // Product of the two Gaussians: information adds, the mean is information-weighted. Repeated
  // observations of a surface point shrink its covariance and average the depth noise out.
  const Eigen::Matrix3f info_stored = stored->covariance.inverse();
  const Eigen::Matrix3f info_new = covariance.inverse();
  const Eigen::Matrix3f fused_cov = (info_stored + info_new).inverse();
  // A map Gaussian counts the re-observation (as the mapper's observation weight will once the
  // keyframe is mapped) but stays where the mapper put it.
  const Eigen::Vector3f fused_mean =
      stored->origin == PointOrigin::map_gaussian
          ? stored->mean
          : Eigen::Vector3f(fused_cov * (info_stored * stored->mean + info_new * mean));
  if (!fused_cov.allFinite() || !fused_mean.allFinite()) return false;

  const VoxelKey from_key = key_of(stored->mean);
  const VoxelKey to_key = key_of(fused_mean);
  Voxel* from = const_cast<Voxel*>(find_voxel(from_key));
  assert(from != nullptr);
  const std::size_t j = static_cast<std::size_t>(stored - from->points.data());
  assert(j < from->points.size());
  if (to_key == from_key) {
    from->points[j].mean = fused_mean;
    from->points[j].covariance = fused_cov;
    for (int a = 0; a < 3; ++a) from->xyz[a * from->capacity + j] = fused_mean[a];
    return true;
  }
  // The fused mean crossed into a neighbouring voxel: the point moves there.
  Voxel& to = find_or_add_voxel(to_key);  // may reallocate voxels_, so `from` is found again
  if (to.points.size() >= static_cast<std::size_t>(config_.max_points_per_voxel)) return false;
  from = const_cast<Voxel*>(find_voxel(from_key));
  TargetPoint moved = from->points[j];
  moved.mean = fused_mean;
  moved.covariance = fused_cov;
  const std::size_t last = from->points.size() - 1;
  if (j != last) {  // the last point takes the freed slot, in both layouts
    from->points[j] = from->points[last];
    for (int a = 0; a < 3; ++a) from->xyz[a * from->capacity + j] = from->xyz[a * from->capacity + last];
  }
  for (int a = 0; a < 3; ++a) from->xyz[a * from->capacity + last] = kFarAway;
  from->points.pop_back();
  from->count = static_cast<std::uint32_t>(from->points.size());
  add_point(&to, moved);
  return true;
}

void LocalMap::drop_voxels_outside(const Eigen::Vector3f& centre_world) {
  const float radius2 = config_.radius * config_.radius;
  const float half = 0.5f * config_.voxel_size;
  const auto outside = [&](const Voxel& v) {
    const Eigen::Vector3f voxel_centre(static_cast<float>(v.key.x) * config_.voxel_size + half,
                                       static_cast<float>(v.key.y) * config_.voxel_size + half,
                                       static_cast<float>(v.key.z) * config_.voxel_size + half);
    return v.points.empty() || (voxel_centre - centre_world).squaredNorm() > radius2;
  };
  std::size_t dropped = 0, dropped_voxels = 0;
  for (const Voxel& v : voxels_) {
    if (!outside(v)) continue;
    dropped += v.points.size();
    ++dropped_voxels;
  }
  if (dropped_voxels == 0) return;
  voxels_.erase(std::remove_if(voxels_.begin(), voxels_.end(), outside), voxels_.end());
  rebuild_table(std::max<std::size_t>(voxels_.size(), kMinTableVoxels));
  size_ -= dropped;
  if (feature_dim_ > 0) {
    dead_feature_rows_ += dropped;
    if (2 * dead_feature_rows_ > feature_rows_stored()) compact_features();
  }
}

// Rewrites features_ with the live rows only, in voxel order, and re-points every offset.
void LocalMap::compact_features() {
  const std::size_t dim = static_cast<std::size_t>(feature_dim_);
  std::vector<float> live;  // [size_ * feature_dim_]
  live.reserve(size_ * dim);
  for (Voxel& voxel : voxels_) {
    for (TargetPoint& p : voxel.points) {
      const float* row = features_.data() + p.feature_offset;
      p.feature_offset = static_cast<std::uint32_t>(live.size());
      live.insert(live.end(), row, row + dim);
    }
  }
  features_.swap(live);
  dead_feature_rows_ = 0;
}

void LocalMap::clear() {
  voxels_.clear();
  rebuild_table(kMinTableVoxels);
  features_.clear();
  features_.shrink_to_fit();
  feature_dim_ = 0;
  dead_feature_rows_ = 0;
  size_ = 0;
}

GaussianPoints LocalMap::points() const {
  GaussianPoints out;
  out.feature_dim = feature_dim_;
  out.means.reserve(size_);
  out.covariances.reserve(size_);
  out.opacities.reserve(size_);
  if (feature_dim_ > 0) out.features.reserve(size_ * static_cast<std::size_t>(feature_dim_));
  for (const Voxel& voxel : voxels_) {
    for (const TargetPoint& p : voxel.points) {
      out.means.push_back(p.mean);
      out.covariances.push_back(p.covariance);
      out.opacities.push_back(p.opacity);
      if (feature_dim_ > 0) {
        const float* row = feature(p);
        out.features.insert(out.features.end(), row, row + feature_dim_);
      }
    }
  }
  return out;
}

}  // namespace fslam::core

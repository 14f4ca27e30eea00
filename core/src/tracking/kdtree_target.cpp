#include "fslam/core/tracking/kdtree_target.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>

#include <flann/algorithms/dist.h>
#include <flann/algorithms/kdtree_single_index.h>
#include <flann/util/matrix.h>
#include <flann/util/params.h>
#include <flann/util/result_set.h>

#include "fslam/core/error.hpp"

namespace fslam::core {
namespace {

constexpr int kLeafSize = 10;  // points per KD-tree leaf

// The single nearest neighbour within a radius. Starting with the radius as the worst distance
// prunes every branch beyond it (FLANN's own k-NN sets start at infinity and allocate).
class NearestWithin final : public flann::ResultSet<float> {
 public:
  // FLANN keeps candidates with dist < worstDist(); nextafter makes the radius inclusive.
  explicit NearestWithin(float max_squared_distance)
      : worst_(std::nextafter(max_squared_distance, std::numeric_limits<float>::infinity())) {}
  bool full() const override { return true; }
  void addPoint(float dist, size_t index) override {
    if (dist < worst_) {
      worst_ = dist;
      index_ = index;
      found_ = true;
    }
  }
  float worstDist() const override { return worst_; }
  bool found() const { return found_; }
  std::size_t index() const { return index_; }

 private:
  float worst_;
  std::size_t index_ = 0;
  bool found_ = false;
};

// Interleaves the low 21 bits of x into every third bit.
std::uint64_t spread_bits(std::uint64_t x) {
  x &= 0x1fffff;
  x = (x | x << 32) & 0x1f00000000ffffULL;
  x = (x | x << 16) & 0x1f0000ff0000ffULL;
  x = (x | x << 8) & 0x100f00f00f00f00fULL;
  x = (x | x << 4) & 0x10c30c30c30c30c3ULL;
  x = (x | x << 2) & 0x1249249249249249ULL;
  return x;
}

// Z-order code of p on a 2^21-cell grid per axis over the box [lo, lo + extent].
std::uint64_t morton_code(const Eigen::Vector3f& p, const Eigen::Vector3f& lo,
                          const Eigen::Vector3f& extent) {
  constexpr float kCells = 2097151.0f;  // 2^21 - 1
  const Eigen::Vector3f u =
      ((p - lo).cwiseQuotient(extent) * kCells).cwiseMax(0.0f).cwiseMin(kCells);
  return spread_bits(static_cast<std::uint64_t>(u.x())) |
         spread_bits(static_cast<std::uint64_t>(u.y())) << 1 |
         spread_bits(static_cast<std::uint64_t>(u.z())) << 2;
}

}  // namespace

// KDTreeSingleIndex used directly (not through flann::Index) to search with our result set.
// findNeighbors is const and touches only the tree and its arguments: concurrent queries are safe.
struct KdTreeTarget::Index {
  flann::KDTreeSingleIndex<flann::L2<float>> tree;
  flann::SearchParams exact{flann::FLANN_CHECKS_UNLIMITED, 0.0f, false};
  // Indexes the means in place: rows of 3 floats, TargetPoint-sized stride ([N, 3], target frame).
  explicit Index(std::vector<TargetPoint>* points)
      : tree(flann::Matrix<float>(points->front().mean.data(), points->size(), 3,
                                  sizeof(TargetPoint)),
             flann::KDTreeSingleIndexParams(kLeafSize)) {
    tree.buildIndex();
  }
};

KdTreeTarget::KdTreeTarget() = default;
KdTreeTarget::~KdTreeTarget() = default;
KdTreeTarget::KdTreeTarget(KdTreeTarget&&) noexcept = default;
KdTreeTarget& KdTreeTarget::operator=(KdTreeTarget&&) noexcept = default;

void KdTreeTarget::clear() {
  index_.reset();
  points_.clear();
  input_index_.clear();
  features_.clear();
  feature_dim_ = 0;
}

bool KdTreeTarget::build(const GaussianPoints& points_target, std::string* why) {
  clear();
  std::string reason;
  if (!points_target.is_consistent(&reason)) return fail(why, "KD-tree target: " + reason);
  const std::size_t n = points_target.size();
  const std::size_t dim = static_cast<std::size_t>(points_target.feature_dim);
  const bool with_features = points_target.has_features();
  if (n > std::numeric_limits<std::uint32_t>::max() ||
      (with_features && n * dim > std::numeric_limits<std::uint32_t>::max()))
    return fail(why, "KD-tree target: " + std::to_string(n) + " points exceed 32-bit offsets");
  if (n == 0) return true;

  // Stored along a Morton curve: a point and its feature row are then near the points a
  // spatially coherent query stream visited just before (measured 10-20 % off a GICP iteration).
  Eigen::Vector3f lo = points_target.means.front(), hi = lo;
  for (const Eigen::Vector3f& p : points_target.means) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const Eigen::Vector3f extent = (hi - lo).cwiseMax(1e-6f);
  std::vector<std::pair<std::uint64_t, std::uint32_t>> order(n);  // (Morton code, input index)
  for (std::size_t i = 0; i < n; ++i)
    order[i] = {morton_code(points_target.means[i], lo, extent), static_cast<std::uint32_t>(i)};
  std::sort(order.begin(), order.end());

  points_.resize(n);
  input_index_.resize(n);
  if (with_features) {
    feature_dim_ = points_target.feature_dim;
    features_.resize(n * dim);
  }
  for (std::size_t k = 0; k < n; ++k) {
    const std::size_t i = order[k].second;
    TargetPoint& p = points_[k];
    p.mean = points_target.means[i];
    p.covariance = points_target.covariances[i];
    p.opacity = points_target.has_opacities() ? points_target.opacities[i] : 1.0f;
    p.feature_offset = with_features ? static_cast<std::uint32_t>(k * dim) : 0u;
    if (with_features)
      std::copy_n(points_target.feature(i), dim,
                  features_.begin() + static_cast<std::ptrdiff_t>(k * dim));
    input_index_[k] = order[k].second;
  }
  index_ = std::make_unique<Index>(&points_);
  return true;
}

std::size_t KdTreeTarget::input_index(const TargetPoint& p) const {
  const auto k = static_cast<std::size_t>(&p - points_.data());
  assert(k < points_.size());
  return input_index_[k];
}

const TargetPoint* KdTreeTarget::nearest(const Eigen::Vector3f& query, float max_distance,
                                         float* squared_distance) const {
  if (!index_ || !(max_distance > 0.0f) || !query.allFinite()) return nullptr;
  NearestWithin result(max_distance * max_distance);
  index_->tree.findNeighbors(result, query.data(), index_->exact);
  if (!result.found()) return nullptr;
  if (squared_distance) *squared_distance = result.worstDist();
  assert(result.index() < points_.size());
  return &points_[result.index()];
}

}  // namespace fslam::core

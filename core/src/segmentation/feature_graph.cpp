#include "fslam/core/segmentation/feature_graph.hpp"

#include <algorithm>

#include "fslam/core/error.hpp"
#include "feature_space.hpp"

namespace fslam::core {
namespace segmentation_detail {

std::vector<std::vector<int>> knn_within(const flann::Index<flann::L2<float>>& index,
                                         const std::vector<float>& points, int knn, float radius) {
  const std::size_t m = points.size() / 3;
  std::vector<std::vector<int>> out(m);
  if (m == 0) return out;
  const int k = std::min<int>(knn + 1, static_cast<int>(m));
  std::vector<int> idx(m * static_cast<std::size_t>(k));
  std::vector<float> d2(m * static_cast<std::size_t>(k));
  flann::Matrix<int> im(idx.data(), m, static_cast<std::size_t>(k));
  flann::Matrix<float> dm(d2.data(), m, static_cast<std::size_t>(k));
  flann::SearchParams params(flann::FLANN_CHECKS_UNLIMITED);
  params.cores = 1;
  const_cast<flann::Index<flann::L2<float>>&>(index).knnSearch(
      flann::Matrix<float>(const_cast<float*>(points.data()), m, 3), im, dm, k, params);
  const float r2 = radius * radius;
  for (std::size_t q = 0; q < m; ++q)
    for (int j = 0; j < k; ++j) {
      const int other = idx[q * k + j];
      if (other < 0 || static_cast<std::size_t>(other) == q || d2[q * k + j] > r2) continue;
      out[q].push_back(other);
    }
  return out;
}

bool check_features(const GaussianMap& map, std::string* why) {
  if (map.feature_dim > 0 && map.features.size() != map.size() * static_cast<std::size_t>(map.feature_dim)) {
    return fail(why, "segmentation: the map's feature array does not match its size");
  }
  if (!has_features(map)) return fail(why, "segmentation: the map carries no features (its latents are all alike)");
  return true;
}

std::vector<std::vector<int>> spatial_neighbours(const GaussianMap& map, const FeatureGraphConfig& config) {
  if (map.empty()) return {};
  std::vector<float> points(map.means);
  flann::Index<flann::L2<float>> index(flann::Matrix<float>(points.data(), map.size(), 3),
                                       flann::KDTreeSingleIndexParams(10));
  index.buildIndex();
  return knn_within(index, points, config.knn, config.max_neighbour_distance);
}

}  // namespace segmentation_detail

bool has_features(const GaussianMap& map) {
  if (map.feature_dim <= 0 || map.features.empty()) return false;
  const auto [lo, hi] = std::minmax_element(map.features.begin(), map.features.end());
  return *hi > *lo;
}

bool FeatureGraphConfig::is_valid(std::string* why) const {
  if (knn < 1) return fail(why, "segmentation: knn must be >= 1");
  if (!(max_neighbour_distance > 0)) return fail(why, "segmentation: max_neighbour_distance must be > 0");
  if (!(feature_threshold > 0)) return fail(why, "segmentation: feature_threshold must be > 0");
  if (!(min_opacity >= 0 && min_opacity < 1)) return fail(why, "segmentation: min_opacity must be in [0, 1)");
  return true;
}

}  // namespace fslam::core

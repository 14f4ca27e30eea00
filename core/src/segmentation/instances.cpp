#include "fslam/core/segmentation/instances.hpp"

#include <algorithm>
#include <map>
#include <numeric>
#include <tuple>

#include <flann/flann.hpp>

#include "fslam/core/error.hpp"
#include "feature_space.hpp"

namespace fslam::core {
namespace {

using segmentation_detail::check_features;
using segmentation_detail::FeatureSpace;

struct UnionFind {
  std::vector<int> parent;
  explicit UnionFind(std::size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  int find(int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void join(int a, int b) { parent[find(a)] = find(b); }
};

}  // namespace

bool PromptlessConfig::is_valid(std::string* why) const { return graph.is_valid(why); }

bool cluster_instances(const GaussianMap& map, const PromptlessConfig& config, GaussianLabels* labels,
                       std::string* why) {
  if (!config.is_valid(why) || !check_features(map, why)) return false;
  const FeatureSpace space(map, config.graph);
  const std::vector<std::vector<int>> neighbours = space.neighbours();
  // Neighbour pairs joined in order of latent difference, and only while the two regions'
  // mean latents stay alike: a region cannot creep across an object boundary through the
  // blended latents there (single linkage would chain through them).
  std::vector<std::tuple<float, int, int>> edges;
  for (int i : space.active())
    for (int j : neighbours[static_cast<std::size_t>(i)]) {
      if (j <= i) continue;
      const float d = space.distance(space.z(i), space.z(j));
      if (d < config.graph.feature_threshold) edges.emplace_back(d, i, j);
    }
  std::sort(edges.begin(), edges.end());
  const int dim = space.dim();
  std::vector<float> sum(map.size() * static_cast<std::size_t>(dim));  // per root: sum of z
  std::vector<float> count(map.size(), 1.0f);
  for (int i : space.active()) std::copy(space.z(i), space.z(i) + dim, &sum[static_cast<std::size_t>(i) * dim]);
  std::vector<float> mean_a(static_cast<std::size_t>(dim)), mean_b(static_cast<std::size_t>(dim));
  UnionFind sets(map.size());
  for (const auto& [d, i, j] : edges) {
    const int a = sets.find(i), b = sets.find(j);
    if (a == b) continue;
    float* sa = &sum[static_cast<std::size_t>(a) * dim];
    float* sb = &sum[static_cast<std::size_t>(b) * dim];
    for (int c = 0; c < dim; ++c) {
      mean_a[c] = sa[c] / count[a];
      mean_b[c] = sb[c] / count[b];
    }
    if (space.distance(mean_a.data(), mean_b.data()) >= config.graph.feature_threshold) continue;
    sets.parent[a] = b;
    for (int c = 0; c < dim; ++c) sb[c] += sa[c];
    count[b] += count[a];
  }
  // Small regions (texture speckle, boundary Gaussians) join their most alike neighbour region.
  for (int round = 0; round < 8; ++round) {
    std::map<int, std::size_t> size;
    for (int i : space.active()) ++size[sets.find(i)];
    std::map<int, std::pair<float, int>> best;  // small root -> (distance, other root)
    for (int i : space.active()) {
      const int a = sets.find(i);
      if (size[a] >= config.min_instance_gaussians) continue;
      for (int j : neighbours[static_cast<std::size_t>(i)]) {
        const int b = sets.find(j);
        if (b == a) continue;
        const float d = space.distance(space.z(i), space.z(j));
        auto it = best.find(a);
        if (it == best.end() || d < it->second.first) best[a] = {d, b};
      }
    }
    if (best.empty()) break;
    for (const auto& [a, target] : best) sets.join(a, target.second);
  }
  std::map<int, std::size_t> size;
  for (int i : space.active()) ++size[sets.find(i)];
  std::vector<std::pair<std::size_t, int>> order;  // (size, root), largest first
  for (const auto& [root, n] : size)
    if (n >= config.min_instance_gaussians) order.push_back({n, root});
  std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  std::map<int, int> id;
  for (std::size_t k = 0; k < order.size(); ++k) id[order[k].second] = static_cast<int>(k);
  labels->label.assign(map.size(), -1);
  labels->count = static_cast<int>(order.size());
  for (int i : space.active()) {
    const auto it = id.find(sets.find(i));
    if (it != id.end()) labels->label[static_cast<std::size_t>(i)] = it->second;
  }
  return true;
}

void carry_instance_ids(const GaussianMap& previous_map, const GaussianLabels& previous,
                        const GaussianMap& map, float radius, GaussianLabels* labels) {
  if (previous_map.empty() || labels->count == 0) return;
  std::vector<float> points(previous_map.means);
  flann::Index<flann::L2<float>> index(flann::Matrix<float>(points.data(), previous_map.size(), 3),
                                       flann::KDTreeSingleIndexParams(10));
  index.buildIndex();
  // votes[new id][old id] = Gaussians of the new instance next to the old one.
  std::vector<std::map<int, std::size_t>> votes(static_cast<std::size_t>(labels->count));
  flann::SearchParams params(flann::FLANN_CHECKS_UNLIMITED);
  params.cores = 1;
  int nn = 0;
  float d2 = 0;
  for (std::size_t i = 0; i < map.size(); ++i) {
    const int l = labels->label[i];
    if (l < 0) continue;
    float q[3] = {map.means[i * 3], map.means[i * 3 + 1], map.means[i * 3 + 2]};
    flann::Matrix<int> im(&nn, 1, 1);
    flann::Matrix<float> dm(&d2, 1, 1);
    index.knnSearch(flann::Matrix<float>(q, 1, 3), im, dm, 1, params);
    if (d2 > radius * radius) continue;
    const int old = previous.label[static_cast<std::size_t>(nn)];
    if (old >= 0) ++votes[static_cast<std::size_t>(l)][old];
  }
  // Greedy by vote count: each old id goes to at most one new instance.
  std::vector<std::tuple<std::size_t, int, int>> pairs;  // (votes, new, old)
  for (int l = 0; l < labels->count; ++l)
    for (const auto& [old, n] : votes[static_cast<std::size_t>(l)]) pairs.push_back({n, l, old});
  std::sort(pairs.begin(), pairs.end(), [](const auto& a, const auto& b) { return std::get<0>(a) > std::get<0>(b); });
  std::vector<int> mapping(static_cast<std::size_t>(labels->count), -1);
  std::vector<bool> taken(static_cast<std::size_t>(std::max(previous.count, 0)), false);
  for (const auto& [n, l, old] : pairs) {
    if (mapping[static_cast<std::size_t>(l)] >= 0 || old >= previous.count || taken[static_cast<std::size_t>(old)]) continue;
    mapping[static_cast<std::size_t>(l)] = old;
    taken[static_cast<std::size_t>(old)] = true;
  }
  int next = previous.count;
  for (int& m : mapping)
    if (m < 0) m = next++;
  for (int& l : labels->label)
    if (l >= 0) l = mapping[static_cast<std::size_t>(l)];
  labels->count = next;
}

bool InstanceLabelCache::labels_for(std::uint64_t version_number, std::shared_ptr<const GaussianMap> map,
                                    VersionLabels* out, std::string* why) {
  if (!map) return fail(why, "instance labels: no map version");
  if (!holds(map)) {
    auto fresh = std::make_shared<GaussianLabels>();
    if (!cluster_instances(*map, config_, fresh.get(), why)) return false;
    if (last_.map) {
      carry_instance_ids(*last_.map, *last_.labels, *map, config_.graph.max_neighbour_distance, fresh.get());
    }
    last_ = {version_number, std::move(map), std::move(fresh)};
  }
  *out = last_;
  return true;
}

}  // namespace fslam::core

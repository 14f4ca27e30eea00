// Promptless instances of a feature-distilled map (docs/segmentation.md): the Gaussians
// clustered in feature space and space, ids carried over from version to version.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "fslam/core/map/gaussian_map.hpp"
#include "fslam/core/segmentation/feature_graph.hpp"

namespace fslam::core {

struct PromptlessConfig {
  FeatureGraphConfig graph;
  // Regions with fewer Gaussians join the neighbouring instance with the most alike latent.
  std::size_t min_instance_gaussians = 100;
  bool is_valid(std::string* why = nullptr) const;
};

// A label per Gaussian: 0..count-1, or -1 for none.
struct GaussianLabels {
  std::vector<int> label;  // [N]
  int count = 0;
};

// Promptless instances: connected regions of the feature graph, small ones merged, numbered by
// size (0 = largest). False with `why` for a map without features or a bad config.
bool cluster_instances(const GaussianMap& map, const PromptlessConfig& config,
                       GaussianLabels* labels, std::string* why);

// Keeps instance ids stable over time: relabels `labels` (of `map`) so that each instance takes
// the id of the earlier instance most of its Gaussians lie next to (within `radius` metres of an
// earlier Gaussian of `previous_map`); new instances get ids after the largest earlier one.
void carry_instance_ids(const GaussianMap& previous_map, const GaussianLabels& previous,
                        const GaussianMap& map, float radius, GaussianLabels* labels);

// The promptless instances of one map version.
struct VersionLabels {
  std::uint64_t version_number = 0;
  std::shared_ptr<const GaussianMap> map;        // the version labelled; null before the first
  std::shared_ptr<const GaussianLabels> labels;  // one per Gaussian of `map`
};

// Promptless instances over the versions of a growing map: each version is clustered once, and
// each clustering carries its ids from the one before (carry_instance_ids within the graph's
// neighbour distance), so that an object keeps its id while the map grows. Not thread-safe: the
// caller serialises the calls (and so keeps the ids one chain over the versions).
class InstanceLabelCache {
 public:
  explicit InstanceLabelCache(const PromptlessConfig& config = {}) : config_(config) {}
  // Whether `map` is the version labelled last, whose labels come without clustering.
  bool holds(const std::shared_ptr<const GaussianMap>& map) const { return map && map == last_.map; }
  // The labels of `map`, version `version_number`: those cached when it is the version labelled
  // last (with the version number it was labelled as), else it is clustered, its ids carried
  // from the last, and it becomes the last. False with `why` when clustering fails (the cache is
  // then unchanged).
  bool labels_for(std::uint64_t version_number, std::shared_ptr<const GaussianMap> map,
                  VersionLabels* out, std::string* why);

 private:
  PromptlessConfig config_;
  VersionLabels last_;
};

}  // namespace fslam::core

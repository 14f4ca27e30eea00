// The feature graph open-set segmentation grows regions in (paper sec. "Novel-View Open-Set
// Segmentation"), shared by promptless instances (instances.hpp) and prompts (prompts.hpp).
#pragma once

#include <string>

#include "fslam/core/map/gaussian_map.hpp"

namespace fslam::core {

// The neighbourhood graph both modes grow regions in: k nearest Gaussian means within a radius,
// joined when their latents are alike. Latents are compared centred and scaled by their spread
// over the map (one scale for all channels), as the RMS difference over the D channels.
struct FeatureGraphConfig {
  int knn = 10;                        // neighbours per Gaussian
  float max_neighbour_distance = 0.08f;  // metres between means; farther is never one object
  float feature_threshold = 0.6f;      // RMS standardised latent difference joining two Gaussians
  float min_opacity = 0.1f;            // fainter Gaussians take no part (label -1)
  bool is_valid(std::string* why = nullptr) const;
};

// Whether the map carries features to segment by: a latent per Gaussian (feature_dim > 0) and
// not all alike (a map built without an encoder keeps every latent at its initial value).
bool has_features(const GaussianMap& map);

// Pixels less opaque than this show background, not an object: the cut of every rendered label,
// selection mask and point prompt.
inline constexpr float kMinObjectAlpha = 0.5f;

}  // namespace fslam::core

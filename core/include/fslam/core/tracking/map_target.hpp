// The GICP target made from the Gaussian map itself (paper eq. gicp_sets: G^t is the global
// map; eq. feat_gicp weights each correspondence by the target's opacity alpha and compares the
// frame's features with the Gaussians' distilled ones). The mapper's optimisation therefore
// moves what the tracker registers against.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/map/gaussian_map.hpp"
#include "fslam/core/tracking/gaussian_points.hpp"
#include "fslam/core/tracking/local_map.hpp"
#include "fslam/core/tracking/preprocess.hpp"

namespace fslam::core {

// What a target Gaussian's covariance is made from (all scale-free like the source's unit discs,
// then scaled by the depth-noise model).
enum class MapTargetCovariance {
  disc,        // a unit disc across the Gaussian's thinnest axis (in-plane elongation dropped)
  shape,       // the Gaussian's normalised shape (largest axis 1, in-plane elongation kept)
  neighbours,  // the plane of its k nearest target means, as the frame's (CovarianceConfig):
               // the Gaussian's own shape is not used, only where the map's means lie
};

struct MapTargetConfig {
  float min_opacity = 0.1f;          // effective opacity below which a Gaussian is no target
  float min_point_distance = 0.015f; // metres; thinning of the target (LocalMap), densest first
  MapTargetCovariance covariance = MapTargetCovariance::disc;
  // Benchmarks only, not real time: before the frame after a keyframe, tracking waits (up to
  // 120 s) for the target built from the map version that contains that keyframe, so the target
  // never lags the tracker (docs/tracking.md "Why the Gaussian target loses").
  bool wait_for_mapper = false;
  // Each target covariance divided by the number of the mapper's stored keyframes whose depth
  // sees the Gaussian (weight_by_observations): what the point map's fusion gives re-observed
  // surfaces. The count also decides which Gaussians hold their means against the bridge's
  // re-observations in the tracker's copy (two views or more; SlamPipeline::publish_map_target).
  // Off: every Gaussian weighs as one observation (the paper's eq. gicp_sets) and every one holds.
  bool observation_weight = true;
  bool is_valid(std::string* why = nullptr) const;
};

// A depth image that observed the map (a mapper's stored keyframe), for weight_by_observations.
struct ObservingDepth {
  PinholeCamera camera;  // of `depth`'s size
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
  cv::Mat depth;  // CV_32FC1 metres, 0 = missing
};

// Divides each point's covariance by the number of `views` whose depth sees its mean
// (depth_sees within max_depth_difference), at least 1. The point map's fusion multiplies a
// re-observed point's Gaussians (LocalMap::insert: information adds, N observations give 1/N of
// the covariance), so a surface many keyframes saw weighs more in GICP and holds the frame to what
// was mapped before; a map Gaussian's target covariance would otherwise be one observation's
// however many keyframes fitted it (docs/tracking.md "Why the Gaussian target loses").
// Returns each point's count of views that see it (0 for none).
std::vector<int> weight_by_observations(const std::vector<ObservingDepth>& views, float max_depth_difference,
                            GaussianPoints* points);

// The Gaussians of `map` within `radius` of `centre_world` as GICP target points, most opaque
// first: mean; covariance as config.covariance says (from R diag(s^2 + filter) R^T of scale and
// rotation, or from the neighbouring means with preprocess.covariance's k-NN, which drops
// Gaussians with too few neighbours), normalised as the frame's source covariances are (largest
// axis 1, thinnest floored at plane_epsilon, times the sensor's depth noise at its distance from
// `centre_world`); opacity sigmoid(logit) with the 3D
// filter's compensation; the distilled latent as its features (when the map has them).
GaussianPoints map_target_points(const GaussianMap& map, const Eigen::Vector3f& centre_world,
                                 float radius, const MapTargetConfig& config,
                                 const PreprocessConfig& preprocess);

// The target of a tracker started in an existing map (Tracker::start_in): every Gaussian of `map`
// as map_target_points makes them, in one LocalMap that forgets nothing (no radius) and fuses
// nothing. The depth-noise scaling is left out: there is no one camera to measure from, so
// every covariance is the unit disc of the reference depth.
LocalMap localisation_target(const GaussianMap& map, const LocalMapConfig& local_map,
                             const MapTargetConfig& config, PreprocessConfig preprocess);

}  // namespace fslam::core

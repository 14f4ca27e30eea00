#include "fslam/core/tracking/map_target.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include <Eigen/Eigenvalues>
#include <tbb/parallel_for.h>

#include "fslam/core/error.hpp"
#include "fslam/core/math/splat_math.hpp"
#include "fslam/core/tracking/point_features.hpp"

namespace fslam::core {

bool MapTargetConfig::is_valid(std::string* why) const {
  if (!(min_opacity >= 0.0f && min_opacity < 1.0f)) return fail(why, "map_target.min_opacity must be in [0, 1)");
  if (!(min_point_distance >= 0.0f)) return fail(why, "map_target.min_point_distance must be >= 0 m");
  return true;
}

GaussianPoints map_target_points(const GaussianMap& map, const Eigen::Vector3f& centre_world,
                                 float radius, const MapTargetConfig& config,
                                 const PreprocessConfig& preprocess) {
  GaussianPoints out;
  const std::size_t n = map.size();
  const float epsilon = preprocess.covariance.plane_epsilon;
  const int D = map.features.empty() ? 0 : map.feature_dim;
  // Candidates with their opacity and axis variances (one pass over the map), then most opaque
  // first: the LocalMap's thinning keeps the first of two Gaussians closer than min_point_distance.
  struct Candidate {
    float opacity;
    std::size_t index;
    Eigen::Vector3f variance;  // scale^2 + filter variance per axis
  };
  std::vector<Candidate> order;
  order.reserve(n);
  const float radius2 = radius * radius;
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector3f mean(map.means[3 * i], map.means[3 * i + 1], map.means[3 * i + 2]);
    if ((mean - centre_world).squaredNorm() > radius2) continue;
    // Effective opacity as the renderer composites it (3D filter compensation).
    const float filter = map.filter_3d.empty() ? 0.0f : map.filter_3d[i];
    float scale[3], scale_eff[3];
    const float coef = math::filtered_scales(&map.log_scales[3 * i], filter, scale, scale_eff);
    const float opacity = math::sigmoid(map.opacity_logits[i]) * coef;
    if (opacity < config.min_opacity) continue;
    order.push_back({opacity, i,
                     Eigen::Vector3f(scale[0] * scale[0] + filter, scale[1] * scale[1] + filter,
                                     scale[2] * scale[2] + filter)});
  }
  std::sort(order.begin(), order.end(), [](const Candidate& a, const Candidate& b) {
    return a.opacity > b.opacity || (a.opacity == b.opacity && a.index < b.index);
  });
  out.reserve(order.size());
  out.opacities.reserve(order.size());
  out.feature_dim = D;
  if (D > 0) out.features.reserve(order.size() * static_cast<std::size_t>(D));
  for (const auto& [opacity, i, axis_variance] : order) {
    const Eigen::Vector3f mean(map.means[3 * i], map.means[3 * i + 1], map.means[3 * i + 2]);
    float q[4] = {map.rotations[4 * i], map.rotations[4 * i + 1], map.rotations[4 * i + 2],
                  map.rotations[4 * i + 3]};
    float R[9];
    math::quat_to_rotmat(q, R);
    Eigen::Vector3f variance = axis_variance;
    const Eigen::Map<const Eigen::Matrix<float, 3, 3, Eigen::RowMajor>> Rg(R);
    if (config.covariance == MapTargetCovariance::disc) {
      // The surface the Gaussian stands for, as the source's: a unit disc across its thinnest
      // axis (eigenvalues epsilon, 1, 1), in-plane elongation dropped.
      int thinnest = 0;
      for (int k = 1; k < 3; ++k)
        if (variance[k] < variance[thinnest]) thinnest = k;
      for (int k = 0; k < 3; ++k) variance[k] = k == thinnest ? epsilon : 1.0f;
    } else if (config.covariance == MapTargetCovariance::shape) {
      // The Gaussian's shape, scale-free like the source's unit discs: largest axis 1, the
      // thinnest no thinner than plane_epsilon.
      const float largest = std::max(variance.maxCoeff(), 1e-12f);
      for (int k = 0; k < 3; ++k) variance[k] = std::max(variance[k] / largest, epsilon);
    }
    out.means.push_back(mean);
    // neighbours: set below from the target's means, once all are known.
    out.covariances.push_back(Rg * variance.asDiagonal() * Rg.transpose());
    out.opacities.push_back(opacity);
    if (D > 0) {
      const float* f = map.features.data() + i * static_cast<std::size_t>(D);
      out.features.insert(out.features.end(), f, f + D);
    }
  }
  if (config.covariance == MapTargetCovariance::neighbours) estimate_covariances_knn(preprocess.covariance, &out);
  for (std::size_t k = 0; k < out.size(); ++k)
    out.covariances[k] *= preprocess.depth_noise.covariance_scale((out.means[k] - centre_world).norm());
  return out;
}

std::vector<int> weight_by_observations(const std::vector<ObservingDepth>& views, float max_depth_difference,
                                        GaussianPoints* points) {
  std::vector<Eigen::Isometry3d> T_camera_world;
  T_camera_world.reserve(views.size());
  for (const ObservingDepth& view : views) T_camera_world.push_back(view.T_world_camera.inverse());
  std::vector<int> seen(points->size(), 0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, points->size()), [&](const auto& r) {
    for (std::size_t k = r.begin(); k != r.end(); ++k) {
      for (std::size_t v = 0; v < views.size(); ++v)
        seen[k] += depth_sees(views[v].camera, views[v].depth, T_camera_world[v], points->means[k], max_depth_difference);
      if (seen[k] > 1) points->covariances[k] /= static_cast<float>(seen[k]);
    }
  });
  return seen;
}

namespace {
constexpr float kUnbounded = 1.0e6f;  // metres: a radius no map reaches (finite, as LocalMap needs)
}  // namespace

LocalMap localisation_target(const GaussianMap& map, const LocalMapConfig& local_map,
                             const MapTargetConfig& config, PreprocessConfig preprocess) {
  LocalMapConfig fixed = local_map;
  fixed.fuse = false;  // Gaussians are not observations to average
  fixed.min_point_distance = std::min(config.min_point_distance, fixed.voxel_size);
  fixed.radius = kUnbounded;
  preprocess.depth_noise.enabled = false;
  LocalMap target(fixed);
  const Eigen::Vector3f origin = Eigen::Vector3f::Zero();
  target.insert(map_target_points(map, origin, kUnbounded, config, preprocess), origin);
  return target;
}

}  // namespace fslam::core

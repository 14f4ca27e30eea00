// GICP as maximum-likelihood pose estimation (paper eq. gicp_pose) and its feature-guided form
// (eq. feat_gicp, feat_dist), solved by Gauss-Newton on se(3) with a robust kernel.
//
// The solver is assembled from small parts (small_gicp's shape): a Target that answers nearest-
// neighbour queries (eq. correspondence), a per-correspondence factor that linearises one
// residual, and a Reduction that sums factors into (H, b, cost) -- serial or TBB, one contract.
#pragma once

#include <cstddef>
#include <limits>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/tracking/gaussian_points.hpp"

namespace fslam::core {

enum class RobustKernel { none, huber, cauchy };

struct GicpConfig {
  int max_iterations = 20;
  float max_correspondence_distance = 0.08f;  // metres; farther nearest neighbours are outliers
  RobustKernel kernel = RobustKernel::huber;
  double kernel_scale = 1.0;         // on the Mahalanobis distance sqrt(d^T C^-1 d), unitless
  double translation_epsilon = 1e-4; // metres; converged when the update is smaller ...
  double rotation_epsilon = 1e-4;    // radians; ... in both translation and rotation
  double lm_lambda = 1e-6;           // Levenberg damping added to H's diagonal (relative)
  // Feature-guided GICP (eq. feat_gicp): each correspondence's Mahalanobis term is weighted by the
  // target opacity alpha and by the feature similarity exp(-gamma ||f_s - f_t||^2 / s) (eq.
  // feat_dist), the distance in units of what a correct correspondence is expected to differ
  // by: s = 2 spread_s + feature_noise (GaussianPoints::feature_spread; docs/tracking.md).
  bool use_opacity = true;           // ignored when the target has no opacities
  bool use_features = true;          // ignored when source or target has no features
  // gamma of eq. feat_dist on the scaled distance, unitless. Same-surface correspondences on
  // redkitchen measure 0.34 (median) and 1.8 (p90), which keep weights 0.98 and 0.89; between
  // unrelated points of a frame the median is 19 (weight 0.30).
  double feature_gamma = 1.0 / 16.0;
  // Feature units^2: the floor of s, the distance between two observations of one surface point
  // where the latent does not vary around it (redkitchen: 0.03 with the camera at rest, 0.2 as
  // the median over successive frames, which includes some motion).
  double feature_noise = 0.1;
  // lambda_f of the feature residual, eq. feat_gicp's d_f read as an added term that depends on
  // T: alpha lambda_f (1 - d_f) / gamma per correspondence, d_f = exp(-gamma ||f_s(T^-1 mu_t) -
  // f_t||^2 / s), the frame's latent read where the target lands in the frame (linearised by
  // GaussianPoints::feature_gradient). Unitless; 0 = off (the default: with the builtin encoder
  // every weight tried made tracking worse, docs/tracking.md "A feature residual").
  double feature_residual_weight = 0.0;
  bool is_valid(std::string* why = nullptr) const;
};

// The linear system of one Gauss-Newton step: sum over inlier correspondences of
// w * J^T C^-1 J (H), w * J^T C^-1 d (b), and the robustified cost.
struct LinearSystem {
  Matrix6d H = Matrix6d::Zero();
  Vector6d b = Vector6d::Zero();
  double cost = 0.0;
  double squared_distance_sum = 0.0;  // sum of |d|^2 over inliers, metres^2 (for the RMS)
  double feature_weight_sum = 0.0;    // sum of eq. feat_dist's similarity over inliers
  double mahalanobis_sum = 0.0;       // sum of d^T C^-1 d over inliers (before weights and kernel)
  std::size_t inliers = 0;
  LinearSystem& operator+=(const LinearSystem& other);
};

struct GicpResult {
  Eigen::Isometry3d T_target_source = Eigen::Isometry3d::Identity();
  bool converged = false;
  int iterations = 0;
  std::size_t source_points = 0;
  std::size_t inliers = 0;          // correspondences within max_correspondence_distance
  double inlier_ratio = 0.0;        // inliers / source_points
  double rms_residual = 0.0;        // metres, sqrt(mean |d|^2) over inliers (sigma_gicp of eq. keyframe_crit)
  double cost = 0.0;                // final robustified objective
  Matrix6d H = Matrix6d::Zero();    // Gauss-Newton Hessian at the solution ([rho; phi] order)
  double condition_number = 0.0;    // lambda_max / lambda_min of H about the camera centre (inf if singular)
  bool features_used = false;       // the feature term of eq. feat_gicp was active
  // Mean over inliers of eq. feat_dist's similarity exp(-gamma d_f / s) at the solution: how
  // alike the frame's features and their matched targets' are (1: identical). NaN without features.
  double mean_feature_weight = std::numeric_limits<double>::quiet_NaN();
  // Mean over inliers of d^T C^-1 d at the solution, unitless: with near-planar covariances it
  // is dominated by the residual along the surfaces' normals, so it says how far the frame's
  // points lie off the target's surfaces (0 without inliers).
  double mean_mahalanobis = 0.0;
};

// Any target: `const TargetPoint* nearest(const Eigen::Vector3f& q, float max_distance,
// float* squared_distance) const`, `int feature_dim() const` and
// `const float* feature(const TargetPoint&) const` (LocalMap and KdTreeTarget provide them).
// Both reductions visit every source point once and return the summed LinearSystem.
struct SerialReduction {};
struct TbbReduction {
  std::size_t grain = 256;  // source points per task
};

// Linearises every correspondence at T_target_source (left perturbation T <- exp(xi) T, xi in
// [rho; phi] order). Defined in gicp_impl.hpp for each (Target, Reduction) pair.
template <typename Target, typename Reduction>
LinearSystem linearize(const GaussianPoints& source, const Target& target,
                       const Eigen::Isometry3d& T_target_source, const GicpConfig& config,
                       const Reduction& reduction);

// Gauss-Newton from T_init until the update is below the epsilons or max_iterations.
template <typename Target, typename Reduction>
GicpResult align(const GaussianPoints& source, const Target& target,
                 const Eigen::Isometry3d& T_init, const GicpConfig& config,
                 const Reduction& reduction);

}  // namespace fslam::core

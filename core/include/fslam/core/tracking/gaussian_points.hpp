// Points with per-point covariances: the source and target sets of GICP (paper eq. gicp_sets).
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace fslam::core {

// Structure of arrays; every array has size() entries except `features` ([size() * feature_dim])
// and the optional ones, which are empty when absent.
struct GaussianPoints {
  std::vector<Eigen::Vector3f> means;        // [N] metres, in the frame the owner names
  std::vector<Eigen::Matrix3f> covariances;  // [N] m^2, regularised (well conditioned)
  std::vector<float> opacities;              // [N] in [0, 1], optional (empty = all 1)
  std::vector<float> features;               // [N * feature_dim], optional (empty = none)
  int feature_dim = 0;
  // [N] feature units^2, optional (empty = none): how far the latent moves one latent cell away
  // from the point (sample_point_features), the feature distance that a correspondence off by
  // about one lattice cell costs. Eq. feat_dist measures the distance in units of it.
  std::vector<float> feature_spread;
  // [N * feature_dim * 3] feature units per metre, optional (empty = none), camera frame only
  // (transformed() drops it): d f / d X of the frame's latent at the point, row-major D x 3, for
  // a point X moving in front of the camera (the image gradient through the projection's
  // Jacobian, so zero along the ray). The feature residual of eq. feat_gicp linearises with it.
  std::vector<float> feature_gradient;

  std::size_t size() const { return means.size(); }
  bool empty() const { return means.empty(); }
  bool has_opacities() const { return !opacities.empty(); }
  bool has_features() const { return feature_dim > 0 && !features.empty(); }
  bool has_feature_spread() const { return !feature_spread.empty(); }
  bool has_feature_gradient() const { return !feature_gradient.empty(); }
  const float* feature(std::size_t i) const { return features.data() + i * feature_dim; }
  void clear();
  void reserve(std::size_t n);
  // Checks the array sizes agree and every mean and covariance is finite.
  bool is_consistent(std::string* why = nullptr) const;
};

// Points and covariances moved by T (eq. rigid_transform: mu -> R mu + t, Sigma -> R Sigma R^T).
GaussianPoints transformed(const GaussianPoints& points, const Eigen::Isometry3d& T_to_from);

}  // namespace fslam::core

#include "fslam/core/tracking/gaussian_points.hpp"

#include <string>

#include "fslam/core/error.hpp"

namespace fslam::core {

void GaussianPoints::clear() {
  means.clear();
  covariances.clear();
  opacities.clear();
  features.clear();
  feature_dim = 0;
  feature_spread.clear();
  feature_gradient.clear();
}

// Only the arrays in use grow: optional opacities and features stay empty when absent, so that
// has_opacities() / has_features() keep meaning "present".
void GaussianPoints::reserve(std::size_t n) {
  means.reserve(n);
  covariances.reserve(n);
  if (!opacities.empty()) opacities.reserve(n);
  if (feature_dim > 0) features.reserve(n * static_cast<std::size_t>(feature_dim));
  if (!feature_spread.empty()) feature_spread.reserve(n);
}

bool GaussianPoints::is_consistent(std::string* why) const {
  const std::size_t n = size();
  if (covariances.size() != n)
    return fail(why, std::to_string(n) + " means but " + std::to_string(covariances.size()) +
                         " covariances");
  if (!opacities.empty() && opacities.size() != n)
    return fail(
        why, std::to_string(n) + " means but " + std::to_string(opacities.size()) + " opacities");
  if (feature_dim < 0)
    return fail(why, "feature_dim is negative (" + std::to_string(feature_dim) + ")");
  if (feature_dim == 0 && !features.empty())
    return fail(why, std::to_string(features.size()) + " feature values but feature_dim is 0");
  if (feature_dim > 0 && !features.empty() &&
      features.size() != n * static_cast<std::size_t>(feature_dim))
    return fail(why, std::to_string(features.size()) + " feature values for " + std::to_string(n) +
                         " points of dimension " + std::to_string(feature_dim));
  if (!feature_spread.empty() && feature_spread.size() != n)
    return fail(why, std::to_string(n) + " means but " + std::to_string(feature_spread.size()) +
                         " feature spreads");
  if (!feature_gradient.empty() && feature_gradient.size() != n * static_cast<std::size_t>(feature_dim) * 3)
    return fail(why, std::to_string(feature_gradient.size()) + " feature-gradient values for " +
                         std::to_string(n) + " points of dimension " + std::to_string(feature_dim));
  for (std::size_t i = 0; i < n; ++i) {
    if (!means[i].allFinite()) return fail(why, "mean " + std::to_string(i) + " is not finite");
    if (!covariances[i].allFinite())
      return fail(why, "covariance " + std::to_string(i) + " is not finite");
  }
  for (std::size_t i = 0; i < opacities.size(); ++i)
    if (!(opacities[i] >= 0.0f && opacities[i] <= 1.0f))
      return fail(why, "opacity " + std::to_string(i) + " is outside [0, 1]");
  return true;
}

GaussianPoints transformed(const GaussianPoints& points, const Eigen::Isometry3d& T_to_from) {
  const Eigen::Matrix3f R = T_to_from.rotation().cast<float>();
  const Eigen::Vector3f t = T_to_from.translation().cast<float>();
  GaussianPoints out;
  out.means.resize(points.size());
  out.covariances.resize(points.covariances.size());
  // Eq. rigid_transform: mu -> R mu + t, Sigma -> R Sigma R^T.
  for (std::size_t i = 0; i < points.means.size(); ++i) out.means[i] = R * points.means[i] + t;
  for (std::size_t i = 0; i < points.covariances.size(); ++i)
    out.covariances[i] = R * points.covariances[i] * R.transpose();
  out.opacities = points.opacities;
  out.features = points.features;
  out.feature_dim = points.feature_dim;
  out.feature_spread = points.feature_spread;
  return out;
}

}  // namespace fslam::core

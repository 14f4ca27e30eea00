#include "fslam/core/tracking/gicp.hpp"

#include <cmath>
#include <string>

#include "fslam/core/error.hpp"
#include "fslam/core/tracking/gicp_impl.hpp"
#include "fslam/core/tracking/kdtree_target.hpp"
#include "fslam/core/tracking/local_map.hpp"

namespace fslam::core {

bool GicpConfig::is_valid(std::string* why) const {
  const auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  if (max_iterations < 1)
    return fail(why,
                "gicp.max_iterations must be at least 1, got " + std::to_string(max_iterations));
  if (!positive(max_correspondence_distance))
    return fail(why, "gicp.max_correspondence_distance must be positive and finite (metres), got " +
                         std::to_string(max_correspondence_distance));
  if (kernel != RobustKernel::none && kernel != RobustKernel::huber &&
      kernel != RobustKernel::cauchy)
    return fail(why, "gicp.kernel is not a known robust kernel");
  if (!positive(kernel_scale))
    return fail(
        why, "gicp.kernel_scale must be positive and finite, got " + std::to_string(kernel_scale));
  if (!positive(translation_epsilon) || !positive(rotation_epsilon))
    return fail(why, "gicp.translation_epsilon and rotation_epsilon must be positive, got " +
                         std::to_string(translation_epsilon) + " and " +
                         std::to_string(rotation_epsilon));
  if (!(std::isfinite(lm_lambda) && lm_lambda >= 0.0))
    return fail(why,
                "gicp.lm_lambda must be finite and non-negative, got " + std::to_string(lm_lambda));
  if (!(std::isfinite(feature_gamma) && feature_gamma >= 0.0))
    return fail(why, "gicp.feature_gamma must be finite and non-negative, got " +
                         std::to_string(feature_gamma));
  if (!(std::isfinite(feature_noise) && feature_noise > 0.0))
    return fail(why, "gicp.feature_noise must be finite and positive, got " +
                         std::to_string(feature_noise));
  if (!(std::isfinite(feature_residual_weight) && feature_residual_weight >= 0.0))
    return fail(why, "gicp.feature_residual_weight must be finite and non-negative, got " +
                         std::to_string(feature_residual_weight));
  return true;
}

LinearSystem& LinearSystem::operator+=(const LinearSystem& other) {
  H += other.H;
  b += other.b;
  cost += other.cost;
  squared_distance_sum += other.squared_distance_sum;
  feature_weight_sum += other.feature_weight_sum;
  mahalanobis_sum += other.mahalanobis_sum;
  inliers += other.inliers;
  return *this;
}

FSLAM_GICP_INSTANTIATION(, KdTreeTarget, SerialReduction)
FSLAM_GICP_INSTANTIATION(, KdTreeTarget, TbbReduction)
FSLAM_GICP_INSTANTIATION(, LocalMap, SerialReduction)
FSLAM_GICP_INSTANTIATION(, LocalMap, TbbReduction)

}  // namespace fslam::core

#include "fslam/core/eval/rpe.hpp"

#include "fslam/core/error.hpp"

#include <algorithm>
#include <cmath>

#include "fslam/core/geometry/se3.hpp"

namespace fslam::core {
namespace {

constexpr double kRadToDeg = 180.0 / 3.14159265358979323846;

}  // namespace

const char* to_string(RpeUnit unit) {
  switch (unit) {
    case RpeUnit::kFrames: return "frames";
    case RpeUnit::kSeconds: return "seconds";
  }
  return "unknown";
}

bool validate(const RpeConfig& config, std::string* why) {
  if (!validate(config.association, why)) return false;
  if (!std::isfinite(config.delta) || !(config.delta > 0.0))
    return fail(why, "RPE delta must be positive, got " + std::to_string(config.delta));
  if (config.unit == RpeUnit::kFrames &&
      (config.delta < 1.0 || config.delta != std::floor(config.delta)))
    return fail(why, "RPE delta in frames must be a whole number >= 1, got " +
                         std::to_string(config.delta));
  if (config.unit != RpeUnit::kFrames && config.unit != RpeUnit::kSeconds)
    return fail(why, "unknown RPE unit");
  if (!std::isfinite(config.scale) || !(config.scale > 0.0))
    return fail(why, "RPE scale must be positive, got " + std::to_string(config.scale));
  return true;
}

bool compute_rpe(const Trajectory& gt, const Trajectory& est, const RpeConfig& config,
                 RpeResult* result, std::string* why) {
  if (!validate(config, why)) return false;
  for (const Trajectory* t : {&gt, &est})
    for (std::size_t i = 0; i < t->size(); ++i)
      if (!std::isfinite((*t)[i].timestamp) || !is_finite((*t)[i].T_world_camera))
        return fail(why, std::string(t == &gt ? "ground-truth" : "estimated") + " pose " +
                             std::to_string(i) + " is not finite");

  // Associated poses in estimate-time order; "frames" are counted along this list.
  auto matches = associate_trajectories(gt, est, config.association);
  std::sort(matches.begin(), matches.end(), [&](const auto& a, const auto& b) {
    return est[a.second].timestamp < est[b.second].timestamp;
  });
  const std::size_t n = matches.size();
  std::vector<double> stamps(n);
  for (std::size_t k = 0; k < n; ++k) stamps[k] = est[matches[k].second].timestamp;

  // Pairs (k, l) of positions in `matches`.
  std::vector<std::pair<std::size_t, std::size_t>> pairs;
  if (config.unit == RpeUnit::kFrames) {
    const auto step = static_cast<std::size_t>(config.delta);
    for (std::size_t k = 0; k + step < n; ++k) pairs.emplace_back(k, k + step);
  } else {
    // l is the pose nearest to t_k + delta, kept when it is within max(association tolerance,
    // delta / 10) of that target: timestamps jitter, but a pair must not span a tracking gap or
    // run past the end of the trajectory at a shorter span.
    const double tolerance = std::max(config.association.max_difference, 0.1 * config.delta);
    for (std::size_t k = 0; k < n; ++k) {
      const double target = stamps[k] + config.delta;
      if (target > stamps.back() + tolerance) break;
      const auto it = std::lower_bound(stamps.begin(), stamps.end(), target);
      std::size_t l = static_cast<std::size_t>(it - stamps.begin());
      if (l == n || (l > 0 && target - stamps[l - 1] <= stamps[l] - target)) --l;
      if (l > k && std::abs(stamps[l] - target) <= tolerance) pairs.emplace_back(k, l);
    }
  }
  if (pairs.empty())
    return fail(why, std::to_string(n) + " poses associated but no pair is " +
                         std::to_string(config.delta) + " " + to_string(config.unit) +
                         " apart: use a smaller RPE delta");

  RpeResult r;
  r.pairs = pairs.size();
  for (const auto& [k, l] : pairs) {
    const auto [gi, ei] = matches[k];
    const auto [gj, ej] = matches[l];
    const Eigen::Isometry3d Q_i_j = gt[gi].T_world_camera.inverse() * gt[gj].T_world_camera;
    Eigen::Isometry3d P_i_j = est[ei].T_world_camera.inverse() * est[ej].T_world_camera;
    P_i_j.translation() *= config.scale;
    const Eigen::Isometry3d E = Q_i_j.inverse() * P_i_j;
    r.first.push_back(ei);
    r.second.push_back(ej);
    r.translation_errors.push_back(E.translation().norm());
    r.rotation_errors.push_back(rotation_angle(E.linear()) * kRadToDeg);
  }
  r.translation = summarize_errors(r.translation_errors);
  r.rotation = summarize_errors(r.rotation_errors);
  *result = std::move(r);
  return true;
}

}  // namespace fslam::core

#include "fslam/core/tracking/tracker.hpp"

#include "fslam/core/tracking/point_features.hpp"

#include <algorithm>
#include <cmath>

#include "fslam/core/compute/thread_clock.hpp"
#include "fslam/core/error.hpp"
#include "fslam/core/tracking/gicp_impl.hpp"
#include "fslam/core/tracking/kdtree_target.hpp"

namespace fslam::core {
namespace {

// Re-registration after a loss searches wider: the prediction may be off by more than one frame.
constexpr float kRecoveryDistanceFactor = 2.0f;
// target = gaussians: keyframes kept for the bridge while the mapper has not mapped them. A
// mapper at full iterations on two CPU cores falls ~80 keyframes behind a tracker that is not
// paced (redkitchen 0-599); 128 keyframes of stride-8 points with 16-D features are ~75 MB.
constexpr std::size_t kMaxUnmappedKeyframes = 128;

}  // namespace

bool TrackingLossConfig::is_valid(std::string* why) const {
  if (!(min_inlier_ratio >= 0.0 && min_inlier_ratio <= 1.0))
    return fail(why, "loss.min_inlier_ratio must be in [0, 1]");
  if (!(max_condition_number > 1.0)) return fail(why, "loss.max_condition_number must be > 1");
  if (recovery_keyframes < 0) return fail(why, "loss.recovery_keyframes must be >= 0");
  return true;
}

bool TrackerConfig::is_valid(std::string* why) const {
  std::string reason;
  if (!preprocess.is_valid(&reason)) return fail(why, "preprocess: " + reason);
  if (!local_map.is_valid(&reason)) return fail(why, "local_map: " + reason);
  if (!gicp.is_valid(&reason)) return fail(why, "gicp: " + reason);
  if (!keyframe.is_valid(&reason)) return fail(why, reason);
  if (!loss.is_valid(&reason)) return fail(why, reason);
  if (!map_target.is_valid(&reason)) return fail(why, reason);
  if (!relocalisation.is_valid(&reason)) return fail(why, reason);
  if (!(wide_baseline_inlier_ratio >= 0.0 && wide_baseline_inlier_ratio <= 1.0))
    return fail(why, "wide_baseline_inlier_ratio must be in [0, 1]");
  if (local_map.voxel_size < gicp.max_correspondence_distance)
    return fail(why, "local_map.voxel_size must be >= gicp.max_correspondence_distance "
                     "(the neighbour search covers one voxel around the query)");
  return true;
}

const char* to_string(TrackingTarget target) {
  return target == TrackingTarget::gaussians ? "gaussians" : "points";
}

std::int64_t bridge_keyframes(const std::deque<KeyframePoints>& bridge, std::int64_t after_id, LocalMap* target) {
  std::int64_t newest = after_id;
  for (const KeyframePoints& kf : bridge) {
    if (kf.frame_id <= after_id) continue;
    target->insert(transformed(*kf.points_camera, kf.T_world_camera), kf.T_world_camera.translation().cast<float>());
    newest = kf.frame_id;
  }
  return newest;
}

void Tracker::set_map_target(LocalMap target, std::int64_t last_keyframe_id, std::int64_t bridged_through) {
  while (!unmapped_.empty() && unmapped_.front().frame_id <= last_keyframe_id) unmapped_.pop_front();
  map_ = std::move(target);
  map_.set_fuse(config_.local_map.fuse);  // the target's own setting (no fusing) is for its Gaussians
  bridge_keyframes(unmapped_, std::max(last_keyframe_id, bridged_through), &map_);
}

const char* to_string(TrackingState state) {
  switch (state) {
    case TrackingState::initialising: return "initialising";
    case TrackingState::ok: return "ok";
    case TrackingState::lost: return "lost";
    case TrackingState::recovered: return "recovered";
  }
  return "unknown";
}

Tracker::Tracker(const TrackerConfig& config)
    : config_(config), map_(config.local_map), relocaliser_(config.relocalisation) {}

void Tracker::start_in(LocalMap map, std::vector<DescribedKeyframe> keyframes, StartMode mode) {
  reset();
  map_ = std::move(map);
  for (DescribedKeyframe& kf : keyframes) relocaliser_.add_keyframe(std::move(kf));
  localising_ = mode == StartMode::localise;
  relocalise_first_ = true;
}

void Tracker::reset() {
  localising_ = false;
  relocalise_first_ = false;
  map_.clear();
  unmapped_.clear();
  T_last_.reset();
  T_velocity_.reset();
  keyframes_.clear();
  relocaliser_.clear();
}

RelocalisationAttempt Tracker::relocalise(const RgbdFrame& frame, const PreparedSource& prepared) const {
  const double t0 = steady_ms();
  FrameDescription query;
  std::string why;
  if (!describe_frame(frame, config_.relocalisation, config_.preprocess.min_depth, config_.preprocess.max_depth,
                      &query, &why)) {
    RelocalisationAttempt failed;
    failed.message = "relocalisation failed: " + why;
    return failed;
  }
  const double described = steady_ms() - t0;
  RelocalisationAttempt a = relocalise(query, prepared);
  a.describe_ms = described;
  return a;
}

RelocalisationAttempt Tracker::relocalise(const FrameDescription& query, const PreparedSource& prepared) const {
  return relocaliser_.relocalise(query, prepared.points, map_, config_.gicp);
}

GicpResult Tracker::register_frame(const GaussianPoints& source,
                                   const Eigen::Isometry3d& T_init) const {
  if (config_.parallel) return align(source, map_, T_init, config_.gicp, TbbReduction{});
  return align(source, map_, T_init, config_.gicp, SerialReduction{});
}

// Eq. keyframe_crit against the last keyframe (keyframe_policy.hpp).
bool Tracker::is_keyframe(const Eigen::Isometry3d& T_world_camera, const GicpResult& gicp) const {
  return core::is_keyframe(config_.keyframe, pose_motion(keyframes_.back().T_world_camera, T_world_camera),
                           gicp.rms_residual);
}

bool Tracker::is_lost(const GicpResult& gicp) const {
  return gicp.inliers < config_.loss.min_inliers ||
         gicp.inlier_ratio < config_.loss.min_inlier_ratio ||
         !(gicp.condition_number < config_.loss.max_condition_number) ||
         !is_finite(gicp.T_target_source);
}

bool Tracker::preprocess(const RgbdFrame& frame, const PlanarImage* latent, PreparedSource* out,
                         std::string* why) const {
  const double t0 = steady_ms();
  // Depth -> camera-frame Gaussian points (source set of eq. gicp_sets), with the frame's
  // features at their pixels (f_s of eq. feat_dist).
  if (!preprocess_frame(frame, config_.preprocess, &out->points, &out->stats, why)) return false;
  if (latent != nullptr && !latent->empty())
    sample_point_features(*latent, frame.camera, &out->points, config_.gicp.feature_residual_weight > 0.0);
  out->preprocess_ms = steady_ms() - t0;
  return true;
}

bool Tracker::track(const RgbdFrame& frame, TrackingResult* result, std::string* why,
                    const PlanarImage* latent) {
  PreparedSource prepared;
  return preprocess(frame, latent, &prepared, why) && track_prepared(frame, prepared, result, why, latent);
}

bool Tracker::track_prepared(const RgbdFrame& frame, const PreparedSource& prepared,
                             TrackingResult* result, std::string* why, const PlanarImage* latent) {
  (void)why;  // registration has no bad-input case left: preprocess checked the frame
  const double t1 = steady_ms();
  *result = TrackingResult{};
  const GaussianPoints& source = prepared.points;
  result->preprocess = prepared.stats;
  result->timings.preprocess_ms = prepared.preprocess_ms;
  const double t0 = t1 - prepared.preprocess_ms;  // totals include the preprocessing

  // The frame's ORB description, made once when the wide-baseline guess or a keyframe needs it.
  FrameDescription description;
  bool described = false;
  const auto describe = [&] {
    if (!described)
      described = describe_frame(frame, config_.relocalisation, config_.preprocess.min_depth,
                                 config_.preprocess.max_depth, &description, nullptr);
    return described;
  };
  auto add_keyframe = [&](const Eigen::Isometry3d& T_world_camera) {
    // The keyframe's points are fused into the map (moving the points they re-observe), then
    // the keyframe re-observes the map's features; a stored point within the correspondence
    // gate of the keyframe's depth is the surface the keyframe sees.
    map_.insert(transformed(source, T_world_camera), T_world_camera.translation().cast<float>());
    // On the map's Gaussians the target features are the distilled ones (eq. feat_dist's f_t):
    // keyframes refresh only their own points' features.
    if (config_.target == TrackingTarget::points && config_.refresh_features && latent != nullptr &&
        !latent->empty())
      refresh_map_features(*latent, frame.camera, frame.depth, T_world_camera,
                           config_.gicp.max_correspondence_distance, &map_);
    // Stored keyframes are registration targets only: the frame's feature gradients stay behind.
    auto points = std::make_shared<GaussianPoints>(source);
    points->feature_gradient.clear();
    points->feature_gradient.shrink_to_fit();
    keyframes_.push_back({frame.id, T_world_camera, std::move(points)});
    if (config_.relocalisation.enabled && describe())
      relocaliser_.add_keyframe(frame.id, T_world_camera, std::move(description));
    if (config_.target == TrackingTarget::gaussians) {
      unmapped_.push_back(keyframes_.back());  // the same points, shared
      // A mapper this far behind is not waited for: the oldest unmapped keyframes leave the
      // bridge (they are still in the current target until the next one replaces it).
      while (unmapped_.size() > kMaxUnmappedKeyframes) unmapped_.pop_front();
    }
    while (keyframes_.size() > static_cast<std::size_t>(config_.loss.recovery_keyframes) + 1)
      keyframes_.pop_front();
  };

  // Global relocalisation against every described keyframe, with no prior pose (the
  // description the wide-baseline start may have made already is reused).
  const auto relocalise_globally = [&] {
    const double t_describe = steady_ms();
    const bool ok = describe();
    const double describe_ms = steady_ms() - t_describe;
    result->relocalisation = ok ? relocalise(description, prepared) : RelocalisationAttempt{};
    result->relocalisation->describe_ms = describe_ms;
    if (!ok) result->relocalisation->message = "relocalisation failed: the frame has no ORB description";
    return result->relocalisation->accepted;
  };

  // Started in an existing map without a pose yet: the frame finds itself in it, or is lost.
  if (relocalise_first_ && !T_last_) {
    if (relocalise_globally()) {
      T_last_ = result->relocalisation->T_world_camera;
      result->T_world_camera = *T_last_;
      result->gicp = result->relocalisation->verification;
      result->state = TrackingState::recovered;
      result->message = result->relocalisation->message;
      if (!localising_) {  // extend: the first keyframe of the session, in the map's world
        add_keyframe(*T_last_);
        result->keyframe = true;
      }
    } else {
      result->state = TrackingState::lost;
      result->message = "not localised yet: " + result->relocalisation->message;
    }
    result->timings.registration_ms = steady_ms() - t1;
    result->timings.total_ms = steady_ms() - t0;
    return true;
  }

  // The first frame defines the world.
  if (!T_last_) {
    if (source.size() < config_.loss.min_inliers) {
      result->state = TrackingState::lost;
      result->message = "first frame has only " + std::to_string(source.size()) +
                        " usable depth points; waiting for a better one";
      result->timings.total_ms = steady_ms() - t0;
      return true;
    }
    T_last_ = T_initial_;
    add_keyframe(T_initial_);
    result->T_world_camera = T_initial_;
    result->state = TrackingState::initialising;
    result->keyframe = true;
    result->timings.map_update_ms = steady_ms() - t1;
    result->timings.total_ms = steady_ms() - t0;
    return true;
  }

  // 2. Register against the local map from the constant-velocity prediction (eq. gicp_pose /
  //    eq. feat_gicp when the map carries opacities and features).
  //    The prediction is re-orthonormalised: the product T_{k-1} T_{k-2}^-1 T_{k-1} (inverse()
  //    assumes a rotation) otherwise compounds its rounding from frame to frame until a pose is
  //    not finite (the ring with --constant-velocity, before the end of its 3,600 frames).
  Eigen::Isometry3d T_predicted = *T_last_;
  if (config_.constant_velocity && T_velocity_) {
    const Eigen::Isometry3d T_moved = orthonormalise((*T_last_ * *T_velocity_).matrix());
    if (is_finite(T_moved)) T_predicted = T_moved;
  }
  GicpResult gicp = register_frame(source, T_predicted);
  result->state = TrackingState::ok;

  // 2b. Wide baseline (issue 20): a registration that keeps few points may have settled in
  //     another basin of the nearest-neighbour cost; ORB matches to the last keyframe (RANSAC)
  //     give a start that does not depend on the prediction. A localising tracker makes no
  //     keyframes: the map's keyframe nearest the last pose serves instead.
  std::optional<std::int64_t> reference;
  if (config_.relocalisation.enabled && gicp.inlier_ratio < config_.wide_baseline_inlier_ratio) {
    if (localising_) reference = relocaliser_.nearest_keyframe(*T_last_);  // a scan of the map's keyframes
    else if (!keyframes_.empty()) reference = keyframes_.back().frame_id;
  }
  if (reference) {
    Eigen::Isometry3d T_guess;
    std::size_t matched = 0;
    if (describe() && relocaliser_.pose_from_keyframe(description, *reference, &T_guess, &matched)) {
      const GicpResult from_guess = register_frame(source, T_guess);
      if (!is_lost(from_guess) && from_guess.inlier_ratio > gicp.inlier_ratio) {
        gicp = from_guess;
        result->wide_baseline = true;
      }
    }
  }

  // 3. Loss detection and recovery: re-register against earlier keyframes from the last good pose.
  if (is_lost(gicp)) {
    const std::string reason = "inliers " + std::to_string(gicp.inliers) + " (" +
                               std::to_string(static_cast<int>(100.0 * gicp.inlier_ratio)) +
                               " %), condition " + std::to_string(gicp.condition_number);
    GicpConfig wide = config_.gicp;
    wide.max_correspondence_distance *= kRecoveryDistanceFactor;
    bool recovered = false;
    for (auto kf = keyframes_.rbegin(); kf != keyframes_.rend() && !recovered; ++kf) {
      KdTreeTarget target;
      if (!target.build(transformed(*kf->points_camera, kf->T_world_camera))) continue;
      GicpResult retry = align(source, target, *T_last_, wide, SerialReduction{});
      if (!is_lost(retry)) {
        gicp = retry;
        recovered = true;
        result->state = TrackingState::recovered;
        result->message = "lost (" + reason + "), recovered against keyframe " +
                          std::to_string(kf->frame_id);
      }
    }
    // Then global relocalisation against every described keyframe, with no prior pose.
    if (!recovered && config_.relocalisation.enabled && relocaliser_.size() > 0) {
      if (relocalise_globally()) {
        gicp = result->relocalisation->verification;
        recovered = true;
        result->state = TrackingState::recovered;
        result->message = "lost (" + reason + "), " + result->relocalisation->message;
      }
    }
    if (!recovered) {
      // Report the prediction as the pose but never let a lost frame change the map or motion.
      result->state = TrackingState::lost;
      result->message = "lost: " + reason;
      if (result->relocalisation) result->message += "; " + result->relocalisation->message;
      result->T_world_camera = T_predicted;
      result->gicp = gicp;
      result->timings.registration_ms = steady_ms() - t1;
      result->timings.total_ms = steady_ms() - t0;
      return true;
    }
  }
  const double t2 = steady_ms();
  result->timings.registration_ms = t2 - t1;

  const Eigen::Isometry3d T_world_camera = gicp.T_target_source;
  T_velocity_ = T_last_->inverse() * T_world_camera;
  T_last_ = T_world_camera;
  result->T_world_camera = T_world_camera;
  result->gicp = gicp;

  // 4. Keyframe decision (eq. keyframe_crit); only keyframes grow the local map (a localising
  //    tracker's map is fixed).
  if (!localising_ && is_keyframe(T_world_camera, gicp)) {
    add_keyframe(T_world_camera);
    result->keyframe = true;
  }
  result->timings.map_update_ms = steady_ms() - t2;
  result->timings.total_ms = steady_ms() - t0;
  return true;
}

}  // namespace fslam::core

// Frame-to-model odometry: preprocess -> feature-guided GICP against the local map -> keyframe
// decision (paper eq. keyframe_crit) -> local-map update, with a constant-velocity initial guess
// and tracking-loss detection and recovery.
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "fslam/core/geometry/rgbd_frame.hpp"
#include "fslam/core/render/planar_image.hpp"
#include "fslam/core/tracking/gicp.hpp"
#include "fslam/core/tracking/keyframe_policy.hpp"
#include "fslam/core/tracking/local_map.hpp"
#include "fslam/core/tracking/map_target.hpp"
#include "fslam/core/tracking/preprocess.hpp"
#include "fslam/core/tracking/relocaliser.hpp"

namespace fslam::core {

// A frame is lost when too few source points find a correspondence or the solve is degenerate.
struct TrackingLossConfig {
  double min_inlier_ratio = 0.3;       // of the source points
  std::size_t min_inliers = 200;
  double max_condition_number = 1e6;   // of the GICP Hessian
  int recovery_keyframes = 5;          // earlier keyframes tried when re-registering
  bool is_valid(std::string* why = nullptr) const;
};

// What a frame registers against (eq. gicp_sets' target G^t).
enum class TrackingTarget : std::uint8_t {
  points,     // the tracker's own local map of fused keyframe depth points
  gaussians,  // the mapper's Gaussians (map_target.hpp), plus the keyframes it has not mapped yet
};
const char* to_string(TrackingTarget target);

struct TrackerConfig {
  PreprocessConfig preprocess;
  LocalMapConfig local_map;
  TrackingTarget target = TrackingTarget::points;
  MapTargetConfig map_target;   // with target = gaussians
  GicpConfig gicp;
  KeyframeConfig keyframe;
  TrackingLossConfig loss;
  // Keyframes are described for global relocalisation, which a lost frame tries after the
  // re-registration against the last keyframes fails (relocaliser.hpp).
  RelocaliserConfig relocalisation;
  // Wide baseline (issue 20): when GICP from the prediction keeps fewer than this share of the
  // source points, the frame's ORB matches to the last keyframe give a second start and the
  // registration that keeps more points wins. 0 = never (needs relocalisation.enabled).
  // 0.95: on redkitchen every 20th frame a wrong basin kept 0.81 and right ones 0.86-1.0; at the
  // full rate 2 of 600 frames fall below it (docs/relocalisation.md).
  double wide_baseline_inlier_ratio = 0.95;
  // Initial guess T_k = T_{k-1} (T_{k-2}^-1 T_{k-1}), re-orthonormalised, instead of T_{k-1}. Off
  // by default: no more accurate (redkitchen 0-599 2.35 cm against 2.33; docs/tracking.md).
  bool constant_velocity = false;
  // Each keyframe overwrites the features of the map points it sees with its own latent there
  // (refresh_map_features). Off: a point keeps the feature of the first keyframe that stored it,
  // and since the latents change with viewpoint, eq. feat_dist then favours the newest keyframes'
  // points (docs/tracking.md). Geometry is never refreshed.
  bool refresh_features = true;
  bool parallel = false;          // TBB reduction instead of the serial one
  bool is_valid(std::string* why = nullptr) const;
};

enum class TrackingState : std::uint8_t { initialising, ok, lost, recovered };

// How a session starts in an existing map (Tracker::start_in, SlamPipeline::start_in).
enum class StartMode : std::uint8_t { localise, extend };
const char* to_string(TrackingState state);

// Wall time of each stage of one frame, milliseconds.
struct TrackingTimings {
  double preprocess_ms = 0.0;
  double registration_ms = 0.0;
  double map_update_ms = 0.0;
  double total_ms = 0.0;      // the three above
  double features_ms = 0.0;   // the frame's latent, when the caller computed one (SlamPipeline)
};

struct TrackingResult {
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
  TrackingState state = TrackingState::initialising;
  bool keyframe = false;
  GicpResult gicp;              // quality of this frame's registration
  PreprocessStats preprocess;
  TrackingTimings timings;
  std::string message;          // why a frame was lost or recovered, empty otherwise
  std::optional<RelocalisationAttempt> relocalisation;  // when the frame tried one
  bool wide_baseline = false;   // the registration from the ORB guess was kept
  // Loop closure's correction included in T_world_camera (SlamPipeline; the tracker's own pose
  // is T_map_odom^-1 T_world_camera). Identity without loop closure.
  Eigen::Isometry3d T_map_odom = Eigen::Isometry3d::Identity();
};

// A frame's source set of eq. gicp_sets, ready to register: what Tracker::preprocess makes
// without touching the tracker's state, so that one thread can prepare the next frame while
// another registers this one.
struct PreparedSource {
  GaussianPoints points;      // camera frame, with the frame's features when a latent was given
  PreprocessStats stats;
  double preprocess_ms = 0.0;
};

// A keyframe's pose and its camera-frame points, shared and never changed: the tracker keeps the
// recent ones for recovery, and with tracker.target = gaussians those no map version contains
// yet, which the mapping thread can bridge into a target it builds.
struct KeyframePoints {
  std::int64_t frame_id = 0;
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
  std::shared_ptr<const GaussianPoints> points_camera;
};

// Inserts the points of every keyframe of `bridge` newer than `after_id` into `target`, oldest
// first, as the point map inserts a keyframe's (LocalMap::insert, with the target's fuse
// setting): a point within min_point_distance of a target point is fused into it (a held map
// Gaussian, PointOrigin::map_gaussian, takes its information and keeps its mean); the rest fill
// what the target lacks, fused among themselves. Returns the newest frame_id inserted, or
// `after_id` when none is newer.
std::int64_t bridge_keyframes(const std::deque<KeyframePoints>& bridge, std::int64_t after_id, LocalMap* target);

class Tracker {
 public:
  explicit Tracker(const TrackerConfig& config);

  // Step 1 of track(): depth -> camera-frame Gaussian points and their features. Const and
  // thread-safe: reads only the configuration. False with `why` for bad input.
  bool preprocess(const RgbdFrame& frame, const PlanarImage* latent, PreparedSource* out,
                  std::string* why) const;
  // Steps 2-4 of track() on a prepared frame: registration, loss handling, keyframe decision,
  // local-map update. latent as track()'s (needed for keyframes' map features).
  bool track_prepared(const RgbdFrame& frame, const PreparedSource& prepared,
                      TrackingResult* result, std::string* why, const PlanarImage* latent = nullptr);

  // Tracks one frame. The first frame defines the world (its pose is T_world_camera_initial).
  // Returns false with `why` only for bad input; tracking failure is a result state, not an error.
  // latent (optional, [D, h, w] over the frame): the points' features for eq. feat_gicp; keyframes
  // then carry them into the local map as targets and refresh those of the map points they see.
  bool track(const RgbdFrame& frame, TrackingResult* result, std::string* why,
             const PlanarImage* latent = nullptr);

  // Global relocalisation of a prepared frame against the tracker's map and described keyframes,
  // with no prior pose. Changes nothing: the caller decides what an accepted pose means.
  RelocalisationAttempt relocalise(const RgbdFrame& frame, const PreparedSource& prepared) const;
  const Relocaliser& relocaliser() const { return relocaliser_; }

  void set_initial_pose(const Eigen::Isometry3d& T_world_camera) { T_initial_ = T_world_camera; }
  // With target = gaussians: the target built from a map version that contains every keyframe
  // up to `last_keyframe_id` (SlamPipeline builds it on the mapping thread). The tracker then
  // registers against it plus the keyframes it made since, which no version holds yet (the
  // bridge between a keyframe and the map version that contains it, bridge_keyframes). The
  // builder may have bridged some of them already, on its own thread: those up to
  // `bridged_through`; the tracker adds only the newer ones.
  void set_map_target(LocalMap target, std::int64_t last_keyframe_id, std::int64_t bridged_through = -1);
  // target = gaussians: the keyframes no map target contains yet, oldest first (bounded).
  const std::deque<KeyframePoints>& unmapped_keyframes() const { return unmapped_; }
  // Starts in an existing map (session modes localise and extend, issue 20): `map` is the target
  // (localisation_target of the map's Gaussians) and `keyframes` the relocaliser's; the first
  // frame, and every frame until one is found, relocalises with no prior pose. localise: the
  // target and keyframes stay fixed (no keyframe, no map point, no description is added) and a
  // lost frame relocalises again. extend: the frame found becomes the first keyframe and
  // tracking goes on as in a new map, describing new keyframes beside the map's. Before the
  // first frame; reset() leaves the mode.
  void start_in(LocalMap map, std::vector<DescribedKeyframe> keyframes, StartMode mode);
  bool localising() const { return localising_; }
  const LocalMap& local_map() const { return map_; }
  std::size_t keyframe_count() const { return keyframes_.size(); }
  void reset();

 private:
  bool is_keyframe(const Eigen::Isometry3d& T_world_camera, const GicpResult& gicp) const;
  bool is_lost(const GicpResult& gicp) const;
  GicpResult register_frame(const GaussianPoints& source, const Eigen::Isometry3d& T_init) const;
  RelocalisationAttempt relocalise(const FrameDescription& query, const PreparedSource& prepared) const;

  TrackerConfig config_;
  LocalMap map_;
  Eigen::Isometry3d T_initial_ = Eigen::Isometry3d::Identity();
  std::optional<Eigen::Isometry3d> T_last_;       // last tracked pose (world <- camera)
  std::optional<Eigen::Isometry3d> T_velocity_;   // T_{k-2}^-1 T_{k-1}
  std::deque<KeyframePoints> keyframes_;          // most recent last, bounded (recovery)

  // target = gaussians: keyframes no map target contains yet, oldest first (their points are
  // added to each new target).
  std::deque<KeyframePoints> unmapped_;
  Relocaliser relocaliser_;                       // every keyframe, described (bounded)
  bool localising_ = false;                       // start_in localise: map and keyframes fixed
  bool relocalise_first_ = false;                 // start_in: no pose until relocalised
};

}  // namespace fslam::core

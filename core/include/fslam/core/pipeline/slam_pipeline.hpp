// One SLAM session: tracking on the caller's thread, mapping on another thread the caller runs
// (core starts no threads of its own). Tracking never waits for mapping: keyframes are handed
// over through a queue and the mapper publishes immutable map versions (design.md data flow).
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "fslam/core/features/latent_features.hpp"
#include "fslam/core/geometry/rgbd_frame.hpp"
#include "fslam/core/mapping/mapper.hpp"
#include "fslam/core/pipeline/loop_thread.hpp"
#include "fslam/core/render/rasterizer.hpp"
#include "fslam/core/tracking/tracker.hpp"

namespace fslam::core {

struct PipelineConfig {
  TrackerConfig tracker;
  MapperConfig mapper;
  // Real-time mode: mapping gets what time is left. With keyframes waiting, each gets
  // iterations_per_keyframe / (1 + waiting) steps (at least min_iterations_when_behind), and
  // while none waits the mapper keeps optimising in steps of idle_iterations, up to
  // max_idle_iterations after the newest keyframe: a session that stops sending frames leaves
  // its mapping thread asleep (and its map version still) instead of busy for good.
  bool realtime = false;
  int min_iterations_when_behind = 2;
  int idle_iterations = 5;
  int max_idle_iterations = 200;
  // Real-time mode: at most this many keyframes wait for the mapper (each holds the frame's colour
  // and depth, ~2 MB at 640x480). Past it the most redundant waiting keyframe -- the one that moved
  // least from the keyframe before it -- is left out of the map (the tracker keeps it) and
  // counted, so memory stays bounded when tracking outruns mapping. 0: no bound.
  int max_queued_keyframes = 16;
  // Image features distilled into the Gaussians (off while features.autoencoder_path is empty).
  LatentFeaturesConfig features;
  // With features on, the tracker registers with the feature-guided weights of eq. feat_gicp:
  // each frame's latent on the tracker's lattice (the encoder and phi on every frame, on the
  // tracking thread). Off: geometry and opacity only, and the encoder runs on keyframes alone.
  bool track_with_features = true;
  // Builtin encoder only: the tracking thread encodes each frame at this square input (pixels, a
  // multiple of 16) instead of features.encoder.builtin's; keyframes are then encoded again at
  // the mapper's input on the mapping thread. 0: one encoding at the mapper's input, shared.
  int tracking_encoder_input = 0;
  // Off: tracking alone (`fslam track`): keyframes are not handed to a mapper. Not a setting.
  bool mapping = true;
  // Loop closure during tracking, on its own thread (loop_thread.hpp); off by default
  // (docs/relocalisation.md has the measurements). Needs tracker.relocalisation.enabled (place
  // recognition) and tracker.target points.
  LoopClosureConfig loop_closure;
  bool is_valid(std::string* why = nullptr) const;
};

// What the mapping thread did for one keyframe.
struct KeyframeReport {
  std::int64_t frame_id = 0;
  RefinementStats refinement;
  std::size_t map_size = 0;
  std::size_t queue_depth = 0;  // keyframes still waiting after this one
  double features_ms = 0;       // encoder + autoencoder for the keyframe's latent target
  // tracker.target = gaussians: the tracker's keyframes newer than this one that the mapping
  // thread bridged into the target it built from this keyframe's map version (0 otherwise).
  std::size_t bridged_keyframes = 0;
};

// A frame made ready for registration: the source Gaussians with their features, the latent on
// the tracker's lattice, and the encoder's pyramid (handed to the mapper if it becomes a
// keyframe). Made by prepare_frame, consumed by track_prepared.
struct PreparedFrame {
  RgbdFrame frame;
  PreparedSource source;
  PlanarImage latent;                       // [D, h, w] on the tracker's lattice, or empty
  std::shared_ptr<FeaturePyramid> pyramid;  // null without features
  double features_ms = 0.0;                 // encoder + phi
};

class SlamPipeline {
 public:
  // features (optional): the keyframes' latent targets for the feature loss; the Gaussians carry
  // its dim() channels (config.mapper.feature_dim is ignored: 0 without features).
  SlamPipeline(const PipelineConfig& config, std::shared_ptr<const Rasterizer> rasterizer,
               std::unique_ptr<LatentFeatures> features = nullptr);
  ~SlamPipeline();

  // Tracker thread: the frame's latent (track_with_features) -> preprocess -> feature-guided
  // GICP (eq. feat_gicp) -> keyframe decision (eq. keyframe_crit) -> hand the keyframe to
  // mapping. Never blocks on the mapper.
  // mapping_pose (optional): map the frame at this pose instead of the tracked one (mapping-only
  // evaluation with ground-truth poses, which separates map quality from tracking drift).
  bool process_frame(const RgbdFrame& frame, TrackingResult* result, std::string* why,
                     const Eigen::Isometry3d* mapping_pose = nullptr);
  // process_frame in two steps, so that a live service prepares frame k+1 on one thread while
  // frame k registers on another (the tracker's state is touched by track_prepared alone):
  // the frame's latent and source Gaussians (encoder, phi, preprocessing) ...
  bool prepare_frame(RgbdFrame frame, PreparedFrame* out, std::string* why);
  // Before the first frame (then the preparing thread may take over): makes the tracking encoder and runs it once
  // on a blank 640x480 image, so that the first frames of a live session are not skipped while
  // its buffers are allocated. A failure is left for the first frame to report.
  void warm_up();
  // ... then feature-guided GICP, the keyframe decision and the hand-over to mapping. Calls of
  // each step come one at a time, and track_prepared in frame order. The trajectory starts at the
  // first frame's ground-truth pose when it has one (evaluation runs and streams), else at the
  // identity.
  bool track_prepared(PreparedFrame&& prepared, TrackingResult* result, std::string* why,
                      const Eigen::Isometry3d* mapping_pose = nullptr);

  // Mapping thread: runs until finish() was called and every queued keyframe is mapped. In real
  // time the caller runs it at a lower priority than tracking (server::MappingThread does).
  // on_keyframe (optional) is called after each keyframe's refinement round. Returns false with
  // `why` when mapping failed (the tracker keeps running; the failure is reported once).
  bool run_mapping(const std::function<void(const KeyframeReport&)>& on_keyframe,
                   std::string* why);
  // No more frames: the mapping loop drains its queue and returns.
  void finish();
  // Shutdown: the keyframes still queued, and the one being mapped, go into the map without
  // their optimisation steps (Mapper::hurry), so a drain takes a fraction of a second each.
  void hurry_mapping() { mapper_.hurry(); }

  // After run_mapping returned: post-trajectory refinement (paper), `steps` steps.
  bool refine(int steps, std::string* why, const std::function<void(int, int)>& progress = nullptr,
              const std::atomic<bool>* stop = nullptr) {
    return mapper_.refine(steps, why, progress, stop);
  }

  // Starts in an existing map (session modes localise and extend, docs/protocol.md): the tracker
  // registers against `map` (localisation_target of its Gaussians) and relocalises its first
  // frame against `keyframes` (Tracker::start_in). localise: nothing reaches the mapper. extend:
  // the mapper continues `map`, numbering its versions after `version_number`, and the map's
  // keyframes are kept beside the ones this pipeline describes, renumbered -n..-1 oldest first
  // so that they never meet the new frames' ids; the decoded L_feat continues through `heads`,
  // the map's online heads (null: the pretrained ones; Mapper::continue_feature_decoder). False
  // with `why` when the mapper cannot take `map` (another SH degree or feature width) or `heads`
  // (other autoencoder weights). Before the first frame.
  bool start_in(const GaussianMap& map, std::uint64_t version_number, std::vector<DescribedKeyframe> keyframes,
                StartMode mode, const FeatureAutoencoder* heads, std::string* why);
  // The keyframes the tracker described so far (relocalisation's, bounded by its max_keyframes),
  // copied: saved with the map so that later sessions can relocalise in it. Any thread.
  std::vector<DescribedKeyframe> described_keyframes() const;
  // The mapper's online heads as of its newest version (null without the decoded L_feat), copied:
  // saved with the map so that an extend session continues them. Any thread.
  std::shared_ptr<const FeatureAutoencoder> feature_heads() const { return mapper_.published_heads(); }

  // Loop closure (config().loop_closure.enabled): what its thread did so far; nullopt when off.
  std::optional<LoopThreadStats> loop_closure_stats() const;
  // The correction loop closure applies to frame `frame_id`'s tracked pose (that of the keyframe
  // at or before it; identity when off). Once run_mapping returned it is final: the pose a frame
  // was reported at, T_world_camera = result.T_map_odom T_odom, becomes
  // loop_correction(id) T_map_odom^-1 T_world_camera in the final map's world.
  Eigen::Isometry3d loop_correction(std::int64_t frame_id) const;

  // The pipeline's config, mapper.feature_dim as the features give it.
  const PipelineConfig& config() const { return config_; }
  Tracker& tracker() { return tracker_; }
  const Mapper& mapper() const { return mapper_; }
  Mapper& mapper() { return mapper_; }
  MapVersions::Version latest_map() { return mapper_.versions().latest(); }
  // The mapping thread's features (nullptr without): for evaluation once run_mapping returned.
  LatentFeatures* features() { return features_.get(); }
  std::size_t queued_keyframes() const;
  // Keyframes left out of the map because max_queued_keyframes were waiting.
  std::uint64_t keyframes_left_out() const;

 private:
  PipelineConfig config_;
  Tracker tracker_;
  Mapper mapper_;
  // A keyframe on its way to the mapper, with the encoder's pyramid of its colour when the
  // tracker already encoded the frame (the mapper then only runs phi at its resolution).
  struct QueuedKeyframe {
    MapperKeyframe keyframe;
    std::shared_ptr<FeaturePyramid> pyramid;
    Eigen::Isometry3d T_odom = Eigen::Isometry3d::Identity();  // as tracked (loop closure)
  };
  class PyramidPool;
  // The tracking encoder's pyramid is also the mapper's (tracking_encoder_input 0 or the same).
  bool tracking_pyramid_is_mappers() const;
  // The tracking encoder (made at the first call) on `colour` of `camera`: its pyramid from the
  // pool, and the latent on the tracker's lattice.
  bool encode_for_tracking(const cv::Mat& colour, const PinholeCamera& camera,
                           std::shared_ptr<FeaturePyramid>* pyramid, PlanarImage* latent, std::string* why);
  // Returns how many of the tracker's newer keyframes it bridged into the target.
  std::size_t publish_map_target(const MapperKeyframe& kf);
  std::unique_ptr<LatentFeatures> features_;  // used by the mapping thread only
  // The preparing thread's own encoder (LatentFeatures is not thread-safe), made by warm_up or the first
  // frame when features_ is set and track_with_features is on.
  std::unique_ptr<LatentFeatures> tracking_features_;
  std::shared_ptr<PyramidPool> pyramids_;
  // tracker.target = gaussians: the newest target built from the map on the mapping thread (the
  // tracking side takes it, moved, not copied), the last keyframe it contains, the newest
  // keyframe it bridges, and a serial the tracking side compares with the one it took.
  std::unique_ptr<LocalMap> map_target_;                // guarded by mutex_
  std::int64_t map_target_keyframe_ = -1;               // guarded by mutex_
  std::int64_t map_target_bridged_ = -1;                // guarded by mutex_
  // The tracker's unmapped keyframes as of its last keyframe, for the mapping thread to bridge
  // into the target it builds (the tracking thread then bridges only what is newer).
  std::deque<KeyframePoints> bridge_;                   // guarded by mutex_
  std::uint64_t map_target_serial_ = 0;                 // guarded by mutex_
  std::uint64_t map_target_taken_ = 0;                  // tracking side only
  std::int64_t keyframe_awaited_ = -1;  // tracking side: map_target.wait_for_mapper waits for it
  std::condition_variable map_target_published_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<QueuedKeyframe> queue_;
  std::uint64_t keyframes_left_out_ = 0;  // guarded by mutex_
  std::deque<DescribedKeyframe> described_;  // guarded by mutex_; copies of the tracker's
  void bound_queue_locked();
  bool finished_ = false;
  // Mapping thread: the keyframe poses loop closure moved since the last call, to the mapper.
  void apply_loop_moves();
  std::unique_ptr<LoopThread> loop_;  // last: joined before the members its callback uses go
};

}  // namespace fslam::core

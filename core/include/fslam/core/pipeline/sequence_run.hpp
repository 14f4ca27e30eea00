// A run of SLAM over a recorded sequence (what `fslam run` and `fslam track` do): frames from a
// Dataset, decoded one ahead while the current one is tracked; optional pacing like a live
// sensor; the first frame's ground truth as the initial pose; after tracking, the caller's
// mapping thread drained, post-trajectory refinement, and rendering metrics of held-out views.
// Results are structs; progress goes through callbacks (core prints nothing).
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/eval/view_eval.hpp"
#include "fslam/core/pipeline/slam_pipeline.hpp"

namespace fslam::core {

struct SequenceRunConfig {
  // > 0: frame i arrives at start + i / realtime_fps, and a frame whose successor has already
  // arrived is skipped (a live system never sees it). 0: as fast as tracking goes.
  double realtime_fps = 0.0;
  // Map (and evaluate views) at the ground-truth poses; tracking still runs and is scored.
  bool ground_truth_poses = false;
  int refine_steps = 0;  // post-trajectory refinement after mapping
  int eval_every = 8;    // every n-th non-keyframe frame is held out (never trained on)
  int renders = 4;       // held-out views, spread over the sequence, handed to on_render
  bool is_valid(std::string* why = nullptr) const;
};

// What tracking the sequence gave, one entry per tracked (not skipped) frame.
struct SequenceTracking {
  Trajectory trajectory;                    // T_world_camera per tracked frame
  std::vector<std::size_t> frame_index;     // the dataset position of each entry
  std::vector<bool> keyframe;               // whether each entry became a keyframe
  std::vector<std::int64_t> frame_id;       // each entry's frame id
  // Loop closure's correction in each entry's pose as tracked (TrackingResult::T_map_odom);
  // run_sequence replaces the poses by the final map world's once mapping is done.
  std::vector<Eigen::Isometry3d> map_from_odom;
  std::vector<Eigen::Isometry3d> mapping_poses;  // with ground_truth_poses: where it was mapped
  std::vector<double> track_ms;             // wall time per frame after the first, ms
  // The tracking thread's CPU time over the same span, ms: track_ms less the time it waited for a
  // core (mapping's threads beside it) or a lock. Work it hands to other threads (OpenCV's pool,
  // tracker.parallel) is not counted.
  std::vector<double> track_cpu_ms;
  std::vector<double> features_ms;          // the latent of frames after the first (when > 0), ms
  std::vector<TrackingTimings> timings;     // per frame after the first (the first initialises)
  // Registration quality per frame after the first (GicpResult): inlier ratio, RMS residual in
  // metres, mean Mahalanobis term, and the mean feature similarity of eq. feat_dist (NaN
  // without features).
  std::vector<double> inlier_ratio, rms_residual_m, mahalanobis, feature_weight;
  std::vector<double> load_ms;              // decoding each frame (on the prefetch thread), ms
  std::size_t lost = 0, recovered = 0, skipped = 0;
  std::size_t wide_baseline = 0;            // frames registered from the ORB guess (tracker.hpp)
  double wall_s = 0.0;                      // tracking the whole sequence
  std::size_t keyframes() const;
};

struct SequenceRunResult {
  SequenceTracking tracking;
  double slam_s = 0.0;    // tracking start until mapping drained
  double refine_s = 0.0;  // post-trajectory refinement
  ViewScores held_out;    // eval_every's frames, from the final map
  ViewScores keyframes;   // the keyframes, from the final map
  std::size_t map_gaussians = 0, map_keyframes = 0, optimisation_steps = 0;
  // The decoded L_feat (loss_l1, in channel spreads) on the held-out views, of the pretrained
  // heads and of the heads after online LoRA; NaN unless the mapper decodes (FeatureLoss::decoded).
  double feature_error_pretrained = std::numeric_limits<double>::quiet_NaN();
  double feature_error_online = std::numeric_limits<double>::quiet_NaN();
  std::int64_t lora_steps = 0;  // online LoRA steps the heads took
  std::optional<LoopThreadStats> loop_closure;  // with loop closure on
  // The map is the pipeline's: pipeline->mapper().map().
};

struct SequenceCallbacks {
  std::function<void(std::size_t done, std::size_t total)> on_frame;  // tracked or skipped
  // A frame tracking lost, or recovered from a loss (result.message says why).
  std::function<void(std::int64_t frame_id, const TrackingResult& result)> on_tracking_event;
  // Tracking is over and pipeline->finish() was called; `queued` keyframes wait for mapping.
  std::function<void(const SequenceTracking& tracking, std::size_t queued)> on_tracking_done;
  // Waits for the caller's mapping thread (core starts none) to drain the queue; false with
  // `why` when mapping failed. Unset: no mapping runs.
  std::function<bool(std::string* why)> wait_for_mapping;
  std::function<void(int done, int total)> on_refine;
  std::function<void(std::size_t done, std::size_t total)> on_evaluated;
  // The `renders` chosen held-out views: the frame and its render from the final map.
  std::function<bool(const RgbdFrame& frame, const RenderResult& rendered, std::string* why)> on_render;
};

// Tracks every frame of `dataset` with pipeline->process_frame on the calling thread (frames are
// decoded one ahead on a helper thread, joined before it returns). Keyframes go to the mapping
// queue unless pipeline's config says mapping is off. Does not call finish().
bool track_sequence(const Dataset& dataset, SlamPipeline* pipeline, const SequenceRunConfig& config,
                    const SequenceCallbacks& callbacks, SequenceTracking* out, std::string* why);

// track_sequence, finish(), wait_for_mapping, refinement, then the rendering metrics of the
// held-out frames and the keyframes from the final map at the tracked (or ground-truth) poses.
bool run_sequence(const Dataset& dataset, SlamPipeline* pipeline, const Rasterizer& rasterizer,
                  const SequenceRunConfig& config, const SequenceCallbacks& callbacks,
                  SequenceRunResult* out, std::string* why);

}  // namespace fslam::core

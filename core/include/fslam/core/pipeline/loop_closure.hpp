// Loop closure (issue 20): each keyframe looks for an older one it revisits with the
// relocaliser's place recognition, the pair is verified by RANSAC over ORB matches and GICP
// between the two keyframes' points, and a pose graph over the keyframes (odometry edges from
// tracking, loop edges from the verified revisits) is optimised with Ceres (pose_graph.hpp).
// LoopCloser does it one keyframe at a time: on the pipeline's loop thread during tracking
// (SlamPipeline, PipelineConfig::loop_closure) and after tracking in close_loops (`fslam track
// --loop-closure`). docs/relocalisation.md gives the design.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "fslam/core/mapping/pose_graph.hpp"
#include "fslam/core/tracking/relocaliser.hpp"
#include "fslam/core/tracking/tracker.hpp"

namespace fslam::core {

class Dataset;            // dataset/dataset.hpp
struct SequenceTracking;  // pipeline/sequence_run.hpp (which includes the pipeline, and so this)

struct LoopClosureConfig {
  bool enabled = false;             // during tracking (SlamPipeline); close_loops ignores it
  std::size_t min_frame_gap = 300;  // frames between a keyframe and an older one it may close with
  int candidates = 3;               // older keyframes place recognition proposes per keyframe
  double min_verified_inlier_ratio = 0.6;  // GICP between the two keyframes' points
  // Each keyframe keeps at most this many of its points (evenly subsampled) as the target that
  // later revisits are verified against and measured from: ~48 bytes each, so ~290 KB a
  // keyframe. 6000 keeps a 640x480 frame's points at the tracker's stride 4 whole; half of them
  // made the loop edges less precise (docs/relocalisation.md).
  std::size_t verification_points = 6000;
  std::size_t max_keyframes = 2000;  // keyframes in the graph; past it loop closure stops adding
  // Edge sigmas: odometry between consecutive keyframes, and loops.
  double odometry_translation_sigma = 0.01, odometry_rotation_sigma = 0.0087;  // m, rad
  double loop_translation_sigma = 0.01, loop_rotation_sigma = 0.0087;          // m, rad
  PoseGraphConfig graph;
  bool is_valid(std::string* why = nullptr) const;
};

// A keyframe as loop closure takes it: its pose as tracked (the tracker's world, which loop
// closure never changes: "odometry"), its description for place recognition and its points
// (camera frame) for verification.
struct LoopKeyframe {
  std::int64_t id = 0;        // frame id; increasing
  std::int64_t position = 0;  // frame position for min_frame_gap (the frame id in a stream)
  Eigen::Isometry3d T_odom_camera = Eigen::Isometry3d::Identity();
  FrameDescription description;
  GaussianPoints points;
};

// What adding one keyframe did.
struct LoopEvent {
  std::int64_t older_id = -1;  // the keyframe a verified loop closed with; -1: none
  std::size_t rejected = 0;    // candidates that failed verification
  bool solved = false;         // the pose graph was optimised (a loop was found)
  PoseGraphResult graph;
  double ms = 0.0;             // search, verification and solve
};

class LoopCloser {
 public:
  LoopCloser(const LoopClosureConfig& config, const TrackerConfig& tracker_config);

  // The next keyframe (ids increasing): place recognition over the keyframes at least
  // min_frame_gap positions older, RANSAC and GICP verification of the best candidates, and on
  // the first verified one a loop edge and a new solve of the whole graph. A keyframe past
  // max_keyframes is not added (event says nothing happened). False with `why` only when the
  // solve fails or the keyframe's ids go backwards.
  bool add(LoopKeyframe keyframe, LoopEvent* event, std::string* why);

  // C_k = T_map_k T_odom_k^-1 of keyframe `id`: how far the graph moved it from where it was
  // tracked. A keyframe added after the newest solve (or not known) takes the correction of the
  // newest keyframe added before it, since the odometry since then is trusted; identity before
  // any loop.
  Eigen::Isometry3d correction(std::int64_t id) const;
  // The correction of the newest keyframe: what maps the tracker's world to the map's for the
  // frames after it.
  Eigen::Isometry3d newest_correction() const;
  // (id, T_map_k) of every keyframe, oldest first.
  std::vector<std::pair<std::int64_t, Eigen::Isometry3d>> corrected_poses() const;

  std::size_t size() const { return nodes_.size(); }
  const std::vector<std::pair<std::int64_t, std::int64_t>>& loops() const { return loops_; }  // (older, newer) ids
  std::size_t rejected() const { return rejected_; }

 private:
  struct Node {
    std::int64_t id = 0, position = 0;
    Eigen::Isometry3d T_odom = Eigen::Isometry3d::Identity();
    Eigen::Isometry3d T_map = Eigen::Isometry3d::Identity();  // T_odom until a solve moves it
    GaussianPoints points_odom;  // subsampled, in the tracker's world
  };
  bool solve(PoseGraphResult* result, std::string* why);
  std::size_t index_at_or_before(std::int64_t id) const;  // nodes_.size() when none

  LoopClosureConfig config_;
  TrackerConfig tracker_config_;
  Relocaliser places_;  // node ids are indices into nodes_
  std::vector<Node> nodes_;
  std::vector<PoseGraphEdge> loop_edges_;
  std::vector<std::pair<std::int64_t, std::int64_t>> loops_;
  std::size_t rejected_ = 0;
  std::size_t far_enough_ = 0;  // nodes [0, far_enough_) are min_frame_gap or more positions older
};

struct LoopClosureResult {
  std::size_t keyframes = 0;
  std::vector<std::pair<std::size_t, std::size_t>> loops;  // (older, newer) dataset positions
  std::size_t rejected = 0;                               // candidates that failed verification
  PoseGraphResult graph;                                  // of the last solve, when loops were found
  double seconds = 0.0;
};

// Loop closure after tracking: the keyframes of `tracking` (frames re-read from `dataset`,
// prepared with the tracker's settings) go through a LoopCloser in order, and every frame then
// moves with the keyframe at or before it: T <- C_k T. False with `why` for bad input or a failed
// solve. on_progress(done, total) per keyframe.
bool close_loops(const Dataset& dataset, const TrackerConfig& tracker_config,
                 const LoopClosureConfig& config, SequenceTracking* tracking, LoopClosureResult* result,
                 std::string* why, const std::function<void(std::size_t, std::size_t)>& on_progress = {});

}  // namespace fslam::core

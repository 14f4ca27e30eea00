// Loop closure over a tracked sequence, after tracking (issue 20, a first step): each keyframe
// looks for an older one it revisits with the relocaliser's place recognition, the pair is
// verified by RANSAC over ORB matches and GICP between the two keyframes' points, and a pose
// graph over the keyframes (odometry edges from tracking, loop edges from the verified
// revisits) is optimised with Ceres (pose_graph.hpp). Every frame then moves with the keyframe
// before it. Not yet on its own thread during tracking, and the map's Gaussians are not moved:
// docs/relocalisation.md says what is built and what is planned.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/mapping/pose_graph.hpp"
#include "fslam/core/pipeline/sequence_run.hpp"
#include "fslam/core/tracking/tracker.hpp"

namespace fslam::core {

struct LoopClosureConfig {
  std::size_t min_frame_gap = 300;  // frames between a keyframe and an older one it may close with
  int candidates = 3;               // older keyframes place recognition proposes per keyframe
  double min_verified_inlier_ratio = 0.6;  // GICP between the two keyframes' points
  // Edge sigmas: odometry between consecutive keyframes, and loops.
  double odometry_translation_sigma = 0.01, odometry_rotation_sigma = 0.0087;  // m, rad
  double loop_translation_sigma = 0.01, loop_rotation_sigma = 0.0087;          // m, rad
  PoseGraphConfig graph;
  bool is_valid(std::string* why = nullptr) const;
};

struct LoopClosureResult {
  std::size_t keyframes = 0;
  std::vector<std::pair<std::size_t, std::size_t>> loops;  // (older, newer) dataset positions
  std::size_t rejected = 0;                               // candidates that failed verification
  PoseGraphResult graph;                                  // when loops were found
  double seconds = 0.0;
};

// Finds loops among the keyframes of `tracking` (frames re-read from `dataset`, prepared with
// the tracker's settings) and, when there are any, corrects tracking->trajectory in place. False
// with `why` for bad input or a failed solve. on_progress(done, total) per keyframe.
bool close_loops(const Dataset& dataset, const TrackerConfig& tracker_config,
                 const LoopClosureConfig& config, SequenceTracking* tracking, LoopClosureResult* result,
                 std::string* why, const std::function<void(std::size_t, std::size_t)>& on_progress = {});

}  // namespace fslam::core

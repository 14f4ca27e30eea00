// Loop closure during tracking (issue 20, PipelineConfig::loop_closure): a LoopCloser on its own
// thread. The tracker stays in its own world ("odometry", never corrected, so its local map stays
// consistent); the loop thread publishes where each keyframe lies in the corrected map world,
// and the pipeline turns that into (1) the pose it reports for each frame, T_map_odom T_odom with
// the newest keyframe's correction, (2) the pose a keyframe is mapped at, and (3) moves of the
// Gaussians each keyframe anchors (Mapper::move_keyframes), applied by the mapping thread
// between steps. Tracking never waits for it. docs/relocalisation.md gives the design.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

#include "fslam/core/pipeline/loop_closure.hpp"

namespace fslam::core {

struct LoopThreadStats {
  std::size_t keyframes = 0;  // in the graph
  std::size_t loops = 0;      // verified
  std::size_t rejected = 0;   // candidates that failed verification
  std::size_t solves = 0;
  std::size_t left_out = 0;   // keyframes dropped because max_queued were waiting
  double last_solve_ms = 0.0;  // search, verification and solve of the newest loop
  std::string error;           // the first failure; loop closure stopped there
};

class LoopThread {
 public:
  // on_moves is called (from the loop thread, no lock held) after new keyframe poses are ready
  // for take_moves, and once more when the thread is done.
  LoopThread(const LoopClosureConfig& config, const TrackerConfig& tracker_config, std::function<void()> on_moves);
  ~LoopThread();  // stops (drops what waits) and joins
  LoopThread(const LoopThread&) = delete;
  LoopThread& operator=(const LoopThread&) = delete;

  // Tracking thread: a new keyframe. At most kMaxQueued wait (each with its frame's points, ~1 MB
  // at 640x480); past that the newest is left out of the graph (counted).
  void add(LoopKeyframe keyframe);
  // No more keyframes: the thread works through those waiting, then done() turns true.
  void finish();
  bool done() const;

  // T_map_odom: the newest keyframe's correction, for frames tracked after it. Any thread.
  Eigen::Isometry3d map_from_odom() const;
  // Where keyframe `id` tracked at T_odom lies in the map world as known now (its own pose once
  // the graph holds it, else the newest correction applied to T_odom). Any thread.
  Eigen::Isometry3d map_pose(std::int64_t id, const Eigen::Isometry3d& T_odom) const;
  // The keyframe poses changed since the last call (id, T_map), newest value per id. Mapping thread.
  std::vector<std::pair<std::int64_t, Eigen::Isometry3d>> take_moves();
  bool has_moves() const;
  // The correction C_k of the keyframe at or before frame `id` (LoopCloser::correction): after
  // done(), what moves a frame's tracked pose into the final map world. Any thread.
  Eigen::Isometry3d correction(std::int64_t id) const;
  LoopThreadStats stats() const;

  static constexpr std::size_t kMaxQueued = 64;

 private:
  void run();

  LoopClosureConfig config_;
  std::function<void()> on_moves_;
  mutable std::mutex closer_mutex_;  // guards closer_ (held by the loop thread while it adds)
  LoopCloser closer_;
  mutable std::mutex mutex_;  // guards everything below
  std::condition_variable wake_;
  std::deque<LoopKeyframe> queue_;
  bool finished_ = false, stop_ = false, done_ = false;
  Eigen::Isometry3d map_from_odom_ = Eigen::Isometry3d::Identity();
  std::unordered_map<std::int64_t, Eigen::Isometry3d> map_pose_;  // every keyframe in the graph
  std::int64_t first_id_ = 0;  // of the graph's first keyframe (when map_pose_ is not empty)
  std::vector<std::pair<std::int64_t, Eigen::Isometry3d>> moves_;
  LoopThreadStats stats_;
  std::thread thread_;  // last: starts after the members it uses
};

}  // namespace fslam::core

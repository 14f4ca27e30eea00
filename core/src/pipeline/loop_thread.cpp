#include "fslam/core/pipeline/loop_thread.hpp"

namespace fslam::core {

LoopThread::LoopThread(const LoopClosureConfig& config, const TrackerConfig& tracker_config,
                       std::function<void()> on_moves)
    : config_(config), on_moves_(std::move(on_moves)), closer_(config, tracker_config), thread_([this] { run(); }) {}

LoopThread::~LoopThread() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void LoopThread::add(LoopKeyframe keyframe) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (finished_ || stop_ || done_) return;
    if (queue_.size() >= kMaxQueued) {
      ++stats_.left_out;
      return;
    }
    queue_.push_back(std::move(keyframe));
  }
  wake_.notify_one();
}

void LoopThread::finish() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    finished_ = true;
  }
  wake_.notify_all();
}

bool LoopThread::done() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return done_;
}

Eigen::Isometry3d LoopThread::map_from_odom() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return map_from_odom_;
}

Eigen::Isometry3d LoopThread::map_pose(std::int64_t id, const Eigen::Isometry3d& T_odom) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = map_pose_.find(id);
  if (it != map_pose_.end()) return it->second;
  // Before the graph's first keyframe (an extended map's own keyframes): never moved.
  if (!map_pose_.empty() && id < first_id_) return T_odom;
  return map_from_odom_ * T_odom;  // waiting for the loop thread: the newest correction
}

std::vector<std::pair<std::int64_t, Eigen::Isometry3d>> LoopThread::take_moves() {
  std::lock_guard<std::mutex> lock(mutex_);
  return std::exchange(moves_, {});
}

bool LoopThread::has_moves() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return !moves_.empty();
}

Eigen::Isometry3d LoopThread::correction(std::int64_t id) const {
  std::lock_guard<std::mutex> lock(closer_mutex_);
  return closer_.correction(id);
}

LoopThreadStats LoopThread::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

void LoopThread::run() {
  for (;;) {
    LoopKeyframe keyframe;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [&] { return stop_ || finished_ || !queue_.empty(); });
      if (stop_ || (queue_.empty() && finished_)) break;
      keyframe = std::move(queue_.front());
      queue_.pop_front();
    }
    LoopEvent event;
    std::string why;
    std::vector<std::pair<std::int64_t, Eigen::Isometry3d>> poses;
    Eigen::Isometry3d newest = Eigen::Isometry3d::Identity();
    std::size_t graph_size = 0;
    bool ok = false;
    {
      std::lock_guard<std::mutex> lock(closer_mutex_);
      const std::size_t before = closer_.size();
      ok = closer_.add(std::move(keyframe), &event, &why);
      if (ok && closer_.size() > before) {  // added (not past max_keyframes)
        // After a solve every keyframe may have moved; otherwise only the new one is placed.
        poses = closer_.corrected_poses();
        if (!event.solved) poses.erase(poses.begin(), poses.end() - 1);
      }
      newest = closer_.newest_correction();
      graph_size = closer_.size();
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!ok) {
        stats_.error = why;
        break;  // loop closure stops; tracking and mapping go on with the corrections so far
      }
      map_from_odom_ = newest;
      if (map_pose_.empty() && !poses.empty()) first_id_ = poses.front().first;
      for (const auto& [kf, T] : poses) {
        map_pose_[kf] = T;
        moves_.emplace_back(kf, T);
      }
      stats_.keyframes = graph_size;
      stats_.loops += event.older_id >= 0 ? 1 : 0;
      stats_.rejected += event.rejected;
      if (event.solved) ++stats_.solves, stats_.last_solve_ms = event.ms;
    }
    if (on_moves_ && !poses.empty()) on_moves_();
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    done_ = true;
  }
  if (on_moves_) on_moves_();
}

}  // namespace fslam::core

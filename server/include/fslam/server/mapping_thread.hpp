// The mapping thread of a SLAM session, for the server's sessions and `fslam run` alike: the
// pipeline's mapping loop in a TBB arena of its own, and in real time below tracking's priority.
#pragma once

#include <atomic>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

#include <sys/types.h>

#include "fslam/core/pipeline/slam_pipeline.hpp"

namespace fslam::server {

// Real-time mapping (its thread and the TBB workers while they work for it) runs under Linux's
// SCHED_IDLE policy: on a shared machine tracking, decoding and the client come first and mapping
// gets only the time nothing else wants. (Nice 10 still took ~10 % of a core from every thread it
// shared one with, which doubled frame-to-pose latency with features on; docs/benchmarks.md.)
// So that an overloaded machine still grows its maps, a mapping thread that got under
// kStarvedCpuShare of a core for kMappingStarvationSeconds while a keyframe waited is lifted one
// step, to kStarvedMappingNice; still starved there for another window (several sessions with
// features on fill every core at nice 0), one more, to nice 0, where it gets a fair share; it
// goes back to SCHED_IDLE once it has mapped the next keyframe.
constexpr double kMappingStarvationSeconds = 2.0;
constexpr double kStarvedCpuShare = 0.05;
constexpr int kStarvedMappingNice = 10;

class MappingThread {
 public:
  // Starts pipeline->run_mapping on a new thread with `threads` TBB threads (0: all cores); low_priority
  // (real time) runs it under SCHED_IDLE, with the starvation guard above on a second thread. on_keyframe as run_mapping's; on_failure is
  // called once, on that thread, with the reason when mapping fails. The pipeline must outlive
  // the thread (join() or the destructor).
  MappingThread(core::SlamPipeline* pipeline, int threads, bool low_priority,
                std::function<void(const core::KeyframeReport&)> on_keyframe,
                std::function<void(const std::string&)> on_failure);
  ~MappingThread();
  MappingThread(const MappingThread&) = delete;
  MappingThread& operator=(const MappingThread&) = delete;

  // Waits for the loop to end (call pipeline->finish() first).
  void join();

 private:
  void guard_starvation(const core::SlamPipeline* pipeline);
  std::thread thread_;
  std::thread guard_;                     // low_priority only
  std::atomic<pid_t> tid_{0};             // the mapping thread's Linux thread id
  std::atomic<int> lifted_{0};            // steps the guard raised the mapping thread (0-2)
  std::mutex mutex_;
  std::condition_variable stop_;
  bool stopping_ = false;  // guarded by mutex_
};

}  // namespace fslam::server

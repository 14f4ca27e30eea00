// The mapping thread of a SLAM session, for the server's sessions and `fslam run` alike: the
// pipeline's mapping loop in a TBB arena of its own, and in real time below tracking's priority.
#pragma once

#include <functional>
#include <string>
#include <thread>

#include "fslam/core/pipeline/slam_pipeline.hpp"

namespace fslam::server {

// Nice value of real-time mapping (its thread and the TBB workers while they work for it): on a
// shared machine tracking, decoding and the client come first and mapping gets what is left.
constexpr int kRealtimeMappingNice = 10;

class MappingThread {
 public:
  // Starts pipeline->run_mapping on a new thread with `threads` TBB threads (0: all cores); low_priority
  // (real time) runs it at kRealtimeMappingNice. on_keyframe as run_mapping's; on_failure is
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
  std::thread thread_;
};

}  // namespace fslam::server

// The mapping thread of a SLAM session, for the server's sessions and `fslam run` alike: the
// pipeline's mapping loop in a TBB arena of its own, and in real time below tracking's priority.
#pragma once

#include <condition_variable>
#include <functional>
#include <mutex>
#include <set>
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
// features on fill every core at nice 0), one more, to nice 0, where it gets a fair share. Each
// step lifts the TBB workers working for it too. It goes back to SCHED_IDLE once no keyframe
// waits after one is mapped. Once the frames are all tracked (finish_fairly(): a session's close,
// the end of `fslam run`'s tracking), what mapping has left is what the user waits for: nice 0
// until the end. Leaving SCHED_IDLE needs CAP_SYS_NICE or an RLIMIT_NICE of 20; without them (a
// container without --cap-add SYS_NICE) mapping runs at kStarvedMappingNice throughout, and TBB
// workers that worked for it stay there (docs/mapping.md).
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

  // The frames are all tracked and a close (or the end of a run) waits for what mapping has left:
  // from now on mapping and its workers run at nice 0 (a fair share beside other sessions' tracking, not
  // what they leave over), where this process may leave SCHED_IDLE; no-op otherwise.
  void finish_fairly();

  // Waits for the loop to end (call pipeline->finish() first).
  void join();

  // The current priority step (Priority below); 0 when not low_priority.
  int priority_step() const { return priority_.step(); }

  // Whether this process may take a thread out of SCHED_IDLE (probed once).
  static bool can_leave_idle();

  // The priority step (0: SCHED_IDLE, 1: kStarvedMappingNice, 2: nice 0) shared by the mapping
  // thread and the TBB workers while they work in its arena.
  class Priority {
   public:
    void enter(pid_t tid);  // a thread starts working for mapping: set to the current step
    void leave(pid_t tid);  // a thread stops working for mapping: back to normal priority
    void set_step(int step);  // never below the floor
    void set_floor(int step);  // and raises the step to it
    int step() const;

   private:
    void apply(pid_t tid) const;  // needs mutex_
    mutable std::mutex mutex_;
    std::set<pid_t> threads_;
    int step_ = 0;
    int floor_ = 0;
  };

 private:
  void guard_starvation(const core::SlamPipeline* pipeline);
  std::thread thread_;
  const bool guarded_;                    // low_priority and allowed to leave SCHED_IDLE
  std::thread guard_;                     // guarded_ only
  Priority priority_;                     // low_priority only
  std::mutex mutex_;
  std::condition_variable stop_;
  bool stopping_ = false;  // guarded by mutex_
};

}  // namespace fslam::server

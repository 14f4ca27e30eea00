#include "fslam/server/mapping_thread.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <chrono>
#include <ctime>

#include <tbb/task_arena.h>
#include <tbb/task_scheduler_observer.h>

namespace fslam::server {
namespace {

pid_t current_tid() { return static_cast<pid_t>(syscall(SYS_gettid)); }

// Linux scheduling policies are per thread. SCHED_IDLE needs no privilege; failing to go back to
// SCHED_OTHER (a container's seccomp profile, say) only leaves a thread at the lower priority.
void set_policy(pid_t tid, bool idle, int nice = 0) {
  const sched_param param{};
  sched_setscheduler(tid, idle ? SCHED_IDLE : SCHED_OTHER, &param);
  if (!idle) setpriority(PRIO_PROCESS, static_cast<id_t>(tid), nice);
}
void set_thread_idle(bool idle) { set_policy(current_tid(), idle); }

// Lowers the priority of every TBB worker while it works in the mapping arena.
class LowPriorityWorkers final : public tbb::task_scheduler_observer {
 public:
  explicit LowPriorityWorkers(tbb::task_arena& arena) : tbb::task_scheduler_observer(arena) { observe(true); }
  ~LowPriorityWorkers() override { observe(false); }
  void on_scheduler_entry(bool worker) override {
    if (worker) set_thread_idle(true);
  }
  void on_scheduler_exit(bool worker) override {
    if (worker) set_thread_idle(false);
  }
};

}  // namespace

MappingThread::MappingThread(core::SlamPipeline* pipeline, int threads, bool low_priority,
                             std::function<void(const core::KeyframeReport&)> on_keyframe,
                             std::function<void(const std::string&)> on_failure) {
  thread_ = std::thread([=] {
    tid_ = current_tid();
    if (low_priority) set_thread_idle(true);
    tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
    arena.initialize();
    std::unique_ptr<LowPriorityWorkers> observer;
    if (low_priority) observer = std::make_unique<LowPriorityWorkers>(arena);
    const auto mapped = [&](const core::KeyframeReport& report) {
      if (lifted_.exchange(0) > 0) set_thread_idle(true);  // the starved keyframe is mapped
      if (on_keyframe) on_keyframe(report);
    };
    std::string why;
    const bool ok = arena.execute([&] { return pipeline->run_mapping(mapped, &why); });
    if (!ok && on_failure) on_failure(why.empty() ? "mapping failed" : why);
  });
  if (low_priority) guard_ = std::thread([this, pipeline] { guard_starvation(pipeline); });
}

void MappingThread::guard_starvation(const core::SlamPipeline* pipeline) {
  using Clock = std::chrono::steady_clock;
  clockid_t cpu_clock{};
  if (pthread_getcpuclockid(thread_.native_handle(), &cpu_clock) != 0) return;
  const auto cpu_seconds = [&] {
    timespec ts{};
    clock_gettime(cpu_clock, &ts);
    return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
  };
  // Starved: a keyframe waited the whole window and the mapping thread ran for under
  // kStarvedCpuShare of it (slow mapping of a big keyframe is not starvation).
  Clock::time_point since = Clock::now();
  double cpu_since = cpu_seconds();
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stop_.wait_for(lock, std::chrono::milliseconds(250), [&] { return stopping_; })) {
    const double window = std::chrono::duration<double>(Clock::now() - since).count();
    if (pipeline->queued_keyframes() == 0) {
      since = Clock::now();
      cpu_since = cpu_seconds();
    } else if (window >= kMappingStarvationSeconds) {
      const double share = (cpu_seconds() - cpu_since) / window;
      const int step = lifted_.load();
      if (share < kStarvedCpuShare && step < 2 && tid_ != 0) {
        // First the step, then the policy: the next keyframe mapped lowers it again.
        lifted_ = step + 1;
        set_policy(tid_, false, step == 0 ? kStarvedMappingNice : 0);
      }
      since = Clock::now();
      cpu_since = cpu_seconds();
    }
  }
}

MappingThread::~MappingThread() { join(); }

void MappingThread::join() {
  if (thread_.joinable()) thread_.join();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  stop_.notify_all();
  if (guard_.joinable()) guard_.join();
}

}  // namespace fslam::server

#include "fslam/server/mapping_thread.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <ctime>

#include <tbb/task_arena.h>
#include <tbb/task_scheduler_observer.h>

namespace fslam::server {
namespace {

pid_t current_tid() { return static_cast<pid_t>(syscall(SYS_gettid)); }

// Linux scheduling policies are per thread. SCHED_IDLE needs no privilege; failing to go back to
// SCHED_OTHER (a container's seccomp profile, say) only leaves a thread at the lower priority.
// Returns false when the kernel refused.
bool set_policy(pid_t tid, bool idle, int nice = 0) {
  const sched_param param{};
  bool ok = sched_setscheduler(tid, idle ? SCHED_IDLE : SCHED_OTHER, &param) == 0;
  if (!idle) ok = setpriority(PRIO_PROCESS, static_cast<id_t>(tid), nice) == 0 && ok;
  return ok;
}
// Keeps every TBB worker at the mapping thread's priority while it works in the mapping arena:
// a worker left at SCHED_IDLE under load holds the task the lifted mapping thread then waits for.
class ArenaWorkers final : public tbb::task_scheduler_observer {
 public:
  ArenaWorkers(tbb::task_arena& arena, MappingThread::Priority* priority)
      : tbb::task_scheduler_observer(arena), priority_(priority) {
    observe(true);
  }
  ~ArenaWorkers() override { observe(false); }
  void on_scheduler_entry(bool worker) override {
    if (worker) priority_->enter(current_tid());
  }
  void on_scheduler_exit(bool worker) override {
    if (worker) priority_->leave(current_tid());
  }

 private:
  MappingThread::Priority* priority_;
};

}  // namespace

bool MappingThread::can_leave_idle() {
  // A thread under SCHED_IDLE counts as nice 20: going back to SCHED_OTHER at nice 0 needs
  // CAP_SYS_NICE or an RLIMIT_NICE of 20 (sched_setscheduler(2)). Tried once, on a thread of its own.
  static const bool can = [] {
    bool ok = false;
    std::thread([&] {
      const pid_t tid = current_tid();
      ok = set_policy(tid, true) && set_policy(tid, false, 0);
    }).join();
    return ok;
  }();
  return can;
}

void MappingThread::Priority::enter(pid_t tid) {
  std::lock_guard<std::mutex> lock(mutex_);
  threads_.insert(tid);
  apply(tid);
}

void MappingThread::Priority::leave(pid_t tid) {
  std::lock_guard<std::mutex> lock(mutex_);
  threads_.erase(tid);
  set_policy(tid, false);  // a worker serves other arenas, an ending thread frees its id
}

void MappingThread::Priority::set_step(int step) {
  std::lock_guard<std::mutex> lock(mutex_);
  step_ = std::max(step, floor_);
  for (const pid_t tid : threads_) apply(tid);
}

void MappingThread::Priority::set_floor(int step) {
  std::lock_guard<std::mutex> lock(mutex_);
  floor_ = step;
  step_ = std::max(step_, floor_);
  for (const pid_t tid : threads_) apply(tid);
}

int MappingThread::Priority::step() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return step_;
}

void MappingThread::Priority::apply(pid_t tid) const {
  if (step_ == 0) {
    set_policy(tid, true);
  } else {
    set_policy(tid, false, step_ == 1 ? kStarvedMappingNice : 0);
  }
}

MappingThread::MappingThread(core::SlamPipeline* pipeline, int threads, bool low_priority,
                             std::function<void(const core::KeyframeReport&)> on_keyframe,
                             std::function<void(const std::string&)> on_failure)
    : guarded_(low_priority && can_leave_idle()) {
  // Without the right to leave SCHED_IDLE, starvation could not be undone: nice 10 from the start.
  if (low_priority && !guarded_) priority_.set_step(1);
  thread_ = std::thread([=] {
    const pid_t tid = current_tid();
    if (low_priority) priority_.enter(tid);
    tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
    arena.initialize();
    std::unique_ptr<ArenaWorkers> observer;
    if (low_priority) observer = std::make_unique<ArenaWorkers>(arena, &priority_);
    const auto mapped = [&](const core::KeyframeReport& report) {
      // Back to SCHED_IDLE once the backlog that starved is mapped, not after each keyframe: a
      // machine that stays loaded would otherwise starve every keyframe for a window again.
      if (guarded_ && pipeline->queued_keyframes() == 0 && priority_.step() > 0) priority_.set_step(0);
      if (on_keyframe) on_keyframe(report);
    };
    std::string why;
    const bool ok = arena.execute([&] { return pipeline->run_mapping(mapped, &why); });
    if (!ok && on_failure) on_failure(why.empty() ? "mapping failed" : why);
    if (low_priority) priority_.leave(tid);  // its id may be reused once it ends
  });
  if (guarded_) guard_ = std::thread([this, pipeline] { guard_starvation(pipeline); });
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
      const int step = priority_.step();
      if (share < kStarvedCpuShare && step < 2) priority_.set_step(step + 1);
      since = Clock::now();
      cpu_since = cpu_seconds();
    }
  }
}

void MappingThread::finish_fairly() {
  if (guarded_) priority_.set_floor(2);
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

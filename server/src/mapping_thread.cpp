#include "fslam/server/mapping_thread.hpp"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <tbb/task_arena.h>
#include <tbb/task_scheduler_observer.h>

namespace fslam::server {
namespace {

void set_thread_nice(int nice) {
  // Linux priorities are per thread; failing to raise one back (no CAP_SYS_NICE) only leaves a
  // TBB worker at the lower priority.
  setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), nice);
}

// Lowers the priority of every TBB worker while it works in the mapping arena.
class LowPriorityWorkers final : public tbb::task_scheduler_observer {
 public:
  explicit LowPriorityWorkers(tbb::task_arena& arena) : tbb::task_scheduler_observer(arena) { observe(true); }
  ~LowPriorityWorkers() override { observe(false); }
  void on_scheduler_entry(bool worker) override {
    if (worker) set_thread_nice(kRealtimeMappingNice);
  }
  void on_scheduler_exit(bool worker) override {
    if (worker) set_thread_nice(0);
  }
};

}  // namespace

MappingThread::MappingThread(core::SlamPipeline* pipeline, int threads, bool low_priority,
                             std::function<void(const core::KeyframeReport&)> on_keyframe,
                             std::function<void(const std::string&)> on_failure) {
  thread_ = std::thread([=] {
    if (low_priority) set_thread_nice(kRealtimeMappingNice);
    tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
    arena.initialize();
    std::unique_ptr<LowPriorityWorkers> observer;
    if (low_priority) observer = std::make_unique<LowPriorityWorkers>(arena);
    std::string why;
    const bool ok = arena.execute([&] { return pipeline->run_mapping(on_keyframe, &why); });
    if (!ok && on_failure) on_failure(why.empty() ? "mapping failed" : why);
  });
}

MappingThread::~MappingThread() { join(); }

void MappingThread::join() {
  if (thread_.joinable()) thread_.join();
}

}  // namespace fslam::server

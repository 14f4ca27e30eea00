// Real-time mapping's priority under load (server/mapping_thread.hpp): SCHED_IDLE, lifted with its
// TBB workers when it starves, back to SCHED_IDLE once its backlog is mapped.
#include <sched.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "cli_runner.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/pipeline/slam_pipeline.hpp"
#include "fslam/core/render/rasterizer.hpp"
#include "fslam/server/mapping_thread.hpp"
#include "test_support.hpp"

namespace fslam {
namespace {

// How many of this process's threads run under SCHED_IDLE (/proc/self/task/*/stat, field 41).
int idle_threads() {
  int idle = 0;
  for (const auto& task : std::filesystem::directory_iterator("/proc/self/task")) {
    std::ifstream in(task.path() / "stat");
    std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const std::size_t close = stat.rfind(')');
    if (close == std::string::npos) continue;
    std::istringstream fields(stat.substr(close + 2));  // field 3 (state) on
    std::string field;
    for (int i = 3; i <= 41 && fields >> field; ++i) {
      if (i == 41 && std::stoi(field) == SCHED_IDLE) ++idle;
    }
  }
  return idle;
}

// Pins the calling thread, and so every thread it starts from now on, to the first CPU it may
// run on: the test loads one core, not the machine (ctest -j runs other tests beside it).
bool pin_to_one_cpu() {
  cpu_set_t allowed;
  if (sched_getaffinity(0, sizeof(allowed), &allowed) != 0) return false;
  for (int cpu = 0; cpu < CPU_SETSIZE; ++cpu) {
    if (!CPU_ISSET(cpu, &allowed)) continue;
    cpu_set_t one;
    CPU_ZERO(&one);
    CPU_SET(cpu, &one);
    return sched_setaffinity(0, sizeof(one), &one) == 0;
  }
  return false;
}

// A thread spinning at nice 10 on the test's one CPU, so SCHED_IDLE threads there get (next to)
// nothing.
class CpuHog {
 public:
  CpuHog()
      : thread_([this] {
          setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 10);
          while (!stop_.load(std::memory_order_relaxed)) {
          }
        }) {}
  ~CpuHog() {
    stop_ = true;
    thread_.join();
  }

 private:
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

// A synthetic room of `frames` frames (seed 7) in a fresh folder, opened.
std::unique_ptr<core::Dataset> synthetic_room(const std::string& name, int frames, std::string* dir) {
  *dir = test::fresh_temp_dir(name).string();
  std::string out, err, why;
  if (test::run_command(test::fslam_bin() + " synth --out " + *dir + " --frames " + std::to_string(frames) +
                            " --seed 7", &out, &err) != 0) {
    ADD_FAILURE() << out << err;
    return nullptr;
  }
  core::DatasetOptions options;
  auto dataset = core::open_dataset(*dir, options, &why);
  EXPECT_TRUE(dataset) << why;
  return dataset;
}

// Tracks every frame of `dataset`; the keyframes handed to the mapper (those it did not leave
// out), or -1 on a failure.
int track_all(const core::Dataset& dataset, core::SlamPipeline* pipeline) {
  std::size_t keyframes = 0;
  std::string why;
  for (std::size_t i = 0; i < dataset.size(); ++i) {
    core::RgbdFrame frame;
    core::TrackingResult result;
    if (!dataset.load(i, &frame, &why) || !pipeline->process_frame(frame, &result, &why)) {
      ADD_FAILURE() << why;
      return -1;
    }
    keyframes += result.keyframe ? 1 : 0;
  }
  return static_cast<int>(keyframes - pipeline->keyframes_left_out());
}

// Ends the pipeline's mapping loop before the MappingThread declared after it is joined, however
// the test ends.
struct FinishOnExit {
  core::SlamPipeline* pipeline;
  ~FinishOnExit() { pipeline->finish(); }
};

// Its CPU busy at nice 10: the mapping thread starves under SCHED_IDLE, is lifted with the
// TBB workers of its arena (no thread of the process stays SCHED_IDLE while it is lifted: a
// worker left there held tasks the lifted thread waited for, and each keyframe was starved
// again), maps every keyframe, and goes back to SCHED_IDLE once none waits.
TEST(MappingThreadUnderLoad, StarvedMappingIsLiftedWithItsWorkersThenGoesBackToIdle) {
  if (!server::MappingThread::can_leave_idle()) {
    GTEST_SKIP() << "this process may not leave SCHED_IDLE (no CAP_SYS_NICE, RLIMIT_NICE below 20): "
                    "mapping runs at nice 10 throughout and is never lifted";
  }
  // Before any thread (TBB's workers included) is started.
  ASSERT_TRUE(pin_to_one_cpu());
  // TBB sizes its worker pool from the CPUs it may use (now one: no worker); the arena below
  // asks for two threads, so that one TBB worker works for mapping beside its thread.
  const tbb::global_control two_threads(tbb::global_control::max_allowed_parallelism, 2);
  std::string dir;
  const auto dataset = synthetic_room("priority", 40, &dir);
  ASSERT_TRUE(dataset);

  core::PipelineConfig config;
  config.realtime = true;
  config.mapper.iterations_per_keyframe = 100;  // a backlog after tracking, on any machine
  core::SlamPipeline pipeline(config, core::make_cpu_rasterizer());
  std::atomic<int> mapped{0};
  CpuHog hog;
  server::MappingThread mapping(&pipeline, 2, true, [&](const core::KeyframeReport&) { ++mapped; }, nullptr);
  const FinishOnExit finish{&pipeline};
  const int to_map = track_all(*dataset, &pipeline);
  ASSERT_GE(to_map, 3);

  // While lifted and no keyframe was mapped in between, no thread of the process is SCHED_IDLE.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(test::scaled_s(120));
  int lifted_snapshots = 0;
  while (std::chrono::steady_clock::now() < deadline && mapped.load() < to_map) {
    const int before = mapped.load();
    if (mapping.priority_step() > 0) {
      const int idle = idle_threads();
      if (mapping.priority_step() > 0 && mapped.load() == before && pipeline.queued_keyframes() > 0) {
        EXPECT_EQ(idle, 0) << "a thread of the process stayed SCHED_IDLE while mapping was lifted";
        ++lifted_snapshots;
      }
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_GT(lifted_snapshots, 0) << "mapping was never lifted while keyframes waited";
  ASSERT_EQ(mapped.load(), to_map) << "the backlog was not mapped in time under load";

  // The backlog mapped: back to SCHED_IDLE (the mapping thread, idling between rounds).
  const auto settle = std::chrono::steady_clock::now() + std::chrono::seconds(test::scaled_s(30));
  while (mapping.priority_step() > 0 && std::chrono::steady_clock::now() < settle) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_EQ(mapping.priority_step(), 0);
  EXPECT_GE(idle_threads(), 1) << "the mapping thread is not back under SCHED_IDLE";

  pipeline.finish();
  mapping.join();
  std::filesystem::remove_all(dir);
}

// A session's close waits for what its mapping has left (server/src/sessions.cpp
// finish_session): from finish_fairly() on, mapping and its workers run at nice 0, and stay
// there when the keyframes waiting are mapped (a background mapper would go back to SCHED_IDLE,
// and a close under load took 37-39 s instead of 8-9: docs/reliability.md).
TEST(MappingThreadUnderLoad, AFinishingSessionsMappingLeavesIdleAndStaysThereUntilItEnds) {
  if (!server::MappingThread::can_leave_idle()) {
    GTEST_SKIP() << "this process may not leave SCHED_IDLE (no CAP_SYS_NICE, RLIMIT_NICE below 20)";
  }
  std::string dir;
  const auto dataset = synthetic_room("finishing", 30, &dir);
  ASSERT_TRUE(dataset);

  core::PipelineConfig config;
  config.realtime = true;
  core::SlamPipeline pipeline(config, core::make_cpu_rasterizer());
  std::atomic<int> mapped{0};
  server::MappingThread mapping(&pipeline, 1, true, [&](const core::KeyframeReport&) { ++mapped; }, nullptr);
  const FinishOnExit finish{&pipeline};
  // While the session streams, mapping is background work: its thread runs under SCHED_IDLE.
  const auto started = std::chrono::steady_clock::now() + std::chrono::seconds(test::scaled_s(10));
  while (idle_threads() == 0 && std::chrono::steady_clock::now() < started)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  EXPECT_GE(idle_threads(), 1) << "the mapping thread did not start under SCHED_IDLE";
  EXPECT_EQ(mapping.priority_step(), 0);

  const int to_map = track_all(*dataset, &pipeline);
  ASSERT_GE(to_map, 1);

  mapping.finish_fairly();
  EXPECT_EQ(mapping.priority_step(), 2);
  EXPECT_EQ(idle_threads(), 0) << "a thread working for the finishing mapper is still SCHED_IDLE";
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(test::scaled_s(120));
  while (mapped.load() < to_map && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  ASSERT_EQ(mapped.load(), to_map);
  EXPECT_EQ(mapping.priority_step(), 2) << "mapping went back to SCHED_IDLE while its session closes";
  EXPECT_EQ(idle_threads(), 0);
  pipeline.finish();
  mapping.join();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace fslam

// The two clocks timings read. The calling thread's CPU time: on a shared machine wall time
// also counts the turns of other threads and processes, so timings that mean "the work of this
// thread" read this clock; wall time (steady) for what a caller waits.
#pragma once

#include <chrono>
#include <ctime>

namespace fslam::core {

// CPU time the calling thread has used so far, milliseconds (Linux per-thread clock).
inline double thread_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}

// Wall time on the steady clock, milliseconds from an arbitrary epoch (differences only).
inline double steady_ms() {
  using namespace std::chrono;
  return duration<double, std::milli>(steady_clock::now().time_since_epoch()).count();
}

}  // namespace fslam::core

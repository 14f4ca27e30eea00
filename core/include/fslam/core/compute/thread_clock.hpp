// The calling thread's CPU time: on a shared machine wall time also counts the turns of other
// threads and processes, so timings that mean "the work of this thread" read this clock.
#pragma once

#include <ctime>

namespace fslam::core {

// CPU time the calling thread has used so far, milliseconds (Linux per-thread clock).
inline double thread_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}

}  // namespace fslam::core

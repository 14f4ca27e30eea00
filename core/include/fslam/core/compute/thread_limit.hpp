// The worker pools of the libraries we run on (TBB, OpenCV), limited for the whole process by the
// environment variable FSLAM_LIBRARY_THREADS. Meant for ThreadSanitizer runs: Debian's TBB and
// OpenCV are not instrumented, so TSan cannot see the synchronisation of their workers and
// reports false races at every parallel_for join; with FSLAM_LIBRARY_THREADS=1 the only threads
// are our own (tracking, mapping, loop closure, queries, DDS), which TSan sees whole
// (docs/reliability.md). Unset: the libraries use every core, as always.
#pragma once

#include <string>

namespace fslam::core {

// Applies FSLAM_LIBRARY_THREADS (a positive integer) when it is set, for the rest of the
// process; true when unset. False with `why` when it is not a positive integer.
bool limit_library_threads_from_environment(std::string* why);

}  // namespace fslam::core

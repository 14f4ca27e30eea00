#include "fslam/core/compute/thread_limit.hpp"

#include <cstdlib>

#include <opencv2/core/utility.hpp>
#include <tbb/global_control.h>

#include "fslam/core/error.hpp"

namespace fslam::core {

bool limit_library_threads_from_environment(std::string* why) {
  const char* text = std::getenv("FSLAM_LIBRARY_THREADS");
  if (text == nullptr) return true;
  char* end = nullptr;
  const long threads = std::strtol(text, &end, 10);
  if (end == text || *end != '\0' || threads < 1 || threads > 4096)
    return fail(why, std::string("FSLAM_LIBRARY_THREADS must be a positive integer, not '") + text + "'");
  // Held until the process exits. Not a pointer to a never-deleted object: its store was
  // optimised away as never read, and LeakSanitizer reported the object as leaked.
  static tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
  // OpenCV's parallel_for_: 1 runs on the caller; n > 1 keeps OpenCV's pool at n threads.
  cv::setNumThreads(threads == 1 ? 0 : static_cast<int>(threads));
  return true;
}

}  // namespace fslam::core

#include "fslam/server/process_setup.hpp"

#include <malloc.h>

#include "fslam/core/compute/cpu_level.hpp"
#include "fslam/core/compute/product_blocking.hpp"
#include "fslam/core/compute/thread_limit.hpp"

namespace fslam::server {

bool prepare_process(std::string* why) {
  if (!core::cpu_runs_this_build(why) || !core::limit_library_threads_from_environment(why)) return false;
  core::use_portable_product_blocking();
  mallopt(M_MMAP_THRESHOLD, 32 << 20);  // glibc's maximum on 64-bit
  mallopt(M_TRIM_THRESHOLD, 256 << 20);
  return true;
}

}  // namespace fslam::server

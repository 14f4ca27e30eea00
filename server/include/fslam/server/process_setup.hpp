// What every featureslam executable does first: refuse a processor that cannot run the build
// (core::cpu_runs_this_build), apply FSLAM_LIBRARY_THREADS (core/compute/thread_limit.hpp), plan
// Eigen's products for fixed cache sizes (core/compute/product_blocking.hpp) and tune the
// allocator for frame-sized buffers.
#pragma once

#include <string>

namespace fslam::server {

// False with `why` when this processor cannot run the build or FSLAM_LIBRARY_THREADS is not a
// positive integer. Also makes Eigen's products round the same on every processor, and keeps
// freed blocks of up to 32 MiB on the heap for reuse instead of returning them to the kernel:
// decoded frames, feature pyramids and render buffers are allocated per frame, and with glibc's
// defaults each came back as fresh pages (measured: page faults and zeroing were 10-18 % of
// tracking and mapping time).
bool prepare_process(std::string* why);

}  // namespace fslam::server

// The main of every test binary: GoogleTest's, after FSLAM_LIBRARY_THREADS is applied as the
// executables apply it (core/compute/thread_limit.hpp), so that a ThreadSanitizer run of the
// suites sees only our own threads, and with Eigen's products planned as the executables plan
// them (core/compute/product_blocking.hpp).
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "fslam/core/compute/product_blocking.hpp"
#include "fslam/core/compute/thread_limit.hpp"

int main(int argc, char** argv) {
  if (std::string why; !fslam::core::limit_library_threads_from_environment(&why)) {
    std::fprintf(stderr, "error: %s\n", why.c_str());
    return 2;
  }
  fslam::core::use_portable_product_blocking();
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}

#include "fslam/core/compute/thread_limit.hpp"

#include <cstdlib>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>

#include <gtest/gtest.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace fslam::core {
namespace {

// Restores FSLAM_LIBRARY_THREADS as it was when the test started.
class LibraryThreadsVariable {
 public:
  LibraryThreadsVariable() {
    if (const char* v = std::getenv("FSLAM_LIBRARY_THREADS")) saved_ = v;
  }
  ~LibraryThreadsVariable() {
    if (saved_) {
      setenv("FSLAM_LIBRARY_THREADS", saved_->c_str(), 1);
    } else {
      unsetenv("FSLAM_LIBRARY_THREADS");
    }
  }

 private:
  std::optional<std::string> saved_;
};

TEST(LibraryThreads, UnsetChangesNothingAndNonPositiveOrGarbledValuesAreClearErrors) {
  const LibraryThreadsVariable restore;
  unsetenv("FSLAM_LIBRARY_THREADS");
  std::string why;
  EXPECT_TRUE(limit_library_threads_from_environment(&why)) << why;
  for (const char* bad : {"0", "-2", "abc", "2x", "", "99999"}) {
    setenv("FSLAM_LIBRARY_THREADS", bad, 1);
    why.clear();
    EXPECT_FALSE(limit_library_threads_from_environment(&why)) << "'" << bad << "'";
    EXPECT_NE(why.find("FSLAM_LIBRARY_THREADS"), std::string::npos) << why;
    EXPECT_NE(why.find(std::string("'") + bad + "'"), std::string::npos) << why;
  }
}

// With FSLAM_LIBRARY_THREADS=1 a parallel_for runs all its chunks on the calling thread (what
// makes ThreadSanitizer runs possible). In a child process: the limit is for the whole process.
TEST(LibraryThreadsDeathTest, OneRunsParallelLoopsOnTheCallingThreadOnly) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  EXPECT_EXIT(
      {
        setenv("FSLAM_LIBRARY_THREADS", "1", 1);
        std::string why;
        if (!limit_library_threads_from_environment(&why)) std::exit(2);
        std::mutex mutex;
        std::set<std::thread::id> threads;
        tbb::parallel_for(tbb::blocked_range<int>(0, 4096, 1), [&](const tbb::blocked_range<int>&) {
          volatile double x = 0;
          for (int k = 0; k < 2000; ++k) x = x + k;  // enough work per chunk for workers to join
          std::lock_guard<std::mutex> lock(mutex);
          threads.insert(std::this_thread::get_id());
        });
        std::exit(threads.size() == 1 && *threads.begin() == std::this_thread::get_id() ? 0 : 3);
      },
      ::testing::ExitedWithCode(0), "");
}

}  // namespace
}  // namespace fslam::core

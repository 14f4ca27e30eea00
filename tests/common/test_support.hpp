// Paths and helpers shared by every test binary.
#pragma once

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

namespace fslam::test {

// ../shared/data, or $FSLAM_DATA_DIR when set.
inline std::filesystem::path data_dir() {
  if (const char* env = std::getenv("FSLAM_DATA_DIR")) return env;
  return FSLAM_TEST_DATA_DIR;
}

// build/bin, where `fslam` and `fslam-server` land.
inline std::filesystem::path bin_dir() { return FSLAM_TEST_BIN_DIR; }

// Forces every DDS participant the test creates onto the loopback profile (never the network).
inline void use_loopback_dds() { setenv("CYCLONEDDS_URI", "file://" FSLAM_TEST_LOOPBACK_PROFILE, 1); }

// How many times slower than a plain build this one runs: deadlines of tests that wait for the
// server are multiplied by it, so that a sanitizer build on two cores fails on what it finds, not
// on time. $FSLAM_TEST_TIME_SCALE (>= 1), else the build's default (tests/CMakeLists.txt: 1, 4
// with ASan, 8 with TSan).
inline double time_scale() {
  if (const char* env = std::getenv("FSLAM_TEST_TIME_SCALE")) {
    const double scale = std::atof(env);
    if (scale >= 1.0) return scale;
  }
  return FSLAM_TEST_DEFAULT_TIME_SCALE;
}
inline int scaled_ms(int ms) { return static_cast<int>(ms * time_scale()); }
inline int scaled_s(int s) { return static_cast<int>(s * time_scale()); }

// A fresh empty folder under the system temp dir, unique per test and process (ctest runs tests
// of one binary in parallel processes).
inline std::filesystem::path fresh_temp_dir(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::filesystem::path dir = std::filesystem::temp_directory_path() / "fslam_tests" /
                              std::to_string(getpid()) /
                              (std::string(info ? info->test_suite_name() : "t") + "." +
                               (info ? info->name() : "t") + "." + name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

}  // namespace fslam::test

// Skips the test with a clear message when ../shared/data/<sub> is absent.
#define FSLAM_REQUIRE_DATA(sub)                                                               \
  do {                                                                                        \
    const auto fslam_data_path = ::fslam::test::data_dir() / (sub);                           \
    if (!std::filesystem::exists(fslam_data_path))                                            \
      GTEST_SKIP() << "real data not found at " << fslam_data_path                            \
                   << " (needs ../shared/data beside the checkout, or FSLAM_DATA_DIR)";       \
  } while (0)

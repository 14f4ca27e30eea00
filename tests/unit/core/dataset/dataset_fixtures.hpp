// Small sequences the dataset tests write for themselves, and checks shared by them.
#pragma once

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "fslam/core/io/image_io.hpp"

namespace fslam::test {

inline void write_text(const std::filesystem::path& path, const std::string& text) {
  std::filesystem::create_directories(path.parent_path());
  std::ofstream(path) << text;
}

// A [height, width] RGB image filled with (value, value + 1, value + 2).
inline void write_colour(const std::filesystem::path& path, int width, int height, int value) {
  std::filesystem::create_directories(path.parent_path());
  const cv::Mat rgb(height, width, CV_8UC3, cv::Scalar(value, value + 1, value + 2));
  std::string why;
  ASSERT_TRUE(core::write_image(path.string(), rgb, &why)) << why;
}

// A [height, width] 16-bit depth image filled with `raw`.
inline void write_depth(const std::filesystem::path& path, int width, int height,
                        std::uint16_t raw) {
  std::filesystem::create_directories(path.parent_path());
  const cv::Mat depth(height, width, CV_16UC1, cv::Scalar(raw));
  std::string why;
  ASSERT_TRUE(core::write_image(path.string(), depth, &why)) << why;
}

}  // namespace fslam::test

// The error message names the file (its file name is enough: folders differ per test).
#define EXPECT_NAMES_FILE(why, file_name)             \
  EXPECT_NE((why).find(file_name), std::string::npos) \
      << "message does not name " << (file_name) << ": " << (why)

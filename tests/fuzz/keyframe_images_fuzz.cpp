// Fuzz target: keyframe_images.bin, the mapper keyframes' colour and depth a saved map carries
// for refinement and extend sessions (core/io/keyframe_images_file.hpp); a map folder is a file
// the server reads at start and on load.
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "fslam/core/io/keyframe_images_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  std::vector<fslam::core::KeyframeImages> keyframes;
  std::string why;
  if (!fslam::core::parse_keyframe_images_file(bytes, "keyframe_images.bin", &keyframes, &why)) {
    if (why.empty()) __builtin_trap();
    return 0;
  }
  // Accepted keyframes are what Mapper::restore_keyframes relies on: a valid camera, a rigid
  // finite pose, 8-bit colour and float depth of one size within the camera's.
  for (const auto& kf : keyframes) {
    if (!kf.input_camera.is_valid(nullptr) || !kf.T_world_camera.matrix().allFinite()) __builtin_trap();
    if (kf.colour.type() != CV_8UC3 || kf.depth.type() != CV_32FC1 || kf.colour.size() != kf.depth.size())
      __builtin_trap();
    if (kf.colour.cols > kf.input_camera.width || kf.colour.rows > kf.input_camera.height) __builtin_trap();
  }
  return 0;
}

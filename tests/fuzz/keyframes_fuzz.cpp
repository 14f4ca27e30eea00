// Fuzz target: keyframes.bin, the keyframe descriptions a saved map carries for localise sessions
// (core/io/keyframe_file.hpp); a map folder is a file the server reads at start and on load.
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "fslam/core/io/keyframe_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  std::vector<fslam::core::DescribedKeyframe> keyframes;
  std::string why;
  if (!fslam::core::parse_keyframe_file(bytes, "keyframes.bin", &keyframes, &why)) {
    if (why.empty()) __builtin_trap();
    return 0;
  }
  // Accepted keyframes are what the relocaliser relies on: rigid finite poses, descriptors that
  // match the points row for row, finite points.
  for (const auto& kf : keyframes) {
    const fslam::core::FrameDescription& d = kf.description;
    if (!kf.T_world_camera.matrix().allFinite()) __builtin_trap();
    if (d.descriptors.rows != static_cast<int>(d.points.size())) __builtin_trap();
    for (const auto& p : d.points)
      if (!p.allFinite()) __builtin_trap();
    for (float g : d.global)
      if (!std::isfinite(g)) __builtin_trap();
  }
  return 0;
}

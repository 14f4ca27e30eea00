// Fuzz target: TUM trajectory files (fslam eval inputs, saved maps' poses).
#include <cmath>
#include <cstdint>
#include <string>

#include "fslam/core/io/trajectory_io.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = fslam::fuzz::write_scratch("trajectory.txt", data, size);
  fslam::core::Trajectory trajectory;
  std::string why;
  if (!fslam::core::read_tum_trajectory(path, &trajectory, &why)) {
    if (why.empty()) __builtin_trap();
    return 0;
  }
  for (const auto& p : trajectory) {  // accepted poses are finite rigid transforms
    if (!std::isfinite(p.timestamp) || !p.T_world_camera.matrix().allFinite()) __builtin_trap();
  }
  return 0;
}

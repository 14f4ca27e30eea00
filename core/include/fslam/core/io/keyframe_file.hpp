// The keyframes a map was built from, as relocalisation describes them (relocaliser.hpp), in one
// binary file saved beside the map's Gaussians (`keyframes.bin`), so that a session can find its
// camera in a map built earlier (session mode `localise`, docs/relocalisation.md).
//
// Little-endian, in this order:
//   "FSLMKFD1"                       8 bytes, magic and version
//   u32 count                        keyframes
//   per keyframe:
//     i64 id
//     f64[12] T_world_camera         rotation row-major (9), then translation (3)
//     u32 K, u32 G                   keypoints, global descriptor length
//     u8[K * 32]                     ORB descriptors
//     f32[K * 3]                     keypoints, camera frame, metres
//     f32[G]                         global descriptor
// A reader checks every count against the bytes left, every value for finiteness and the
// rotation for orthonormality, so a truncated or corrupt file is an error, never a crash.
#pragma once

#include <string>
#include <vector>

#include "fslam/core/tracking/relocaliser.hpp"

namespace fslam::core {

// Largest file accepted: 2000 keyframes (relocalisation's default bound) of 2000 keypoints.
constexpr std::size_t kMaxKeyframeFileBytes = 512u << 20;

bool write_keyframe_file(const std::string& path, const std::vector<DescribedKeyframe>& keyframes,
                         std::string* why);
bool read_keyframe_file(const std::string& path, std::vector<DescribedKeyframe>* keyframes, std::string* why);
// The same, from bytes in memory (the fuzz target's entry); `name` names them in errors.
bool parse_keyframe_file(const std::string& bytes, const std::string& name,
                         std::vector<DescribedKeyframe>* keyframes, std::string* why);

}  // namespace fslam::core

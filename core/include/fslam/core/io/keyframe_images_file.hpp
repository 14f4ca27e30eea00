// The mapper's stored keyframe images (Mapper::published_keyframe_images) in one binary file
// saved beside a map's Gaussians (`keyframe_images.bin`), so that a map loaded later can be
// refined (docs/protocol.md "Refinement") and an extend session keeps optimising what was mapped
// before it.
//
// Little-endian, in this order:
//   "FSLMKFI1"                       8 bytes, magic and version
//   u32 count                        keyframes
//   per keyframe:
//     i64 frame_id
//     f64[4] fx fy cx cy, u32 width, u32 height    the input camera
//     f64[12] T_world_camera         rotation row-major (9), then translation (3)
//     u32 C, u8[C]                   colour, PNG (8-bit, 3 channels)
//     u32 D, u8[D]                   depth, PNG (16-bit, kKeyframeDepthScale units per metre, 0 = missing)
// A reader checks every count against the bytes left, the camera, every value for finiteness,
// the rotation for orthonormality and the images' types and sizes (colour and depth alike), so a
// truncated or corrupt file is an error, never a crash. Depth is rounded to 0.2 mm; depth past
// 13.1 m (65535 units) is saved as missing.
#pragma once

#include <string>
#include <vector>

#include "fslam/core/mapping/mapper.hpp"

namespace fslam::core {

constexpr double kKeyframeDepthScale = 5000.0;  // units per metre
// Largest file accepted: 1000 keyframes (mapper.max_stored_keyframes' default) of 1280x960
// images at about 2 MB each.
constexpr std::size_t kMaxKeyframeImagesFileBytes = 4096ull << 20;

bool write_keyframe_images_file(const std::string& path, const std::vector<KeyframeImages>& keyframes,
                                std::string* why);
bool read_keyframe_images_file(const std::string& path, std::vector<KeyframeImages>* keyframes, std::string* why);
// The same, from bytes in memory (the fuzz target's entry); `name` names them in errors.
bool parse_keyframe_images_file(const std::string& bytes, const std::string& name,
                                std::vector<KeyframeImages>* keyframes, std::string* why);

}  // namespace fslam::core

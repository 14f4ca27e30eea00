// Wire frames (proto) to core frames, with every check a server needs before accepting one.
#pragma once

#include <string>

#include "fslam/core/geometry/rgbd_frame.hpp"
#include "fslam/proto/types.h"

namespace fslam::server {

// Largest payload accepted per image: a 4K RGB frame, raw.
constexpr std::size_t kMaxImageBytes = 3840u * 2160u * 3u;

// Decodes colour (RAW RGB, PNG or JPEG) and depth (RAW or PNG, 16-bit) and fills `frame`
// (depth in metres by depth_scale, camera from the intrinsics, ground truth when present).
// False with `why` on anything malformed: zero or non-finite intrinsics, sizes that disagree,
// a lossy depth encoding, an undecodable or oversized payload, a non-positive depth scale.
bool decode_frame(const fslam_proto_Frame& msg, core::RgbdFrame* frame, std::string* why);

}  // namespace fslam::server

// Wire frames (proto) to core frames in two steps: accept_frame makes the cheap checks and an
// owned copy of the payloads when a sample arrives, decode_frame decodes on the session's
// tracking thread, so that a frame the live policy skips is never decoded.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/geometry/rgbd_frame.hpp"
#include "fslam/proto/types.h"

namespace fslam::server {

// Largest payload accepted per image: a 4K RGB frame, raw.
constexpr std::size_t kMaxImageBytes = 3840u * 2160u * 3u;
// Largest frame accepted, in pixels (4K): checked on the declared size and on the PNG or JPEG
// header before anything is decoded, so that a small payload cannot decode to gigabytes.
constexpr std::size_t kMaxFramePixels = 3840u * 2160u;

// The image size a PNG (IHDR) or JPEG (first SOF marker) payload declares in its header; false
// when the header cannot be read.
bool encoded_image_size(const std::uint8_t* data, std::size_t n, fslam_proto_ImageEncoding encoding,
                        std::uint32_t* width, std::uint32_t* height);

// One image payload as it came (RAW rows, PNG or JPEG), owned.
struct EncodedImage {
  fslam_proto_ImageEncoding encoding = fslam_proto_ENCODING_RAW;
  std::uint32_t width = 0, height = 0;
  std::uint8_t channels = 0, bytes_per_channel = 0;
  std::vector<std::uint8_t> data;
};

// A frame accepted for a session and not decoded yet.
struct EncodedFrame {
  std::uint64_t frame_id = 0;
  double timestamp = 0.0;              // seconds
  core::PinholeCamera camera;          // of colour and depth
  float depth_scale = 1000.0f;         // raw depth units per metre
  EncodedImage colour;                 // RGB
  EncodedImage depth;                  // 16-bit, lossless
  std::optional<Eigen::Isometry3d> T_world_camera_gt;  // evaluation only
};

// The checks that need no decoding, then an owned copy into `out`. False with `why` on: zero,
// non-finite or implausible intrinsics, a non-positive or non-finite depth scale, a non-finite
// timestamp, sizes that disagree with the intrinsics, channels or bytes per channel that do not
// fit, a lossy depth encoding, an unknown encoding, an empty or oversized payload, a raw payload
// of the wrong length, a ground-truth pose that is not a finite rigid transform.
bool accept_frame(const fslam_proto_Frame& msg, EncodedFrame* out, std::string* why);

// Decodes colour (RAW RGB, PNG or JPEG) and depth (RAW or PNG, 16-bit; 0 and 65535 missing)
// into `frame` (depth in metres by depth_scale). False with `why` when a payload does not decode
// to its declared size and type.
bool decode_frame(const EncodedFrame& in, core::RgbdFrame* frame, std::string* why);

// accept_frame then decode_frame.
bool decode_frame(const fslam_proto_Frame& msg, core::RgbdFrame* frame, std::string* why);

}  // namespace fslam::server

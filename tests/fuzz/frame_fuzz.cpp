// Fuzz target: a frame as a peer can publish it -> accept_frame (the checks made on arrival) ->
// decode_frame (RAW / PNG / JPEG colour, RAW / PNG depth). Input layout: fuzz_support.hpp's
// little-endian fields in the order read below, then the colour payload (colour_len bytes),
// then the depth payload (the rest). tests/fuzz/make_seeds.cpp writes valid frames as seeds.
#include <cstdint>
#include <string>

#include "fslam/core/geometry/rgbd_frame.hpp"
#include "fslam/server/wire.hpp"
#include "fuzz_support.hpp"

namespace {

void read_image_header(fslam::fuzz::ByteReader& in, fslam_proto_Image* image) {
  // Any byte, in range or not: a peer's CDR may carry an enum value we do not know.
  image->encoding = static_cast<fslam_proto_ImageEncoding>(in.take<std::uint8_t>());
  image->width = in.take<std::uint16_t>();
  image->height = in.take<std::uint16_t>();
  image->channels = in.take<std::uint8_t>();
  image->bytes_per_channel = in.take<std::uint8_t>();
}

void point_at(std::string& bytes, fslam_proto_Image* image) {
  image->data._buffer = reinterpret_cast<std::uint8_t*>(bytes.data());
  image->data._length = image->data._maximum = static_cast<std::uint32_t>(bytes.size());
  image->data._release = false;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  fslam::fuzz::ByteReader in(data, size);
  fslam_proto_Frame msg{};
  std::string session = "fuzz";
  msg.session = session.data();
  msg.frame_id = in.take<std::uint64_t>();
  msg.timestamp = in.take<double>();
  msg.intrinsics.fx = in.take<float>();
  msg.intrinsics.fy = in.take<float>();
  msg.intrinsics.cx = in.take<float>();
  msg.intrinsics.cy = in.take<float>();
  msg.intrinsics.width = in.take<std::uint16_t>();
  msg.intrinsics.height = in.take<std::uint16_t>();
  msg.depth_scale = in.take<float>();
  read_image_header(in, &msg.colour);
  read_image_header(in, &msg.depth);
  msg.has_gt_pose = (in.take<std::uint8_t>() & 1u) != 0;
  for (double& t : msg.gt_pose.translation) t = in.take<double>();
  for (double& q : msg.gt_pose.rotation) q = in.take<double>();
  const std::uint32_t colour_len = in.take<std::uint32_t>();
  std::string colour = in.bytes(colour_len);
  std::string depth = in.rest();
  point_at(colour, &msg.colour);
  point_at(depth, &msg.depth);

  fslam::server::EncodedFrame encoded;
  std::string why;
  if (!fslam::server::accept_frame(msg, &encoded, &why)) {
    if (why.empty()) __builtin_trap();  // every refusal says why
    return 0;
  }
  fslam::core::RgbdFrame frame;
  if (!fslam::server::decode_frame(encoded, &frame, &why)) {
    if (why.empty()) __builtin_trap();
    return 0;
  }
  // A decoded frame has the sizes it declared.
  if (frame.colour.cols != static_cast<int>(msg.intrinsics.width) ||
      frame.depth.rows != static_cast<int>(msg.intrinsics.height)) {
    __builtin_trap();
  }
  return 0;
}

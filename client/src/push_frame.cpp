// Client::push_frame: a frame encoded (raw rows, PNG or JPEG colour; raw or PNG depth) and
// written on <prefix>/frames under the frame writer's flow control (docs/protocol.md).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "depth_png.hpp"
#include "fslam/client/client.hpp"
#include "fslam/proto/types.h"

namespace fslam::client {
namespace {

bool fail(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

// Encodes an image into bytes: raw rows, PNG (lossless) or JPEG.
bool encode(const cv::Mat& image, PayloadEncoding encoding, int jpeg_quality,
            std::vector<std::uint8_t>* bytes, std::string* why) {
  if (encoding == PayloadEncoding::raw) {
    const std::size_t n = image.total() * image.elemSize();
    bytes->assign(image.data, image.data + n);
    return true;
  }
  std::vector<int> params;
  const char* ext = ".png";
  if (encoding == PayloadEncoding::jpeg) {
    ext = ".jpg";
    params = {cv::IMWRITE_JPEG_QUALITY, jpeg_quality};
  } else {
    params = {cv::IMWRITE_PNG_COMPRESSION, 1};  // fast: frames are streamed, not archived
  }
  if (!cv::imencode(ext, image, *bytes, params)) return fail(why, std::string("cannot encode ") + ext);
  return true;
}

fslam_proto_ImageEncoding wire(PayloadEncoding e) {
  switch (e) {
    case PayloadEncoding::png: return fslam_proto_ENCODING_PNG;
    case PayloadEncoding::jpeg: return fslam_proto_ENCODING_JPEG;
    default: return fslam_proto_ENCODING_RAW;
  }
}

// What every frame's header must say, encoded or not.
bool check_header(const CameraIntrinsics& k, float depth_scale, PayloadEncoding depth_encoding,
                  std::string* why) {
  if (!(k.fx > 0 && k.fy > 0 && std::isfinite(k.fx) && std::isfinite(k.fy) && std::isfinite(k.cx) &&
        std::isfinite(k.cy)) ||
      k.width == 0 || k.height == 0) {
    return fail(why, "push_frame: intrinsics must be finite with positive focal lengths and size");
  }
  if (depth_encoding == PayloadEncoding::jpeg) {
    return fail(why, "push_frame: depth must be encoded losslessly (raw or png)");
  }
  if (!(depth_scale > 0) || !std::isfinite(depth_scale)) {
    return fail(why, "push_frame: depth scale must be positive");
  }
  return true;
}

}  // namespace

bool Client::encode_frame(const FrameInput& frame, EncodedFrame* out, std::string* why) {
  const CameraIntrinsics& k = frame.intrinsics;
  if (!check_header(k, frame.depth_scale, frame.depth_encoding, why)) return false;
  if (frame.rgb == nullptr || frame.depth == nullptr) return fail(why, "push_frame: colour and depth are required");
  const int w = static_cast<int>(k.width), h = static_cast<int>(k.height);
  // Encoded payloads are ordinary PNG/JPEG files of the colour image (OpenCV's encoder takes BGR,
  // hence the swap); raw payloads are RGB rows (docs/protocol.md).
  cv::Mat rgb(h, w, CV_8UC3, const_cast<std::uint8_t*>(frame.rgb));
  cv::Mat depth(h, w, CV_16UC1, const_cast<std::uint16_t*>(frame.depth));
  cv::Mat bgr;
  if (frame.colour_encoding != PayloadEncoding::raw) cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
  if (!encode(frame.colour_encoding == PayloadEncoding::raw ? rgb : bgr, frame.colour_encoding,
              frame.jpeg_quality, &out->colour, why) ||
      !(frame.depth_encoding == PayloadEncoding::png
            ? encode_depth_png(frame.depth, w, h, &out->depth, why)
            : encode(depth, frame.depth_encoding, 0, &out->depth, why))) {
    return false;
  }
  out->frame_id = frame.frame_id;
  out->timestamp = frame.timestamp;
  out->intrinsics = k;
  out->depth_scale = frame.depth_scale;
  out->colour_encoding = frame.colour_encoding;
  out->depth_encoding = frame.depth_encoding;
  out->has_gt_pose = frame.has_gt_pose;
  std::copy_n(frame.gt_translation, 3, out->gt_translation);
  std::copy_n(frame.gt_rotation, 4, out->gt_rotation);
  return true;
}

bool Client::push_frame(const std::string& session, const FrameInput& frame, std::string* why, int wait_ms) {
  EncodedFrame encoded;
  return encode_frame(frame, &encoded, why) && push_encoded(session, encoded, why, wait_ms);
}

bool Client::push_encoded(const std::string& session, const EncodedFrame& frame, std::string* why, int wait_ms) {
  const CameraIntrinsics& k = frame.intrinsics;
  if (session.empty()) return fail(why, "push_frame: no session name");
  if (!frame_writer_) return fail(why, "push_frame: " + frames_refused_);
  if (!check_header(k, frame.depth_scale, frame.depth_encoding, why)) return false;
  if (frame.colour.empty() || frame.depth.empty()) return fail(why, "push_frame: colour and depth are required");
  {
    std::lock_guard<std::mutex> lock(callback_mutex_);
    if (addresses_.count(session) == 0) addresses_.insert(session);
  }
  fslam_proto_Frame msg{};
  std::string session_copy = session;
  msg.session = session_copy.data();
  msg.frame_id = frame.frame_id;
  msg.timestamp = frame.timestamp;
  msg.intrinsics = {k.fx, k.fy, k.cx, k.cy, k.width, k.height};
  msg.depth_scale = frame.depth_scale;
  msg.colour = {wire(frame.colour_encoding), k.width, k.height, 3, 1, {}};
  // The sequences point into `frame` (release false): dds_write only reads them.
  const auto colour_size = static_cast<uint32_t>(frame.colour.size());
  const auto depth_size = static_cast<uint32_t>(frame.depth.size());
  msg.colour.data = {colour_size, colour_size, const_cast<std::uint8_t*>(frame.colour.data()), false};
  msg.depth = {wire(frame.depth_encoding), k.width, k.height, 1, 2, {}};
  msg.depth.data = {depth_size, depth_size, const_cast<std::uint8_t*>(frame.depth.data()), false};
  msg.has_gt_pose = frame.has_gt_pose;
  for (int i = 0; i < 3; ++i) msg.gt_pose.translation[i] = frame.gt_translation[i];
  for (int i = 0; i < 4; ++i) msg.gt_pose.rotation[i] = frame.gt_rotation[i];
  // Each write blocks up to the reliability's 1 s while the frames in flight (kFramesInFlight,
  // or Cyclone's limit on unacknowledged bytes) are not acknowledged; try again until wait_ms.
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::milliseconds(std::max(wait_ms, 0));
  dds_return_t rc = dds_write(frame_writer_.get(), &msg);
  while (rc == DDS_RETCODE_TIMEOUT && std::chrono::steady_clock::now() < give_up)
    rc = dds_write(frame_writer_.get(), &msg);
  if (rc == DDS_RETCODE_TIMEOUT) {
    return fail(why, "push_frame: the server has not acknowledged the frames in flight (at most " +
                         std::to_string(kFramesInFlight) + ") for " + std::to_string(std::max(wait_ms, 1000) / 1000) +
                         " s; frame " + std::to_string(frame.frame_id) + " not sent");
  }
  if (rc != DDS_RETCODE_OK) {
    return fail(why, std::string("push_frame: DDS write failed: ") + dds_strretcode(rc));
  }
  return true;
}

}  // namespace fslam::client

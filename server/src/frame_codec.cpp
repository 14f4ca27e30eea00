#include "fslam/server/frame_codec.hpp"

#include <cmath>
#include <cstring>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/core/error.hpp"

namespace fslam::server {
namespace {

bool decode_image(const fslam_proto_Image& image, int cv_type, const char* what, cv::Mat* out,
                  std::string* why) {
  const std::size_t n = image.data._length;
  if (n == 0 || image.data._buffer == nullptr) return core::fail(why, std::string(what) + ": empty payload");
  if (n > kMaxImageBytes) return core::fail(why, std::string(what) + ": payload over the size limit");
  const int channels = CV_MAT_CN(cv_type);
  if (image.channels != channels) {
    return core::fail(why, std::string(what) + ": expected " + std::to_string(channels) +
                               " channel(s), got " + std::to_string(image.channels));
  }
  if (image.encoding == fslam_proto_ENCODING_RAW) {
    const std::size_t expected = static_cast<std::size_t>(image.width) * image.height *
                                 CV_ELEM_SIZE(cv_type);
    if (n != expected) {
      return core::fail(why, std::string(what) + ": raw payload of " + std::to_string(n) +
                                 " bytes, expected " + std::to_string(expected));
    }
    *out = cv::Mat(static_cast<int>(image.height), static_cast<int>(image.width), cv_type);
    std::memcpy(out->data, image.data._buffer, n);
    return true;
  }
  const std::vector<std::uint8_t> bytes(image.data._buffer, image.data._buffer + n);
  cv::Mat decoded = cv::imdecode(bytes, cv_type == CV_16UC1 ? cv::IMREAD_UNCHANGED : cv::IMREAD_COLOR);
  if (decoded.empty()) return core::fail(why, std::string(what) + ": cannot decode the payload");
  if (decoded.type() != cv_type) return core::fail(why, std::string(what) + ": wrong pixel type after decoding");
  if (cv_type == CV_8UC3) cv::cvtColor(decoded, decoded, cv::COLOR_BGR2RGB);
  if (decoded.cols != static_cast<int>(image.width) || decoded.rows != static_cast<int>(image.height)) {
    return core::fail(why, std::string(what) + ": decoded size differs from the declared one");
  }
  *out = decoded;
  return true;
}

}  // namespace

bool decode_frame(const fslam_proto_Frame& msg, core::RgbdFrame* frame, std::string* why) {
  const fslam_proto_Intrinsics& k = msg.intrinsics;
  core::PinholeCamera camera{k.fx, k.fy, k.cx, k.cy, static_cast<int>(k.width),
                             static_cast<int>(k.height)};
  std::string reason;
  if (!camera.is_valid(&reason)) return core::fail(why, "intrinsics: " + reason);
  if (!(msg.depth_scale > 0) || !std::isfinite(msg.depth_scale)) {
    return core::fail(why, "depth scale must be positive and finite");
  }
  if (msg.depth.encoding == fslam_proto_ENCODING_JPEG) return core::fail(why, "depth: JPEG is lossy; send RAW or PNG");
  if (msg.colour.width != k.width || msg.colour.height != k.height || msg.depth.width != k.width ||
      msg.depth.height != k.height) {
    return core::fail(why, "colour and depth must have the intrinsics' size");
  }
  cv::Mat colour, depth_raw;
  if (!decode_image(msg.colour, CV_8UC3, "colour", &colour, why) ||
      !decode_image(msg.depth, CV_16UC1, "depth", &depth_raw, why)) {
    return false;
  }
  cv::Mat depth;
  depth_raw.convertTo(depth, CV_32FC1, 1.0 / msg.depth_scale);
  depth.setTo(0.0f, depth_raw == 65535);
  frame->id = static_cast<std::int64_t>(msg.frame_id);
  frame->timestamp = msg.timestamp;
  frame->colour = colour;
  frame->depth = depth;
  frame->camera = camera;
  frame->T_world_camera_gt.reset();
  if (msg.has_gt_pose) {
    const auto& p = msg.gt_pose;
    const Eigen::Quaterniond q(p.rotation[3], p.rotation[0], p.rotation[1], p.rotation[2]);
    if (std::isfinite(q.norm()) && std::abs(q.norm() - 1.0) < 1e-3) {
      Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
      T.linear() = q.normalized().toRotationMatrix();
      T.translation() = Eigen::Vector3d(p.translation[0], p.translation[1], p.translation[2]);
      frame->T_world_camera_gt = T;
    }
  }
  return true;
}

}  // namespace fslam::server

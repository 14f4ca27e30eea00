// The thin client: pushes RGB-D frames to a featureslam server and receives the poses it
// publishes. Depends on the wire contract (proto) and image codecs only: no Eigen, no core.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

#include "fslam/client/dds.hpp"

namespace fslam::client {

enum class PayloadEncoding { raw, png, jpeg };

struct CameraIntrinsics {
  float fx = 0, fy = 0, cx = 0, cy = 0;  // pixels
  std::uint32_t width = 0, height = 0;
};

// One RGB-D frame as the client holds it before encoding. The pointers must stay valid for the
// duration of push_frame.
struct FrameInput {
  std::uint64_t frame_id = 0;
  double timestamp = 0.0;               // seconds
  CameraIntrinsics intrinsics;
  float depth_scale = 1000.0f;          // raw depth units per metre
  const std::uint8_t* rgb = nullptr;    // [H, W, 3] RGB
  const std::uint16_t* depth = nullptr; // [H, W] raw units, 0 = missing
  PayloadEncoding colour_encoding = PayloadEncoding::jpeg;
  PayloadEncoding depth_encoding = PayloadEncoding::png;  // raw or png: depth stays lossless
  int jpeg_quality = 90;
  bool has_gt_pose = false;             // evaluation only; the server never tracks with it
  double gt_translation[3] = {0, 0, 0}; // camera-to-world, metres
  double gt_rotation[4] = {0, 0, 0, 1}; // qx qy qz qw
};

// A pose the server published for one frame.
struct PoseUpdate {
  std::string session;
  std::uint64_t frame_id = 0;
  double timestamp = 0.0;
  double translation[3] = {0, 0, 0};  // camera-to-world, metres
  double rotation[4] = {0, 0, 0, 1};  // qx qy qz qw
  int state = 0;                      // fslam_proto_TrackingState
  bool keyframe = false;
};

struct ClientOptions {
  std::string prefix = "fslam";        // topic prefix of the deployment
  dds_domainid_t domain = DDS_DOMAIN_DEFAULT;
};

class Client {
 public:
  // Joins the domain (the network profile comes from CYCLONEDDS_URI); throws DdsError.
  explicit Client(const ClientOptions& options = {});
  ~Client();
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;

  // Encodes the frame and publishes it on <prefix>/frames for `session`. False with `why` for
  // bad input (no session, zero or non-finite intrinsics, missing images, a lossy depth
  // encoding, an encoder failure).
  bool push_frame(const std::string& session, const FrameInput& frame, std::string* why);
  // Called on the client's listener thread for every pose the server publishes.
  void on_pose(std::function<void(const PoseUpdate&)> callback);
  // Writers and readers matched so far (for waiting on discovery).
  std::uint32_t matched_servers() const;

 private:
  void listen();

  Entity participant_, frames_topic_, poses_topic_, frame_writer_, pose_reader_, waitset_;
  std::mutex callback_mutex_;
  std::function<void(const PoseUpdate&)> pose_callback_;
  std::atomic<bool> stop_{false};
  std::thread listener_;
};

}  // namespace fslam::client

// The thin client: pushes RGB-D frames to a featureslam server and receives the poses it
// publishes. Depends on the wire contract (proto) and image codecs only: no Eigen, no core.
#pragma once

#include <atomic>
#include <cstdint>
#include <condition_variable>
#include <functional>
#include <map>
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

// A server's answer to a request or session control, or its report of a rejected or dropped
// frame (request_id = frame id, client = session).
struct ResultUpdate {
  std::string client;
  std::uint64_t request_id = 0;
  std::string map_name;
  bool ok = false;
  std::string error;
};

// A session's health as the server reports it at a fixed rate (best effort).
struct StatusUpdate {
  std::string session, map_name, last_drop_reason;
  std::uint32_t queue_depth = 0;
  std::uint64_t frames_received = 0, frames_processed = 0, frames_dropped = 0;
  std::uint64_t map_gaussians = 0, resident_bytes = 0;
  float track_ms_p50 = 0, track_ms_p99 = 0;
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
  // Opens (creates or attaches to `map_name`) or closes a streaming session and waits up to
  // timeout_ms for the server's answer. False with `why` on an error result or no answer.
  bool open_session(const std::string& session, const std::string& map_name, int timeout_ms,
                    std::string* why);
  bool close_session(const std::string& session, int timeout_ms, std::string* why);
  // Called on the client's listener thread for every pose the server publishes.
  void on_pose(std::function<void(const PoseUpdate&)> callback);
  // Called on the listener thread for results that no open/close call is waiting for (frame
  // errors and drops).
  void on_result(std::function<void(const ResultUpdate&)> callback);
  // Called on the listener thread for every status report of any session.
  void on_status(std::function<void(const StatusUpdate&)> callback);
  // Writers and readers matched so far (for waiting on discovery).
  std::uint32_t matched_servers() const;

 private:
  void listen();
  bool control(const std::string& session, const std::string& map_name, bool open, int timeout_ms,
               std::string* why);

  Entity participant_, frames_topic_, poses_topic_, control_topic_, results_topic_, status_topic_;
  Entity frame_writer_, pose_reader_, control_writer_, result_reader_, status_reader_, waitset_;
  std::mutex callback_mutex_;
  std::function<void(const PoseUpdate&)> pose_callback_;
  std::function<void(const ResultUpdate&)> result_callback_;
  std::function<void(const StatusUpdate&)> status_callback_;
  std::condition_variable result_arrived_;
  std::map<std::uint64_t, ResultUpdate> awaited_;  // request id -> answer (filled when it comes)
  std::uint64_t next_request_ = 1ull << 62;  // apart from frame ids, which frame results echo
  std::atomic<bool> stop_{false};
  std::thread listener_;
};

}  // namespace fslam::client

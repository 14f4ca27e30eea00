// Views pushed to a localise session's client (docs/protocol.md "Session modes"): the map
// rendered at the session's newest localised pose with the frame's camera, on <prefix>/views.
// Renders run on a thread of the stream's own, so tracking never waits for one; at most
// `rate_hz` are started a second, and a pose that arrives while one renders replaces the pose
// waiting (an AR overlay wants the newest view, not a backlog).
#pragma once

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include <Eigen/Geometry>

#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/render/rasterizer.hpp"
#include "fslam/server/rate_limit.hpp"
#include "fslam/server/wire.hpp"

namespace fslam::server {

struct MapEntry;

class ViewStream {
 public:
  using Log = std::function<void(const std::string&)>;
  // `rasterizer` and `replies` must outlive the stream; rate_hz > 0; channels are CHANNEL_* bits
  // (check_render_channels passed).
  ViewStream(std::string session, std::shared_ptr<MapEntry> map, const core::Rasterizer& rasterizer,
             const Replies& replies, double rate_hz, std::uint32_t channels, Log log);
  // Renders the pose waiting, if any, then stops.
  ~ViewStream();
  ViewStream(const ViewStream&) = delete;
  ViewStream& operator=(const ViewStream&) = delete;

  // A localised frame (any thread): rendered and sent unless the rate allows none yet.
  void offer(std::uint64_t frame_id, double timestamp, const Eigen::Isometry3d& T_world_camera,
             const core::PinholeCamera& camera);
  // Views sent so far.
  std::uint64_t sent() const;

  // The depth scale of a view's depth image (raw units per metre), as a render's default.
  static constexpr float kDepthScale = 1000.0f;

 private:
  struct Pending {
    std::uint64_t frame_id = 0;
    double timestamp = 0.0;
    Eigen::Isometry3d T_world_camera;
    core::PinholeCamera camera;
  };
  void run();
  void send(const Pending& pending);

  const std::string session_;
  const std::shared_ptr<MapEntry> map_;
  const core::Rasterizer& rasterizer_;
  client::Entity writer_;  // this session's own (Replies::view_writer)
  const std::uint32_t channels_;
  Log log_;
  mutable std::mutex mutex_;  // guards everything below
  std::condition_variable wake_;
  RateLimit rate_;
  std::optional<Pending> pending_;
  bool stopping_ = false, failure_logged_ = false;
  std::uint64_t sent_ = 0;
  std::thread thread_;
};

}  // namespace fslam::server

#include "view_stream.hpp"

#include <utility>

#include "map_registry.hpp"

namespace fslam::server {

ViewStream::ViewStream(std::string session, std::shared_ptr<MapEntry> map, const core::Rasterizer& rasterizer,
                       const Replies& replies, double rate_hz, std::uint32_t channels, Log log)
    : session_(std::move(session)),
      map_(std::move(map)),
      rasterizer_(rasterizer),
      writer_(replies.view_writer()),
      channels_(channels),
      log_(std::move(log)),
      rate_(rate_hz, 0.0),  // no bursts: one view per 1 / rate_hz on average
      thread_([this] { run(); }) {}

ViewStream::~ViewStream() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  thread_.join();
}

void ViewStream::offer(std::uint64_t frame_id, double timestamp, const Eigen::Isometry3d& T_world_camera,
                       const core::PinholeCamera& camera) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_ || !rate_.take()) return;
    pending_ = Pending{frame_id, timestamp, T_world_camera, camera};  // replaces one not started
  }
  wake_.notify_one();
}

std::uint64_t ViewStream::sent() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return sent_;
}

void ViewStream::run() {
  for (;;) {
    Pending pending;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [&] { return pending_.has_value() || stopping_; });
      if (!pending_) return;
      pending = std::move(*pending_);
      pending_.reset();
    }
    send(pending);
  }
}

void ViewStream::send(const Pending& pending) {
  // The newest version of the map: a map another session still builds grows under the views.
  const std::uint64_t version_number = map_->versions().version_number();
  const core::MapVersions::Version version = map_->versions().latest();
  core::RenderView view;
  view.camera = pending.camera;
  view.T_camera_world = pending.T_world_camera.inverse();
  fslam_proto_View v{};
  ResultImages images;
  std::string why;
  if (!version || !render_to_wire(rasterizer_, *version, view, channels_, kDepthScale, &v.images, &images, &why)) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!failure_logged_ && log_) log_("session '" + session_ + "': no view for frame " +
                                       std::to_string(pending.frame_id) + ": " + (version ? why : "no map version"));
    failure_logged_ = true;
    return;
  }
  std::string session = session_, map_name = map_->name;
  v.session = session.data();
  v.frame_id = pending.frame_id;
  v.timestamp = pending.timestamp;
  v.map_name = map_name.data();
  v.map_version = version_number;
  v.map_gaussians = version->size();
  v.channels = channels_;
  describe_view(view, pending.T_world_camera, &v.T_world_camera, &v.intrinsics);
  dds_write(writer_.get(), &v);
  std::lock_guard<std::mutex> lock(mutex_);
  ++sent_;
}

}  // namespace fslam::server

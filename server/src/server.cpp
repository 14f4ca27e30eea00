#include "fslam/server/server.hpp"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <utility>
#include <vector>

#include "fslam/core/error.hpp"
#include "fslam/server/backend_factory.hpp"
#include "fslam/server/frame_codec.hpp"

namespace fslam::server {

using client::check_dds;
using client::Entity;

// One streaming session: its pipeline, its bounded queue and its two threads.
struct Server::Session {
  std::string name, map_name;
  std::unique_ptr<core::SlamPipeline> pipeline;
  std::mutex mutex;
  std::condition_variable wake;
  std::deque<core::RgbdFrame> queue;
  bool closing = false;
  std::thread tracking, mapping;
  // Status counters (guarded by `mutex`).
  std::uint64_t received = 0, processed = 0, dropped = 0;
  std::string last_drop_reason;
  std::deque<double> track_ms;  // the latest tracking times, for p50 / p99
};

namespace {

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5)];
}

std::uint64_t resident_bytes() {
  long pages = 0, resident = 0;
  if (FILE* f = std::fopen("/proc/self/statm", "r")) {
    if (std::fscanf(f, "%ld %ld", &pages, &resident) != 2) resident = 0;
    std::fclose(f);
  }
  return static_cast<std::uint64_t>(resident) * static_cast<std::uint64_t>(sysconf(_SC_PAGESIZE));
}

}  // namespace

bool ServerConfig::is_valid(std::string* why) const {
  if (prefix.empty()) return core::fail(why, "server: empty topic prefix");
  if (queue_capacity == 0) return core::fail(why, "server: queue_capacity must be > 0");
  if (status_period_ms <= 0) return core::fail(why, "server: status_period_ms must be > 0");
  return pipeline.is_valid(why);
}

Server::Server() = default;
Server::~Server() {
  deactivate();
  cleanup();
}

bool Server::configure(const ServerConfig& config, std::string* why) {
  if (!config.is_valid(why)) return false;
  config_ = config;
  configured_ = true;
  return true;
}

bool Server::activate(std::string* why) {
  if (!configured_) return core::fail(why, "server: activate before configure");
  try {
    participant_ = client::make_participant(config_.domain);
    dds_qos_t* qos = dds_create_qos();
    dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
    dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 64);
    auto topic = [&](const dds_topic_descriptor_t* desc, const char* name) {
      return Entity(check_dds(dds_create_topic(participant_.get(), desc,
                                               client::topic_name(config_.prefix, name).c_str(),
                                               qos, nullptr),
                              std::string("create topic ") + name));
    };
    frames_topic_ = topic(&fslam_proto_Frame_desc, "frames");
    poses_topic_ = topic(&fslam_proto_PoseStamped_desc, "poses");
    control_topic_ = topic(&fslam_proto_SessionControl_desc, "session");
    results_topic_ = topic(&fslam_proto_Result_desc, "results");
    status_topic_ = topic(&fslam_proto_SessionStatus_desc, "status");
    frame_reader_ = Entity(check_dds(dds_create_reader(participant_.get(), frames_topic_.get(), qos, nullptr), "frame reader"));
    control_reader_ = Entity(check_dds(dds_create_reader(participant_.get(), control_topic_.get(), qos, nullptr), "session reader"));
    pose_writer_ = Entity(check_dds(dds_create_writer(participant_.get(), poses_topic_.get(), qos, nullptr), "pose writer"));
    result_writer_ = Entity(check_dds(dds_create_writer(participant_.get(), results_topic_.get(), qos, nullptr), "result writer"));
    dds_delete_qos(qos);
    dds_qos_t* best_effort = dds_create_qos();
    dds_qset_reliability(best_effort, DDS_RELIABILITY_BEST_EFFORT, 0);
    status_writer_ = Entity(check_dds(dds_create_writer(participant_.get(), status_topic_.get(), best_effort, nullptr), "status writer"));
    dds_delete_qos(best_effort);
    waitset_ = Entity(check_dds(dds_create_waitset(participant_.get()), "waitset"));
    for (const Entity* reader : {&frame_reader_, &control_reader_}) {
      check_dds(dds_set_status_mask(reader->get(), DDS_DATA_AVAILABLE_STATUS), "status mask");
      check_dds(dds_waitset_attach(waitset_.get(), reader->get(), reader->get()), "attach");
    }
  } catch (const client::DdsError& e) {
    return core::fail(why, e.what());
  }
  stop_ = false;
  ingest_thread_ = std::thread([this] { ingest(); });
  return true;
}

void Server::deactivate() {
  if (ingest_thread_.joinable()) {
    stop_ = true;
    dds_waitset_set_trigger(waitset_.get(), true);
    ingest_thread_.join();
  }
  std::map<std::string, std::unique_ptr<Session>> sessions;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    sessions.swap(sessions_);
  }
  for (auto& [name, s] : sessions) finish_session(s.get());
  std::vector<std::thread> closers;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    closers.swap(closers_);
  }
  for (std::thread& t : closers) t.join();
}

void Server::cleanup() {
  waitset_.reset();
  frame_reader_.reset();
  control_reader_.reset();
  pose_writer_.reset();
  result_writer_.reset();
  status_writer_.reset();
  participant_.reset();
}

ServerStats Server::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  ServerStats s = stats_;
  s.sessions = sessions_.size();
  return s;
}

void Server::ingest() {
  auto next_status = std::chrono::steady_clock::now();
  while (!stop_) {
    if (std::chrono::steady_clock::now() >= next_status) {
      publish_status();
      next_status += std::chrono::milliseconds(config_.status_period_ms);
    }
    dds_attach_t triggered[2];
    dds_waitset_wait(waitset_.get(), triggered, 2, DDS_MSECS(200));
    // Session control first, so that a session opened just before its first frame exists.
    client::take_each<fslam_proto_SessionControl>(
        control_reader_.get(), [&](const fslam_proto_SessionControl& m) { handle_control(m); });
    client::take_each<fslam_proto_Frame>(frame_reader_.get(),
                                         [&](const fslam_proto_Frame& m) { handle_frame(m); });
  }
}

void Server::publish_status() {
  std::lock_guard<std::mutex> lock(mutex_);
  const std::uint64_t rss = resident_bytes();
  for (const auto& [name, s] : sessions_) {
    fslam_proto_SessionStatus st{};
    std::string session = s->name, map = s->map_name, reason;
    std::vector<double> ms;
    {
      std::lock_guard<std::mutex> qlock(s->mutex);
      st.queue_depth = static_cast<std::uint32_t>(s->queue.size());
      st.frames_received = s->received;
      st.frames_processed = s->processed;
      st.frames_dropped = s->dropped;
      reason = s->last_drop_reason;
      ms.assign(s->track_ms.begin(), s->track_ms.end());
    }
    st.session = session.data();
    st.map_name = map.data();
    st.last_drop_reason = reason.data();
    st.map_gaussians = s->pipeline->latest_map()->size();
    st.track_ms_p50 = static_cast<float>(quantile(ms, 0.5));
    st.track_ms_p99 = static_cast<float>(quantile(ms, 0.99));
    st.resident_bytes = rss;
    dds_write(status_writer_.get(), &st);
  }
}

void Server::publish_result(const char* client, std::uint64_t request_id, const std::string& map_name,
                            const std::string& error) {
  fslam_proto_Result r{};
  std::string c = client != nullptr ? client : "", m = map_name, e = error;
  r.client = c.data();
  r.request_id = request_id;
  r.map_name = m.data();
  r.status = error.empty() ? fslam_proto_RESULT_OK : fslam_proto_RESULT_ERROR;
  r.error = e.data();
  dds_write(result_writer_.get(), &r);
}

void Server::handle_control(const fslam_proto_SessionControl& msg) {
  const std::string name = msg.session != nullptr ? msg.session : "";
  const std::string map = msg.map_name != nullptr && msg.map_name[0] ? msg.map_name : name;
  if (name.empty()) return publish_result(msg.session, msg.request_id, map, "session name is empty");
  std::unique_ptr<Session> closing;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = sessions_.find(name);
    if (msg.command == fslam_proto_SESSION_OPEN) {
      if (it != sessions_.end()) {
        publish_result(msg.session, msg.request_id, it->second->map_name, "");
        return;  // opening twice is harmless
      }
      if (msg.attach_only) {
        return publish_result(msg.session, msg.request_id, map, "no map named '" + map + "'");
      }
      std::string why, notice;
      std::shared_ptr<const core::Rasterizer> rasterizer = make_rasterizer("auto", &notice, &why);
      if (!rasterizer) return publish_result(msg.session, msg.request_id, map, why);
      auto s = std::make_unique<Session>();
      s->name = name;
      s->map_name = map;
      s->pipeline = std::make_unique<core::SlamPipeline>(config_.pipeline, rasterizer);
      Session* raw = s.get();
      s->tracking = std::thread([this, raw] { run_tracking(raw); });
      s->mapping = std::thread([this, raw] {
        std::string mwhy;
        if (!raw->pipeline->run_mapping(nullptr, &mwhy)) {
          // Tracking goes on; clients learn that the map stopped growing, and why.
          publish_result(raw->name.c_str(), 0, raw->map_name, "mapping failed: " + mwhy);
        }
      });
      sessions_[name] = std::move(s);
    } else {
      if (it == sessions_.end()) {
        return publish_result(msg.session, msg.request_id, map, "unknown session '" + name + "'");
      }
      closing = std::move(it->second);
      sessions_.erase(it);
    }
  }
  if (closing) {
    // Draining a session (its queued frames, then mapping) can take a while: do it off the
    // ingest thread so that other sessions keep flowing, and answer when it is done.
    std::string client = msg.session, map_name = map;
    const std::uint64_t request_id = msg.request_id;
    std::lock_guard<std::mutex> lock(mutex_);
    closers_.push_back(std::thread([this, owned = std::move(closing), client, map_name, request_id] {
      finish_session(owned.get());
      publish_result(client.c_str(), request_id, map_name, "");
    }));
    return;
  }
  publish_result(msg.session, msg.request_id, map, "");
}

void Server::finish_session(Session* s) {
  {
    std::lock_guard<std::mutex> lock(s->mutex);
    s->closing = true;
  }
  s->wake.notify_all();
  if (s->tracking.joinable()) s->tracking.join();  // every accepted frame is tracked
  s->pipeline->finish();
  if (s->mapping.joinable()) s->mapping.join();
}

void Server::handle_frame(const fslam_proto_Frame& msg) {
  const std::string name = msg.session != nullptr ? msg.session : "";
  // Decoding (PNG/JPEG) is the costly part: done before taking the server's lock.
  core::RgbdFrame frame;
  std::string decode_why, why;
  const bool decoded = decode_frame(msg, &frame, &decode_why);
  std::lock_guard<std::mutex> lock(mutex_);
  ++stats_.frames_received;
  const auto it = sessions_.find(name);
  if (it == sessions_.end()) why = "unknown session '" + name + "' (open it first)";
  else if (!decoded) why = decode_why;
  if (!why.empty()) {
    ++stats_.frames_rejected;
    const std::string message = "frame " + std::to_string(msg.frame_id) + ": " + why;
    if (it != sessions_.end()) {
      std::lock_guard<std::mutex> qlock(it->second->mutex);
      ++it->second->received;
      ++it->second->dropped;
      it->second->last_drop_reason = message;
    }
    publish_result(msg.session, msg.frame_id, name, message);
    return;
  }
  Session& s = *it->second;
  {
    std::lock_guard<std::mutex> qlock(s.mutex);
    ++s.received;
    if (s.queue.size() >= config_.queue_capacity) {
      ++stats_.frames_dropped;
      ++s.dropped;
      s.last_drop_reason = "frame " + std::to_string(msg.frame_id) + " dropped: queue full (" +
                           std::to_string(config_.queue_capacity) + " frames)";
      publish_result(msg.session, msg.frame_id, name, s.last_drop_reason);
      return;
    }
    s.queue.push_back(std::move(frame));
  }
  s.wake.notify_one();
}

void Server::run_tracking(Session* s) {
  bool first = true;
  for (;;) {
    core::RgbdFrame frame;
    {
      std::unique_lock<std::mutex> lock(s->mutex);
      s->wake.wait(lock, [&] { return !s->queue.empty() || s->closing; });
      if (s->queue.empty()) return;  // closing and drained
      frame = std::move(s->queue.front());
      s->queue.pop_front();
    }
    if (first && frame.T_world_camera_gt) s->pipeline->set_initial_pose(*frame.T_world_camera_gt);
    first = false;
    core::TrackingResult result;
    std::string why;
    const auto t0 = std::chrono::steady_clock::now();
    const bool tracked = s->pipeline->process_frame(frame, &result, &why);
    {
      std::lock_guard<std::mutex> lock(s->mutex);
      ++s->processed;
      s->track_ms.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      if (s->track_ms.size() > 1000) s->track_ms.pop_front();
    }
    if (!tracked) {
      std::string session = s->name;
      publish_result(session.c_str(), static_cast<std::uint64_t>(frame.id), s->map_name, why);
      continue;
    }
    fslam_proto_PoseStamped pose{};
    std::string session = s->name;
    pose.session = session.data();
    pose.frame_id = static_cast<std::uint64_t>(frame.id);
    pose.timestamp = frame.timestamp;
    const Eigen::Quaterniond q(result.T_world_camera.rotation());
    for (int k = 0; k < 3; ++k) pose.T_world_camera.translation[k] = result.T_world_camera.translation()[k];
    pose.T_world_camera.rotation[0] = q.x();
    pose.T_world_camera.rotation[1] = q.y();
    pose.T_world_camera.rotation[2] = q.z();
    pose.T_world_camera.rotation[3] = q.w();
    pose.state = static_cast<fslam_proto_TrackingState>(static_cast<int>(result.state));
    pose.keyframe = result.keyframe;
    dds_write(pose_writer_.get(), &pose);
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.poses_published;
  }
}

}  // namespace fslam::server

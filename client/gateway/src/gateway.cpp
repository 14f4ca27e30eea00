#include "gateway.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <utility>

#include <nlohmann/json.hpp>

#include "messages.hpp"

namespace fslam::client::gateway {
namespace {

using Clock = std::chrono::steady_clock;
using nlohmann::json;

// A status row not heard of for this long is gone (its session closed or its server stopped);
// status comes once a second.
constexpr auto kStatusStale = std::chrono::seconds(4);
constexpr std::size_t kMaxPosesPerSession = 200000;
constexpr std::size_t kMaxQueuedJobs = 16;
constexpr int kMaxPendingPerViewer = 4;

OutgoingPtr text_message(const json& j) {
  auto m = std::make_shared<Outgoing>();
  m->data = j.dump();
  return m;
}

json status_json(const StatusUpdate& s) {
  return {{"session", s.session},
          {"map", s.map_name},
          {"streaming", s.streaming},
          {"map_version", s.map_version},
          {"map_gaussians", s.map_gaussians},
          {"frames_received", s.frames_received},
          {"frames_processed", s.frames_processed},
          {"frames_dropped", s.frames_dropped},
          {"frames_tracked", s.frames_tracked},
          {"queue_depth", s.queue_depth},
          {"track_ms_p50", s.track_ms_p50},
          {"track_cpu_ms_p50", s.track_cpu_ms_p50},
          {"map_ms_p50", s.map_ms_p50},
          {"last_drop_reason", s.last_drop_reason}};
}

}  // namespace

Gateway::Gateway(const GatewayOptions& options, Client* client) : options_(options), client_(client) {}

Gateway::~Gateway() { stop(); }

void Gateway::start(ViewerHub* hub) {
  hub_ = hub;
  client_->on_pose([this](const PoseUpdate& p) {
    PoseRow row{p.frame_id, {p.translation[0], p.translation[1], p.translation[2]},
                {p.rotation[0], p.rotation[1], p.rotation[2], p.rotation[3]}, p.state, p.keyframe};
    {
      std::lock_guard<std::mutex> lock(mutex_);
      std::vector<PoseRow>& poses = trajectories_[p.session];
      if (poses.size() >= kMaxPosesPerSession) return;  // the page keeps drawing what it has
      poses.push_back(row);
    }
    hub_->broadcast(text_message({{"type", "pose"},
                                  {"session", p.session},
                                  {"frame", p.frame_id},
                                  {"t", {p.translation[0], p.translation[1], p.translation[2]}},
                                  {"q", {p.rotation[0], p.rotation[1], p.rotation[2], p.rotation[3]}},
                                  {"state", p.state},
                                  {"keyframe", p.keyframe}}));
  });
  client_->on_status([this](const StatusUpdate& s) {
    bool newer = false;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      status_[{s.session, s.map_name}] = {s, Clock::now()};
      if (!s.session.empty()) session_maps_[s.session] = s.map_name;
      text_queries_ = s.text_queries;
      const auto it = maps_.find(s.map_name);
      newer = it == maps_.end() || it->second.version < s.map_version;
    }
    if (newer) wake_maps_.notify_all();
  });
  map_thread_ = std::thread([this] { read_maps(); });
  for (int i = 0; i < options_.workers; ++i) workers_.emplace_back([this] { work(); });
}

void Gateway::stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return;
    stopping_ = true;
  }
  client_->on_pose(nullptr);
  client_->on_status(nullptr);
  wake_maps_.notify_all();
  wake_workers_.notify_all();
  if (map_thread_.joinable()) map_thread_.join();
  for (std::thread& t : workers_) t.join();
  workers_.clear();
}

GatewayStats Gateway::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

OutgoingPtr Gateway::status_message() {
  // Called with mutex_ held.
  json rows = json::array();
  const auto now = Clock::now();
  for (auto it = status_.begin(); it != status_.end();) {
    if (now - it->second.seen > kStatusStale) {
      it = status_.erase(it);
      continue;
    }
    rows.push_back(status_json(it->second.status));
    ++it;
  }
  return text_message({{"type", "status"}, {"rows", rows}, {"text_queries", text_queries_}});
}

OutgoingPtr Gateway::trajectories_message() {
  // Called with mutex_ held. Rows: [frame, tx, ty, tz, qx, qy, qz, qw].
  json sessions = json::object();
  for (const auto& [session, poses] : trajectories_) {
    json rows = json::array();
    for (const PoseRow& p : poses) rows.push_back({p.frame, p.t[0], p.t[1], p.t[2], p.q[0], p.q[1], p.q[2], p.q[3]});
    const auto map = session_maps_.find(session);
    sessions[session] = {{"map", map == session_maps_.end() ? "" : map->second}, {"poses", rows}};
  }
  return text_message({{"type", "trajectories"}, {"sessions", sessions}});
}

std::vector<OutgoingPtr> Gateway::welcome(std::uint64_t viewer) {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<OutgoingPtr> out;
  out.push_back(text_message({{"type", "hello"},
                              {"viewer", viewer},
                              {"prefix", options_.prefix},
                              {"bytes_per_gaussian", kGaussianRecordBytes}}));
  out.push_back(status_message());
  out.push_back(trajectories_message());
  return out;
}

void Gateway::on_viewer_closed(std::uint64_t viewer) {
  std::lock_guard<std::mutex> lock(mutex_);
  subscriptions_.erase(viewer);
}

void Gateway::reply_error(std::uint64_t viewer, const std::string& type, std::int64_t id,
                          const std::string& error) {
  hub_->send(viewer, text_message({{"type", type}, {"id", id}, {"ok", false}, {"error", error}}));
}

void Gateway::on_message(std::uint64_t viewer, const std::string& text) {
  const json msg = json::parse(text, nullptr, false);
  if (msg.is_discarded() || !msg.is_object() || !msg.contains("type") || !msg["type"].is_string()) {
    return reply_error(viewer, "error", 0, "expected a JSON object with a \"type\"");
  }
  const std::string type = msg["type"].get<std::string>();
  try {
    if (type == "subscribe") {
      if (!msg.contains("map") || !msg["map"].is_string()) return reply_error(viewer, "error", 0, "subscribe: no map");
      return subscribe(viewer, msg["map"].get<std::string>());
    }
    if (type == "segment") return handle_segment(viewer, msg);
    if (type == "render") return handle_render(viewer, msg);
  } catch (const json::exception& e) {
    // A field of the wrong type (value() throws): the browser hears what, nothing else happens.
    return reply_error(viewer, type, 0, type + ": " + e.what());
  }
  // Nothing else is forwarded: no save, no load, no session control from a browser.
  reply_error(viewer, "error", 0, "unknown message type '" + type + "'");
}

void Gateway::subscribe(std::uint64_t viewer, const std::string& map) {
  OutgoingPtr current;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    subscriptions_[viewer] = map;
    const auto it = maps_.find(map);
    if (it != maps_.end()) current = it->second.message;
  }
  if (current) hub_->send(viewer, current);  // the full map first; newer versions follow
  wake_maps_.notify_all();
}

void Gateway::read_maps() {
  auto next_status = Clock::now();
  std::map<std::string, Clock::time_point> last_read;
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_) {
    wake_maps_.wait_for(lock, std::chrono::milliseconds(options_.map_period_ms));
    if (stopping_) break;
    if (Clock::now() >= next_status) {
      // Status to every viewer twice a second, whether or not it changed: rows age out here.
      OutgoingPtr status = status_message();
      lock.unlock();
      hub_->broadcast(status);
      lock.lock();
      next_status = Clock::now() + std::chrono::milliseconds(500);
    }
    // The maps someone looks at whose status reports a version newer than the one held.
    std::vector<std::pair<std::string, std::uint64_t>> due;
    std::set<std::string> wanted;
    for (const auto& [viewer, map] : subscriptions_) wanted.insert(map);
    for (const std::string& map : wanted) {
      std::uint64_t reported = 0;
      bool known = false;
      for (const auto& [key, row] : status_) {
        if (key.second == map) {
          reported = std::max(reported, row.status.map_version);
          known = true;
        }
      }
      const auto cached = maps_.find(map);
      const std::uint64_t held = cached == maps_.end() ? 0 : cached->second.version;
      const bool first = cached == maps_.end();
      const auto last = last_read.find(map);
      const bool rested = last == last_read.end() ||
                          Clock::now() - last->second >= std::chrono::milliseconds(options_.map_period_ms);
      if (known && (first || reported > held) && rested) due.emplace_back(map, first ? 0 : held);
    }
    for (const auto& [map, since] : due) {
      last_read[map] = Clock::now();
      lock.unlock();
      MapGaussians gaussians;
      std::string why;
      const bool ok = client_->map_gaussians({map, since, 0}, &gaussians, options_.request_timeout_ms, &why);
      OutgoingPtr message;
      if (ok && !gaussians.unchanged) {
        auto m = std::make_shared<Outgoing>();
        m->binary = true;
        m->replaceable = map;
        m->data = binary_frame("GMAP",
                               {{"map", map},
                                {"version", gaussians.version},
                                {"count", gaussians.count},
                                {"bytes_per_gaussian", kGaussianRecordBytes}},
                               gaussians.records.data(), gaussians.records.size());
        message = m;
      }
      lock.lock();
      ++stats_.map_reads;
      if (options_.verbose) {
        std::fprintf(stderr, "fslam-gateway: map '%s' since %llu: %s\n", map.c_str(),
                     static_cast<unsigned long long>(since),
                     !ok ? why.c_str()
                         : gaussians.unchanged ? "unchanged"
                                               : ("version " + std::to_string(gaussians.version) + ", " +
                                                  std::to_string(gaussians.count) + " Gaussians in " +
                                                  std::to_string(gaussians.requests) + " requests").c_str());
      }
      if (!message) continue;
      maps_[map] = {gaussians.version, gaussians.count, message};
      std::vector<std::uint64_t> viewers;
      for (const auto& [viewer, shown] : subscriptions_) {
        if (shown == map) viewers.push_back(viewer);
      }
      stats_.map_versions_sent += viewers.empty() ? 0 : 1;
      stats_.map_bytes_sent += message->data.size() * viewers.size();
      lock.unlock();
      for (const std::uint64_t viewer : viewers) hub_->send(viewer, message);
      lock.lock();
    }
  }
}

bool Gateway::submit(std::uint64_t viewer, std::function<void()> job) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (stopping_ || jobs_.size() >= kMaxQueuedJobs || pending_[viewer] >= kMaxPendingPerViewer) return false;
  ++pending_[viewer];
  ++stats_.requests;
  jobs_.push_back([this, viewer, job = std::move(job)] {
    job();
    std::lock_guard<std::mutex> lock(mutex_);
    if (--pending_[viewer] <= 0) pending_.erase(viewer);
  });
  wake_workers_.notify_one();
  return true;
}

void Gateway::work() {
  for (;;) {
    std::function<void()> job;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_workers_.wait(lock, [&] { return stopping_ || !jobs_.empty(); });
      if (stopping_) return;
      job = std::move(jobs_.front());
      jobs_.pop_front();
    }
    job();
  }
}

void Gateway::handle_segment(std::uint64_t viewer, const json& msg) {
  const std::int64_t id = msg.value("id", std::int64_t{0});
  SegmentQuery query;
  std::string why;
  query.map_name = msg.value("map", std::string());
  const std::string mode = msg.value("mode", std::string());
  if (mode == "points") query.mode = SegmentMode::points;
  else if (mode == "boxes") query.mode = SegmentMode::boxes;
  else if (mode == "text") query.mode = SegmentMode::text;
  else if (mode == "promptless") query.mode = SegmentMode::promptless;
  else return reply_error(viewer, "segment", id, "segment: mode must be points, boxes, text or promptless");
  auto numbers = [&](const char* key, std::vector<float>* out) {
    const auto it = msg.find(key);
    if (it == msg.end()) return true;
    if (!it->is_array() || it->size() > 256) return false;
    for (const json& v : *it) {
      if (!v.is_number() || !std::isfinite(v.get<double>())) return false;
      out->push_back(v.get<float>());
    }
    return true;
  };
  if (!numbers("points", &query.points) || !numbers("boxes", &query.boxes)) {
    return reply_error(viewer, "segment", id, "segment: points and boxes are arrays of at most 256 numbers");
  }
  query.text = msg.value("text", std::string());
  if (query.text.size() > 512) return reply_error(viewer, "segment", id, "segment: text of more than 512 bytes");
  if (!parse_view(msg.value("view", json()), &query.view, &why)) return reply_error(viewer, "segment", id, why);
  const bool queued = submit(viewer, [this, viewer, id, mode, query] {
    SegmentOutput out;
    std::string why;
    std::vector<std::uint8_t> png;
    std::size_t covered = 0, instances = 0;
    if (!client_->segment(query, &out, options_.request_timeout_ms, &why) ||
        !labels_overlay_png(out.labels, &png, &covered, &instances, &why)) {
      return reply_error(viewer, "segment", id, why);
    }
    auto m = std::make_shared<Outgoing>();
    m->binary = true;
    m->data = binary_frame("SEGM",
                           {{"type", "segment"}, {"id", id}, {"ok", true}, {"mode", mode},
                            {"width", out.labels.width}, {"height", out.labels.height},
                            {"map_version", out.map_version}, {"map_gaussians", out.map_gaussians},
                            {"covered", covered}, {"instances", instances}},
                           png.data(), png.size());
    hub_->send(viewer, m);
  });
  if (!queued) reply_error(viewer, "segment", id, "gateway busy: too many requests waiting; try again");
}

void Gateway::handle_render(std::uint64_t viewer, const json& msg) {
  const std::int64_t id = msg.value("id", std::int64_t{0});
  RenderQuery query;
  std::string why;
  if (!parse_view(msg.value("view", json()), &query, &why)) return reply_error(viewer, "render", id, why);
  query.map_name = msg.value("map", std::string());
  query.channels = kColour;
  const bool queued = submit(viewer, [this, viewer, id, query] {
    RenderOutput out;
    std::string why;
    std::vector<std::uint8_t> png;
    if (!client_->render(query, &out, options_.request_timeout_ms, &why) ||
        !rgb_png(out.images.at(0), &png, &why)) {
      return reply_error(viewer, "render", id, why);
    }
    auto m = std::make_shared<Outgoing>();
    m->binary = true;
    m->data = binary_frame("REND",
                           {{"type", "render"}, {"id", id}, {"ok", true},
                            {"width", out.images[0].width}, {"height", out.images[0].height},
                            {"map_version", out.map_version}, {"map_gaussians", out.map_gaussians}},
                           png.data(), png.size());
    hub_->send(viewer, m);
  });
  if (!queued) reply_error(viewer, "render", id, "gateway busy: too many requests waiting; try again");
}

}  // namespace fslam::client::gateway

#include "fslam/server/server.hpp"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <set>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include <opencv2/core/mat.hpp>
#include <tbb/task_arena.h>

#include "fslam/core/error.hpp"
#include "fslam/core/eval/percentile.hpp"
#include "fslam/core/segmentation/segmentation.hpp"
#include "fslam/server/backend_factory.hpp"
#include "fslam/server/frame_codec.hpp"
#include "fslam/server/map_export.hpp"
#include "fslam/server/health_file.hpp"
#include "fslam/server/map_directory.hpp"
#include "fslam/server/map_files.hpp"
#include "fslam/server/mapping_thread.hpp"
#include "fslam/server/render_images.hpp"

namespace fslam::server {

using Clock = std::chrono::steady_clock;

// The promptless instances of one map version (docs/segmentation.md).
struct InstanceLabels {
  std::uint64_t version_number = 0;
  core::MapVersions::Version map;  // the version labelled; null before the first request
  std::shared_ptr<const core::GaussianLabels> labels;
};

// A map the server serves: built by a streaming session (pipeline) or loaded from disk (loaded).
// Kept after its session closes, so that it can still be queried and saved.
struct Server::MapEntry {
  std::string name;
  std::shared_ptr<core::SlamPipeline> pipeline;  // null for a loaded map
  core::MapVersions loaded;
  std::mutex mutex;  // guards everything below
  core::PinholeCamera camera;  // of the frames streamed into it; width 0 before the first
  std::vector<FramePose> poses;
  std::unordered_map<std::uint64_t, std::size_t> pose_index;  // frame id -> poses[]
  bool streaming = false;
  std::pair<std::uint64_t, std::size_t> saved{0, 0};  // (version, poses) last saved at home
  // Held while clustering (apart from `mutex`, which tracking takes per frame), so that each
  // clustering carries its ids from the one before: ids form one chain over the versions.
  std::mutex instances_mutex;
  InstanceLabels instances;  // guarded by instances_mutex
  MapExporter exporter;      // versions that chunked exports read (map_export.hpp)

  core::MapVersions& versions() { return pipeline ? pipeline->mapper().versions() : loaded; }
};

struct Server::QueuedFrame {
  EncodedFrame frame;
  Clock::time_point queued;
};

// A decoded frame with its latent and source Gaussians (core::SlamPipeline::prepare_frame),
// waiting for registration; the times so far go on its pose.
struct Server::PreparedFrame {
  core::PreparedFrame frame;
  Clock::time_point ready;
  double decode_ms = 0, queue_ms = 0, prepare_ms = 0;
};

namespace {
// Frames prepared ahead of registration in a queue-policy session (each holds a decoded frame
// and a feature pyramid, ~20 MB): the preparing thread waits rather than run further ahead.
constexpr std::size_t kPreparedAhead = 2;
}  // namespace

// One streaming session: its waiting frames and its two threads; the pipeline is its map's.
struct Server::Session {
  std::string name;
  std::shared_ptr<MapEntry> map;
  bool live = true;  // frame policy: live (newest frame only) or queue
  std::mutex mutex;
  std::condition_variable wake;
  std::deque<QueuedFrame> queue;  // accepted, waiting to be prepared; live: at most one
  std::deque<PreparedFrame> prepared;  // waiting to be registered; live: at most one
  bool closing = false;
  bool preparing_done = false;    // the preparing thread drained `queue` after closing
  bool started = false;           // the first frame was registered (tracking thread only)
  std::thread preparing, tracking;
  std::unique_ptr<MappingThread> mapping;
  // Status counters (guarded by `mutex`).
  std::uint64_t received = 0, processed = 0, dropped = 0, skipped = 0;
  std::string last_drop_reason, last_skip_reason;
  // The latest stage times, for p50 / p99 (each bounded to kTimingWindow entries).
  std::deque<double> decode_ms, queue_ms, track_ms, map_ms;
};

// An owned copy of a fslam/requests sample.
struct Server::Query {
  std::string client, map_name, path;
  std::uint64_t request_id = 0;
  fslam_proto_RequestKind kind = fslam_proto_REQUEST_RENDER;
  fslam_proto_RenderRequest render{};
  // REQUEST_SEGMENT
  fslam_proto_SegmentMode segment_mode = fslam_proto_SEGMENT_PROMPTLESS;
  std::vector<float> points, boxes;
  std::string text;
  bool has_output_view = false;
  fslam_proto_RenderRequest output_view{};
  ExportRequest export_request;  // REQUEST_MAP_GAUSSIANS
};

namespace {

constexpr std::size_t kTimingWindow = 1000;

void record(std::deque<double>* window, double ms) {
  window->push_back(ms);
  if (window->size() > kTimingWindow) window->pop_front();
}

std::uint64_t resident_bytes() {
  long pages = 0, resident = 0;
  if (FILE* f = std::fopen("/proc/self/statm", "r")) {
    if (std::fscanf(f, "%ld %ld", &pages, &resident) != 2) resident = 0;
    std::fclose(f);
  }
  return static_cast<std::uint64_t>(resident) * static_cast<std::uint64_t>(sysconf(_SC_PAGESIZE));
}

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

void to_wire(const Eigen::Isometry3d& T, fslam_proto_Pose* pose) {
  const Eigen::Quaterniond q(T.rotation());
  for (int k = 0; k < 3; ++k) pose->translation[k] = T.translation()[k];
  pose->rotation[0] = q.x();
  pose->rotation[1] = q.y();
  pose->rotation[2] = q.z();
  pose->rotation[3] = q.w();
}

bool from_wire(const fslam_proto_Pose& pose, Eigen::Isometry3d* T, std::string* why) {
  const Eigen::Quaterniond q(pose.rotation[3], pose.rotation[0], pose.rotation[1], pose.rotation[2]);
  const Eigen::Vector3d t(pose.translation[0], pose.translation[1], pose.translation[2]);
  if (!t.allFinite() || !std::isfinite(q.norm()) || std::abs(q.norm() - 1.0) > 1e-3) {
    return core::fail(why, "pose: translation must be finite and the quaternion unit length");
  }
  T->setIdentity();
  T->linear() = q.normalized().toRotationMatrix();
  T->translation() = t;
  return true;
}

const char* text(const char* s) { return s != nullptr ? s : ""; }

template <class Sequence>
std::vector<float> floats(const Sequence& seq) {
  return seq._buffer == nullptr ? std::vector<float>{}
                                : std::vector<float>(seq._buffer, seq._buffer + seq._length);
}

// Result images as PNG on the wire; `images` point into `buffers`.
bool attach_images(const std::vector<cv::Mat>& mats, fslam_proto_Result* result,
                   std::vector<std::vector<std::uint8_t>>* buffers,
                   std::vector<fslam_proto_Image>* images) {
  buffers->resize(mats.size());
  images->resize(mats.size());
  for (std::size_t i = 0; i < mats.size(); ++i) {
    const cv::Mat& image = mats[i];
    if (!encode_png(image, &(*buffers)[i])) return false;
    (*images)[i] = {fslam_proto_ENCODING_PNG,
                    static_cast<std::uint32_t>(image.cols),
                    static_cast<std::uint32_t>(image.rows),
                    static_cast<std::uint8_t>(image.channels()),
                    static_cast<std::uint8_t>(image.elemSize1()),
                    {static_cast<std::uint32_t>((*buffers)[i].size()),
                     static_cast<std::uint32_t>((*buffers)[i].size()), (*buffers)[i].data(), false}};
  }
  result->images = {static_cast<std::uint32_t>(images->size()),
                    static_cast<std::uint32_t>(images->size()), images->data(), false};
  return true;
}

void describe_view(const core::RenderView& view, const Eigen::Isometry3d& T_world_camera,
                   fslam_proto_Result* result) {
  to_wire(T_world_camera, &result->T_world_camera);
  result->intrinsics = {static_cast<float>(view.camera.fx), static_cast<float>(view.camera.fy),
                        static_cast<float>(view.camera.cx), static_cast<float>(view.camera.cy),
                        static_cast<std::uint32_t>(view.camera.width),
                        static_cast<std::uint32_t>(view.camera.height)};
}

}  // namespace

bool ServerConfig::is_valid(std::string* why) const {
  if (prefix.empty()) return core::fail(why, "server: empty topic prefix");
  if (frame_policy != "live" && frame_policy != "queue") {
    return core::fail(why, "server: frame_policy must be live or queue, not '" + frame_policy + "'");
  }
  if (queue_capacity == 0) return core::fail(why, "server: queue_capacity must be > 0");
  if (status_period_ms <= 0) return core::fail(why, "server: status_period_ms must be > 0");
  if (query_threads < 1) return core::fail(why, "server: query_threads must be >= 1");
  if (query_queue_capacity == 0) return core::fail(why, "server: query_queue_capacity must be > 0");
  if (mapping_threads < 0) return core::fail(why, "server: mapping_threads must be >= 0");
  if (max_render_pixels == 0) return core::fail(why, "server: max_render_pixels must be > 0");
  if (max_sessions == 0 || max_maps == 0 || max_prompts == 0) {
    return core::fail(why, "server: max_sessions, max_maps and max_prompts must be > 0");
  }
  if (instance.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-") !=
      std::string::npos) {
    return core::fail(why, "server: instance '" + instance + "' may hold only letters, digits, '-' and '_'");
  }
  if (!grounding().is_valid(why)) return false;
  if (!ros2.is_valid(why)) return false;
  return pipeline.is_valid(why);
}

Server::Server() = default;
Server::~Server() {
  deactivate();
  cleanup();
}

void Server::set_log(std::function<void(const std::string&)> log) { log_ = std::move(log); }

void Server::log(const std::string& message) const {
  if (log_) log_(message);
}

bool Server::configure(const ServerConfig& config, std::string* why) {
  if (!config.is_valid(why)) return false;
  config_ = config;
  configured_ = true;
  return true;
}

bool Server::activate(std::string* why) {
  if (!configured_) return core::fail(why, "server: activate before configure");
  std::string notice;
  query_rasterizer_ = make_rasterizer("auto", RasterUse::kRender, &notice, why);
  if (!query_rasterizer_) return false;
  grounding_.reset();
  if (!config_.grounding_model.empty()) {
    // A configured model that does not load is a start-up error, not a surprise at the first query.
    auto detector = std::make_unique<GroundingDetector>();
    if (!detector->load(config_.grounding(), why)) return false;
    grounding_ = std::move(detector);
    log("grounding model " + config_.grounding_model + " loaded for text queries");
  }
  if (!config_.map_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(config_.map_dir, ec);
    if (ec) return core::fail(why, "map_dir " + config_.map_dir + ": " + ec.message());
    if (config_.load_maps_at_start) {
      // A save killed half-way left `.NAME.saving` / `.NAME.old` beside NAME: whole versions
      // first (map_files.hpp), then every map folder. One bad folder is reported and skipped:
      // the other maps are still served.
      std::set<std::string> interrupted;
      for (const auto& entry : std::filesystem::directory_iterator(config_.map_dir, ec)) {
        const std::string hidden = entry.path().filename().string();
        for (const std::string suffix : {".saving", ".old"}) {
          if (hidden.size() > suffix.size() + 1 && hidden[0] == '.' &&
              hidden.compare(hidden.size() - suffix.size(), suffix.size(), suffix) == 0) {
            interrupted.insert(hidden.substr(1, hidden.size() - suffix.size() - 1));
          }
        }
      }
      for (const std::string& name : interrupted) {
        std::string note;
        recover_map_folder((std::filesystem::path(config_.map_dir) / name).string(), &note);
        if (!note.empty()) log(note);
      }
      for (const auto& entry : std::filesystem::directory_iterator(config_.map_dir, ec)) {
        const std::string name = entry.path().filename().string();
        if (name.empty() || name[0] == '.') continue;  // a save's staging, or not ours
        if (!entry.is_directory() || !is_map_folder(entry.path().string())) continue;
        std::string invalid;
        if (!valid_map_name(name, &invalid)) {
          log("skipped map folder " + entry.path().string() + ": " + invalid);
          continue;
        }
        std::string load_why;
        if (load(name, entry.path().string(), &load_why)) {
          log("loaded map '" + name + "' from " + entry.path().string() + " (" +
              std::to_string(find_map(name)->loaded.latest()->size()) + " Gaussians)");
        } else {
          log("skipped map folder " + entry.path().string() + ": " + load_why);
        }
      }
    }
  }
  try {
    using client::Delivery;
    participant_ = client::make_participant(config_.domain);
    const std::string prefix = config_.service_prefix();
    frames_topic_ = client::make_topic(participant_, &fslam_proto_Frame_desc, prefix, "frames");
    poses_topic_ = client::make_topic(participant_, &fslam_proto_PoseStamped_desc, prefix, "poses");
    control_topic_ = client::make_topic(participant_, &fslam_proto_SessionControl_desc, prefix, "session");
    requests_topic_ = client::make_topic(participant_, &fslam_proto_Request_desc, prefix, "requests");
    results_topic_ = client::make_topic(participant_, &fslam_proto_Result_desc, prefix, "results");
    status_topic_ = client::make_topic(participant_, &fslam_proto_SessionStatus_desc, prefix, "status");
    frame_reader_ = client::make_reader(participant_, frames_topic_, Delivery::reliable);
    control_reader_ = client::make_reader(participant_, control_topic_, Delivery::reliable);
    request_reader_ = client::make_reader(participant_, requests_topic_, Delivery::reliable);
    pose_writer_ = client::make_writer(participant_, poses_topic_, Delivery::reliable);
    result_writer_ = client::make_writer(participant_, results_topic_, Delivery::reliable);
    status_writer_ = client::make_writer(participant_, status_topic_, Delivery::best_effort);
    waitset_ = client::make_waitset(participant_, {&frame_reader_, &control_reader_, &request_reader_});
    // Scale-out: the instance's record and a claim per map it serves (map_directory.hpp).
    directory_ = std::make_unique<MapDirectoryMember>(
        participant_, config_.prefix,
        InstanceRecord{config_.instance.empty() ? default_instance_name() : config_.instance, prefix,
                       config_.map_group});
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& [name, map] : maps_) directory_->claim(name);
  } catch (const client::DdsError& e) {
    return core::fail(why, e.what());
  }
  stop_ = false;
  queries_stopping_ = false;
  ingest_thread_ = std::thread([this] { ingest(); });
  for (int i = 0; i < config_.query_threads; ++i) query_threads_.emplace_back([this] { serve_queries(); });
  if (!config_.health_file.empty()) health_ = std::make_unique<HealthFile>(config_.health_file);
  return true;
}

void Server::deactivate() {
  if (ingest_thread_.joinable()) {
    stop_ = true;
    dds_waitset_set_trigger(waitset_.get(), true);
    ingest_thread_.join();
  }
  health_.reset();     // not ready while draining
  directory_.reset();  // claims withdrawn: this instance stops serving
  {
    std::lock_guard<std::mutex> lock(mutex_);
    queries_stopping_ = true;  // the queued requests are still answered
  }
  query_wake_.notify_all();
  for (std::thread& t : query_threads_) t.join();
  query_threads_.clear();
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
  if (!configured_ || config_.map_dir.empty() || !config_.save_maps_at_shutdown) return;
  std::map<std::string, std::shared_ptr<MapEntry>> maps;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    maps = maps_;
  }
  for (auto& [name, map] : maps) {
    std::string folder, why;
    {
      std::lock_guard<std::mutex> lock(map->mutex);
      if (map->saved == std::make_pair(map->versions().version_number(), map->poses.size())) continue;
    }
    if (resolve_map_folder(config_.map_dir, "", name, &folder, &why) && save(*map, folder, &why)) {
      log("saved map '" + name + "' to " + folder);
    } else {
      log("could not save map '" + name + "': " + why);
    }
  }
}

void Server::cleanup() {
  directory_.reset();
  waitset_.reset();
  frame_reader_.reset();
  control_reader_.reset();
  request_reader_.reset();
  pose_writer_.reset();
  result_writer_.reset();
  status_writer_.reset();
  participant_.reset();
}

ServerStats Server::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  ServerStats s = stats_;
  s.sessions = sessions_.size();
  s.maps = maps_.size();
  return s;
}

std::shared_ptr<Server::MapEntry> Server::find_map(const std::string& name) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = maps_.find(name);
  return it == maps_.end() ? nullptr : it->second;
}

void Server::ingest() {
  auto next_status = Clock::now();
  while (!stop_) {
    if (Clock::now() >= next_status) {
      publish_status();
      next_status += std::chrono::milliseconds(config_.status_period_ms);
      for (const auto& [map, holder] : directory_->take_lost()) {
        withdraw_map(map, "is held by instance '" + holder.instance + "' (claimed first)");
      }
      if (health_) {
        const ServerStats s = stats();
        health_->beat(config_.service_prefix(), s.maps, s.sessions);
      }
    }
    dds_attach_t triggered[3];
    dds_waitset_wait(waitset_.get(), triggered, 3, DDS_MSECS(200));
    // Session control first, so that a session opened just before its first frame exists.
    client::take_each<fslam_proto_SessionControl>(
        control_reader_.get(), [&](const fslam_proto_SessionControl& m) { handle_control(m); });
    client::take_each<fslam_proto_Frame>(frame_reader_.get(),
                                         [&](const fslam_proto_Frame& m) { handle_frame(m); });
    client::take_each<fslam_proto_Request>(request_reader_.get(),
                                           [&](const fslam_proto_Request& m) { accept_request(m); });
  }
}

void Server::publish_status() {
  const std::uint64_t rss = resident_bytes();
  std::vector<std::shared_ptr<MapEntry>> idle;
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [name, map] : maps_) {
    std::lock_guard<std::mutex> mlock(map->mutex);
    if (!map->streaming) idle.push_back(map);
  }
  auto describe_map = [&](MapEntry& map, fslam_proto_SessionStatus* st) {
    std::lock_guard<std::mutex> mlock(map.mutex);
    st->streaming = map.streaming;
    st->frames_tracked = map.poses.size();
    st->map_version = map.versions().version_number();
    st->map_gaussians = map.versions().latest()->size();
    st->resident_bytes = rss;
    st->text_queries = grounding_ != nullptr;
  };
  for (const auto& [name, s] : sessions_) {
    fslam_proto_SessionStatus st{};
    std::string session = s->name, map = s->map->name, reason, skip_reason;
    std::string policy = s->live ? "live" : "queue";
    {
      std::lock_guard<std::mutex> qlock(s->mutex);
      st.queue_depth = static_cast<std::uint32_t>(s->queue.size());
      st.frames_received = s->received;
      st.frames_processed = s->processed;
      st.frames_dropped = s->dropped;
      st.frames_skipped = s->skipped;
      reason = s->last_drop_reason;
      skip_reason = s->last_skip_reason;
      auto p = [](const std::deque<double>& w, double q) {
        return static_cast<float>(core::percentile(std::vector<double>(w.begin(), w.end()), q));
      };
      st.decode_ms_p50 = p(s->decode_ms, 0.5);
      st.decode_ms_p99 = p(s->decode_ms, 0.99);
      st.queue_ms_p50 = p(s->queue_ms, 0.5);
      st.queue_ms_p99 = p(s->queue_ms, 0.99);
      st.track_ms_p50 = p(s->track_ms, 0.5);
      st.track_ms_p99 = p(s->track_ms, 0.99);
      st.map_ms_p50 = p(s->map_ms, 0.5);
      st.map_ms_p99 = p(s->map_ms, 0.99);
    }
    st.session = session.data();
    st.map_name = map.data();
    st.last_drop_reason = reason.data();
    st.last_skip_reason = skip_reason.data();
    st.frame_policy = policy.data();
    describe_map(*s->map, &st);
    dds_write(status_writer_.get(), &st);
  }
  for (const auto& map : idle) {
    fslam_proto_SessionStatus st{};
    std::string empty, name = map->name;
    st.session = empty.data();
    st.map_name = name.data();
    st.last_drop_reason = empty.data();
    st.last_skip_reason = empty.data();
    st.frame_policy = empty.data();
    describe_map(*map, &st);
    dds_write(status_writer_.get(), &st);
  }
}

void Server::publish_result(const char* client, std::uint64_t request_id, const std::string& map_name,
                            const std::string& error) {
  fslam_proto_Result r{};
  std::string c = text(client), m = map_name, e = error, empty;
  r.client = c.data();
  r.request_id = request_id;
  r.map_name = m.data();
  r.status = error.empty() ? fslam_proto_RESULT_OK : fslam_proto_RESULT_ERROR;
  r.error = e.data();
  r.path = empty.data();
  dds_write(result_writer_.get(), &r);
}

void Server::publish_skip(const std::string& session, std::uint64_t frame_id, double timestamp,
                          const std::string& reason) {
  fslam_proto_PoseStamped pose{};
  std::string name = session, note = reason;
  pose.session = name.data();
  pose.frame_id = frame_id;
  pose.timestamp = timestamp;
  pose.T_world_camera.rotation[3] = 1.0;
  pose.state = fslam_proto_TRACKING_SKIPPED;
  pose.note = note.data();
  dds_write(pose_writer_.get(), &pose);
}

void Server::handle_control(const fslam_proto_SessionControl& msg) {
  const std::string name = text(msg.session);
  const std::string map_name = msg.map_name != nullptr && msg.map_name[0] ? msg.map_name : name;
  if (name.empty()) return publish_result(msg.session, msg.request_id, map_name, "session name is empty");
  if (msg.attach_only) {
    // A query-only client: nothing to create, the answer says whether the map is there.
    const bool exists = find_map(map_name) != nullptr;
    return publish_result(msg.session, msg.request_id, map_name,
                          exists ? "" : "no map named '" + map_name + "'");
  }
  std::unique_ptr<Session> closing;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = sessions_.find(name);
    if (msg.command == fslam_proto_SESSION_OPEN) {
      if (it != sessions_.end()) {
        if (it->second->map->name == map_name) return publish_result(msg.session, msg.request_id, map_name, "");
        return publish_result(msg.session, msg.request_id, map_name,
                              "session '" + name + "' already streams into map '" +
                                  it->second->map->name + "'");
      }
      std::string invalid;
      if (!valid_map_name(map_name, &invalid)) return publish_result(msg.session, msg.request_id, map_name, invalid);
      if (sessions_.size() >= config_.max_sessions) {
        return publish_result(msg.session, msg.request_id, map_name,
                              "the server streams its limit of " + std::to_string(config_.max_sessions) +
                                  " sessions (server.max_sessions); close one first");
      }
      if (maps_.size() >= config_.max_maps) {
        return publish_result(msg.session, msg.request_id, map_name,
                              "the server holds its limit of " + std::to_string(config_.max_maps) +
                                  " maps (server.max_maps)");
      }
      if (maps_.count(map_name) != 0) {
        // Growing a finished or loaded map would need relocalising in it first: not supported.
        return publish_result(msg.session, msg.request_id, map_name,
                              "map '" + map_name + "' exists; stream into a new map name (query "
                              "this one with render requests)");
      }
      std::string claim_why;
      if (!directory_->may_claim(map_name, true, &claim_why)) {
        return publish_result(msg.session, msg.request_id, map_name, claim_why);
      }
      std::string why, notice;
      std::shared_ptr<const core::Rasterizer> rasterizer =
          make_rasterizer("auto", RasterUse::kMapping, &notice, &why);
      if (!rasterizer) return publish_result(msg.session, msg.request_id, map_name, why);
      std::unique_ptr<core::LatentFeatures> features;
      if (config_.pipeline.features.enabled()) {
        features = core::LatentFeatures::create(config_.pipeline.features, &why);
        if (!features) return publish_result(msg.session, msg.request_id, map_name, why);
      }
      auto map = std::make_shared<MapEntry>();
      map->name = map_name;
      map->pipeline = std::make_shared<core::SlamPipeline>(config_.pipeline, rasterizer, std::move(features));
      map->streaming = true;
      auto s = std::make_unique<Session>();
      s->name = name;
      s->map = map;
      s->live = msg.policy == fslam_proto_POLICY_LIVE ||
                (msg.policy != fslam_proto_POLICY_QUEUE && config_.frame_policy == "live");
      Session* raw = s.get();
      if (config_.pipelined_tracking) {
        s->preparing = std::thread([this, raw] { run_on_one_thread([&] { prepare_frames(raw); }); });
        s->tracking = std::thread([this, raw] { run_on_one_thread([&] { track_frames(raw); }); });
      } else {
        s->tracking = std::thread([this, raw] { run_on_one_thread([&] { prepare_and_track_frames(raw); }); });
      }
      s->mapping = std::make_unique<MappingThread>(
          raw->map->pipeline.get(), config_.mapping_threads, config_.pipeline.realtime,
          [raw](const core::KeyframeReport& report) {
            const core::RefinementStats& r = report.refinement;
            std::lock_guard<std::mutex> lock(raw->mutex);
            record(&raw->map_ms, r.insert_ms + r.optimise_ms + r.prune_ms);
          },
          [this, raw](const std::string& mwhy) {
            // Tracking goes on; clients learn that the map stopped growing, and why.
            publish_result(raw->name.c_str(), 0, raw->map->name, "mapping failed: " + mwhy);
          });
      maps_[map_name] = map;
      directory_->claim(map_name);
      sessions_[name] = std::move(s);
    } else {
      if (it == sessions_.end()) {
        return publish_result(msg.session, msg.request_id, map_name, "unknown session '" + name + "'");
      }
      closing = std::move(it->second);
      sessions_.erase(it);
    }
  }
  if (closing) {
    // Draining a session (its queued frames, then mapping) can take a while: do it off the
    // ingest thread so that other sessions keep flowing, and answer when it is done.
    std::string client = text(msg.session), map = closing->map->name;
    const std::uint64_t request_id = msg.request_id;
    std::lock_guard<std::mutex> lock(mutex_);
    closers_.push_back(std::thread([this, owned = std::move(closing), client, map, request_id] {
      finish_session(owned.get());
      publish_result(client.c_str(), request_id, map, "");
    }));
    return;
  }
  publish_result(msg.session, msg.request_id, map_name, "");
}

void Server::finish_session(Session* s) {
  {
    std::lock_guard<std::mutex> lock(s->mutex);
    s->closing = true;
  }
  s->wake.notify_all();
  if (s->preparing.joinable()) s->preparing.join();
  if (s->tracking.joinable()) s->tracking.join();  // every accepted frame is tracked
  s->map->pipeline->finish();
  if (s->mapping) s->mapping->join();
  std::lock_guard<std::mutex> lock(s->map->mutex);
  s->map->streaming = false;
}

void Server::handle_frame(const fslam_proto_Frame& msg) {
  const std::string name = text(msg.session);
  // Cheap checks and a copy of the payloads; decoding waits for the tracking thread, so that a
  // frame the live policy skips costs nothing more.
  QueuedFrame queued;
  std::string accept_why, why;
  const bool accepted = accept_frame(msg, &queued.frame, &accept_why);
  std::lock_guard<std::mutex> lock(mutex_);
  ++stats_.frames_received;
  const auto it = sessions_.find(name);
  if (it == sessions_.end()) why = "unknown session '" + name + "' (open it first)";
  else if (!accepted) why = accept_why;
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
    if (s.live) {
      // Live: the tracker takes the newest frame; one still waiting is skipped, and said so.
      while (!s.queue.empty()) {
        const EncodedFrame& old = s.queue.front().frame;
        ++stats_.frames_skipped;
        ++s.skipped;
        s.last_skip_reason = "frame " + std::to_string(old.frame_id) + " skipped: frame " +
                             std::to_string(msg.frame_id) + " arrived while tracking was busy (live policy)";
        publish_skip(s.name, old.frame_id, old.timestamp, s.last_skip_reason);
        s.queue.pop_front();
      }
    } else if (s.queue.size() >= config_.queue_capacity) {
      ++stats_.frames_dropped;
      ++s.dropped;
      s.last_drop_reason = "frame " + std::to_string(msg.frame_id) + " dropped: queue full (" +
                           std::to_string(config_.queue_capacity) + " frames)";
      publish_result(msg.session, msg.frame_id, name, s.last_drop_reason);
      return;
    }
    queued.queued = Clock::now();
    s.queue.push_back(std::move(queued));
  }
  s.wake.notify_all();
}

void Server::run_on_one_thread(const std::function<void()>& work) {
  // A session's frame threads (prepare, register; or both in one) each run in an arena of their
  // own with no workers: the parallel loops inside decoding and the feature encoder
  // (OpenCV runs on TBB) never wait for a TBB worker busy with, or niced by, mapping.
  tbb::task_arena one_thread(1);
  one_thread.execute(work);
}

bool Server::prepare_one(Session* s, QueuedFrame&& queued, PreparedFrame* prepared) {
  prepared->queue_ms = ms_since(queued.queued);
  std::string why;
  core::RgbdFrame frame;
  const Clock::time_point t_decode = Clock::now();
  const bool decoded = decode_frame(queued.frame, &frame, &why);
  prepared->decode_ms = ms_since(t_decode);
  const Clock::time_point t_prepare = Clock::now();
  const bool ready = decoded && s->map->pipeline->prepare_frame(std::move(frame), &prepared->frame, &why);
  prepared->prepare_ms = ms_since(t_prepare);
  prepared->ready = Clock::now();
  if (ready) return true;
  const std::string message = "frame " + std::to_string(queued.frame.frame_id) + ": " + why;
  {
    std::lock_guard<std::mutex> lock(s->mutex);
    ++s->dropped;
    s->last_drop_reason = message;
  }
  publish_result(s->name.c_str(), queued.frame.frame_id, s->map->name, message);
  return false;
}

// Waits for the next accepted frame; false when the session closes with nothing left.
// `room`: in a queue-policy session, wait until registration has room for one more.
bool Server::next_queued(Session* s, bool room, QueuedFrame* queued) {
  std::unique_lock<std::mutex> lock(s->mutex);
  s->wake.wait(lock, [&] {
    return (!s->queue.empty() && (!room || s->live || s->prepared.size() < kPreparedAhead)) ||
           (s->closing && s->queue.empty());
  });
  if (s->queue.empty()) return false;
  *queued = std::move(s->queue.front());
  s->queue.pop_front();
  return true;
}

void Server::prepare_and_track_frames(Session* s) {
  QueuedFrame queued;
  while (next_queued(s, false, &queued)) {
    PreparedFrame prepared;
    if (prepare_one(s, std::move(queued), &prepared)) track_one(s, std::move(prepared));
  }
}

void Server::prepare_frames(Session* s) {
  QueuedFrame queued;
  while (next_queued(s, true, &queued)) {
    PreparedFrame prepared;
    if (!prepare_one(s, std::move(queued), &prepared)) continue;
    {
      std::lock_guard<std::mutex> lock(s->mutex);
      if (s->live) {
        // Live: registration takes the newest prepared frame; one still waiting is skipped.
        while (!s->prepared.empty()) {
          const core::RgbdFrame& old = s->prepared.front().frame.frame;
          ++s->skipped;
          s->last_skip_reason = "frame " + std::to_string(old.id) + " skipped: frame " +
                                std::to_string(prepared.frame.frame.id) +
                                " was ready while registration was busy (live policy)";
          publish_skip(s->name, static_cast<std::uint64_t>(old.id), old.timestamp, s->last_skip_reason);
          s->prepared.pop_front();
        }
      }
      s->prepared.push_back(std::move(prepared));
    }
    s->wake.notify_all();
  }
  std::lock_guard<std::mutex> lock(s->mutex);
  s->preparing_done = true;
  s->wake.notify_all();
}

void Server::track_frames(Session* s) {
  for (;;) {
    PreparedFrame prepared;
    {
      std::unique_lock<std::mutex> lock(s->mutex);
      s->wake.wait(lock, [&] { return !s->prepared.empty() || s->preparing_done; });
      if (s->prepared.empty()) return;  // closing, and everything prepared was registered
      prepared = std::move(s->prepared.front());
      s->prepared.pop_front();
    }
    s->wake.notify_all();  // a queue-policy preparer may be waiting for room
    track_one(s, std::move(prepared));
  }
}

void Server::track_one(Session* s, PreparedFrame&& prepared) {
  core::SlamPipeline& pipeline = *s->map->pipeline;
  const double queue_ms = prepared.queue_ms + ms_since(prepared.ready);
  const core::RgbdFrame& frame = prepared.frame.frame;
  const std::uint64_t frame_id = static_cast<std::uint64_t>(frame.id);
  const double timestamp = frame.timestamp;
  const core::PinholeCamera camera = frame.camera;
  if (!s->started) {
    if (frame.T_world_camera_gt) pipeline.set_initial_pose(*frame.T_world_camera_gt);
    s->started = true;
  }
  core::TrackingResult result;
  std::string why;
  const Clock::time_point t0 = Clock::now();
  const bool tracked = pipeline.track_prepared(std::move(prepared.frame), &result, &why);
  const double track_ms = prepared.prepare_ms + ms_since(t0);
  {
    std::lock_guard<std::mutex> lock(s->mutex);
    ++s->processed;
    record(&s->decode_ms, prepared.decode_ms);
    record(&s->queue_ms, queue_ms);
    record(&s->track_ms, track_ms);
  }
  if (!tracked) {
    publish_result(s->name.c_str(), frame_id, s->map->name, why);
    return;
  }
  {
    std::lock_guard<std::mutex> lock(s->map->mutex);
    MapEntry& map = *s->map;
    map.camera = camera;
    map.pose_index[frame_id] = map.poses.size();
    map.poses.push_back({frame_id, timestamp, result.T_world_camera});
  }
  fslam_proto_PoseStamped pose{};
  std::string session = s->name;
  pose.session = session.data();
  pose.frame_id = frame_id;
  pose.timestamp = timestamp;
  to_wire(result.T_world_camera, &pose.T_world_camera);
  pose.state = static_cast<fslam_proto_TrackingState>(static_cast<int>(result.state));
  pose.keyframe = result.keyframe;
  pose.decode_ms = static_cast<float>(prepared.decode_ms);
  pose.queue_ms = static_cast<float>(queue_ms);
  pose.track_ms = static_cast<float>(track_ms);
  std::string note = result.message;
  pose.note = note.data();
  dds_write(pose_writer_.get(), &pose);
  {
    std::lock_guard<std::mutex> lock(pose_listener_mutex_);  // ROS 2 bridge hook
    if (pose_listener_) pose_listener_({s->name, frame_id, result.T_world_camera, result.keyframe});
  }
  std::lock_guard<std::mutex> lock(mutex_);
  ++stats_.poses_published;
}

void Server::accept_request(const fslam_proto_Request& msg) {
  auto query = std::make_unique<Query>();
  query->client = text(msg.client);
  query->request_id = msg.request_id;
  query->map_name = text(msg.map_name);
  query->path = text(msg.path);
  query->kind = msg.kind;
  query->render = msg.render;
  if (msg.kind == fslam_proto_REQUEST_SEGMENT) {
    const fslam_proto_SegmentRequest& seg = msg.segment;
    query->segment_mode = seg.mode;
    query->points = floats(seg.points);
    query->boxes = floats(seg.boxes);
    query->text = text(seg.text);
    query->has_output_view = seg.has_output_view;
    query->output_view = seg.output_view;
  }
  if (msg.kind == fslam_proto_REQUEST_MAP_GAUSSIANS) query->export_request = export_request_of(msg);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (queries_.size() < config_.query_queue_capacity) {
      queries_.push_back(std::move(query));
      query_wake_.notify_one();
      return;
    }
    ++stats_.requests_failed;
  }
  publish_result(msg.client, msg.request_id, query->map_name,
                 "server busy: " + std::to_string(config_.query_queue_capacity) +
                     " requests already waiting; try again");
}

void Server::serve_queries() {
  for (;;) {
    std::unique_ptr<Query> query;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      query_wake_.wait(lock, [&] { return !queries_.empty() || queries_stopping_; });
      if (queries_.empty()) return;
      query = std::move(queries_.front());
      queries_.pop_front();
    }
    answer(*query);
  }
}

void Server::answer(const Query& query) {
  fslam_proto_Result r{};
  std::vector<std::vector<std::uint8_t>> buffers;  // image bytes the result points into
  std::vector<fslam_proto_Image> images;
  std::vector<std::uint8_t> records;  // exported Gaussians the result points into
  std::string folder, why;
  bool ok = false;
  const std::shared_ptr<MapEntry> map = find_map(query.map_name);
  switch (query.kind) {
    case fslam_proto_REQUEST_RENDER:
      if (!map) why = "no map named '" + query.map_name + "'";
      else ok = render(query, *map, &r, &buffers, &images, &why);
      break;
    case fslam_proto_REQUEST_SEGMENT:
      if (!map) why = "no map named '" + query.map_name + "'";
      else ok = segment(query, *map, &r, &buffers, &images, &why);
      break;
    case fslam_proto_REQUEST_MAP_GAUSSIANS:
      if (!map) why = "no map named '" + query.map_name + "'";
      else ok = answer_map_gaussians(map->versions(), &map->exporter, query.export_request, &r, &records, &why);
      break;
    case fslam_proto_REQUEST_SAVE_MAP:
      if (!map) why = "no map named '" + query.map_name + "'";
      else ok = resolve_map_folder(config_.map_dir, query.path, query.map_name, &folder, &why) &&
                save(*map, folder, &why);
      break;
    case fslam_proto_REQUEST_LOAD_MAP:
      ok = resolve_map_folder(config_.map_dir, query.path, query.map_name, &folder, &why) &&
           load(query.map_name, folder, &why);
      if (ok) log("loaded map '" + query.map_name + "' from " + folder + " on request");
      break;
    default:
      why = "unknown request kind " + std::to_string(static_cast<int>(query.kind));
  }
  if (ok && (query.kind == fslam_proto_REQUEST_SAVE_MAP || query.kind == fslam_proto_REQUEST_LOAD_MAP)) {
    const std::shared_ptr<MapEntry> now = find_map(query.map_name);
    r.map_version = now->versions().version_number();
    r.map_gaussians = now->versions().latest()->size();
  }
  std::string client = query.client, map_name = query.map_name, error = ok ? "" : why;
  r.client = client.data();
  r.request_id = query.request_id;
  r.map_name = map_name.data();
  r.status = ok ? fslam_proto_RESULT_OK : fslam_proto_RESULT_ERROR;
  r.error = error.data();
  r.path = folder.data();
  dds_write(result_writer_.get(), &r);
  std::lock_guard<std::mutex> lock(mutex_);
  ++(ok ? stats_.requests_answered : stats_.requests_failed);
}

bool Server::resolve_view(const fslam_proto_RenderRequest& req, MapEntry& map, core::RenderView* view,
                          Eigen::Isometry3d* T_world_camera, std::string* why) const {
  {
    std::lock_guard<std::mutex> lock(map.mutex);
    if (req.from_frame) {
      const auto it = map.pose_index.find(req.frame_id);
      if (it == map.pose_index.end()) {
        return core::fail(why, "map '" + map.name + "' has no tracked pose for frame " +
                                   std::to_string(req.frame_id));
      }
      *T_world_camera = map.poses[it->second].T_world_camera;
    } else if (!from_wire(req.T_world_camera, T_world_camera, why)) {
      return false;
    }
    view->camera = map.camera;
  }
  const fslam_proto_Intrinsics& k = req.intrinsics;
  if (k.width != 0) {
    view->camera = {k.fx, k.fy, k.cx, k.cy, static_cast<int>(k.width), static_cast<int>(k.height)};
  } else if (view->camera.width == 0) {
    return core::fail(why, "map '" + map.name + "' has no camera of its own; give intrinsics");
  }
  std::string reason;
  if (!view->camera.is_valid(&reason)) return core::fail(why, "intrinsics: " + reason);
  if (static_cast<std::uint64_t>(view->camera.width) * static_cast<std::uint64_t>(view->camera.height) >
      config_.max_render_pixels) {
    return core::fail(why, std::to_string(view->camera.width) + "x" +
                               std::to_string(view->camera.height) + " is over the server's limit of " +
                               std::to_string(config_.max_render_pixels) + " pixels");
  }
  view->T_camera_world = T_world_camera->inverse();
  return true;
}

bool Server::render(const Query& query, MapEntry& map, fslam_proto_Result* result,
                    std::vector<std::vector<std::uint8_t>>* buffers,
                    std::vector<fslam_proto_Image>* images, std::string* why) {
  const fslam_proto_RenderRequest& req = query.render;
  constexpr std::uint32_t kKnown = fslam_proto_CHANNEL_COLOUR | fslam_proto_CHANNEL_DEPTH |
                                   fslam_proto_CHANNEL_NORMALS | fslam_proto_CHANNEL_OPACITY;
  if (req.channels == 0 || (req.channels & ~kKnown) != 0) {
    return core::fail(why, "render: channels must be a non-empty set of CHANNEL_* bits");
  }
  const float depth_scale = req.depth_scale == 0.0f ? 1000.0f : req.depth_scale;
  if (!(depth_scale > 0) || !std::isfinite(depth_scale)) return core::fail(why, "render: depth_scale must be positive");
  core::RenderView view;
  Eigen::Isometry3d T_world_camera;
  std::string reason;
  if (!resolve_view(req, map, &view, &T_world_camera, &reason)) return core::fail(why, "render: " + reason);
  const std::uint64_t version_number = map.versions().version_number();
  const core::MapVersions::Version version = map.versions().latest();
  core::RenderSettings settings;
  settings.features = false;
  core::RenderResult rendered;
  if (!query_rasterizer_->forward(*version, view, settings, &rendered, why)) return false;
  std::vector<cv::Mat> mats;
  for (ChannelImage& channel : render_channels(rendered, view.camera, req.channels, depth_scale)) {
    mats.push_back(channel.image);
  }
  if (!attach_images(mats, result, buffers, images)) return core::fail(why, "render: cannot encode a result image");
  describe_view(view, T_world_camera, result);
  result->map_version = version_number;
  result->map_gaussians = version->size();
  return true;
}

namespace {

std::string number(double x) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", x);
  return text;
}

// Checks the prompts of a segment request against their mode and the prompt view; `boxes` gets
// the box prompts. Cheap checks only: nothing is rendered.
bool check_prompts(const fslam_proto_SegmentMode mode, const std::vector<float>& points,
                   const std::vector<float>& box_values, const core::PinholeCamera& camera,
                   std::size_t max_prompts, std::vector<Eigen::Vector2d>* uv,
                   std::vector<core::BoxPrompt>* boxes, std::string* why) {
  const double w = camera.width, h = camera.height;
  if (points.size() / 2 > max_prompts || box_values.size() / 4 > max_prompts) {
    return core::fail(why, "segment: more than " + std::to_string(max_prompts) +
                               " points or boxes in one request (server.max_prompts)");
  }
  const std::string size = std::to_string(camera.width) + "x" + std::to_string(camera.height);
  if (mode == fslam_proto_SEGMENT_POINTS) {
    if (points.empty()) return core::fail(why, "segment: a point query needs at least one point (u, v)");
    if (points.size() % 2 != 0) {
      return core::fail(why, "segment: points are u, v pairs; got an odd number of coordinates (" +
                                 std::to_string(points.size()) + ")");
    }
    for (std::size_t i = 0; i < points.size(); i += 2) {
      const double u = points[i], v = points[i + 1];
      // Pixel centres at integers: a point belongs to the view when it rounds into its grid.
      if (!(u >= -0.5 && u < w - 0.5 && v >= -0.5 && v < h - 0.5)) {
        return core::fail(why, "segment: point (" + number(u) + ", " + number(v) +
                                   ") lies outside the " + size + " view");
      }
      uv->emplace_back(u, v);
    }
  } else if (mode == fslam_proto_SEGMENT_BOXES) {
    if (box_values.empty()) return core::fail(why, "segment: a box query needs at least one box (u0, v0, u1, v1)");
    if (box_values.size() % 4 != 0) {
      return core::fail(why, "segment: boxes are u0, v0, u1, v1 quadruples; got " +
                                 std::to_string(box_values.size()) + " numbers");
    }
    for (std::size_t i = 0; i < box_values.size(); i += 4) {
      const core::BoxPrompt b{box_values[i], box_values[i + 1], box_values[i + 2], box_values[i + 3]};
      const std::string name = "box (" + number(b.u0) + ", " + number(b.v0) + ", " + number(b.u1) +
                               ", " + number(b.v1) + ")";
      if (!(b.u1 > b.u0 && b.v1 > b.v0)) {
        return core::fail(why, "segment: " + name + " is empty: it needs u1 > u0 and v1 > v0");
      }
      if (!(b.u0 >= 0 && b.v0 >= 0 && b.u1 <= w && b.v1 <= h)) {
        return core::fail(why, "segment: " + name + " reaches outside the " + size + " view");
      }
      boxes->push_back(b);
    }
  }
  return true;
}

}  // namespace

bool Server::segment(const Query& query, MapEntry& map, fslam_proto_Result* result,
                     std::vector<std::vector<std::uint8_t>>* buffers,
                     std::vector<fslam_proto_Image>* images, std::string* why) {
  const fslam_proto_SegmentMode mode = query.segment_mode;
  if (mode != fslam_proto_SEGMENT_PROMPTLESS && mode != fslam_proto_SEGMENT_POINTS &&
      mode != fslam_proto_SEGMENT_BOXES && mode != fslam_proto_SEGMENT_TEXT) {
    return core::fail(why, "segment: unknown mode " + std::to_string(static_cast<int>(mode)));
  }
  if (mode == fslam_proto_SEGMENT_TEXT) {
    if (query.text.find_first_not_of(" \t\r\n") == std::string::npos) {
      return core::fail(why, "segment: a text query needs a text");
    }
    if (!grounding_) {
      return core::fail(why, "text queries need a grounding detector: set server.grounding_model to "
                             "an ONNX model (docs/segmentation.md)");
    }
  }
  core::RenderView view, out_view;
  Eigen::Isometry3d T_world_camera, T_world_out;
  std::string reason;
  if (!resolve_view(query.render, map, &view, &T_world_camera, &reason)) {
    return core::fail(why, "segment: " + reason);
  }
  if (query.has_output_view) {
    if (!resolve_view(query.output_view, map, &out_view, &T_world_out, &reason)) {
      return core::fail(why, "segment: output view: " + reason);
    }
  } else {
    out_view = view;
    T_world_out = T_world_camera;
  }
  std::vector<Eigen::Vector2d> points;
  std::vector<core::BoxPrompt> boxes;
  if (!check_prompts(mode, query.points, query.boxes, view.camera, config_.max_prompts, &points, &boxes, why)) return false;

  const core::Rasterizer& rasterizer = *query_rasterizer_;
  std::uint64_t version_number = map.versions().version_number();
  core::MapVersions::Version version = map.versions().latest();
  cv::Mat labels_image;  // CV_16UC1 ids + 1, or CV_8UC1 mask
  if (mode == fslam_proto_SEGMENT_PROMPTLESS) {
    std::shared_ptr<const core::GaussianLabels> labels;
    {
      // Labels are computed once per map version, always for the newest, and carried from the
      // clustering before so that an object keeps its id while the map grows.
      std::lock_guard<std::mutex> lock(map.instances_mutex);
      InstanceLabels& cache = map.instances;
      version_number = map.versions().version_number();
      version = map.versions().latest();
      if (cache.map != version) {
        if (!core::has_features(*version)) {
          return core::fail(why, "segment: the map carries no features; stream with features on");
        }
        const core::PromptlessConfig config;
        auto fresh = std::make_shared<core::GaussianLabels>();
        if (!core::cluster_instances(*version, config, fresh.get(), why)) return false;
        if (cache.map) {
          core::carry_instance_ids(*cache.map, *cache.labels, *version,
                                   config.graph.max_neighbour_distance, fresh.get());
        }
        cache = {version_number, version, std::move(fresh)};
      }
      version_number = cache.version_number;
      labels = cache.labels;
    }
    cv::Mat ids;  // CV_32SC1, -1 = none
    if (!core::render_labels(rasterizer, *version, *labels, out_view, core::kMinObjectAlpha, &ids, why)) return false;
    // On the wire: id + 1 in 16 bits, 0 = none; ids beyond 16 bits saturate (never seen in practice).
    ids.convertTo(labels_image, CV_16UC1, 1.0, 1.0);
  } else {
    if (!core::has_features(*version)) {
      return core::fail(why, "segment: the map carries no features; stream with features on");
    }
    const core::PromptSelector prompts(*version, core::PromptConfig{});  // one graph for all boxes
    std::vector<std::uint8_t> selected;
    if (mode == fslam_proto_SEGMENT_POINTS) {
      if (!prompts.select_by_points(rasterizer, view, points, &selected, why)) return false;
    } else {
      if (mode == fslam_proto_SEGMENT_TEXT) {
        // The detector looks at the prompt view as the map renders it; its boxes become prompts.
        core::RenderSettings settings;
        settings.features = false;
        core::RenderResult rendered;
        if (!rasterizer.forward(*version, view, settings, &rendered, why)) return false;
        std::vector<GroundedBox> found;
        if (!grounding_->detect(colour_to_rgb8(rendered.colour), query.text, &found, &reason)) {
          return core::fail(why, "segment: " + reason);
        }
        if (found.empty()) {
          return core::fail(why, "segment: the grounding detector found nothing for '" + query.text +
                                     "' (no box scored " + number(config_.grounding_box_threshold) +
                                     " or more)");
        }
        for (const GroundedBox& g : found) boxes.push_back({g.u0, g.v0, g.u1, g.v1});
      }
      // Several boxes: the union of their objects.
      selected.assign(version->size(), 0);
      for (const core::BoxPrompt& box : boxes) {
        std::vector<std::uint8_t> one;
        if (!prompts.select_by_box(rasterizer, view, box, &one, why)) return false;
        for (std::size_t i = 0; i < one.size(); ++i) selected[i] |= one[i];
      }
    }
    if (!core::render_selection(rasterizer, *version, selected, out_view, core::kMinObjectAlpha, &labels_image, why)) {
      return false;
    }
  }
  core::RenderSettings settings;
  settings.features = false;
  core::RenderResult rendered;
  if (!rasterizer.forward(*version, out_view, settings, &rendered, why)) return false;
  if (!attach_images({labels_image, colour_to_rgb8(rendered.colour)}, result, buffers, images)) {
    return core::fail(why, "segment: cannot encode a result image");
  }
  describe_view(out_view, T_world_out, result);
  result->map_version = version_number;
  result->map_gaussians = version->size();
  return true;
}

bool Server::save(MapEntry& map, const std::string& folder, std::string* why) {
  StoredMap stored;
  std::pair<std::uint64_t, std::size_t> state;
  {
    std::lock_guard<std::mutex> lock(map.mutex);
    state = {map.versions().version_number(), map.poses.size()};
    stored.gaussians = map.versions().latest();
    stored.camera = map.camera;
    stored.poses = map.poses;
  }
  if (!save_map_folder(folder, stored, why)) return false;
  // Only a save to the map's own folder (the one a restart loads it from) counts as saved.
  std::string home, ignored;
  if (resolve_map_folder(config_.map_dir, "", map.name, &home, &ignored) && home == folder) {
    std::lock_guard<std::mutex> lock(map.mutex);
    map.saved = state;
  }
  return true;
}

bool Server::load(const std::string& name, const std::string& folder, std::string* why) {
  if (!valid_map_name(name, why)) return false;
  StoredMap stored;
  if (!load_map_folder(folder, &stored, why)) return false;
  auto map = std::make_shared<MapEntry>();
  map->name = name;
  map->loaded.publish(stored.gaussians);
  map->camera = stored.camera;
  map->poses = std::move(stored.poses);
  for (std::size_t i = 0; i < map->poses.size(); ++i) map->pose_index[map->poses[i].frame_id] = i;
  map->saved = {map->loaded.version_number(), map->poses.size()};
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = maps_.find(name);
  if (it != maps_.end()) {
    std::lock_guard<std::mutex> mlock(it->second->mutex);
    if (it->second->streaming) {
      return core::fail(why, "load map: map '" + name + "' has a streaming session; close it first");
    }
  }
  if (it == maps_.end() && maps_.size() >= config_.max_maps) {
    return core::fail(why, "load map: the server holds its limit of " + std::to_string(config_.max_maps) +
                               " maps (server.max_maps)");
  }
  // At start the directory does not exist yet: activate() claims every loaded map.
  if (directory_ && !directory_->may_claim(name, false, why)) return false;
  maps_[name] = map;  // queries in flight keep the version they hold
  if (directory_) directory_->claim(name);
  return true;
}

void Server::withdraw_map(const std::string& name, const std::string& reason) {
  std::unique_ptr<Session> closing;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (auto it = sessions_.begin(); it != sessions_.end(); ++it) {
      if (it->second->map->name != name) continue;
      closing = std::move(it->second);
      sessions_.erase(it);
      break;
    }
    maps_.erase(name);  // queries in flight keep the version they hold; nothing is saved
  }
  log("gave up map '" + name + "': it " + reason);
  if (!closing) return;
  std::string session = closing->name;
  publish_result(session.c_str(), 0, name, "map '" + name + "' " + reason + "; session '" +
                                               session + "' is closed here");
  std::lock_guard<std::mutex> lock(mutex_);
  closers_.push_back(std::thread([this, owned = std::move(closing)] { finish_session(owned.get()); }));
}

// ---- ROS 2 bridge hook (ros2_bridge.hpp) ----------------------------------------------------

bool Server::open_session(const std::string& session, const std::string& map, bool live, std::string* why) {
  std::string name = session, map_name = map;
  fslam_proto_SessionControl msg{};
  msg.session = name.data();
  msg.command = fslam_proto_SESSION_OPEN;
  msg.map_name = map_name.data();
  msg.policy = live ? fslam_proto_POLICY_LIVE : fslam_proto_POLICY_QUEUE;
  handle_control(msg);
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = sessions_.find(session);
  if (it != sessions_.end() && it->second->map->name == map) return true;
  return core::fail(why, "the server refused session '" + session + "' on map '" + map +
                             "' (the reason is on " + config_.service_prefix() + "/results)");
}

void Server::report_rejected(const std::string& session, const std::string& message) {
  std::string map = session;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.frames_received;
    ++stats_.frames_rejected;
    const auto it = sessions_.find(session);
    if (it != sessions_.end()) {
      map = it->second->map->name;
      std::lock_guard<std::mutex> qlock(it->second->mutex);
      ++it->second->received;
      ++it->second->dropped;
      it->second->last_drop_reason = message;
    }
  }
  publish_result(session.c_str(), 0, map, message);
}

void Server::set_pose_listener(std::function<void(const TrackedPose&)> listener) {
  std::lock_guard<std::mutex> lock(pose_listener_mutex_);
  pose_listener_ = std::move(listener);
}

}  // namespace fslam::server

#include "fslam/server/server.hpp"

#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include "fslam/core/error.hpp"
#include "fslam/server/backend_factory.hpp"
#include "fslam/server/health_file.hpp"
#include "fslam/server/map_directory.hpp"
#include "fslam/server/mapping_thread.hpp"
#include "fslam/server/wire.hpp"
#include "counters.hpp"
#include "map_registry.hpp"
#include "queries.hpp"
#include "sessions.hpp"

namespace fslam::server {
namespace {

using Clock = std::chrono::steady_clock;

// Samples a bounded writer holds until every reader acknowledged them; a write past it waits up
// to 1 s, then fails. Poses: over 30 s of four 30-Hz sessions for a reader that stopped
// acknowledging while still matched (its DDS lease runs out first). Results answer requests,
// which a client sends at most 32 at a time (Client::kMaxCallsInFlight).
constexpr std::int32_t kPosesUnacknowledged = 4096, kResultsUnacknowledged = 1024;

// A status sample of (session, map_name) with every other string empty and every number zero;
// the strings must outlive it (the IDL's are char*).
fslam_proto_SessionStatus keyed_status(std::string& session, std::string& map_name, std::string& empty) {
  fslam_proto_SessionStatus st{};
  st.session = session.data();
  st.map_name = map_name.data();
  st.last_drop_reason = st.last_skip_reason = st.frame_policy = st.mode = empty.data();
  return st;
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
  if (frame_policy != "live" && frame_policy != "queue") {
    return core::fail(why, "server: frame_policy must be live or queue, not '" + frame_policy + "'");
  }
  if (queue_capacity == 0) return core::fail(why, "server: queue_capacity must be > 0");
  if (status_period_ms <= 0) return core::fail(why, "server: status_period_ms must be > 0");
  if (query_threads < 1) return core::fail(why, "server: query_threads must be >= 1");
  if (query_queue_capacity == 0) return core::fail(why, "server: query_queue_capacity must be > 0");
  if (mapping_threads < 0) return core::fail(why, "server: mapping_threads must be >= 0");
  if (max_render_pixels == 0) return core::fail(why, "server: max_render_pixels must be > 0");
  if (max_sessions == 0 || max_maps == 0 || max_prompts == 0 || max_refine_steps == 0) {
    return core::fail(why, "server: max_sessions, max_maps, max_prompts and max_refine_steps must be > 0");
  }
  if (instance.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-") !=
      std::string::npos) {
    return core::fail(why, "server: instance '" + instance + "' may hold only letters, digits, '-' and '_'");
  }
  if (compute.backend != "auto" && compute.backend != "cpu" && compute.backend != "cuda") {
    return core::fail(why, "compute.backend must be auto, cpu or cuda, not '" + compute.backend + "'");
  }
  if (!grounding().is_valid(why)) return false;
  if (!ros2.is_valid(why)) return false;
  return pipeline.is_valid(why);
}

Server::Server() : counters_(std::make_unique<Counters>()) {}

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
  if (!maps_) maps_ = std::make_unique<MapRegistry>(config_, [this](const std::string& m) { log(m); });
  configured_ = true;
  return true;
}

bool Server::activate(std::string* why) {
  if (!configured_) return core::fail(why, "server: activate before configure");
  std::string notice;
  query_rasterizer_ = make_rasterizer(config_.compute.backend, RasterUse::kRender, &notice, why);
  if (!query_rasterizer_) return false;
  grounding_.reset();
  if (!config_.grounding_model.empty()) {
    // A configured model that does not load is a start-up error, not a surprise at the first query.
    auto detector = std::make_unique<GroundingDetector>();
    if (!detector->load(config_.grounding(), why)) return false;
    grounding_ = std::move(detector);
    log("grounding model " + config_.grounding_model + " loaded for text queries");
  }
  if (!maps_->load_saved_maps(why)) return false;
  if (config_.pipeline.realtime && !MappingThread::can_leave_idle())
    log("mapping runs at nice " + std::to_string(kStarvedMappingNice) +
        " instead of SCHED_IDLE: this process may not take a thread out of SCHED_IDLE (no CAP_SYS_NICE, "
        "RLIMIT_NICE below 20), so starved mapping could not be lifted; tracking latency is higher under "
        "load (grant CAP_SYS_NICE: --cap-add SYS_NICE; docs/mapping.md)");
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
    frame_reader_ = client::make_bounded_reader(participant_, frames_topic_, 8);
    control_reader_ = client::make_reader(participant_, control_topic_, Delivery::reliable);
    request_reader_ = client::make_reader(participant_, requests_topic_, Delivery::reliable);
    // Poses and results: bounded writers (keep all, up to N unacknowledged), not keep-last
    // ones: a keep-last writer keeps its last samples of every instance after they are
    // acknowledged, for its life, and every session name is an instance (a result instance per
    // session opened grew the server ~10 KB per session; docs/reliability.md "Measured").
    pose_writer_ = client::make_bounded_writer(participant_, poses_topic_, kPosesUnacknowledged);
    result_writer_ = client::make_bounded_writer(participant_, results_topic_, kResultsUnacknowledged);
    status_writer_ = client::make_writer(participant_, status_topic_, Delivery::best_effort);
    views_topic_ = client::make_topic(participant_, &fslam_proto_View_desc, prefix, "views");
    waitset_ = client::make_waitset(participant_, {&frame_reader_, &control_reader_, &request_reader_});
    // Scale-out: the instance's record and a claim per map it serves (map_directory.hpp).
    directory_ = std::make_unique<MapDirectoryMember>(
        participant_, config_.prefix,
        InstanceRecord{config_.instance.empty() ? default_instance_name() : config_.instance, prefix,
                       config_.map_group});
    maps_->set_directory(directory_.get());
  } catch (const client::DdsError& e) {
    return core::fail(why, e.what());
  }
  const auto to_log = [this](const std::string& m) { log(m); };
  queries_.reset();  // those of an earlier activation hold the replies replaced here
  sessions_.reset();
  replies_ = std::make_unique<Replies>(pose_writer_.get(), result_writer_.get(), participant_, views_topic_);
  sessions_ = std::make_unique<Sessions>(config_, *maps_, *replies_, *counters_, *query_rasterizer_, to_log);
  sessions_->set_pose_listener(pose_listener_);
  queries_ = std::make_unique<Queries>(config_, *maps_, *replies_, *counters_, *query_rasterizer_,
                                       grounding_.get(), to_log);
  stop_ = false;
  maps_->allow_refining();
  ingest_thread_ = std::thread([this] { ingest(); });
  queries_->start();
  if (!config_.health_file.empty()) health_ = std::make_unique<HealthFile>(config_.health_file);
  return true;
}

void Server::deactivate() {
  if (ingest_thread_.joinable()) {
    stop_ = true;
    dds_waitset_set_trigger(waitset_.get(), true);
    ingest_thread_.join();
    close_frame_reader();
  }
  health_.reset();  // not ready while draining
  if (maps_) maps_->stop_refining();  // a refinement running ends within a step, saying so
  if (maps_) maps_->set_directory(nullptr);
  directory_.reset();  // claims withdrawn: this instance stops serving
  if (queries_) queries_->stop();  // the queued requests are still answered
  if (sessions_) sessions_->close_all();
  if (!configured_ || config_.map_dir.empty() || !config_.save_maps_at_shutdown) return;
  maps_->save_changed_maps();
}

void Server::close_frame_reader() {
  // Frames that arrive once ingest has stopped are not accepted (no pose, no error). They are
  // taken and dropped while the reader is deleted: a full keep-all reader makes Cyclone's delivery
  // wait for room, and the reader's deletion waits for that delivery, for as long as a client
  // keeps streaming (measured: SIGTERM took 52 s with a client streaming; docs/reliability.md).
  const dds_entity_t reader = frame_reader_.get();
  std::atomic<bool> deleted{false};
  std::atomic<int> dropped{0};
  std::thread drain([&] {
    while (!deleted) {
      dropped += client::take_each<fslam_proto_Frame>(reader, [](const fslam_proto_Frame&) {});
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  });
  frame_reader_.reset();
  deleted = true;
  drain.join();
  if (dropped > 0) log(std::to_string(dropped.load()) + " frame(s) that came after the stop were not taken");
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
  status_keys_.clear();
  participant_.reset();
}

ServerStats Server::stats() const {
  ServerStats s = counters_->totals();
  s.sessions = sessions_ ? sessions_->count() : 0;
  s.maps = maps_ ? maps_->count() : 0;
  return s;
}

void Server::ingest() {
  auto next_status = Clock::now();
  while (!stop_) {
    if (Clock::now() >= next_status) {
      publish_status();
      next_status += std::chrono::milliseconds(config_.status_period_ms);
      for (const auto& [map, holder] : directory_->take_lost()) {
        sessions_->withdraw_map(map, "is held by instance '" + holder.instance + "' (claimed first)");
      }
      if (config_.session_lease_s > 0) sessions_->close_idle(config_.session_lease_s);
      if (health_) {
        const ServerStats s = stats();
        health_->beat(config_.service_prefix(), s.maps, s.sessions);
      }
    }
    dds_attach_t triggered[3];
    dds_waitset_wait(waitset_.get(), triggered, 3, DDS_MSECS(200));
    // Session control first, so that a session opened just before its first frame exists.
    client::take_each<fslam_proto_SessionControl>(
        control_reader_.get(), [&](const fslam_proto_SessionControl& m) { sessions_->handle_control(m); });
    client::take_each<fslam_proto_Frame>(frame_reader_.get(),
                                         [&](const fslam_proto_Frame& m) { sessions_->handle_frame(m); });
    client::take_each<fslam_proto_Request>(request_reader_.get(),
                                           [&](const fslam_proto_Request& m) { queries_->accept(m); });
  }
}

void Server::publish_status() {
  const std::uint64_t rss = resident_bytes();
  const std::vector<std::shared_ptr<MapEntry>> idle = maps_->idle();
  std::set<std::pair<std::string, std::string>> keys;  // the instances written this round
  auto describe_map = [&](MapEntry& map, fslam_proto_SessionStatus* st) {
    std::lock_guard<std::mutex> mlock(map.mutex);
    st->streaming = map.streaming;
    st->frames_tracked = map.poses.size();
    st->map_version = map.versions().version_number();
    st->map_gaussians = map.versions().latest()->size();
    st->resident_bytes = rss;
    st->text_queries = grounding_ != nullptr;
  };
  for (SessionReport& report : sessions_->reports()) {
    fslam_proto_SessionStatus& st = report.numbers;
    st.session = report.session.data();
    st.map_name = report.map_name.data();
    st.last_drop_reason = report.last_drop_reason.data();
    st.last_skip_reason = report.last_skip_reason.data();
    st.frame_policy = report.frame_policy.data();
    st.mode = report.mode.data();
    describe_map(*report.map, &st);
    dds_write(status_writer_.get(), &st);
    keys.emplace(report.session, report.map_name);
  }
  for (const auto& map : idle) {
    std::string empty, name = map->name;
    fslam_proto_SessionStatus st = keyed_status(empty, name, empty);
    describe_map(*map, &st);
    dds_write(status_writer_.get(), &st);
    keys.emplace(std::string(), map->name);
  }
  // A closed session's (or removed map's) instance: Cyclone keeps every instance a writer wrote
  // until it is unregistered, and so does every reader until it takes the unregistration.
  for (const auto& [session, map_name] : status_keys_) {
    if (keys.count({session, map_name})) continue;
    std::string s = session, m = map_name, empty;
    const fslam_proto_SessionStatus key = keyed_status(s, m, empty);
    dds_unregister_instance(status_writer_.get(), &key);
  }
  status_keys_ = std::move(keys);
}

// ---- in-process sessions (the ROS 2 bridge) ------------------------------------------------

bool Server::open_session(const std::string& session, const std::string& map, bool live, std::string* why) {
  if (!sessions_) return core::fail(why, "the server is not active");
  std::string name = session, map_name = map;
  fslam_proto_SessionControl msg{};
  msg.session = name.data();
  msg.command = fslam_proto_SESSION_OPEN;
  msg.map_name = map_name.data();
  msg.policy = live ? fslam_proto_POLICY_LIVE : fslam_proto_POLICY_QUEUE;
  sessions_->handle_control(msg);
  if (sessions_->streams_into(session, map)) {
    sessions_->exempt_from_lease(session);
    return true;
  }
  return core::fail(why, "the server refused session '" + session + "' on map '" + map +
                             "' (the reason is on " + config_.service_prefix() + "/results)");
}

void Server::submit_frame(const fslam_proto_Frame& frame) {
  if (sessions_) sessions_->handle_frame(frame);
}

void Server::report_rejected(const std::string& session, const std::string& message) {
  if (sessions_) sessions_->report_rejected(session, message);
}

void Server::set_pose_listener(std::function<void(const TrackedPose&)> listener) {
  pose_listener_ = std::move(listener);
  if (sessions_) sessions_->set_pose_listener(pose_listener_);
}

}  // namespace fslam::server

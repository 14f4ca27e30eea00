#include "sessions.hpp"

#include <cstdio>
#include <optional>
#include <sstream>
#include <utility>

#include <tbb/task_arena.h>

#include "fslam/core/compute/thread_clock.hpp"
#include "fslam/core/error.hpp"
#include "fslam/core/eval/percentile.hpp"
#include "fslam/server/backend_factory.hpp"
#include "fslam/server/map_files.hpp"
#include "fslam/server/request_checks.hpp"
#include "counters.hpp"
#include "map_registry.hpp"
#include "fslam/server/rate_limit.hpp"

namespace fslam::server {
namespace {

using Clock = std::chrono::steady_clock;

// Frames prepared ahead of registration in a queue-policy session (each holds a decoded frame
// and a feature pyramid, ~20 MB): the preparing thread waits rather than run further ahead.
constexpr std::size_t kPreparedAhead = 2;
constexpr std::size_t kTimingWindow = 1000;

void record(std::deque<double>* window, double ms) {
  window->push_back(ms);
  if (window->size() > kTimingWindow) window->pop_front();
}

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

}  // namespace

struct Sessions::QueuedFrame {
  EncodedFrame frame;
  Clock::time_point queued;
};

// A decoded frame with its latent and source Gaussians (core::SlamPipeline::prepare_frame),
// waiting for registration; the times so far go on its pose.
struct Sessions::PreparedFrame {
  core::PreparedFrame frame;
  Clock::time_point ready;
  double decode_ms = 0, queue_ms = 0, prepare_ms = 0;
  double prepare_cpu_ms = 0;  // the preparing thread's CPU time for it
};

// One streaming session: its waiting frames and its threads. The pipeline is its map's (mode
// map), or its own tracking-only one fixed on the map (mode localise: nothing reaches the map).
struct Sessions::Session {
  std::string name;
  std::shared_ptr<MapEntry> map;
  std::shared_ptr<core::SlamPipeline> pipeline;
  fslam_proto_SessionMode mode = fslam_proto_SESSION_MAP;
  // Mode localise: the pipeline is the session's, not the map's, and nothing reaches the map.
  bool localises() const { return mode == fslam_proto_SESSION_LOCALISE; }
  std::unique_ptr<ViewStream> views;  // localise with views asked for: renders at its poses
  bool live = true;  // frame policy: live (newest frame only) or queue
  std::mutex mutex;
  std::condition_variable wake;
  std::deque<QueuedFrame> queue;  // accepted, waiting to be prepared; live: at most one
  std::deque<PreparedFrame> prepared;  // waiting to be registered; live: at most one
  bool closing = false;
  bool preparing_done = false;    // the preparing thread drained `queue` after closing
  // Opened, the newest frame arrived, or the last frame of it was tracked (guarded by `mutex`).
  Clock::time_point last_active = Clock::now();
  // server.session_lease_s closes the session when its client stops sending and no frame of it
  // waits; false for a
  // session the server itself feeds (the ROS 2 bridge), which no dead client can leave behind.
  bool leased = true;
  RateLimit frame_rate;                          // server.max_session_fps (guarded by `mutex`)
  std::thread preparing, tracking;
  std::unique_ptr<MappingThread> mapping;
  // Status counters (guarded by `mutex`).
  std::uint64_t received = 0, processed = 0, dropped = 0, skipped = 0;
  std::string last_drop_reason, last_skip_reason;
  // The latest stage times, for p50 / p99 (each bounded to kTimingWindow entries).
  std::deque<double> decode_ms, queue_ms, track_ms, track_cpu_ms, map_ms;
  bool at_capacity_reported = false;  // mapper.max_gaussians reached, and said so
};

Sessions::Sessions(const ServerConfig& config, MapRegistry& maps, const Replies& replies,
                   Counters& counters, const core::Rasterizer& view_rasterizer, Log log)
    : config_(config),
      maps_(maps),
      replies_(replies),
      counters_(counters),
      view_rasterizer_(view_rasterizer),
      log_(std::move(log)) {}

Sessions::~Sessions() { close_all(); }

std::size_t Sessions::count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return sessions_.size();
}

// ---- control ---------------------------------------------------------------------------------

void Sessions::handle_control(const fslam_proto_SessionControl& msg) {
  const std::string name = text(msg.session);
  const std::string map_name = msg.map_name != nullptr && msg.map_name[0] ? msg.map_name : name;
  if (name.empty()) return replies_.result(msg.session, msg.request_id, map_name, "session name is empty");
  if (msg.attach_only) {
    // A query-only client: nothing to create, the answer says whether the map is there.
    const bool exists = maps_.find(map_name) != nullptr;
    return replies_.result(msg.session, msg.request_id, map_name,
                           exists ? "" : "no map named '" + map_name + "'");
  }
  if (msg.command == fslam_proto_SESSION_OPEN) return open_session(msg, name, map_name);
  std::unique_ptr<Session> closing;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = sessions_.find(name);
    if (it == sessions_.end()) {
      return replies_.result(msg.session, msg.request_id, map_name, "unknown session '" + name + "'");
    }
    if (msg.refine_steps > 0 && (it->second->localises() || msg.refine_steps > config_.max_refine_steps)) {
      // Refused before anything closes: the client may close again without it.
      return replies_.result(msg.session, msg.request_id, map_name,
                             it->second->localises() ? "close: a localise session has no map of its own to refine"
                                                  : "close: refine_steps must be at most " +
                                                        std::to_string(config_.max_refine_steps) +
                                                        " (server.max_refine_steps)");
    }
    closing = std::move(it->second);
    sessions_.erase(it);
  }
  // Draining a session (its queued frames, then mapping, then any refinement) can take a while:
  // do it off the ingest thread so that other sessions keep flowing, and answer when it is done.
  close_later(std::move(closing), text(msg.session), msg.request_id, "", msg.refine_steps);
}

void Sessions::open_session(const fslam_proto_SessionControl& msg, const std::string& name,
                            const std::string& map_name) {
  const auto reply = [&](const std::string& error) {
    replies_.result(msg.session, msg.request_id, map_name, error);
  };
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = sessions_.find(name);
    if (it != sessions_.end()) {
      if (it->second->map->name == map_name) return reply("");
      return reply("session '" + name + "' already streams into map '" + it->second->map->name + "'");
    }
    std::string why;
    if (!valid_map_name(map_name, &why)) return reply(why);
    if (sessions_.size() >= config_.max_sessions) {
      return reply("the server streams its limit of " + std::to_string(config_.max_sessions) +
                   " sessions (server.max_sessions); close one first");
    }
    auto s = std::make_unique<Session>();
    s->name = name;
    s->mode = msg.mode;
    std::uint32_t view_channels = 0;
    if (!check_view_request(s->localises(), msg.view_rate_hz, msg.view_channels, &view_channels, &why)) return reply(why);
    const Clock::time_point t_open = Clock::now();
    if (s->localises()) {
      s->pipeline = make_localiser(map_name, &s->map, &why);
    } else if (msg.mode == fslam_proto_SESSION_MAP) {
      s->map = maps_.open_streaming(
          map_name, [this](std::string* pipeline_why) { return make_pipeline(pipeline_why); }, &why);
      if (s->map) s->pipeline = s->map->pipeline;
    } else if (msg.mode == fslam_proto_SESSION_EXTEND) {
      s->map = maps_.open_extending(
          map_name, [this](MapEntry& old, std::string* pipeline_why) { return make_extender(old, pipeline_why); }, &why);
      if (s->map) s->pipeline = s->map->pipeline;
    } else {
      why = "unknown session mode " + std::to_string(static_cast<int>(msg.mode)) + " (map, localise or extend)";
    }
    if (!s->pipeline) return reply(why);
    if (msg.mode != fslam_proto_SESSION_MAP && log_) {
      // Made under the sessions' lock (frames of other sessions wait meanwhile): say how long.
      char line[256];
      std::snprintf(line, sizeof line, "session '%s' %s map '%s': %zu target points from its Gaussians, %zu keyframes to relocalise against, "
                    "built in %.0f ms", name.c_str(), s->localises() ? "localises in" : "extends", map_name.c_str(),
                    s->pipeline->tracker().local_map().size(), s->pipeline->tracker().relocaliser().size(),
                    ms_since(t_open));
      log_(line);
    }
    if (msg.view_rate_hz > 0.0f) {
      s->views = std::make_unique<ViewStream>(name, s->map, view_rasterizer_, replies_, msg.view_rate_hz,
                                              view_channels, log_);
    }
    s->live = msg.policy == fslam_proto_POLICY_LIVE ||
              (msg.policy != fslam_proto_POLICY_QUEUE && config_.frame_policy == "live");
    s->frame_rate = RateLimit(config_.max_session_fps);
    start_threads(s.get());
    sessions_[name] = std::move(s);
  }
  reply("");
}

bool Sessions::startable(MapEntry& map, const std::string& verb, core::MapVersions::Version* version,
                         std::shared_ptr<const std::vector<core::DescribedKeyframe>>* keyframes,
                         std::string* why) const {
  *version = map.versions().latest();
  if (!*version || (*version)->size() == 0)
    return core::fail(why, "map '" + map.name + "' has no Gaussians yet to " + verb);
  *keyframes = map.keyframes();
  if (!*keyframes || (*keyframes)->empty()) {
    return core::fail(why, "map '" + map.name + "' has no keyframe descriptions to relocalise against (saved "
                           "without keyframes.bin, or built with tracker.relocalisation.enabled false)");
  }
  return true;
}

std::shared_ptr<core::SlamPipeline> Sessions::make_localiser(const std::string& map_name,
                                                             std::shared_ptr<MapEntry>* map,
                                                             std::string* why) const {
  *map = maps_.find(map_name);
  if (!*map) {
    core::fail(why, "no map named '" + map_name + "' to localise in (load it or stream it first)");
    return nullptr;
  }
  core::MapVersions::Version version;
  std::shared_ptr<const std::vector<core::DescribedKeyframe>> keyframes;
  if (!startable(**map, "localise against", &version, &keyframes, why)) return nullptr;
  // Tracking alone, geometry and opacity: no encoder, no mapper, no feature term (docs/protocol.md).
  core::PipelineConfig config = config_.pipeline;
  config.mapping = false;
  config.features = {};
  config.loop_closure.enabled = false;  // the map is fixed: nothing to correct
  config.tracker.relocalisation.enabled = true;
  auto pipeline = std::make_shared<core::SlamPipeline>(config, nullptr);
  if (!pipeline->start_in(*version, 0, *keyframes, core::StartMode::localise, nullptr, why)) return nullptr;
  return pipeline;
}

std::shared_ptr<core::SlamPipeline> Sessions::make_extender(MapEntry& map, std::string* why) const {
  if (!config_.pipeline.tracker.relocalisation.enabled) {
    core::fail(why, "extend: this server runs with tracker.relocalisation.enabled false");
    return nullptr;
  }
  core::MapVersions::Version version;
  std::shared_ptr<const std::vector<core::DescribedKeyframe>> keyframes;
  if (!startable(map, "extend", &version, &keyframes, why)) return nullptr;
  std::shared_ptr<core::SlamPipeline> pipeline = make_pipeline(why);
  std::string reason;
  const std::shared_ptr<const core::FeatureAutoencoder> heads = map.heads();
  if (pipeline && !pipeline->start_in(*version, map.versions().version_number(), *keyframes,
                                      core::StartMode::extend, heads.get(), &reason)) {
    core::fail(why, "extend map '" + map.name + "': " + reason);
    return nullptr;
  }
  // The keyframes the map was mapped from stay in the mapper's sampling (the regions mapped
  // before keep being optimised) and are saved with the extended map.
  std::vector<core::KeyframeImages> images;
  if (pipeline && (!map.keyframe_images(&images, &reason) ||
                   (!images.empty() && !pipeline->mapper().restore_keyframes(images, &reason)))) {
    core::fail(why, "extend map '" + map.name + "': " + reason);
    return nullptr;
  }
  if (pipeline && pipeline->feature_heads() && log_) {
    log_("extend map '" + map.name + "': the decoded L_feat continues through " +
         (heads ? std::string("the map's online feature heads") : "the pretrained heads (the map has none saved)"));
  }
  return pipeline;
}

std::shared_ptr<core::SlamPipeline> Sessions::make_pipeline(std::string* why) const {
  std::string notice;
  std::shared_ptr<const core::Rasterizer> rasterizer =
      make_rasterizer(config_.compute.backend, RasterUse::kMapping, &notice, why);
  if (!rasterizer) return nullptr;
  std::unique_ptr<core::LatentFeatures> features;
  if (config_.pipeline.features.enabled()) {
    features = core::LatentFeatures::create(config_.pipeline.features, why);
    if (!features) return nullptr;
  }
  return std::make_shared<core::SlamPipeline>(config_.pipeline, rasterizer, std::move(features));
}

// The threads hold `raw`: the session outlives them (finish_session joins them).
void Sessions::start_threads(Session* raw) {
  // Before the open is answered, so that a live session's first frames are not skipped while the
  // tracking encoder is made (its first frame is the map's origin).
  raw->pipeline->warm_up();
  if (config_.pipelined_tracking) {
    raw->preparing = std::thread([this, raw] { run_on_one_thread([&] { prepare_frames(raw); }); });
    raw->tracking = std::thread([this, raw] { run_on_one_thread([&] { track_frames(raw); }); });
  } else {
    raw->tracking = std::thread([this, raw] { run_on_one_thread([&] { prepare_and_track_frames(raw); }); });
  }
  if (raw->localises()) return;  // nothing to map
  raw->mapping = std::make_unique<MappingThread>(
      raw->pipeline.get(), config_.mapping_threads, config_.pipeline.realtime,
      [this, raw](const core::KeyframeReport& report) {
        const core::RefinementStats& r = report.refinement;
        std::lock_guard<std::mutex> lock(raw->mutex);
        record(&raw->map_ms, r.insert_ms + r.optimise_ms + r.prune_ms);
        if (r.at_capacity && !raw->at_capacity_reported) {
          // Tracking goes on and the map keeps being optimised; said once per session.
          raw->at_capacity_reported = true;
          log_("map '" + raw->map->name + "' reached mapper.max_gaussians (" +
               std::to_string(config_.pipeline.mapper.max_gaussians) +
               " Gaussians): new surface is no longer added, the map is still optimised");
        }
      },
      [this, raw](const std::string& mwhy) {
        // Tracking goes on; clients learn that the map stopped growing, and why.
        replies_.result(raw->name.c_str(), 0, raw->map->name, "mapping failed: " + mwhy);
      });
}

void Sessions::close_later(std::unique_ptr<Session> session, std::string client, std::uint64_t request_id,
                           std::string answer, std::uint32_t refine_steps) {
  const std::string map = session->map->name;
  auto owned = std::shared_ptr<Session>(std::move(session));
  start_closer(owned, [this, owned, client, map, request_id, answer, refine_steps]() mutable {
    finish_session(owned.get());
    // Post-trajectory refinement at close (paper): the session is closed either way.
    std::string why;
    if (refine_steps > 0 && answer.empty() && !maps_.refine(*owned->map, refine_steps, &why))
      answer = "session '" + owned->name + "' closed; " + why;
    replies_.result(client.c_str(), request_id, map, answer);
  });
}

void Sessions::start_closer(const std::shared_ptr<Session>& session, std::function<void()> work) {
  auto done = std::make_shared<std::atomic<bool>>(false);
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto it = closers_.begin(); it != closers_.end();) {
    if (!*it->done) {
      ++it;
      continue;
    }
    it->thread.join();
    it = closers_.erase(it);
  }
  closers_.push_back({std::thread([work = std::move(work), done] {
                        work();
                        *done = true;
                      }),
                      done, session});
}

void Sessions::close_idle(double lease_s) {
  const auto lease = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(lease_s));
  std::vector<std::unique_ptr<Session>> idle;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (auto it = sessions_.begin(); it != sessions_.end();) {
      bool expired = false;
      {
        std::lock_guard<std::mutex> qlock(it->second->mutex);
        // From the last frame tracked too: a queue-policy client waiting for the poses of its
        // backlog, then closing, is not gone (under TSan a 3-s lease closed such sessions).
        const Session& s = *it->second;
        expired = s.leased && s.queue.empty() && s.prepared.empty() && Clock::now() - s.last_active > lease;
      }
      if (!expired) {
        ++it;
        continue;
      }
      idle.push_back(std::move(it->second));
      it = sessions_.erase(it);
    }
  }
  for (auto& s : idle) {
    const std::string name = s->name, map = s->map->name;
    std::ostringstream lease_text;
    lease_text << lease_s;
    const std::string why = "session '" + name + "' closed: no frame for " + lease_text.str() +
                            " s (server.session_lease_s); map '" + map + "' stays served";
    if (log_) log_(why);
    close_later(std::move(s), name, 0, why);
  }
}

void Sessions::withdraw_map(const std::string& name, const std::string& reason) {
  std::vector<std::unique_ptr<Session>> closing;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (auto it = sessions_.begin(); it != sessions_.end();) {
      if (it->second->map->name != name) {
        ++it;
        continue;
      }
      closing.push_back(std::move(it->second));
      it = sessions_.erase(it);
    }
    maps_.withdraw(name);  // queries in flight keep the version they hold; nothing is saved
  }
  if (log_) log_("gave up map '" + name + "': it " + reason);
  for (auto& s : closing) {
    const std::string session = s->name;
    replies_.result(session.c_str(), 0, name, "map '" + name + "' " + reason + "; session '" +
                                                  session + "' is closed here");
    auto owned = std::shared_ptr<Session>(std::move(s));
    start_closer(owned, [this, owned] { finish_session(owned.get()); });
  }
}

void Sessions::finish_session(Session* s) {
  {
    std::lock_guard<std::mutex> lock(s->mutex);
    s->closing = true;
  }
  s->wake.notify_all();
  if (s->preparing.joinable()) s->preparing.join();
  if (s->tracking.joinable()) s->tracking.join();  // every accepted frame is tracked
  s->views.reset();  // the last view offered is sent
  if (s->mapping) s->mapping->finish_fairly();  // the close waits for it: no longer background work
  s->pipeline->finish();
  if (s->mapping) s->mapping->join();
  if (s->localises()) return;  // the map was never the session's
  std::lock_guard<std::mutex> lock(s->map->mutex);
  s->map->streaming = false;
}

void Sessions::close_all() {
  std::map<std::string, std::unique_ptr<Session>> sessions;
  std::vector<Closer> closers;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    sessions.swap(sessions_);
    closers.swap(closers_);
  }
  // Shutdown keeps every accepted frame but not every optimisation step: the keyframes waiting
  // for a mapper go in unoptimised, so SIGTERM is honoured within seconds (docs/reliability.md).
  for (auto& [name, s] : sessions) s->pipeline->hurry_mapping();
  for (Closer& c : closers)
    if (const std::shared_ptr<Session> s = c.session.lock()) s->pipeline->hurry_mapping();
  for (auto& [name, s] : sessions) finish_session(s.get());
  for (Closer& c : closers) c.thread.join();
}

std::vector<SessionReport> Sessions::reports() const {
  std::vector<SessionReport> reports;
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [name, s] : sessions_) {
    SessionReport r;
    r.session = s->name;
    r.map_name = s->map->name;
    r.map = s->map;
    r.frame_policy = s->live ? "live" : "queue";
    r.mode = s->mode == fslam_proto_SESSION_LOCALISE ? "localise"
             : s->mode == fslam_proto_SESSION_EXTEND ? "extend"
                                                     : "map";
    fslam_proto_SessionStatus& st = r.numbers;
    std::lock_guard<std::mutex> qlock(s->mutex);
    st.queue_depth = static_cast<std::uint32_t>(s->queue.size());
    st.frames_received = s->received;
    st.frames_processed = s->processed;
    st.frames_dropped = s->dropped;
    st.frames_skipped = s->skipped;
    r.last_drop_reason = s->last_drop_reason;
    r.last_skip_reason = s->last_skip_reason;
    auto p = [](const std::deque<double>& w, double q) {
      return static_cast<float>(core::percentile(std::vector<double>(w.begin(), w.end()), q));
    };
    st.decode_ms_p50 = p(s->decode_ms, 0.5);
    st.decode_ms_p99 = p(s->decode_ms, 0.99);
    st.queue_ms_p50 = p(s->queue_ms, 0.5);
    st.queue_ms_p99 = p(s->queue_ms, 0.99);
    st.track_ms_p50 = p(s->track_ms, 0.5);
    st.track_ms_p99 = p(s->track_ms, 0.99);
    st.track_cpu_ms_p50 = p(s->track_cpu_ms, 0.5);
    st.track_cpu_ms_p99 = p(s->track_cpu_ms, 0.99);
    st.map_ms_p50 = p(s->map_ms, 0.5);
    st.map_ms_p99 = p(s->map_ms, 0.99);
    st.mapping_queue = static_cast<std::uint32_t>(s->pipeline->queued_keyframes());
    st.keyframes_left_out = s->pipeline->keyframes_left_out();
    if (const std::optional<core::LoopThreadStats> loops = s->pipeline->loop_closure_stats()) {
      st.loop_closure = true;
      st.loops_closed = static_cast<std::uint32_t>(loops->loops);
    }
    reports.push_back(std::move(r));
  }
  return reports;
}

// ---- frames ----------------------------------------------------------------------------------

void Sessions::handle_frame(const fslam_proto_Frame& msg) {
  const std::string name = text(msg.session);
  // Cheap checks and a copy of the payloads; decoding waits for the tracking thread, so that a
  // frame the live policy skips costs nothing more.
  QueuedFrame queued;
  std::string accept_why, why;
  const bool accepted = accept_frame(msg, &queued.frame, &accept_why);
  std::lock_guard<std::mutex> lock(mutex_);
  counters_.add(&ServerStats::frames_received);
  const auto it = sessions_.find(name);
  if (it == sessions_.end()) why = "unknown session '" + name + "' (open it first)";
  else if (!accepted) why = accept_why;
  if (!why.empty()) {
    return reject_locked(it == sessions_.end() ? nullptr : it->second.get(), msg.session, msg.frame_id, name,
                         "frame " + std::to_string(msg.frame_id) + ": " + why);
  }
  Session& s = *it->second;
  {
    std::lock_guard<std::mutex> qlock(s.mutex);
    ++s.received;
    s.last_active = Clock::now();
    if (!s.frame_rate.take(s.last_active)) {
      return drop_locked(&s, msg, "frame " + std::to_string(msg.frame_id) + " refused: more than " +
                                      number_text(config_.max_session_fps) +
                                      " frames per second (server.max_session_fps)");
    }
    if (s.live) {
      // Live: the tracker takes the newest frame; one still waiting is skipped, and said so.
      while (!s.queue.empty()) {
        const EncodedFrame& old = s.queue.front().frame;
        counters_.add(&ServerStats::frames_skipped);
        ++s.skipped;
        s.last_skip_reason = "frame " + std::to_string(old.frame_id) + " skipped: frame " +
                             std::to_string(msg.frame_id) + " arrived while tracking was busy (live policy)";
        replies_.skip(s.name, old.frame_id, old.timestamp, s.last_skip_reason);
        s.queue.pop_front();
      }
    } else if (s.queue.size() >= config_.queue_capacity) {
      return drop_locked(&s, msg, "frame " + std::to_string(msg.frame_id) + " dropped: queue full (" +
                                      std::to_string(config_.queue_capacity) + " frames)");
    }
    queued.queued = Clock::now();
    s.queue.push_back(std::move(queued));
  }
  s.wake.notify_all();
}

void Sessions::reject_locked(Session* s, const char* client, std::uint64_t frame_id, const std::string& map,
                             const std::string& message) {
  counters_.add(&ServerStats::frames_rejected);
  if (s != nullptr) {
    std::lock_guard<std::mutex> qlock(s->mutex);
    ++s->received;
    ++s->dropped;
    s->last_drop_reason = message;
  }
  replies_.result(client, frame_id, map, message);
}

void Sessions::drop_locked(Session* s, const fslam_proto_Frame& msg, std::string reason) {
  counters_.add(&ServerStats::frames_dropped);
  ++s->dropped;
  s->last_drop_reason = std::move(reason);
  replies_.result(msg.session, msg.frame_id, text(msg.session), s->last_drop_reason);
}

void Sessions::run_on_one_thread(const std::function<void()>& work) {
  // A session's frame threads (prepare, register; or both in one) each run in an arena of their
  // own with no workers: the parallel loops inside decoding and the feature encoder
  // (OpenCV runs on TBB) never wait for a TBB worker busy with, or niced by, mapping.
  tbb::task_arena one_thread(1);
  one_thread.execute(work);
}
bool Sessions::prepare_one(Session* s, QueuedFrame&& queued, PreparedFrame* prepared) {
  prepared->queue_ms = ms_since(queued.queued);
  std::string why;
  core::RgbdFrame frame;
  const Clock::time_point t_decode = Clock::now();
  const bool decoded = decode_frame(queued.frame, &frame, &why);
  prepared->decode_ms = ms_since(t_decode);
  const Clock::time_point t_prepare = Clock::now();
  const double cpu_prepare = core::thread_cpu_ms();
  const bool ready = decoded && s->pipeline->prepare_frame(std::move(frame), &prepared->frame, &why);
  prepared->prepare_ms = ms_since(t_prepare);
  prepared->prepare_cpu_ms = core::thread_cpu_ms() - cpu_prepare;
  prepared->ready = Clock::now();
  if (ready) return true;
  const std::string message = "frame " + std::to_string(queued.frame.frame_id) + ": " + why;
  {
    std::lock_guard<std::mutex> lock(s->mutex);
    ++s->dropped;
    s->last_drop_reason = message;
  }
  replies_.result(s->name.c_str(), queued.frame.frame_id, s->map->name, message);
  return false;
}

// Waits for the next accepted frame; false when the session closes with nothing left.
// `room`: in a queue-policy session, wait until registration has room for one more.
bool Sessions::next_queued(Session* s, bool room, QueuedFrame* queued) {
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

void Sessions::prepare_and_track_frames(Session* s) {
  QueuedFrame queued;
  while (next_queued(s, false, &queued)) {
    PreparedFrame prepared;
    if (prepare_one(s, std::move(queued), &prepared)) track_one(s, std::move(prepared));
  }
}

void Sessions::prepare_frames(Session* s) {
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
          replies_.skip(s->name, static_cast<std::uint64_t>(old.id), old.timestamp, s->last_skip_reason);
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

void Sessions::track_frames(Session* s) {
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

void Sessions::track_one(Session* s, PreparedFrame&& prepared) {
  core::SlamPipeline& pipeline = *s->pipeline;
  const double queue_ms = prepared.queue_ms + ms_since(prepared.ready);
  const core::RgbdFrame& frame = prepared.frame.frame;
  const std::uint64_t frame_id = static_cast<std::uint64_t>(frame.id);
  const double timestamp = frame.timestamp;
  const core::PinholeCamera camera = frame.camera;
  core::TrackingResult result;
  std::string why;
  const Clock::time_point t0 = Clock::now();
  const double cpu0 = core::thread_cpu_ms();
  const bool tracked = pipeline.track_prepared(std::move(prepared.frame), &result, &why);
  const double track_ms = prepared.prepare_ms + ms_since(t0);
  const double track_cpu_ms = prepared.prepare_cpu_ms + (core::thread_cpu_ms() - cpu0);
  {
    std::lock_guard<std::mutex> lock(s->mutex);
    ++s->processed;
    s->last_active = Clock::now();
    record(&s->decode_ms, prepared.decode_ms);
    record(&s->queue_ms, queue_ms);
    record(&s->track_ms, track_ms);
    record(&s->track_cpu_ms, track_cpu_ms);
  }
  if (!tracked) {
    replies_.result(s->name.c_str(), frame_id, s->map->name, why);
    return;
  }
  if (!s->localises()) {  // a localising session's poses are its client's, not the map's
    std::lock_guard<std::mutex> lock(s->map->mutex);
    MapEntry& map = *s->map;
    map.camera = camera;
    map.pose_index[frame_id] = map.poses.size();
    map.poses.push_back({frame_id, timestamp, result.T_world_camera});
  }
  replies_.pose(s->name, frame_id, timestamp, result, prepared.decode_ms, queue_ms, track_ms);
  counters_.add(&ServerStats::poses_published);
  if (s->views && (result.state == core::TrackingState::ok || result.state == core::TrackingState::recovered))
    s->views->offer(frame_id, timestamp, result.T_world_camera, camera);
  std::lock_guard<std::mutex> lock(listener_mutex_);
  if (pose_listener_) pose_listener_({s->name, frame_id, result.T_world_camera, result.keyframe});
}

// ---- in-process sessions ---------------------------------------------------------------------

bool Sessions::streams_into(const std::string& session, const std::string& map) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = sessions_.find(session);
  return it != sessions_.end() && it->second->map->name == map;
}

void Sessions::exempt_from_lease(const std::string& session) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = sessions_.find(session);
  if (it == sessions_.end()) return;
  std::lock_guard<std::mutex> qlock(it->second->mutex);
  it->second->leased = false;
}

void Sessions::report_rejected(const std::string& session, const std::string& message) {
  std::lock_guard<std::mutex> lock(mutex_);
  counters_.add(&ServerStats::frames_received);
  const auto it = sessions_.find(session);
  Session* s = it == sessions_.end() ? nullptr : it->second.get();
  reject_locked(s, session.c_str(), 0, s != nullptr ? s->map->name : session, message);
}

void Sessions::set_pose_listener(std::function<void(const Server::TrackedPose&)> listener) {
  std::lock_guard<std::mutex> lock(listener_mutex_);
  pose_listener_ = std::move(listener);
}

}  // namespace fslam::server

// The featureslam server: a component with an explicit lifecycle (configure -> activate ->
// deactivate -> cleanup) that owns maps and the SLAM sessions streaming into them, and talks DDS
// (docs/protocol.md). Each session runs tracking and mapping on their own threads. Its frames
// follow its frame policy: live (the default) tracks the newest frame and skips older waiting
// ones, reporting each skip on the pose stream; queue tracks every frame from a bounded queue
// whose overflow drops the newest with an error result. Nothing accepted is lost silently.
// Render, segment, save and load requests run on query threads against the newest map version,
// so any number of clients can query any map while it is being built. The parts live in
// server/src: sessions, the map registry, queries, and the wire conversions (wire.hpp).
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "fslam/client/dds.hpp"
#include "fslam/core/pipeline/slam_pipeline.hpp"
#include "fslam/proto/types.h"
#include "fslam/server/grounding.hpp"
#include "fslam/server/ros2_config.hpp"

namespace fslam::server {

class Counters;
class HealthFile;
class MapDirectoryMember;
class MapRegistry;
class Queries;
class Replies;
class Sessions;

inline core::PipelineConfig realtime_pipeline() {
  core::PipelineConfig c;
  c.realtime = true;
  // Measured (docs/benchmarks.md, service at 30 Hz): features cost 10.9 -> 6.3 ms per frame, p50
  // frame -> pose 49-50 -> 31-32 ms on the synthetic room, tracking ATE within noise.
  c.tracking_encoder_input = 512;
  return c;
}

// Settings of the commands that read recorded sequences (`dataset.*`; the server reads none):
// what --intrinsics and --colour-camera give, so that a preset can carry them
// (configs/presets/seven_scenes.yaml).
struct DatasetSettings {
  std::string intrinsics;     // fx,fy,cx,cy[,width,height]; empty: the dataset's own
  std::string colour_camera;  // fx,fy,cx,cy,tx,ty,tz; empty: colour registered to depth
};

// What runs the server's rasterisers (compute.backend): "auto" takes a usable GPU for rendering
// queries and keeps mapping on the CPU; "cpu"; or "cuda", which needs a CUDA build and a usable GPU
// (else activation fails saying why). backend_factory.hpp says what each choice makes.
struct ComputeSettings {
  std::string backend = "auto";  // auto | cpu | cuda
};

struct ServerConfig {
  std::string prefix = "fslam";                 // topic prefix of this deployment
  // Scale-out (docs/deployment.md): the instance's name in the deployment's map directory
  // (<prefix>/maps). Set, the instance serves on service_prefix() = <prefix>/<instance>/...;
  // empty, it serves on <prefix>/... and is listed as <host>-<pid>.
  std::string instance;
  std::string map_group = "*";                  // glob of the new map names it creates; "" = none
  // Written every status period while the server serves, removed when it stops: readiness and
  // liveness probes look at it (deploy/k8s). Empty: none.
  std::string health_file;
  dds_domainid_t domain = DDS_DOMAIN_DEFAULT;
  // Frame policy of sessions that do not choose one: "live" or "queue" (docs/protocol.md).
  std::string frame_policy = "live";
  std::size_t queue_capacity = 64;              // frames waiting per queue-policy session
  int mapping_threads = 0;                      // TBB threads of each session's mapping; 0 = all cores
  // Each session prepares its next frame (decode, features, source Gaussians) on a second
  // thread while the current one registers; false: one thread does both, frame after frame.
  bool pipelined_tracking = true;
  int status_period_ms = 1000;                  // fslam/status, per session and idle map
  // Persistence: maps live in <map_dir>/<name>/ (map_files.hpp). Empty: nothing is saved or
  // loaded, and save / load requests are refused.
  std::string map_dir;
  bool load_maps_at_start = true;               // serve every map saved under map_dir
  bool save_maps_at_shutdown = true;            // save every map changed since its last save
  int query_threads = 1;                        // render / segment / save / load requests in parallel
  std::size_t query_queue_capacity = 16;        // requests waiting; more are refused as busy
  std::uint32_t max_render_pixels = 4096 * 4096;
  // Bounds a client cannot push the server past (each refused with an error naming the setting).
  std::size_t max_sessions = 16;                // streaming sessions at once
  std::size_t max_maps = 64;                    // maps held in memory (streamed, loaded)
  std::size_t max_prompts = 64;                 // points or boxes in one segment request
  std::uint32_t max_refine_steps = 5000;        // refinement steps one request or close may ask
  // A save that would leave less than this free on map_dir's disk is refused before it writes
  // (a full disk mid-save is an error too, and leaves the previous version). 0 = no reserve.
  std::size_t min_free_disk_mb = 64;
  // A session that receives no frame for this long is closed as its client's would be (its map
  // stays served); a client killed mid-stream does not keep its session's threads. 0 = never.
  double session_lease_s = 60.0;
  // Frames per second one session may send (bursts of one second's worth); faster frames are
  // refused with an error result naming the setting. 0 = no limit.
  double max_session_fps = 120.0;
  // Requests per second one client may make (bursts of one second's worth); more are refused
  // with an error result naming the setting. 0 = no limit.
  double max_client_requests_per_s = 100.0;
  // Text segmentation queries: a grounding detector (grounding.hpp, docs/segmentation.md).
  // Empty: text queries get an error result saying to set it.
  std::string grounding_model;
  int grounding_input_size = 800;               // pixels, square
  float grounding_box_threshold = 0.35f;        // boxes scoring lower are dropped
  // Real-time mapping by default: a live stream must not build a backlog of keyframes that
  // makes closing a session wait for it (core's default suits offline `fslam run`).
  core::PipelineConfig pipeline = realtime_pipeline();
  DatasetSettings dataset;
  ComputeSettings compute;
  Ros2Config ros2;  // the ROS 2 bridge (ros2_bridge.hpp); off by default
  bool is_valid(std::string* why = nullptr) const;
  // The prefix of the instance's own topics (frames, poses, session, requests, results, status):
  // <prefix>/<instance> with '-' as '_' (Cyclone refuses '-' in topic names; pod names have it).
  std::string service_prefix() const {
    std::string topic_safe = instance;
    for (char& c : topic_safe)
      if (c == '-') c = '_';
    return instance.empty() ? prefix : prefix + "/" + topic_safe;
  }
  GroundingConfig grounding() const {
    return {grounding_model, grounding_input_size, grounding_box_threshold};
  }
};

struct ServerStats {
  std::uint64_t frames_received = 0, frames_rejected = 0, frames_dropped = 0, frames_skipped = 0;
  std::uint64_t poses_published = 0;
  std::uint64_t requests_answered = 0, requests_failed = 0;
  std::size_t sessions = 0, maps = 0;
};

class Server {
 public:
  Server();
  ~Server();
  bool configure(const ServerConfig& config, std::string* why);
  // Loads the saved maps (when configured), joins the DDS domain and starts the ingest and query
  // threads.
  bool activate(std::string* why);
  // Stops ingest and queries, lets every session track what it accepted, stops the sessions and
  // saves the changed maps (when configured).
  void deactivate();
  void cleanup();
  // Deletes the frame reader while dropping what still arrives (server.cpp says why).
  void close_frame_reader();
  ServerStats stats() const;
  // Where lifecycle messages go (map loaded / saved, failures); default: nowhere.
  void set_log(std::function<void(const std::string&)> log);

  // ---- In-process sessions (the ROS 2 bridge, ros2_bridge.hpp): fed without fslam/frames ----
  struct TrackedPose {
    std::string session;
    std::uint64_t frame_id = 0;
    Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
    bool keyframe = false;
  };
  // Opens a session as a fslam/session SESSION_OPEN would; false with `why` when refused.
  bool open_session(const std::string& session, const std::string& map, bool live, std::string* why);
  // A frame for its session through the path a fslam/frames sample takes (checks, policy, queue).
  void submit_frame(const fslam_proto_Frame& frame);
  // A frame that could not be built from its messages: counted and reported as a rejected
  // fslam/frames sample is (session status, fslam/results).
  void report_rejected(const std::string& session, const std::string& message);
  // Called on a session's tracking thread after each pose it publishes; empty: none.
  void set_pose_listener(std::function<void(const TrackedPose&)> listener);

 private:
  void ingest();
  void publish_status();
  void log(const std::string& message) const;

  ServerConfig config_;
  bool configured_ = false;
  std::function<void(const std::string&)> log_;
  client::Entity participant_, frames_topic_, poses_topic_, control_topic_, results_topic_;
  client::Entity status_topic_, requests_topic_, frame_reader_, control_reader_, request_reader_;
  client::Entity pose_writer_, result_writer_, status_writer_, views_topic_, waitset_;
  std::thread ingest_thread_;
  std::atomic<bool> stop_{false};
  std::shared_ptr<const core::Rasterizer> query_rasterizer_;
  std::unique_ptr<GroundingDetector> grounding_;  // null without server.grounding_model
  std::unique_ptr<MapDirectoryMember> directory_;  // while active
  std::unique_ptr<HealthFile> health_;             // null without server.health_file
  std::unique_ptr<Counters> counters_;
  std::unique_ptr<MapRegistry> maps_;    // from configure on
  std::unique_ptr<Replies> replies_;     // from activate on, with
  std::unique_ptr<Sessions> sessions_;   //   the sessions
  std::unique_ptr<Queries> queries_;     //   and the queries
  std::function<void(const TrackedPose&)> pose_listener_;  // handed to each activation's sessions
  // The (session, map) status instances written last round (ingest thread only): those no longer
  // reported are unregistered, so that a writer and its readers do not keep one per session ever
  // opened.
  std::set<std::pair<std::string, std::string>> status_keys_;
};

// Prints the effective configuration, then runs a server until SIGINT or SIGTERM, reporting on
// stderr; returns the exit code. Shared by `fslam-server` and `fslam serve` (serve_options.hpp).
int serve_until_signal(const ServerConfig& config);

}  // namespace fslam::server

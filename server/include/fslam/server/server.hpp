// The featureslam server: a component with an explicit lifecycle (configure -> activate ->
// deactivate -> cleanup) that owns SLAM sessions and talks DDS (docs/protocol.md). Each session
// runs tracking and mapping on their own threads, fed by a bounded frame queue; a full queue
// drops the newest frame and says so in an error result — nothing accepted is lost silently.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "fslam/client/dds.hpp"
#include "fslam/core/pipeline/slam_pipeline.hpp"
#include "fslam/proto/types.h"

namespace fslam::server {

struct ServerConfig {
  std::string prefix = "fslam";                 // topic prefix of this deployment
  dds_domainid_t domain = DDS_DOMAIN_DEFAULT;
  std::size_t queue_capacity = 64;              // frames waiting per session
  int status_period_ms = 1000;                  // fslam/status, per session
  core::PipelineConfig pipeline;
  bool is_valid(std::string* why = nullptr) const;
};

struct ServerStats {
  std::uint64_t frames_received = 0, frames_rejected = 0, frames_dropped = 0, poses_published = 0;
  std::size_t sessions = 0;
};

class Server {
 public:
  Server();
  ~Server();
  bool configure(const ServerConfig& config, std::string* why);
  // Joins the DDS domain and starts the ingest thread.
  bool activate(std::string* why);
  // Stops ingest, lets every session track what it accepted, and stops them.
  void deactivate();
  void cleanup();
  ServerStats stats() const;

 private:
  struct Session;
  void ingest();
  void handle_control(const fslam_proto_SessionControl& msg);
  void handle_frame(const fslam_proto_Frame& msg);
  void publish_result(const char* client, std::uint64_t request_id, const std::string& map_name,
                      const std::string& error);
  void run_tracking(Session* session);
  void publish_status();
  void finish_session(Session* session);

  ServerConfig config_;
  bool configured_ = false;
  client::Entity participant_, frames_topic_, poses_topic_, control_topic_, results_topic_;
  client::Entity status_topic_, frame_reader_, control_reader_, pose_writer_, result_writer_;
  client::Entity status_writer_, waitset_;
  std::thread ingest_thread_;
  std::atomic<bool> stop_{false};
  mutable std::mutex mutex_;
  std::map<std::string, std::unique_ptr<Session>> sessions_;
  std::vector<std::thread> closers_;  // sessions being drained after a close
  ServerStats stats_;
};

// Prints the effective configuration, then runs a server until SIGINT or SIGTERM, reporting on
// stderr; returns the exit code. Shared by `fslam-server` and `fslam serve` (serve_options.hpp).
int serve_until_signal(const ServerConfig& config);

}  // namespace fslam::server

// The gateway's state between the server (one fslam::client::Client) and the browsers: the maps'
// Gaussians by version, the tracked trajectories, the sessions' status; and the render and
// segmentation requests browsers send, forwarded on worker threads. The web server (web_server.hpp)
// carries the messages; docs/viewer.md describes them.
#pragma once

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

#include <nlohmann/json_fwd.hpp>

#include "fslam/client/client.hpp"
#include "options.hpp"

namespace fslam::client::gateway {

// One WebSocket message to a browser. Map messages (`replaceable`) may be replaced in a viewer's
// queue by a newer one of the same map before they are sent: a slow browser skips versions
// instead of queueing them.
struct Outgoing {
  bool binary = false;
  std::string data;
  std::string replaceable;  // non-empty: the map whose Gaussians this is
};
using OutgoingPtr = std::shared_ptr<const Outgoing>;

// Where the gateway's messages go. Implementations must not block: they are called from DDS
// callbacks and worker threads.
class ViewerHub {
 public:
  virtual ~ViewerHub() = default;
  virtual void broadcast(OutgoingPtr message) = 0;
  virtual void send(std::uint64_t viewer, OutgoingPtr message) = 0;
};

// Figures the gateway keeps about what it sent (docs/benchmarks.md "Viewer").
struct GatewayStats {
  std::uint64_t map_reads = 0, map_versions_sent = 0, map_bytes_sent = 0, requests = 0;
};

class Gateway {
 public:
  Gateway(const GatewayOptions& options, Client* client);
  ~Gateway();
  Gateway(const Gateway&) = delete;
  Gateway& operator=(const Gateway&) = delete;

  // Subscribes to the client's poses and status and starts the map reader and the workers.
  void start(ViewerHub* hub);
  void stop();
  // What a newly connected viewer gets first: hello, status, trajectories.
  std::vector<OutgoingPtr> welcome(std::uint64_t viewer);
  // A text message from a viewer (docs/viewer.md "Page to gateway").
  void on_message(std::uint64_t viewer, const std::string& text);
  void on_viewer_closed(std::uint64_t viewer);
  GatewayStats stats() const;

 private:
  struct MapCache {
    std::uint64_t version = 0, count = 0;
    OutgoingPtr message;  // the newest version read, as sent
  };
  struct StatusRow {
    StatusUpdate status;
    std::chrono::steady_clock::time_point seen;
  };
  struct PoseRow {
    std::uint64_t frame = 0;
    double t[3], q[4];
    int state = 0;
    bool keyframe = false;
  };
  void read_maps();
  void work();
  // Queues `job` for a worker; false when too many wait (the viewer gets a busy error).
  bool submit(std::uint64_t viewer, std::function<void()> job);
  void reply_error(std::uint64_t viewer, const std::string& type, std::int64_t id,
                   const std::string& error);
  void handle_segment(std::uint64_t viewer, const nlohmann::json& msg);
  void handle_render(std::uint64_t viewer, const nlohmann::json& msg);
  void subscribe(std::uint64_t viewer, const std::string& map);
  OutgoingPtr status_message();
  OutgoingPtr trajectories_message();

  GatewayOptions options_;
  Client* client_;
  ViewerHub* hub_ = nullptr;
  bool stopping_ = false;
  std::thread map_thread_;
  std::vector<std::thread> workers_;

  mutable std::mutex mutex_;  // guards everything below
  std::condition_variable wake_maps_, wake_workers_;
  std::map<std::uint64_t, std::string> subscriptions_;  // viewer -> map it shows
  std::map<std::string, MapCache> maps_;
  std::map<std::pair<std::string, std::string>, StatusRow> status_;  // (session, map)
  std::map<std::string, std::string> session_maps_;                    // session -> map
  std::map<std::string, std::vector<PoseRow>> trajectories_;           // session -> poses
  std::deque<std::function<void()>> jobs_;
  std::map<std::uint64_t, int> pending_;  // viewer -> its requests queued or running
  bool text_queries_ = false;             // a server said it answers text prompts
  GatewayStats stats_;
};

}  // namespace fslam::client::gateway

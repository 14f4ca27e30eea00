#include <csignal>
#include <cstdio>
#include <exception>
#include <memory>
#include <thread>

#include <CLI/CLI.hpp>

#include "fslam/server/config_fields.hpp"
#include "fslam/server/ros2_bridge.hpp"
#include "fslam/server/serve_options.hpp"
#include "fslam/server/server.hpp"

namespace fslam::server {
namespace {
volatile std::sig_atomic_t g_stop = 0;
void on_signal(int) { g_stop = 1; }
}  // namespace

int serve_until_signal(const ServerConfig& config) {
  try {
    // The whole configuration, so a log shows what a session ran with, whatever layers set it.
    std::fprintf(stderr, "fslam-server: effective configuration:\n%s",
                 effective_config_yaml(config).c_str());
    Server server;
    server.set_log([](const std::string& m) { std::fprintf(stderr, "fslam-server: %s\n", m.c_str()); });
    std::string why;
    if (!server.configure(config, &why) || !server.activate(&why)) {
      std::fprintf(stderr, "fslam-server: error: %s\n", why.c_str());
      return 1;
    }
    // ROS 2 camera topics in, ROS 2 poses out (ros2.enabled, docs/ros2.md).
    std::unique_ptr<Ros2Bridge> bridge;
    if (config.ros2.enabled) {
      bridge = std::make_unique<Ros2Bridge>(&server, config);
      bridge->set_log([](const std::string& m) { std::fprintf(stderr, "fslam-server: %s\n", m.c_str()); });
      if (!bridge->start(&why)) {
        std::fprintf(stderr, "fslam-server: error: %s\n", why.c_str());
        bridge.reset();
        server.deactivate();
        return 1;
      }
      std::fprintf(stderr, "fslam-server: %s\n", bridge->describe().c_str());
    }
    g_stop = 0;
    std::signal(SIGINT, on_signal);
    std::signal(SIGTERM, on_signal);
    std::fprintf(stderr,
                 "fslam-server: serving on prefix '%s', frame policy %s by default (queue sessions "
                 "hold %zu frames), %s\n",
                 config.service_prefix().c_str(), config.frame_policy.c_str(), config.queue_capacity,
                 config.map_dir.empty() ? "maps are not kept on disk (no --map-dir)"
                                        : ("maps in " + config.map_dir).c_str());
    while (!g_stop) std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (bridge) bridge->stop_input();
    server.deactivate();  // the bridge still publishes the poses of the frames tracked here
    if (bridge) {
      const Ros2BridgeStats b = bridge->stats();
      std::fprintf(stderr,
                   "fslam-server: ROS 2 bridge: colour %llu, depth %llu, camera info %llu received; frames "
                   "%llu submitted, %llu unpaired, %llu rejected; poses %llu published (%llu keyframes)%s%s\n",
                   static_cast<unsigned long long>(b.colour_received), static_cast<unsigned long long>(b.depth_received),
                   static_cast<unsigned long long>(b.camera_info_received),
                   static_cast<unsigned long long>(b.frames_submitted), static_cast<unsigned long long>(b.unpaired),
                   static_cast<unsigned long long>(b.rejected), static_cast<unsigned long long>(b.poses_published),
                   static_cast<unsigned long long>(b.keyframes), b.last_problem.empty() ? "" : "; last problem: ",
                   b.last_problem.c_str());
      bridge.reset();
    }
    const ServerStats stats = server.stats();
    std::fprintf(stderr,
                 "fslam-server: stopped; frames received %llu, rejected %llu, dropped %llu, poses "
                 "%llu; requests answered %llu, failed %llu\n",
                 static_cast<unsigned long long>(stats.frames_received),
                 static_cast<unsigned long long>(stats.frames_rejected),
                 static_cast<unsigned long long>(stats.frames_dropped),
                 static_cast<unsigned long long>(stats.poses_published),
                 static_cast<unsigned long long>(stats.requests_answered),
                 static_cast<unsigned long long>(stats.requests_failed));
    server.cleanup();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fslam-server: error: %s\n", e.what());
    return 1;
  }
  return 0;
}

bool ServeOptions::resolve(ServerConfig* config_out, std::string* why) const {
  ServerConfig resolved;
  if (!config.apply(&resolved, why) || !resolved.is_valid(why)) return false;
  if (domain >= 0) resolved.domain = static_cast<dds_domainid_t>(domain);
  *config_out = resolved;
  return true;
}

void add_server_options(CLI::App* app, ServeOptions* options) {
  add_config_options(app, &options->config);
  add_setting_option(app, "--prefix", "server.prefix", "Topic prefix", &options->config);
  app->add_option("--domain", options->domain, "DDS domain id (default: Cyclone's default)");
  add_setting_option(app, "--instance", "server.instance",
                     "Scale-out: this instance's name; it serves on <prefix>/<instance>/...",
                     &options->config);
  add_setting_option(app, "--map-group", "server.map_group",
                     "Scale-out: glob of the new map names this instance creates", &options->config);
  add_setting_option(app, "--health-file", "server.health_file",
                     "Rewritten every status period while serving (for probes)", &options->config);
  add_setting_option(app, "--queue", "server.queue_capacity",
                     "Frames queued per session before dropping", &options->config);
  add_setting_option(app, "--map-dir", "server.map_dir",
                     "Keep maps here: serve the saved ones at start, save changed ones at shutdown",
                     &options->config);
  add_setting_option(app, "--query-threads", "server.query_threads",
                     "Render / save / load requests answered in parallel", &options->config);
  add_setting_option(app, "--status-period", "server.status_period_ms",
                     "Milliseconds between status reports per session", &options->config);
}

int serve(const ServeOptions& options) {
  ServerConfig config;
  std::string why;
  if (!options.resolve(&config, &why)) {
    std::fprintf(stderr, "fslam-server: error: %s\n", why.c_str());
    return 1;
  }
  return serve_until_signal(config);
}

}  // namespace fslam::server

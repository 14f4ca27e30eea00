#include <csignal>
#include <cstdio>
#include <exception>
#include <thread>

#include <CLI/CLI.hpp>

#include "fslam/server/server.hpp"

namespace fslam::server {
namespace {
volatile std::sig_atomic_t g_stop = 0;
void on_signal(int) { g_stop = 1; }
}  // namespace

int serve_until_signal(const ServerConfig& config) {
  try {
    Server server;
    server.set_log([](const std::string& m) { std::fprintf(stderr, "fslam-server: %s\n", m.c_str()); });
    std::string why;
    if (!server.configure(config, &why) || !server.activate(&why)) {
      std::fprintf(stderr, "fslam-server: error: %s\n", why.c_str());
      return 1;
    }
    g_stop = 0;
    std::signal(SIGINT, on_signal);
    std::signal(SIGTERM, on_signal);
    std::fprintf(stderr, "fslam-server: serving on prefix '%s', queue %zu frames per session, %s\n",
                 config.prefix.c_str(), config.queue_capacity,
                 config.map_dir.empty() ? "maps are not kept on disk (no --map-dir)"
                                        : ("maps in " + config.map_dir).c_str());
    while (!g_stop) std::this_thread::sleep_for(std::chrono::milliseconds(100));
    server.deactivate();
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

void add_server_options(CLI::App* app, ServerConfig* config, int* domain) {
  app->add_option("--prefix", config->prefix, "Topic prefix")->capture_default_str();
  app->add_option("--domain", *domain, "DDS domain id (default: Cyclone's default)");
  app->add_option("--queue", config->queue_capacity, "Frames queued per session before dropping")
      ->capture_default_str();
  app->add_option("--map-dir", config->map_dir,
                  "Keep maps here: serve the saved ones at start, save changed ones at shutdown");
  app->add_option("--query-threads", config->query_threads, "Render / save / load requests in parallel")
      ->capture_default_str();
  app->add_option("--status-period", config->status_period_ms,
                  "Milliseconds between status reports per session")
      ->capture_default_str();
}

}  // namespace fslam::server

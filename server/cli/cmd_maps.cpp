// Map commands against a running server: `fslam status` (what it serves and how each session is
// doing), `fslam save-map` and `fslam load-map` (persistence under the server's --map-dir).
#include <chrono>
#include <cstdio>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>

#include <CLI/CLI.hpp>

#include "client_args.hpp"
#include "commands.hpp"
#include "fslam/client/client.hpp"

namespace fslam::cli {
namespace {

struct StatusArgs {
  ClientArgs client;
  double seconds = 2.5;  // listen this long: status is published once a second
};

int run_status(const StatusArgs& args) {
  client::Client client(args.client.options());
  std::mutex mutex;
  std::map<std::pair<std::string, std::string>, client::StatusUpdate> latest;
  client.on_status([&](const client::StatusUpdate& s) {
    std::lock_guard<std::mutex> lock(mutex);
    latest[{s.map_name, s.session}] = s;
  });
  std::this_thread::sleep_for(std::chrono::duration<double>(args.seconds));
  std::lock_guard<std::mutex> lock(mutex);
  if (latest.empty()) {
    return fail("no status from a server on prefix '" + args.client.prefix + "' within " +
                std::to_string(args.seconds) + " s (is fslam-server running with that prefix?)");
  }
  std::printf("%-16s %-14s %-6s %9s %8s %8s %9s %9s %5s %8s %8s %31s %8s\n", "map", "session", "policy",
              "gaussians", "version", "tracked", "received", "processed", "queue", "skipped", "dropped",
              "ms p50/p99: decode track map", "rss MiB");
  for (const auto& [key, s] : latest) {
    char timing[64] = "-";
    if (s.streaming) {
      std::snprintf(timing, sizeof timing, "%.0f/%.0f %.0f/%.0f %.0f/%.0f", s.decode_ms_p50,
                    s.decode_ms_p99, s.track_ms_p50, s.track_ms_p99, s.map_ms_p50, s.map_ms_p99);
    }
    std::printf("%-16s %-14s %-6s %9llu %8llu %8llu %9llu %9llu %5u %8llu %8llu %31s %8.0f\n",
                s.map_name.c_str(), s.streaming ? s.session.c_str() : "(idle)",
                s.streaming ? s.frame_policy.c_str() : "-",
                static_cast<unsigned long long>(s.map_gaussians),
                static_cast<unsigned long long>(s.map_version),
                static_cast<unsigned long long>(s.frames_tracked),
                static_cast<unsigned long long>(s.frames_received),
                static_cast<unsigned long long>(s.frames_processed), s.queue_depth,
                static_cast<unsigned long long>(s.frames_skipped),
                static_cast<unsigned long long>(s.frames_dropped), timing,
                static_cast<double>(s.resident_bytes) / (1024.0 * 1024.0));
    if (!s.last_skip_reason.empty()) std::printf("  last skip: %s\n", s.last_skip_reason.c_str());
    if (!s.last_drop_reason.empty()) std::printf("  last drop: %s\n", s.last_drop_reason.c_str());
  }
  return 0;
}

struct MapFileArgs {
  ClientArgs client;
  std::string map;
  std::string folder;  // under the server's map_dir; empty = the map's name
};

int run_save(const MapFileArgs& args) {
  client::Client client(args.client.options());
  std::string why, folder;
  if (!client.save_map(args.map, args.folder, args.client.timeout_ms(), &folder, &why)) return fail(why);
  std::printf("saved map '%s' to %s (on the server)\n", args.map.c_str(), folder.c_str());
  return 0;
}

int run_load(const MapFileArgs& args) {
  client::Client client(args.client.options());
  std::string why;
  if (!client.load_map(args.map, args.folder, args.client.timeout_ms(), &why)) return fail(why);
  std::printf("the server now serves '%s'\n", args.map.c_str());
  return 0;
}

}  // namespace

void add_map_commands(CLI::App& root, CommandList* commands) {
  auto* status = root.add_subcommand("status", "Show the maps and sessions a running server has");
  auto status_args = std::make_shared<StatusArgs>();
  add_client_options(status, &status_args->client);
  status->add_option("--seconds", status_args->seconds, "Listen for status this long")
      ->capture_default_str();
  commands->push_back({status, [status_args] { return run_status(*status_args); }});

  auto* save = root.add_subcommand("save-map", "Save a map on the server (under its --map-dir)");
  auto save_args = std::make_shared<MapFileArgs>();
  add_client_options(save, &save_args->client);
  save->add_option("--map", save_args->map, "The map to save")->required();
  save->add_option("--folder", save_args->folder,
                   "Folder under the server's --map-dir (default: the map's name)");
  commands->push_back({save, [save_args] { return run_save(*save_args); }});

  auto* load = root.add_subcommand("load-map", "Load a saved map on the server and serve it");
  auto load_args = std::make_shared<MapFileArgs>();
  add_client_options(load, &load_args->client);
  load->add_option("--map", load_args->map, "The name to serve it as")->required();
  load->add_option("--folder", load_args->folder,
                   "Folder under the server's --map-dir (default: the map's name)");
  commands->push_back({load, [load_args] { return run_load(*load_args); }});
}

}  // namespace fslam::cli

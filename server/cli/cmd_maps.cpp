// Map commands against running servers: `fslam status` (what they serve and how each session is
// doing), `fslam maps` (the deployment's map directory: which instance serves which map),
// `fslam save-map` and `fslam load-map` (persistence under a server's --map-dir).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <set>
#include <vector>
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
#include "fslam/client/map_directory.hpp"

namespace fslam::cli {
namespace {

struct StatusArgs {
  ClientArgs client;
  double seconds = 2.5;  // listen this long: status is published once a second
};

// The service prefixes of the deployment's instances (one with --instance), discovered within
// timeout_ms.
std::set<std::string> service_prefixes(const ClientArgs& args, int timeout_ms) {
  const client::MapDirectory directory(args.prefix, DDS_DOMAIN_DEFAULT);
  std::set<std::string> prefixes;
  for (const client::MapClaimInfo& e : directory.discover(args.discovery.settle_ms, timeout_ms)) {
    if (e.map_name.empty() && (args.discovery.instance.empty() || e.instance == args.discovery.instance)) {
      prefixes.insert(e.service_prefix);
    }
  }
  return prefixes;
}

int run_status(const StatusArgs& args) {
  // Declared before the clients: their listener threads call the callback until they are
  // destroyed (client.hpp).
  std::mutex mutex;
  std::map<std::pair<std::string, std::string>, client::StatusUpdate> latest;
  // One client per instance: each serves its status on its own prefix.
  std::vector<std::unique_ptr<client::Client>> clients;
  // As before the map directory: no server within --seconds is "no status".
  const int discovery_ms = std::max(500, static_cast<int>(args.seconds * 1000.0));
  for (const std::string& prefix : service_prefixes(args.client, discovery_ms)) {
    client::ClientOptions options;
    options.prefix = prefix;
    clients.push_back(std::make_unique<client::Client>(options));
  }
  for (auto& client : clients) {
    client->on_status([&](const client::StatusUpdate& s) {
      std::lock_guard<std::mutex> lock(mutex);
      latest[{s.map_name, s.session}] = s;
    });
  }
  std::this_thread::sleep_for(std::chrono::duration<double>(args.seconds));
  std::lock_guard<std::mutex> lock(mutex);
  if (latest.empty()) {
    char seconds[32];
    std::snprintf(seconds, sizeof seconds, "%g", args.seconds);
    return fail("no status from a server on prefix '" + args.client.prefix + "' within " + seconds +
                " s (is fslam-server running with that prefix?)");
  }
  std::printf("%-16s %-14s %-8s %-6s %9s %8s %8s %9s %9s %5s %8s %8s %40s %8s\n", "map", "session", "mode", "policy",
              "gaussians", "version", "tracked", "received", "processed", "queue", "skipped", "dropped",
              "ms p50/p99: decode track (cpu) map", "rss MiB");
  for (const auto& [key, s] : latest) {
    // A session's report (a localise session's map may have no streaming session of its own).
    const bool session = !s.session.empty();
    char timing[96] = "-";
    if (session) {
      std::snprintf(timing, sizeof timing, "%.0f/%.0f %.0f/%.0f (%.0f/%.0f) %.0f/%.0f", s.decode_ms_p50,
                    s.decode_ms_p99, s.track_ms_p50, s.track_ms_p99, s.track_cpu_ms_p50,
                    s.track_cpu_ms_p99, s.map_ms_p50, s.map_ms_p99);
    }
    std::printf("%-16s %-14s %-8s %-6s %9llu %8llu %8llu %9llu %9llu %5u %8llu %8llu %40s %8.0f\n",
                s.map_name.c_str(), session ? s.session.c_str() : "(idle)",
                session ? s.mode.c_str() : "-", session ? s.frame_policy.c_str() : "-",
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
    if (s.loop_closure) std::printf("  loop closure: %u loop(s) closed\n", s.loops_closed);
    if (s.keyframes_left_out > 0) {
      std::printf("  mapping behind: %u keyframes waiting, %llu left out of the map (max_queued_keyframes)\n",
                  s.mapping_queue, static_cast<unsigned long long>(s.keyframes_left_out));
    }
  }
  return 0;
}

struct MapFileArgs {
  ClientArgs client;
  std::string map;
  std::string folder;  // under the server's map_dir; empty = the map's name
};

int run_save(const MapFileArgs& args) {
  std::string why, folder;
  client::ClientOptions options;
  if (!args.client.locate(args.map, false, &options, &why)) return fail(why);
  client::Client client(options);
  if (!client.save_map(args.map, args.folder, args.client.timeout_ms(), &folder, &why)) return fail(why);
  std::printf("saved map '%s' to %s (on the server)\n", args.map.c_str(), folder.c_str());
  return 0;
}

int run_load(const MapFileArgs& args) {
  std::string why;
  // A map no instance serves yet goes where a new map of that name would (or to --instance).
  client::ClientOptions options;
  if (!args.client.locate(args.map, true, &options, &why)) return fail(why);
  client::Client client(options);
  if (!client.load_map(args.map, args.folder, args.client.timeout_ms(), &why)) return fail(why);
  std::printf("the server now serves '%s'\n", args.map.c_str());
  return 0;
}

struct RefineArgs {
  ClientArgs client;
  std::string map;
  std::uint32_t steps = 500;
};

int run_refine(const RefineArgs& args) {
  std::string why;
  client::ClientOptions options;
  if (!args.client.locate(args.map, false, &options, &why)) return fail(why);
  client::Client client(options);
  if (!client.refine_map(args.map, args.steps, args.client.timeout_ms(), &why)) return fail(why);
  std::printf("refined map '%s' on the server: %u steps\n", args.map.c_str(), args.steps);
  return 0;
}

struct DirectoryArgs {
  ClientArgs client;
};

int run_maps(const DirectoryArgs& args) {
  const client::MapDirectory directory(args.client.prefix, DDS_DOMAIN_DEFAULT);
  const std::vector<client::MapClaimInfo> entries =
      directory.discover(args.client.discovery.settle_ms, args.client.timeout_ms());
  std::map<std::string, client::MapClaimInfo> records;
  std::map<std::string, std::vector<client::MapClaimInfo>> claims;  // map -> claims, holder first
  for (const client::MapClaimInfo& e : entries) {
    if (e.map_name.empty()) records[e.instance] = e;
    else claims[e.map_name].push_back(e);
  }
  if (records.empty()) {
    return fail("no featureslam server found on prefix '" + args.client.prefix + "'");
  }
  std::printf("%-24s %-32s %s\n", "instance", "serves on prefix", "creates new maps matching");
  for (const auto& [name, r] : records) {
    std::printf("%-24s %-32s %s\n", name.c_str(), r.service_prefix.c_str(),
                r.map_group.empty() ? "(none)" : r.map_group.c_str());
  }
  std::printf("\n%-24s %-24s %s\n", "map", "instance", "claimed (UTC)");
  for (auto& [map, list] : claims) {
    std::sort(list.begin(), list.end(), client::claim_precedes);
    for (std::size_t i = 0; i < list.size(); ++i) {
      const std::time_t t = static_cast<std::time_t>(list[i].claimed_at_ns / 1000000000ull);
      char when[32];
      std::strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&t));
      std::printf("%-24s %-24s %s%s\n", map.c_str(), list[i].instance.c_str(), when,
                  i == 0 ? "" : "  (giving it up: claimed later)");
    }
  }
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

  auto* maps = root.add_subcommand("maps", "Show the map directory: server instances and the maps each serves");
  auto maps_args = std::make_shared<DirectoryArgs>();
  add_client_options(maps, &maps_args->client);
  commands->push_back({maps, [maps_args] { return run_maps(*maps_args); }});

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

  auto* refine = root.add_subcommand(
      "refine-map", "Post-trajectory refinement of a map the server streamed (no session streaming into it)");
  auto refine_args = std::make_shared<RefineArgs>();
  add_client_options(refine, &refine_args->client);
  refine->add_option("--map", refine_args->map, "The map to refine")->required();
  refine->add_option("--steps", refine_args->steps, "Gradient steps (at most the server's server.max_refine_steps)")
      ->capture_default_str();
  commands->push_back({refine, [refine_args] { return run_refine(*refine_args); }});
}

}  // namespace fslam::cli

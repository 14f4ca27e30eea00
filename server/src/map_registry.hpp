// The maps a server serves, by name: built by a streaming session or loaded from disk, found by
// queries, saved and loaded under server.map_dir (map_files.hpp), given up when another instance
// holds them (map_directory.hpp), and bounded by server.max_maps.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "fslam/core/pipeline/slam_pipeline.hpp"
#include "fslam/core/segmentation/instances.hpp"
#include "fslam/server/map_export.hpp"
#include "fslam/server/map_files.hpp"
#include "fslam/server/server.hpp"

namespace fslam::server {

// A map the server serves: built by a streaming session (pipeline) or loaded from disk (loaded).
// Kept after its session closes, so that it can still be queried and saved.
struct MapEntry {
  std::string name;
  std::shared_ptr<core::SlamPipeline> pipeline;  // null for a loaded map
  core::MapVersions loaded;
  std::mutex mutex;  // guards everything below
  core::PinholeCamera camera;  // of the frames streamed into it; width 0 before the first
  std::vector<FramePose> poses;
  std::unordered_map<std::uint64_t, std::size_t> pose_index;  // frame id -> poses[]
  bool streaming = false;
  std::pair<std::uint64_t, std::size_t> saved{0, 0};  // (version, poses) last saved at home
  bool refining = false;  // MapRegistry::refine runs on its pipeline
  // Held while clustering (apart from `mutex`, which tracking takes per frame), so that each
  // clustering carries its ids from the one before: ids form one chain over the versions.
  std::mutex instances_mutex;
  core::InstanceLabelCache instances;  // guarded by instances_mutex
  MapExporter exporter;                // versions that chunked exports read (map_export.hpp)

  // A loaded map's keyframe descriptions (map_files.hpp keyframes.bin); null: none saved.
  std::shared_ptr<const std::vector<core::DescribedKeyframe>> loaded_keyframes;
  // A loaded map's online feature heads (map_files.hpp heads.fae); null: none saved.
  std::shared_ptr<const core::FeatureAutoencoder> loaded_heads;
  // A loaded map's keyframe_images.bin (map_files.hpp), read when the map is refined or
  // extended; empty: none saved. Set at load and never changed.
  std::string loaded_keyframe_images_file;

  core::MapVersions& versions() { return pipeline ? pipeline->mapper().versions() : loaded; }
  // The keyframes a session can relocalise against: those the streaming pipeline described so
  // far, or the loaded ones (null or empty: none).
  std::shared_ptr<const std::vector<core::DescribedKeyframe>> keyframes() const {
    if (!pipeline) return loaded_keyframes;
    return std::make_shared<const std::vector<core::DescribedKeyframe>>(pipeline->described_keyframes());
  }
  // The heads the map's latents were fitted through: the streaming pipeline's online ones as of
  // its newest version, or the loaded ones (null: none, as without the decoded L_feat).
  std::shared_ptr<const core::FeatureAutoencoder> heads() const {
    return pipeline ? pipeline->feature_heads() : loaded_heads;
  }
  // The images of the keyframes the map was mapped from, as of its newest version: the streaming
  // pipeline's mapper's, or those saved with a loaded map, read from its file (empty: none).
  // False with `why` when that file cannot be read.
  bool keyframe_images(std::vector<core::KeyframeImages>* images, std::string* why) const;
};

class MapRegistry {
 public:
  using Log = std::function<void(const std::string&)>;
  // `config` must outlive the registry.
  MapRegistry(const ServerConfig& config, Log log) : config_(config), log_(std::move(log)) {}

  // The instance's membership of the map directory while it serves (null: none, as at start):
  // every map it holds is claimed there, and a new one only when the claim rule allows.
  void set_directory(MapDirectoryMember* directory);

  std::shared_ptr<MapEntry> find(const std::string& name) const;
  std::size_t count() const;
  std::map<std::string, std::shared_ptr<MapEntry>> all() const;
  // The maps no session streams into.
  std::vector<std::shared_ptr<MapEntry>> idle() const;

  // A new map for a streaming session, its pipeline made by `make_pipeline` once the name is
  // free, within server.max_maps and claimable; null with `why` otherwise.
  std::shared_ptr<MapEntry> open_streaming(
      const std::string& name,
      const std::function<std::shared_ptr<core::SlamPipeline>(std::string* why)>& make_pipeline,
      std::string* why);
  // A served map no session streams into, for a session that extends it: a new entry that takes
  // over its poses, camera and save state, with the pipeline `make_pipeline` makes from the old
  // one, and replaces it (queries and localise sessions that hold the old entry keep it; new
  // queries see the map grow). Null with `why` when there is no such map or it streams.
  std::shared_ptr<MapEntry> open_extending(
      const std::string& name,
      const std::function<std::shared_ptr<core::SlamPipeline>(MapEntry& old, std::string* why)>& make_pipeline,
      std::string* why);
  // Post-trajectory refinement of `map` (docs/protocol.md "Refinement"): `steps` steps of its
  // pipeline's mapper over the keyframes it stored, then a new version; a loaded map (no
  // pipeline) is refined by a mapper of the server's settings over the keyframe images saved
  // with it. Needs keyframe images (a map saved before they were has none), no streaming
  // session and no other refinement running; steps within server.max_refine_steps. Stops early,
  // saying so, once stop_refining() was called. False with `why` otherwise.
  bool refine(MapEntry& map, std::uint32_t steps, std::string* why);
  // Refinements running, and any asked for from now on, stop within a step (shutdown); and again
  // allowed.
  void stop_refining() { stop_refining_ = true; }
  void allow_refining() { stop_refining_ = false; }
  // Stops serving `name` (queries in flight keep the version they hold; nothing is saved).
  void withdraw(const std::string& name);

  // Loads the map saved in `folder` as `name`, replacing a map of that name without a session.
  bool load(const std::string& name, const std::string& folder, std::string* why);
  // Saves the newest version of `map` to `folder`; a save to its home folder marks it saved.
  bool save(MapEntry& map, const std::string& folder, std::string* why);
  // At start: makes server.map_dir and, with server.load_maps_at_start, loads every map saved
  // there (after finishing saves a kill interrupted); bad folders are logged and skipped.
  // False with `why` when map_dir cannot be made.
  bool load_saved_maps(std::string* why);
  // At shutdown: saves every map changed since its last save to its home folder, logging each.
  void save_changed_maps();

 private:
  // server.min_free_disk_mb: room on map_dir's disk for a save of `stored` and the reserve.
  bool enough_disk_for(const StoredMap& stored, std::string* why) const;
  // refine() of a loaded map: a mapper over its saved keyframe images.
  bool refine_loaded(MapEntry& map, std::uint32_t steps, std::string* why);
  void log(const std::string& message) const {
    if (log_) log_(message);
  }

  const ServerConfig& config_;
  Log log_;
  mutable std::mutex mutex_;  // guards everything below
  std::map<std::string, std::shared_ptr<MapEntry>> maps_;
  MapDirectoryMember* directory_ = nullptr;
  std::atomic<bool> stop_refining_{false};
};

}  // namespace fslam::server

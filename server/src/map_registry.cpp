#include "map_registry.hpp"

#include <filesystem>
#include <set>

#include "fslam/core/error.hpp"
#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/keyframe_images_file.hpp"
#include "fslam/server/backend_factory.hpp"
#include "fslam/server/map_directory.hpp"

namespace fslam::server {

bool MapEntry::keyframe_images(std::vector<core::KeyframeImages>* images, std::string* why) const {
  images->clear();
  if (pipeline) {
    *images = *pipeline->mapper().published_keyframe_images();
    return true;
  }
  return loaded_keyframe_images_file.empty() || core::read_keyframe_images_file(loaded_keyframe_images_file, images, why);
}

void MapRegistry::set_directory(MapDirectoryMember* directory) {
  std::lock_guard<std::mutex> lock(mutex_);
  directory_ = directory;
  if (directory_) {
    for (const auto& [name, map] : maps_) directory_->claim(name);
  }
}

std::shared_ptr<MapEntry> MapRegistry::find(const std::string& name) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = maps_.find(name);
  return it == maps_.end() ? nullptr : it->second;
}

std::size_t MapRegistry::count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return maps_.size();
}

std::map<std::string, std::shared_ptr<MapEntry>> MapRegistry::all() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return maps_;
}

std::vector<std::shared_ptr<MapEntry>> MapRegistry::idle() const {
  std::vector<std::shared_ptr<MapEntry>> idle;
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [name, map] : maps_) {
    std::lock_guard<std::mutex> mlock(map->mutex);
    if (!map->streaming) idle.push_back(map);
  }
  return idle;
}

std::shared_ptr<MapEntry> MapRegistry::open_streaming(
    const std::string& name,
    const std::function<std::shared_ptr<core::SlamPipeline>(std::string* why)>& make_pipeline,
    std::string* why) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (maps_.size() >= config_.max_maps) {
    core::fail(why, "the server holds its limit of " + std::to_string(config_.max_maps) +
                        " maps (server.max_maps)");
    return nullptr;
  }
  if (maps_.count(name) != 0) {
    core::fail(why, "map '" + name + "' exists; stream into a new map name, or extend or localise "
                    "in this one (session modes, docs/protocol.md)");
    return nullptr;
  }
  if (directory_ && !directory_->may_claim(name, true, why)) return nullptr;
  std::shared_ptr<core::SlamPipeline> pipeline = make_pipeline(why);
  if (!pipeline) return nullptr;
  auto map = std::make_shared<MapEntry>();
  map->name = name;
  map->pipeline = std::move(pipeline);
  map->streaming = true;
  maps_[name] = map;
  if (directory_) directory_->claim(name);
  return map;
}

std::shared_ptr<MapEntry> MapRegistry::open_extending(
    const std::string& name,
    const std::function<std::shared_ptr<core::SlamPipeline>(MapEntry& old, std::string* why)>& make_pipeline,
    std::string* why) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = maps_.find(name);
  if (it == maps_.end()) {
    core::fail(why, "no map named '" + name + "' to extend (load it or stream it first)");
    return nullptr;
  }
  MapEntry& old = *it->second;
  auto map = std::make_shared<MapEntry>();
  map->name = name;
  {
    std::lock_guard<std::mutex> mlock(old.mutex);
    if (old.streaming || old.refining) {
      core::fail(why, "map '" + name + "' has " + (old.streaming ? "a streaming session" : "a refinement running") +
                          "; extend it once that is done (or localise in it)");
      return nullptr;
    }
    map->camera = old.camera;
    map->poses = old.poses;
    map->pose_index = old.pose_index;
    map->saved = old.saved;
  }
  map->pipeline = make_pipeline(old, why);
  if (!map->pipeline) return nullptr;
  map->streaming = true;
  it->second = map;
  return map;
}

bool MapRegistry::refine(MapEntry& map, std::uint32_t steps, std::string* why) {
  const std::string what = "refine map '" + map.name + "': ";
  if (steps == 0 || steps > config_.max_refine_steps) {
    return core::fail(why, what + "steps must be 1 to " + std::to_string(config_.max_refine_steps) +
                               " (server.max_refine_steps), not " + std::to_string(steps));
  }
  std::shared_ptr<core::SlamPipeline> pipeline;
  {
    std::lock_guard<std::mutex> lock(map.mutex);
    if (!map.pipeline && map.loaded_keyframe_images_file.empty()) {
      return core::fail(why, what + "it was loaded from a folder without keyframe images (keyframe_images.bin: "
                                    "saved before they were), and refinement needs the images it was mapped from");
    }
    if (map.streaming) {
      return core::fail(why, what + "it has a streaming session; refine when it closes (SESSION_CLOSE "
                                    "refine_steps, fslam stream --refine)");
    }
    if (map.refining) return core::fail(why, what + "a refinement of it is running");
    map.refining = true;
    pipeline = map.pipeline;  // null: a loaded map (refine_loaded)
  }
  std::string reason;
  const bool ok = pipeline ? pipeline->refine(static_cast<int>(steps), &reason, nullptr, &stop_refining_)
                           : refine_loaded(map, steps, &reason);
  {
    std::lock_guard<std::mutex> lock(map.mutex);
    map.refining = false;
  }
  if (!ok) return core::fail(why, what + reason);
  log("refined map '" + map.name + "': " + std::to_string(steps) + " steps");
  return true;
}

void MapRegistry::withdraw(const std::string& name) {
  std::lock_guard<std::mutex> lock(mutex_);
  maps_.erase(name);
}

bool MapRegistry::refine_loaded(MapEntry& map, std::uint32_t steps, std::string* why) {
  // The server's mapper settings, its SH degree and feature width the map's; no feature decoder:
  // the saved keyframes carry no feature targets, so the steps fit colour and geometry and leave
  // the distilled latents as they are (Mapper::restore_keyframes).
  const core::MapVersions::Version version = map.loaded.latest();
  core::MapperConfig config = config_.pipeline.mapper;
  config.sh_degree = version->sh_degree;
  config.feature_dim = version->feature_dim;
  std::string notice;
  std::shared_ptr<const core::Rasterizer> rasterizer =
      make_rasterizer(config_.compute.backend, RasterUse::kMapping, &notice, why);
  if (!rasterizer) return false;
  std::vector<core::KeyframeImages> images;
  if (!map.keyframe_images(&images, why)) return false;
  core::Mapper mapper(config, std::move(rasterizer));
  if (!mapper.set_map(*version, why) || !mapper.restore_keyframes(images, why)) return false;
  const bool ok = mapper.refine(static_cast<int>(steps), why, nullptr, &stop_refining_);
  // What was done is published either way (refine publishes the steps done before a stop).
  map.loaded.publish(mapper.versions().latest());
  return ok;
}

bool MapRegistry::load(const std::string& name, const std::string& folder, std::string* why) {
  if (!valid_map_name(name, why)) return false;
  StoredMap stored;
  if (!load_map_folder(folder, &stored, why)) return false;
  auto map = std::make_shared<MapEntry>();
  map->name = name;
  map->loaded.publish(stored.gaussians);
  map->camera = stored.camera;
  map->poses = std::move(stored.poses);
  map->loaded_keyframes = std::move(stored.keyframes);
  map->loaded_heads = std::move(stored.heads);
  map->loaded_keyframe_images_file = stored.keyframe_images_file;
  for (std::size_t i = 0; i < map->poses.size(); ++i) map->pose_index[map->poses[i].frame_id] = i;
  map->saved = {map->loaded.version_number(), map->poses.size()};
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = maps_.find(name);
  if (it != maps_.end()) {
    std::lock_guard<std::mutex> mlock(it->second->mutex);
    if (it->second->streaming) {
      return core::fail(why, "load map: map '" + name + "' has a streaming session; close it first");
    }
  }
  if (it == maps_.end() && maps_.size() >= config_.max_maps) {
    return core::fail(why, "load map: the server holds its limit of " + std::to_string(config_.max_maps) +
                               " maps (server.max_maps)");
  }
  // At start the directory does not exist yet: set_directory claims every loaded map.
  if (directory_ && !directory_->may_claim(name, false, why)) return false;
  maps_[name] = map;  // queries in flight keep the version they hold
  if (directory_) directory_->claim(name);
  return true;
}

bool MapRegistry::enough_disk_for(const StoredMap& stored, std::string* why) const {
  std::error_code ec;
  const std::filesystem::space_info space = std::filesystem::space(config_.map_dir, ec);
  if (ec) return true;  // the save itself then says what is wrong with the folder
  // map.ply, and poses.txt + trajectory.txt at under 200 bytes a line each (format_poses);
  // keyframes.bin at ~25 KB a keyframe (500 ORB keypoints of 44 bytes, a 768-value thumbnail).
  const std::uint64_t keyframes = stored.keyframes ? stored.keyframes->size() : 0;
  // heads.fae: its parameters and the normalisation as f32, names and shapes under 4 KB.
  const std::uint64_t heads =
      stored.heads ? 4 * (stored.heads->parameters().size() + 2 * stored.heads->input_mean().size()) + 4096 : 0;
  // keyframe_images.bin: the PNGs at level 1, at most 3 bytes a pixel for colour and 2 for depth.
  std::uint64_t images = 0;
  if (stored.keyframe_images) {
    for (const core::KeyframeImages& k : *stored.keyframe_images) images += 5 * k.colour.total() + 4096;
  } else if (!stored.keyframe_images_file.empty()) {
    images = std::filesystem::file_size(stored.keyframe_images_file, ec);  // copied as it is
    if (ec) images = 0;
  }
  const std::uint64_t needed = core::gaussian_ply_bytes(*stored.gaussians) + 400 * stored.poses.size() +
                               32768 * keyframes + heads + images + 4096;
  const std::uint64_t reserve = static_cast<std::uint64_t>(config_.min_free_disk_mb) << 20;
  if (space.available >= needed + reserve) return true;
  const auto mib = [](std::uint64_t bytes) { return std::to_string((bytes + (1 << 20) - 1) >> 20); };
  return core::fail(why, "save map: " + mib(space.available) + " MiB free on the disk of " + config_.map_dir +
                             "; the save needs " + mib(needed) + " MiB and server.min_free_disk_mb keeps " +
                             std::to_string(config_.min_free_disk_mb) + " MiB free");
}

bool MapRegistry::save(MapEntry& map, const std::string& folder, std::string* why) {
  StoredMap stored;
  std::pair<std::uint64_t, std::size_t> state;
  {
    std::lock_guard<std::mutex> lock(map.mutex);
    state = {map.versions().version_number(), map.poses.size()};
    stored.gaussians = map.versions().latest();
    stored.camera = map.camera;
    stored.poses = map.poses;
  }
  stored.keyframes = map.keyframes();
  stored.heads = map.heads();
  if (map.pipeline) stored.keyframe_images = map.pipeline->mapper().published_keyframe_images();
  stored.keyframe_images_file = map.loaded_keyframe_images_file;
  if (!enough_disk_for(stored, why)) return false;
  if (!save_map_folder(folder, stored, why)) return false;
  // Only a save to the map's own folder (the one a restart loads it from) counts as saved.
  std::string home, ignored;
  if (resolve_map_folder(config_.map_dir, "", map.name, &home, &ignored) && home == folder) {
    std::lock_guard<std::mutex> lock(map.mutex);
    map.saved = state;
  }
  return true;
}

bool MapRegistry::load_saved_maps(std::string* why) {
  if (config_.map_dir.empty()) return true;
  std::error_code ec;
  std::filesystem::create_directories(config_.map_dir, ec);
  if (ec) return core::fail(why, "map_dir " + config_.map_dir + ": " + ec.message());
  if (!config_.load_maps_at_start) return true;
  // A save killed half-way left `.NAME.saving` / `.NAME.old` beside NAME: whole versions
  // first (map_files.hpp), then every map folder. One bad folder is reported and skipped:
  // the other maps are still served.
  std::set<std::string> interrupted;
  for (const auto& entry : std::filesystem::directory_iterator(config_.map_dir, ec)) {
    const std::string hidden = entry.path().filename().string();
    for (const std::string suffix : {".saving", ".old"}) {
      if (hidden.size() > suffix.size() + 1 && hidden[0] == '.' &&
          hidden.compare(hidden.size() - suffix.size(), suffix.size(), suffix) == 0) {
        interrupted.insert(hidden.substr(1, hidden.size() - suffix.size() - 1));
      }
    }
  }
  for (const std::string& name : interrupted) {
    std::string note;
    recover_map_folder((std::filesystem::path(config_.map_dir) / name).string(), &note);
    if (!note.empty()) log(note);
  }
  for (const auto& entry : std::filesystem::directory_iterator(config_.map_dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.empty() || name[0] == '.') continue;  // a save's staging, or not ours
    if (!entry.is_directory() || !is_map_folder(entry.path().string())) continue;
    std::string invalid;
    if (!valid_map_name(name, &invalid)) {
      log("skipped map folder " + entry.path().string() + ": " + invalid);
      continue;
    }
    std::string load_why;
    if (load(name, entry.path().string(), &load_why)) {
      log("loaded map '" + name + "' from " + entry.path().string() + " (" +
          std::to_string(find(name)->loaded.latest()->size()) + " Gaussians)");
    } else {
      log("skipped map folder " + entry.path().string() + ": " + load_why);
    }
  }
  return true;
}

void MapRegistry::save_changed_maps() {
  for (auto& [name, map] : all()) {
    std::string folder, why;
    {
      std::lock_guard<std::mutex> lock(map->mutex);
      if (map->saved == std::make_pair(map->versions().version_number(), map->poses.size())) continue;
    }
    if (resolve_map_folder(config_.map_dir, "", name, &folder, &why) && save(*map, folder, &why)) {
      log("saved map '" + name + "' to " + folder);
    } else {
      log("could not save map '" + name + "': " + why);
    }
  }
}

}  // namespace fslam::server

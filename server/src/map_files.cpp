#include "fslam/server/map_files.hpp"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <system_error>
#include <thread>

#include "fslam/core/error.hpp"
#include "fslam/core/io/file_writer.hpp"
#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/keyframe_file.hpp"
#include "fslam/core/io/keyframe_images_file.hpp"
#include "fslam/core/io/text_tables.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::server {
namespace fs = std::filesystem;

namespace {

std::string format_poses(const std::vector<FramePose>& poses) {
  std::string text = "# frame_id timestamp tx ty tz qx qy qz qw (camera-to-world)\n";
  char line[480];
  for (const FramePose& p : poses) {
    const Eigen::Quaterniond q(p.T_world_camera.rotation());
    const Eigen::Vector3d t = p.T_world_camera.translation();
    std::snprintf(line, sizeof line, "%llu %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n",
                  static_cast<unsigned long long>(p.frame_id), p.timestamp, t.x(), t.y(), t.z(),
                  q.x(), q.y(), q.z(), q.w());
    text += line;
  }
  return text;
}

}  // namespace

bool is_map_folder(const std::string& dir) {
  std::error_code ec;
  return fs::is_regular_file(fs::path(dir) / "map.ply", ec);
}

namespace {

// The save's staging and previous-version folders beside `dir`: hidden names, which no map name
// can take (valid_map_name), so that saving map X never touches a map or folder of the user's.
fs::path staging_of(const fs::path& dir) { return dir.parent_path() / ("." + dir.filename().string() + ".saving"); }
fs::path previous_of(const fs::path& dir) { return dir.parent_path() / ("." + dir.filename().string() + ".old"); }
// Written last into the staging folder: a staging folder without it is half a save.
constexpr const char* kCompleteMarker = ".complete";
constexpr const char* kKeyframeFile = "keyframes.bin";
constexpr const char* kHeadsFile = "heads.fae";
constexpr const char* kKeyframeImagesFile = "keyframe_images.bin";

// Fault tests only (tests/integration/save_kill_test.sh): FSLAM_FAULT_SAVE_PAUSE_MS widens the
// steps of the swap so that a kill lands inside them; unset (always, in use) it costs nothing.
void fault_pause() {
  static const int ms = [] {
    const char* v = std::getenv("FSLAM_FAULT_SAVE_PAUSE_MS");
    return v != nullptr ? std::atoi(v) : 0;
  }();
  if (ms > 0) std::this_thread::sleep_for(std::chrono::milliseconds(ms));
}

}  // namespace

bool valid_map_name(const std::string& name, std::string* why) {
  if (name.empty() || name.size() > 128) return core::fail(why, "map name must be 1-128 characters");
  if (name[0] == '.') return core::fail(why, "map name '" + name + "' may not start with '.'");
  for (const char c : name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '-' || c == '_' || c == '.';
    if (!ok) {
      return core::fail(why, "map name '" + name + "' may hold only letters, digits, '-', '_' and '.' "
                             "(it names the map's folder on disk)");
    }
  }
  return true;
}

bool recover_map_folder(const std::string& dir, std::string* note) {
  const fs::path target(dir), staging = staging_of(target), old = previous_of(target);
  std::error_code ec;
  note->clear();
  if (is_map_folder(dir)) {
    // A save that was killed before the swap, or after it but before the old version was removed.
    if (fs::exists(staging, ec) || fs::exists(old, ec)) *note = "removed an interrupted save's leftovers beside " + dir;
    fs::remove_all(staging, ec);
    fs::remove_all(old, ec);
    return true;
  }
  if (fs::exists(staging / kCompleteMarker, ec) && !fs::exists(target, ec)) {
    // Killed between moving the old version aside and moving the new one in: the new is whole.
    fs::rename(staging, target, ec);
    if (!ec) {
      fs::remove_all(old, ec);
      *note = "finished an interrupted save of " + dir;
      return true;
    }
  }
  if (fs::exists(old / "map.ply", ec) && !fs::exists(target, ec)) {
    fs::rename(old, target, ec);
    if (!ec) {
      fs::remove_all(staging, ec);
      *note = "restored the previous version of " + dir + " (an interrupted save had not finished writing)";
      return true;
    }
  }
  return is_map_folder(dir);
}

namespace {

// A loaded map's keyframe_images.bin into a save's staging folder, as it is. A source that is gone
// (its folder removed behind the server's back) leaves the map saved without them: the map itself
// matters more than being able to refine it.
bool copy_keyframe_images(const std::string& source, const fs::path& target, std::string* why) {
  std::error_code ec;
  if (source.empty() || !fs::exists(source, ec)) return true;
  fs::copy_file(source, target, fs::copy_options::overwrite_existing, ec);
  if (ec) return core::fail(why, "cannot copy " + source + ": " + ec.message());
  return true;
}

}  // namespace

bool save_map_folder(const std::string& dir, const StoredMap& map, std::string* why) {
  if (!map.gaussians) return core::fail(why, "save map: no map");
  const fs::path target(dir), staging = staging_of(target), old = previous_of(target);
  std::error_code ec;
  std::string note;
  recover_map_folder(dir, &note);  // a crash of an earlier save: whole versions only
  fs::remove_all(staging, ec);
  if (!fs::create_directories(staging, ec) && ec) {
    return core::fail(why, "save map: cannot create " + staging.string() + ": " + ec.message());
  }
  core::Trajectory trajectory;
  for (const FramePose& p : map.poses) trajectory.push_back({p.timestamp, p.T_world_camera});
  char camera[256];
  std::snprintf(camera, sizeof camera, "# fx fy cx cy width height\n%.9g %.9g %.9g %.9g %d %d\n",
                map.camera.fx, map.camera.fy, map.camera.cx, map.camera.cy, map.camera.width,
                map.camera.height);
  if (!core::write_gaussian_ply((staging / "map.ply").string(), *map.gaussians, why) ||
      !core::write_file((staging / "poses.txt").string(), format_poses(map.poses), why) ||
      !core::write_tum_trajectory((staging / "trajectory.txt").string(), trajectory, why) ||
      !core::write_file((staging / "camera.txt").string(), camera, why) ||
      (map.keyframes && !map.keyframes->empty() &&
       !core::write_keyframe_file((staging / kKeyframeFile).string(), *map.keyframes, why)) ||
      (map.heads && !map.heads->save((staging / kHeadsFile).string(), why)) ||
      (map.keyframe_images && !map.keyframe_images->empty() &&
       !core::write_keyframe_images_file((staging / kKeyframeImagesFile).string(), *map.keyframe_images, why)) ||
      (!map.keyframe_images && !copy_keyframe_images(map.keyframe_images_file, staging / kKeyframeImagesFile, why)) ||
      !core::write_file((staging / kCompleteMarker).string(), "", why) || !core::sync_directory(staging.string(), why)) {
    // A full disk lands here ("No space left on device"): the previous version is untouched.
    fs::remove_all(staging, ec);
    if (why) *why = "save map: " + *why;
    return false;
  }
  // Swap in. At every point a kill leaves a whole version that recover_map_folder finds: the
  // target (old or new), else the complete staging folder, else the old one moved aside.
  fs::remove_all(old, ec);
  fault_pause();
  if (fs::exists(target)) fs::rename(target, old, ec);
  if (ec) return core::fail(why, "save map: cannot move the previous " + dir + " aside: " + ec.message());
  fault_pause();
  fs::rename(staging, target, ec);
  if (ec) return core::fail(why, "save map: cannot rename into " + dir + ": " + ec.message());
  fs::remove_all(old, ec);
  // The renames reach the disk before the save is reported done.
  return core::sync_directory(target.has_parent_path() ? target.parent_path().string() : ".", why);
}

bool load_map_folder(const std::string& dir, StoredMap* map, std::string* why) {
  const fs::path folder(dir);
  if (!is_map_folder(dir)) return core::fail(why, "load map: " + dir + " holds no map.ply");
  auto gaussians = std::make_shared<core::GaussianMap>();
  if (!core::read_gaussian_ply((folder / "map.ply").string(), gaussians.get(), why)) return false;
  StoredMap loaded;
  loaded.gaussians = std::move(gaussians);
  std::vector<core::NumberRow> rows;
  if (fs::exists(folder / "camera.txt")) {
    if (!core::read_number_rows((folder / "camera.txt").string(), &rows, why)) return false;
    if (rows.size() != 1 || rows[0].values.size() != 6) {
      return core::fail(why, "load map: " + (folder / "camera.txt").string() +
                                 " must hold one line 'fx fy cx cy width height'");
    }
    const std::vector<double>& v = rows[0].values;
    loaded.camera = {v[0], v[1], v[2], v[3], static_cast<int>(v[4]), static_cast<int>(v[5])};
    std::string reason;
    if (loaded.camera.width != 0 && !loaded.camera.is_valid(&reason)) {
      return core::fail(why, "load map: camera.txt: " + reason);
    }
  }
  if (fs::exists(folder / "poses.txt")) {
    if (!core::read_number_rows((folder / "poses.txt").string(), &rows, why)) return false;
    for (const core::NumberRow& row : rows) {
      const std::vector<double>& v = row.values;
      if (v.size() != 9 || v[0] < 0) {
        return core::fail(why, "load map: poses.txt line " + std::to_string(row.line) +
                                   ": expected frame_id timestamp tx ty tz qx qy qz qw");
      }
      const Eigen::Quaterniond q(v[8], v[5], v[6], v[7]);
      if (std::abs(q.norm() - 1.0) > 1e-3) {
        return core::fail(why, "load map: poses.txt line " + std::to_string(row.line) +
                                   ": the quaternion is not unit length");
      }
      FramePose p;
      p.frame_id = static_cast<std::uint64_t>(v[0]);
      p.timestamp = v[1];
      p.T_world_camera.linear() = q.normalized().toRotationMatrix();
      p.T_world_camera.translation() = Eigen::Vector3d(v[2], v[3], v[4]);
      loaded.poses.push_back(p);
    }
  }
  if (fs::exists(folder / kKeyframeFile)) {
    auto keyframes = std::make_shared<std::vector<core::DescribedKeyframe>>();
    if (!core::read_keyframe_file((folder / kKeyframeFile).string(), keyframes.get(), why)) {
      if (why) *why = "load map: " + *why;
      return false;
    }
    loaded.keyframes = std::move(keyframes);
  }
  if (fs::exists(folder / kHeadsFile)) {
    auto heads = std::make_shared<core::FeatureAutoencoder>();
    if (!heads->load((folder / kHeadsFile).string(), why)) {
      if (why) *why = "load map: " + *why;
      return false;
    }
    loaded.heads = std::move(heads);
  }
  // Read when used (refine, extend): a server loads every saved map at start.
  if (fs::exists(folder / kKeyframeImagesFile)) loaded.keyframe_images_file = fs::absolute(folder / kKeyframeImagesFile).string();
  *map = std::move(loaded);
  return true;
}

bool resolve_map_folder(const std::string& map_dir, const std::string& relative,
                        const std::string& fallback, std::string* folder, std::string* why) {
  if (map_dir.empty()) {
    return core::fail(why, "the server keeps no maps on disk (start it with a map_dir)");
  }
  const fs::path rel(relative.empty() ? fallback : relative);
  if (rel.empty() || rel.is_absolute()) {
    return core::fail(why, "map folder '" + rel.string() + "' must be a relative path under map_dir");
  }
  for (const fs::path& part : rel) {
    if (part == "." || part == ".." || part.empty()) {
      return core::fail(why, "map folder '" + rel.string() + "' may not contain '.' or '..'");
    }
  }
  *folder = (fs::path(map_dir) / rel).string();
  return true;
}

}  // namespace fslam::server

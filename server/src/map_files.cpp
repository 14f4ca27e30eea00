#include "fslam/server/map_files.hpp"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <system_error>

#include "fslam/core/error.hpp"
#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/text_tables.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::server {
namespace fs = std::filesystem;

namespace {

bool write_text(const fs::path& path, const std::string& text, std::string* why) {
  std::ofstream out(path);
  out << text;
  out.close();
  if (!out) return core::fail(why, "cannot write " + path.string());
  return true;
}

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

bool save_map_folder(const std::string& dir, const StoredMap& map, std::string* why) {
  if (!map.gaussians) return core::fail(why, "save map: no map");
  const fs::path target(dir), staging(dir + ".saving"), old(dir + ".old");
  std::error_code ec;
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
      !write_text(staging / "poses.txt", format_poses(map.poses), why) ||
      !core::write_tum_trajectory((staging / "trajectory.txt").string(), trajectory, why) ||
      !write_text(staging / "camera.txt", camera, why)) {
    fs::remove_all(staging, ec);
    return false;
  }
  // Swap in: the old folder survives until the new one is in place.
  fs::remove_all(old, ec);
  if (fs::exists(target)) fs::rename(target, old, ec);
  if (ec) return core::fail(why, "save map: cannot move the previous " + dir + " aside: " + ec.message());
  fs::rename(staging, target, ec);
  if (ec) return core::fail(why, "save map: cannot rename into " + dir + ": " + ec.message());
  fs::remove_all(old, ec);
  return true;
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

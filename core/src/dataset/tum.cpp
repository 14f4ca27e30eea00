// TUM RGB-D benchmark sequences (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats).
#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <optional>
#include <system_error>

#include "fslam/core/error.hpp"
#include "fslam/core/dataset/frame_index.hpp"
#include "fslam/core/dataset/readers.hpp"
#include "fslam/core/io/text_tables.hpp"
#include "fslam/core/geometry/associate.hpp"
#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

constexpr double kTumDepthScale = 5000.0;    // raw units per metre
constexpr double kMaxAssociationGap = 0.02;  // s, associate.py's default
constexpr double kMaxGroundTruthGap = 0.1;   // s, widest bracket we interpolate across

// One line of rgb.txt or depth.txt.
struct ListEntry {
  double timestamp = 0.0;
  std::string stamp_text;  // as written, to name per-frame files after it
  std::string path;        // relative paths resolved against the sequence folder
};

bool read_image_list(const std::string& root, const std::string& name,
                     std::vector<ListEntry>* entries, std::string* why) {
  const std::string path = join_path(root, name);
  std::vector<TextRow> rows;
  if (!read_text_rows(path, &rows, why)) return false;
  entries->clear();
  for (const TextRow& row : rows) {
    const std::string where = path + ":" + std::to_string(row.line);
    if (row.fields.size() < 2) return fail(why, where + ": expected 'timestamp filename'");
    ListEntry e;
    if (!parse_double(row.fields[0], &e.timestamp) || !std::isfinite(e.timestamp))
      return fail(why, where + ": timestamp '" + row.fields[0] + "' is not a finite number");
    e.stamp_text = row.fields[0];
    e.path = fs::path(row.fields[1]).is_absolute() ? row.fields[1] : join_path(root, row.fields[1]);
    entries->push_back(std::move(e));
  }
  return true;
}

struct TumPreset {
  const char* name;
  const char* short_name;
  double fx, fy, cx, cy;
};
// The benchmark's published ROS-default intrinsics per Kinect (distortion ignored).
constexpr TumPreset kTumPresets[] = {
    {"freiburg1", "fr1", 517.3, 516.5, 318.6, 255.3},
    {"freiburg2", "fr2", 520.9, 521.0, 325.1, 249.7},
    {"freiburg3", "fr3", 535.4, 539.2, 320.1, 247.6},
};

std::string folder_name(const std::string& root) {
  std::error_code ec;
  fs::path p = fs::canonical(root, ec);
  if (ec) p = fs::absolute(root, ec).lexically_normal();
  if (!p.has_filename()) p = p.parent_path();
  std::string name = p.filename().string();
  std::transform(name.begin(), name.end(), name.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return name;
}

// intrinsics.txt ('#' comments, then "fx fy cx cy width height") or the preset the folder's name
// points at. Not called when the caller overrides the intrinsics.
bool tum_camera(const std::string& root, FrameIndex* index, std::string* why) {
  const std::string file = join_path(root, "intrinsics.txt");
  if (!first_existing_file({file}).empty()) {
    std::vector<NumberRow> rows;
    if (!read_number_rows(file, &rows, why)) return false;
    std::string reason;
    if (rows.size() != 1 || rows[0].values.size() != 6)
      return fail(why, file + ": bad intrinsics: expected one line 'fx fy cx cy width height'");
    if (!camera_from_values(rows[0].values, &index->camera, &reason))
      return fail(why, file + ": bad intrinsics: " + reason);
    index->camera_source = file;
    return true;
  }
  const std::string name = folder_name(root);
  std::vector<const TumPreset*> matches;
  for (const TumPreset& preset : kTumPresets)
    if (name.find(preset.name) != std::string::npos ||
        name.find(preset.short_name) != std::string::npos)
      matches.push_back(&preset);
  if (matches.size() == 1) {
    const TumPreset& p = *matches.front();
    index->camera = {p.fx, p.fy, p.cx, p.cy, 0, 0};  // size from the images
    index->camera_source = std::string("TUM ") + p.name + " preset (folder name '" + name + "')";
    return true;
  }
  return fail(
      why, root + ": no intrinsics for this TUM sequence: " +
               (matches.empty()
                    ? "the folder name '" + name + "' names no freiburg1/2/3 (fr1/fr2/fr3) camera"
                    : "the folder name '" + name + "' names more than one camera") +
               " and there is no intrinsics.txt; write intrinsics.txt ('fx fy cx cy "
               "width height') into the folder or pass the intrinsics explicitly "
               "(fslam: --intrinsics fx,fy,cx,cy)");
}

// Geodesic interpolation between the samples bracketing t when they are close enough.
std::optional<Eigen::Isometry3d> pose_at(const Trajectory& sorted, double t) {
  const auto after =
      std::lower_bound(sorted.begin(), sorted.end(), t,
                       [](const StampedPose& p, double stamp) { return p.timestamp < stamp; });
  if (after == sorted.end()) return std::nullopt;
  if (after->timestamp == t) return after->T_world_camera;
  if (after == sorted.begin()) return std::nullopt;
  const auto before = after - 1;
  const double gap = after->timestamp - before->timestamp;
  if (gap > kMaxGroundTruthGap) return std::nullopt;
  return interpolate(before->T_world_camera, after->T_world_camera, (t - before->timestamp) / gap);
}

// labels/<kind>/<ts>.png, named after rgb.txt's stamp or, equivalently, the colour file's stem.
std::string label_path(const std::string& root, const std::string& kind, const ListEntry& rgb) {
  const std::string dir = join_path(join_path(root, "labels"), kind);
  return first_existing_file({join_path(dir, rgb.stamp_text + ".png"),
                              join_path(dir, fs::path(rgb.path).stem().string() + ".png")});
}

}  // namespace

bool looks_like_tum(const std::string& root) {
  return !first_existing_file({join_path(root, "rgb.txt")}).empty() &&
         !first_existing_file({join_path(root, "depth.txt")}).empty();
}

std::unique_ptr<Dataset> open_tum_dataset(const std::string& path, const DatasetOptions& options,
                                          std::string* why) {
  FrameIndex index;
  index.kind = "tum";
  index.root = normalise_root(path);
  index.depth_scale = kTumDepthScale;
  const std::string& root = index.root;
  if (!options.intrinsics && !tum_camera(root, &index, why)) return nullptr;

  std::vector<ListEntry> rgb, depth;
  if (!read_image_list(root, "rgb.txt", &rgb, why) ||
      !read_image_list(root, "depth.txt", &depth, why))
    return nullptr;
  std::vector<double> rgb_stamps, depth_stamps;
  for (const ListEntry& e : rgb) rgb_stamps.push_back(e.timestamp);
  for (const ListEntry& e : depth) depth_stamps.push_back(e.timestamp);
  const auto pairs = associate_timestamps(rgb_stamps, depth_stamps, 0.0, kMaxAssociationGap);
  if (pairs.empty()) {
    fail(why, join_path(root, "rgb.txt") + ": no entry has a depth.txt entry within " +
                  std::to_string(kMaxAssociationGap) + " s");
    return nullptr;
  }

  std::vector<std::size_t> positions;
  if (!options.frames.apply(pairs.size(), root, &positions, why)) return nullptr;

  Trajectory ground_truth;
  const std::string gt_file = join_path(root, "groundtruth.txt");
  const bool has_gt = !first_existing_file({gt_file}).empty();
  if (has_gt) {
    if (!read_tum_trajectory(gt_file, &ground_truth, why)) return nullptr;
    std::stable_sort(
        ground_truth.begin(), ground_truth.end(),
        [](const StampedPose& a, const StampedPose& b) { return a.timestamp < b.timestamp; });
  }

  std::error_code ec;
  const bool has_labels = fs::is_directory(join_path(root, "labels"), ec);
  for (std::size_t position : positions) {
    const ListEntry& colour = rgb[pairs[position].first];
    FrameRecord r;
    r.id = static_cast<std::int64_t>(position);
    r.timestamp = colour.timestamp;
    r.colour_path = colour.path;
    r.depth_path = depth[pairs[position].second].path;
    if (has_gt) r.T_world_camera_gt = pose_at(ground_truth, r.timestamp);
    if (has_labels) {
      r.instance_label_path = label_path(root, "instance", colour);
      r.class_label_path = label_path(root, "class", colour);
    }
    index.frames.push_back(std::move(r));
  }
  return make_indexed_dataset(std::move(index), options, why);
}

}  // namespace fslam::core

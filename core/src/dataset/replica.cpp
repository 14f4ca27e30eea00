// Replica renders as NICE-SLAM and SplaTAM distribute them.
#include <cmath>

#include <opencv2/core.hpp>
#include <opencv2/core/persistence.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/dataset/frame_index.hpp"
#include "fslam/core/dataset/readers.hpp"
#include "fslam/core/io/text_tables.hpp"

namespace fslam::core {
namespace {

// NICE-SLAM's Replica camera; cam_params.json overrides it.
constexpr int kReplicaWidth = 1200;
constexpr int kReplicaHeight = 680;
constexpr double kReplicaFocal = 600.0;
constexpr double kReplicaCx = 599.5;
constexpr double kReplicaCy = 339.5;
constexpr double kReplicaDepthScale = 6553.5;  // raw units per metre (65535 = 10 m)

// {"camera": {"w", "h", "fx", "fy", "cx", "cy", "scale"}}; scale is optional.
bool read_cam_params(const std::string& file, FrameIndex* index, std::string* why) {
  try {
    cv::FileStorage fs(file, cv::FileStorage::READ | cv::FileStorage::FORMAT_JSON);
    if (!fs.isOpened()) return fail(why, file + ": cannot open camera parameters");
    const cv::FileNode camera = fs["camera"];
    if (!camera.isMap()) return fail(why, file + ": bad intrinsics: no \"camera\" object");
    // Read as fx fy cx cy w h, the order camera_from_values takes.
    std::vector<double> values;
    for (const char* key : {"fx", "fy", "cx", "cy", "w", "h"}) {
      const cv::FileNode node = camera[key];
      if (!node.isInt() && !node.isReal())
        return fail(why, file + ": bad intrinsics: camera." + key + " is missing or not a number");
      values.push_back(node.real());
    }
    std::string reason;
    if (!camera_from_values(values, &index->camera, &reason))
      return fail(why, file + ": bad intrinsics: " + reason);
    const cv::FileNode scale = camera["scale"];
    if (!scale.empty()) {
      if ((!scale.isInt() && !scale.isReal()) || !(scale.real() > 0.0) ||
          !std::isfinite(scale.real()))
        return fail(why, file + ": camera.scale must be a positive number");
      index->depth_scale = scale.real();
    }
  } catch (const cv::Exception& e) {
    // OpenCV's parser puts "file(line): reason" in func, the failing step in err.
    return fail(why, file + ": cannot parse JSON (" + e.err + " in " + e.func + ")");
  }
  index->camera_source = file;
  return true;
}

}  // namespace

bool looks_like_replica(const std::string& root) {
  return !list_numbered_files(join_path(root, "results"), "depth", ".png").empty();
}

std::unique_ptr<Dataset> open_replica_dataset(const std::string& path,
                                              const DatasetOptions& options, std::string* why) {
  FrameIndex index;
  index.kind = "replica";
  index.root = normalise_root(path);
  index.depth_scale = kReplicaDepthScale;
  index.camera = {kReplicaFocal, kReplicaFocal, kReplicaCx,
                  kReplicaCy,    kReplicaWidth, kReplicaHeight};
  index.camera_source = "Replica default intrinsics (no cam_params.json found)";
  const std::string& root = index.root;
  const std::string params = first_existing_file(
      {join_path(root, "cam_params.json"), join_path(parent_folder(root), "cam_params.json")});
  // The file also carries the depth scale, so it is read even when intrinsics are overridden.
  if (!params.empty() && !read_cam_params(params, &index, why)) return nullptr;

  const std::string results = join_path(root, "results");
  const std::vector<NumberedFile> depth = list_numbered_files(results, "depth", ".png");
  if (depth.empty()) {
    fail(why, results + ": no depthNNNNNN.png files");
    return nullptr;
  }
  std::vector<std::size_t> positions;
  if (!options.frames.apply(depth.size(), root, &positions, why)) return nullptr;

  const std::string traj_file = join_path(root, "traj.txt");
  std::vector<NumberRow> traj;
  const bool has_traj = !first_existing_file({traj_file}).empty();
  if (has_traj && !read_number_rows(traj_file, &traj, why)) return nullptr;

  for (std::size_t position : positions) {
    const NumberedFile& d = depth[position];
    const std::string stem = join_path(results, "frame" + d.digits);
    FrameRecord r;
    r.id = d.number;
    r.timestamp = static_cast<double>(d.number) / kUntimedFrameRate;
    r.depth_path = d.path;
    r.colour_path = first_existing_file({stem + ".jpg", stem + ".png"});
    if (r.colour_path.empty()) {
      fail(why, stem + ".jpg (or .png): missing colour image");
      return nullptr;
    }
    if (has_traj) {
      // Line N (comments and blank lines aside) is frame N's camera-to-world pose.
      if (static_cast<std::size_t>(d.number) >= traj.size()) {
        fail(why, traj_file + ": has " + std::to_string(traj.size()) + " poses, but " + d.path +
                      " needs pose " + std::to_string(d.number));
        return nullptr;
      }
      const NumberRow& row = traj[static_cast<std::size_t>(d.number)];
      const std::string where = traj_file + ":" + std::to_string(row.line);
      if (row.values.size() != 16) {
        fail(why, where + ": expected 16 numbers (a 4x4 row-major matrix), found " +
                      std::to_string(row.values.size()));
        return nullptr;
      }
      const Eigen::Matrix4d M =
          Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>>(row.values.data());
      Eigen::Isometry3d T;
      if (!rigid_pose_from_matrix(M, where, &T, why)) return nullptr;
      r.T_world_camera_gt = T;
    }
    index.frames.push_back(std::move(r));
  }
  return make_indexed_dataset(std::move(index), options, why);
}

}  // namespace fslam::core

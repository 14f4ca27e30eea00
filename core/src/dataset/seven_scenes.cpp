// Microsoft 7-Scenes (and the same layout as tsdf-fusion's sample data ships it).
#include <cmath>
#include <filesystem>

#include "fslam/core/error.hpp"
#include "fslam/core/dataset/frame_index.hpp"
#include "fslam/core/dataset/readers.hpp"
#include "fslam/core/io/text_tables.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

constexpr double kSevenScenesDepthScale = 1000.0;  // millimetres
// Published with the dataset; used when no camera-intrinsics.txt comes with it.
constexpr double kSevenScenesFocal = 585.0;
constexpr double kSevenScenesCx = 320.0;
constexpr double kSevenScenesCy = 240.0;

struct FrameFiles {
  std::string dir;
  std::vector<NumberedFile> depth;
};

// The frames sit in the folder itself or, as tsdf-fusion ships them, in data/rgbd-frames.
FrameFiles find_frames(const std::string& root) {
  for (const std::string& dir : {root, join_path(join_path(root, "data"), "rgbd-frames")}) {
    FrameFiles files{dir, list_numbered_files(dir, "frame-", ".depth.png")};
    if (!files.depth.empty()) return files;
  }
  return {root, {}};
}

bool seven_scenes_camera(const std::string& root, const std::string& frames_dir, FrameIndex* index,
                         std::string* why) {
  const std::string name = "camera-intrinsics.txt";
  const std::string file = first_existing_file(
      {join_path(frames_dir, name), join_path(root, name), join_path(join_path(root, "data"), name),
       join_path(parent_folder(frames_dir), name), join_path(parent_folder(root), name)});
  if (file.empty()) {
    index->camera = {kSevenScenesFocal, kSevenScenesFocal, kSevenScenesCx, kSevenScenesCy, 0, 0};
    index->camera_source = "7-Scenes default intrinsics (no " + name + " found)";
    return true;
  }
  Eigen::MatrixXd K;
  if (!read_matrix_file(file, 3, 3, &K, why)) return false;
  if (K(0, 1) != 0.0 || K(1, 0) != 0.0 || K(2, 0) != 0.0 || K(2, 1) != 0.0 || K(2, 2) != 1.0)
    return fail(why, file + ": bad intrinsics: expected K = [fx 0 cx; 0 fy cy; 0 0 1]");
  index->camera = {K(0, 0), K(1, 1), K(0, 2), K(1, 2), 0, 0};  // size from the images
  index->camera_source = file;
  return true;
}

}  // namespace

bool looks_like_seven_scenes(const std::string& root) { return !find_frames(root).depth.empty(); }

std::unique_ptr<Dataset> open_seven_scenes_dataset(const std::string& path,
                                                   const DatasetOptions& options,
                                                   std::string* why) {
  FrameIndex index;
  index.kind = "7scenes";
  index.root = normalise_root(path);
  index.depth_scale = kSevenScenesDepthScale;
  const FrameFiles files = find_frames(index.root);
  if (files.depth.empty()) {
    fail(why, index.root + ": no frame-NNNNNN.depth.png files here or in data/rgbd-frames");
    return nullptr;
  }
  if (!options.intrinsics && !seven_scenes_camera(index.root, files.dir, &index, why))
    return nullptr;

  std::vector<std::size_t> positions;
  if (!options.frames.apply(files.depth.size(), index.root, &positions, why)) return nullptr;

  // Ground truth is all or nothing: a sequence with some pose files missing is damaged.
  std::string first_pose_missing;
  bool any_pose = false;
  for (std::size_t position : positions) {
    const NumberedFile& depth = files.depth[position];
    const std::string stem = join_path(files.dir, "frame-" + depth.digits);
    FrameRecord r;
    r.id = depth.number;
    r.timestamp = static_cast<double>(depth.number) / kUntimedFrameRate;
    r.depth_path = depth.path;
    r.colour_path = first_existing_file({stem + ".color.png", stem + ".color.jpg"});
    if (r.colour_path.empty()) {
      fail(why, stem + ".color.png (or .jpg): missing colour image");
      return nullptr;
    }
    const std::string pose_file = stem + ".pose.txt";
    if (!first_existing_file({pose_file}).empty()) {
      any_pose = true;
      Eigen::MatrixXd M;
      Eigen::Isometry3d T;
      if (!read_matrix_file(pose_file, 4, 4, &M, why) ||
          !rigid_pose_from_matrix(M, pose_file, &T, why))
        return nullptr;
      r.T_world_camera_gt = T;
    } else if (first_pose_missing.empty()) {
      first_pose_missing = pose_file;
    }
    index.frames.push_back(std::move(r));
  }
  if (any_pose && !first_pose_missing.empty()) {
    fail(why, first_pose_missing + ": missing pose (other frames of the sequence have one)");
    return nullptr;
  }
  return make_indexed_dataset(std::move(index), options, why);
}

}  // namespace fslam::core

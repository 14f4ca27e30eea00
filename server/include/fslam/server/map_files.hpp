// A map on disk: the folder a server saves a map to and serves it again from after a restart.
//   map.ply         the Gaussians (standard 3DGS PLY, core/io/gaussian_ply.hpp)
//   poses.txt       "frame_id timestamp tx ty tz qx qy qz qw" per tracked frame, camera-to-world
//   trajectory.txt  the same poses as a TUM trajectory, for evaluation tools
//   camera.txt      "fx fy cx cy width height" of the camera the map was built with
//   keyframes.bin   the keyframes' relocalisation descriptions (core/io/keyframe_file.hpp), for
//                   sessions that localise in the map; absent when the map has none
//   heads.fae       the feature autoencoder with the heads' LoRA as online mapping adapted them
//                   (core/features/feature_autoencoder.hpp's weights file), for sessions that
//                   extend the map; absent when it was mapped without the decoded L_feat
//   keyframe_images.bin  the mapper's stored keyframes' colour and depth (at its kept scale) and
//                   poses (core/io/keyframe_images_file.hpp), for refining the map after a
//                   restart and for extend sessions; absent in maps saved before it was written
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "fslam/core/features/feature_autoencoder.hpp"
#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/map/gaussian_map.hpp"
#include "fslam/core/mapping/mapper.hpp"
#include "fslam/core/tracking/relocaliser.hpp"

namespace fslam::server {

struct FramePose {
  std::uint64_t frame_id = 0;
  double timestamp = 0.0;  // seconds
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
};

struct StoredMap {
  std::shared_ptr<const core::GaussianMap> gaussians;
  core::PinholeCamera camera;     // width 0 when no frame was ever seen
  std::vector<FramePose> poses;   // in processing order
  std::shared_ptr<const std::vector<core::DescribedKeyframe>> keyframes;  // null: none
  std::shared_ptr<const core::FeatureAutoencoder> heads;  // null: none (no decoded L_feat)
  // The mapper's keyframe images: in memory (a streamed map's), or, for a loaded map, the
  // keyframe_images.bin it was loaded from, read only when refined or extended (they are ~0.5 MB
  // a keyframe decoded) and copied as they are by a save. Neither: none.
  std::shared_ptr<const std::vector<core::KeyframeImages>> keyframe_images;
  std::string keyframe_images_file;
};

// Writes the folder next to `dir` first (hidden: `.NAME.saving`) and renames it into place
// (the previous version moved aside to `.NAME.old` meanwhile), so that a crash or a full disk
// never leaves half a map where a whole one was.
bool save_map_folder(const std::string& dir, const StoredMap& map, std::string* why);
bool load_map_folder(const std::string& dir, StoredMap* map, std::string* why);
// After a crash: makes `dir` hold a whole version again if a save was interrupted (the new one
// when it was complete, else the previous one) and removes a save's leftovers. True when `dir`
// then holds a map; `note` says what was done (empty: nothing).
bool recover_map_folder(const std::string& dir, std::string* note);
// A map's name names its folder: 1-128 letters, digits, '-', '_', '.', not starting with '.'.
bool valid_map_name(const std::string& name, std::string* why);
// True when `dir` holds a saved map (its map.ply).
bool is_map_folder(const std::string& dir);

// The folder a request names, under the server's map_dir: a relative path without "." or ".."
// components (clients never reach outside map_dir). Empty `relative` means `fallback`.
bool resolve_map_folder(const std::string& map_dir, const std::string& relative,
                        const std::string& fallback, std::string* folder, std::string* why);

}  // namespace fslam::server

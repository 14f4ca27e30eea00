// What every dataset reader produces: the list of frames (file paths, stamps, poses) and the
// camera. One Dataset implementation serves every layout from it, so image loading and its
// validation exist once.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/geometry/colour_camera.hpp"
#include "fslam/core/geometry/pinhole_camera.hpp"

namespace fslam::core {

struct FrameRecord {
  std::int64_t id = 0;     // number in the file name, or position in the layout's frame list
  double timestamp = 0.0;  // seconds
  std::string colour_path;
  std::string depth_path;  // 16-bit single channel
  std::optional<Eigen::Isometry3d> T_world_camera_gt;
  std::string instance_label_path;  // empty when the frame has none
  std::string class_label_path;
};

struct FrameIndex {
  std::string kind;  // tum | 7scenes | replica
  std::string root;  // the folder the dataset was opened from
  // The layout's intrinsics; width/height 0 when the layout does not state the image size.
  PinholeCamera camera;
  std::string camera_source;        // where `camera` came from (a file, or a preset), for messages
  double depth_scale = 1000.0;      // raw depth units per metre
  std::vector<FrameRecord> frames;  // the selected frames, in order
  std::optional<ColourCamera> colour_camera;  // DatasetOptions::colour_camera
};

// Applies options.intrinsics, sizes the camera from the first frame's depth image (checking a
// stated size against it), validates the camera and wraps the index as a Dataset.
std::unique_ptr<Dataset> make_indexed_dataset(FrameIndex index, const DatasetOptions& options,
                                              std::string* why);

// Helpers the readers share.

// Layouts without timestamps (7-Scenes, Replica) were recorded or rendered at this rate.
constexpr double kUntimedFrameRate = 30.0;  // Hz

// How far a pose read from text may be from a rotation (max |R^T R - I| and |det R - 1|) before
// it is rejected rather than orthonormalised. KinectFusion's 7-Scenes poses drift from
// orthonormality as a sequence goes on (3.7e-4 by frame 599 of redkitchen), so is_rigid's default
// 1e-4 rejects real data; 1e-2 still rejects any scale, shear or transposed-row mistake.
constexpr double kPoseRigidityTolerance = 1e-2;

// A camera-to-world matrix read from `source` as an exact isometry: it must be finite and rigid
// (is_rigid within kPoseRigidityTolerance) before it is orthonormalised.
bool rigid_pose_from_matrix(const Eigen::Matrix4d& M, const std::string& source,
                            Eigen::Isometry3d* T, std::string* why);

// A camera from "fx fy cx cy" or "fx fy cx cy width height" (width and height then positive
// integers; 0 when absent). Validity beyond that is checked once the image size is known.
bool camera_from_values(const std::vector<double>& values, PinholeCamera* camera, std::string* why);

// The root as given, without trailing separators or "./" noise, so messages show the user's path.
std::string normalise_root(const std::string& path);

// dir/name.
std::string join_path(const std::string& dir, const std::string& name);

// The folder above `path`, also for a relative path with no parent part ("scene" -> "/abs").
std::string parent_folder(const std::string& path);

// The first of `candidates` that is a regular file, or "" when none is.
std::string first_existing_file(const std::vector<std::string>& candidates);

struct NumberedFile {
  std::int64_t number = 0;
  std::string digits;  // the number as written in the name, leading zeros kept
  std::string path;
};
// Files in `dir` named <prefix><digits><suffix>, sorted by number.
std::vector<NumberedFile> list_numbered_files(const std::string& dir, const std::string& prefix,
                                              const std::string& suffix);

}  // namespace fslam::core

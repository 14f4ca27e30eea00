// One reader per on-disk layout. Each lists its frames, applies the selection, attaches ground
// truth and intrinsics, and hands a FrameIndex to make_indexed_dataset. open_dataset() picks one.
#pragma once

#include <memory>
#include <string>

#include "fslam/core/dataset/dataset.hpp"

namespace fslam::core {

// TUM RGB-D: rgb.txt + depth.txt associated like associate.py, groundtruth.txt interpolated.
bool looks_like_tum(const std::string& root);
std::unique_ptr<Dataset> open_tum_dataset(const std::string& root, const DatasetOptions& options,
                                          std::string* why);

// Microsoft 7-Scenes: frame-NNNNNN.{color.jpg|color.png,depth.png,pose.txt}, 30 Hz.
bool looks_like_seven_scenes(const std::string& root);
std::unique_ptr<Dataset> open_seven_scenes_dataset(const std::string& root,
                                                   const DatasetOptions& options, std::string* why);

// Replica as NICE-SLAM / SplaTAM ship it: results/frameNNNNNN.jpg, results/depthNNNNNN.png,
// traj.txt, cam_params.json, 30 Hz.
bool looks_like_replica(const std::string& root);
std::unique_ptr<Dataset> open_replica_dataset(const std::string& root,
                                              const DatasetOptions& options, std::string* why);

}  // namespace fslam::core

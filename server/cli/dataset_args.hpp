// The dataset options every command that reads a recorded sequence shares (info, track, run,
// stream): --dataset DIR [--kind K] [--frames A:B[:S]] [--intrinsics fx,fy,cx,cy]
// [--colour-camera fx,fy,cx,cy,tx,ty,tz].
#pragma once

#include <string>

#include "fslam/core/dataset/dataset.hpp"
#include "fslam/server/config_options.hpp"

namespace CLI {
class App;
}

namespace fslam::cli {

struct DatasetArgs {
  std::string path;
  std::string kind = "auto";
  std::string frames;      // empty: all frames
  std::string intrinsics;  // empty: dataset.intrinsics, else the dataset's own
  std::string colour_camera;  // empty: dataset.colour_camera, else registered to depth
  // The settings layers (--config, --set) the dataset.* keys come from: the command's own, or
  // these when it has none.
  const server::ConfigOptions* config = nullptr;
  server::ConfigOptions own_config;

  // Parses --frames, --intrinsics and --colour-camera (or their dataset.* settings) into core's
  // options; the message says which flag or setting is wrong.
  bool to_options(core::DatasetOptions* options, std::string* why) const;
};

// Registers the options on `app`, writing into `args` (which must outlive parsing). `config`:
// the command's --config / --set when it has them; else the dataset options add their own.
void add_dataset_options(CLI::App* app, DatasetArgs* args, bool required = true,
                         const server::ConfigOptions* config = nullptr);

// The dataset opened with `args`, or null with `why`. Warns on stderr when a recording whose
// colour sensor is not registered to depth (7-Scenes, Kinect v1) is opened without its colour
// camera: colour then lands 10-20 px off at depth edges and maps lose ~2 dB (docs/datasets.md).
std::unique_ptr<core::Dataset> open_dataset(const DatasetArgs& args, core::DatasetOptions* options,
                                            std::string* why);

}  // namespace fslam::cli

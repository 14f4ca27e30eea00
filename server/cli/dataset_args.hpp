// The dataset options every command that reads a recorded sequence shares (info, track, run,
// stream): --dataset DIR [--kind K] [--frames A:B[:S]] [--intrinsics fx,fy,cx,cy]
// [--colour-camera fx,fy,cx,cy,tx,ty,tz].
#pragma once

#include <string>

#include "fslam/core/dataset/dataset.hpp"

namespace CLI {
class App;
}

namespace fslam::cli {

struct DatasetArgs {
  std::string path;
  std::string kind = "auto";
  std::string frames;      // empty: all frames
  std::string intrinsics;  // empty: the dataset's own
  std::string colour_camera;  // empty: colour is registered to depth

  // Parses --frames, --intrinsics and --colour-camera into core's options; the message says which flag is wrong.
  bool to_options(core::DatasetOptions* options, std::string* why) const;
};

// Registers the options on `app`, writing into `args` (which must outlive parsing).
void add_dataset_options(CLI::App* app, DatasetArgs* args, bool required = true);

}  // namespace fslam::cli

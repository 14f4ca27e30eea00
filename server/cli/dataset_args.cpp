#include "dataset_args.hpp"

#include <CLI/CLI.hpp>

namespace fslam::cli {

bool DatasetArgs::to_options(core::DatasetOptions* options, std::string* why) const {
  core::DatasetOptions result;
  result.kind = kind;
  if (!frames.empty() && !core::FrameSelection::parse(frames, &result.frames, why)) {
    if (why) *why = "--frames: " + *why;
    return false;
  }
  if (!intrinsics.empty()) {
    core::PinholeCamera camera;
    if (!core::parse_intrinsics(intrinsics, &camera, why)) {
      if (why) *why = "--intrinsics: " + *why;
      return false;
    }
    result.intrinsics = camera;
  }
  if (!colour_camera.empty()) {
    core::ColourCamera colour;
    if (!core::ColourCamera::parse(colour_camera, &colour, why)) {
      if (why) *why = "--colour-camera: " + *why;
      return false;
    }
    result.colour_camera = colour;
  }
  *options = result;
  return true;
}

void add_dataset_options(CLI::App* app, DatasetArgs* args, bool required) {
  auto* dataset =
      app->add_option("--dataset", args->path,
                      "Sequence folder (TUM RGB-D, 7-Scenes or Replica; docs/datasets.md)");
  if (required) dataset->required();
  std::vector<std::string> kinds = {"auto"};
  kinds.insert(kinds.end(), core::dataset_kinds().begin(), core::dataset_kinds().end());
  app->add_option("--kind", args->kind, "Dataset layout; auto detects it from the folder")
      ->check(CLI::IsMember(kinds))
      ->capture_default_str();
  app->add_option("--frames", args->frames,
                  "Frames to use, A:B[:S] (half-open positions in the sequence, every S-th)");
  app->add_option("--intrinsics", args->intrinsics,
                  "Override the camera: fx,fy,cx,cy in pixels, optionally ,width,height (default: "
                  "the images' size)");
  app->add_option("--colour-camera", args->colour_camera,
                  "Colour not registered to depth: the colour sensor as fx,fy,cx,cy,tx,ty,tz "
                  "(pixels; metres from the depth camera); colour is resampled onto the depth "
                  "pixels (fslam calibrate-colour estimates it; docs/datasets.md)");
}

}  // namespace fslam::cli

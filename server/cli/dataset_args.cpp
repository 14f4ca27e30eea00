#include "dataset_args.hpp"

#include <cstdio>

#include <CLI/CLI.hpp>

#include "fslam/server/config_fields.hpp"

namespace fslam::cli {

bool DatasetArgs::to_options(core::DatasetOptions* options, std::string* why) const {
  core::DatasetOptions result;
  result.kind = kind;
  // dataset.* from the command's own table (fslam run / track: the run settings, else the server's).
  const server::ConfigOptions& layers = config != nullptr ? *config : own_config;
  server::DatasetSettings settings;
  if (layers.kind == server::SettingsKind::run) {
    server::RunConfig layered = server::run_defaults();
    if (!layers.apply(&layered, why)) return false;
    settings = layered.dataset;
  } else {
    server::ServerConfig layered;
    if (!layers.apply(&layered, why)) return false;
    settings = layered.dataset;
  }
  const std::string& intrinsics = this->intrinsics.empty() ? settings.intrinsics : this->intrinsics;
  const std::string& colour_camera =
      this->colour_camera.empty() ? settings.colour_camera : this->colour_camera;
  if (!frames.empty() && !core::FrameSelection::parse(frames, &result.frames, why)) {
    if (why) *why = "--frames: " + *why;
    return false;
  }
  if (!intrinsics.empty()) {
    core::PinholeCamera camera;
    if (!core::parse_intrinsics(intrinsics, &camera, why)) {
      if (why) *why = "--intrinsics / dataset.intrinsics: " + *why;
      return false;
    }
    result.intrinsics = camera;
  }
  if (!colour_camera.empty()) {
    core::ColourCamera colour;
    if (!core::ColourCamera::parse(colour_camera, &colour, why)) {
      if (why) *why = "--colour-camera / dataset.colour_camera: " + *why;
      return false;
    }
    result.colour_camera = colour;
  }
  *options = result;
  return true;
}

void add_dataset_options(CLI::App* app, DatasetArgs* args, bool required,
                         const server::ConfigOptions* config) {
  args->config = config;
  if (config == nullptr) server::add_config_options(app, &args->own_config);
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

std::unique_ptr<core::Dataset> open_dataset(const DatasetArgs& args, core::DatasetOptions* options,
                                            std::string* why) {
  if (!args.to_options(options, why)) return nullptr;
  std::unique_ptr<core::Dataset> dataset = core::open_dataset(args.path, *options, why);
  if (dataset && dataset->kind() == "7scenes" && !options->colour_camera) {
    std::fprintf(stderr,
                 "warning: %s is a 7-Scenes recording, whose colour is not registered to depth "
                 "(colour lands 10-20 px off at depth edges); give its colour camera with "
                 "--config configs/presets/seven_scenes.yaml (redkitchen's) or --colour-camera, "
                 "estimated by `fslam calibrate-colour --dataset %s` (docs/datasets.md)\n",
                 args.path.c_str(), args.path.c_str());
  }
  return dataset;
}

}  // namespace fslam::cli

// `fslam calibrate-colour`: estimates the colour sensor of a recording whose colour is not
// registered to depth (core/calibration/colour_calibration.hpp) and prints the --colour-camera
// value that registers it.
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "commands.hpp"
#include "dataset_args.hpp"
#include "fslam/core/calibration/colour_calibration.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::cli {
namespace {

struct CalibrateArgs {
  DatasetArgs dataset;
  std::string trajectory;  // empty: ground truth
  int gap = 10;            // frames between the two views of a pair
  int pairs = 24;          // pairs spread evenly over the selection
  std::string out;         // optional file for the value
};

// The depth camera's pose of `frame`: from the trajectory by timestamp, else ground truth.
bool frame_pose(const core::Trajectory& trajectory,
                const core::RgbdFrame& frame, Eigen::Isometry3d* pose) {
  if (!trajectory.empty()) {
    const core::StampedPose* p = core::nearest_pose(trajectory, frame.timestamp);
    if (!p) return false;
    *pose = p->T_world_camera;
    return true;
  }
  if (!frame.T_world_camera_gt) return false;
  *pose = *frame.T_world_camera_gt;
  return true;
}

int run_calibrate(const CalibrateArgs& args) {
  core::DatasetOptions options;
  std::string why;
  if (!args.dataset.to_options(&options, &why)) return fail(why);
  // --colour-camera is the starting point here; the frames are read unregistered.
  core::ColourCamera initial;
  const bool had_initial = options.colour_camera.has_value();
  if (had_initial) initial = *options.colour_camera;
  options.colour_camera.reset();
  const std::unique_ptr<core::Dataset> dataset = core::open_dataset(args.dataset.path, options, &why);
  if (!dataset) return fail(why);
  if (!had_initial) initial.camera = dataset->camera();  // registered: same pinhole, no offset
  initial.camera.width = initial.camera.height = 0;

  core::Trajectory trajectory;
  if (!args.trajectory.empty() && !core::read_tum_trajectory(args.trajectory, &trajectory, &why))
    return fail(why);
  if (args.trajectory.empty() && !dataset->has_ground_truth())
    return fail(dataset->root() + ": no ground-truth poses; give --trajectory (TUM format)");
  const std::size_t n = dataset->size();
  const std::size_t gap = static_cast<std::size_t>(args.gap);
  if (n <= gap)
    return fail("need more than --gap " + std::to_string(args.gap) + " frames, the selection has " +
                std::to_string(n));

  const std::size_t count = std::min<std::size_t>(static_cast<std::size_t>(args.pairs), n - gap);
  std::vector<core::ColourCalibrationPair> pairs;
  Progress progress("calibrate-colour: load", count);
  for (std::size_t k = 0; k < count; ++k) {
    const std::size_t a = count > 1 ? k * (n - gap - 1) / (count - 1) : 0;
    core::ColourCalibrationPair pair;
    core::RgbdFrame fa, fb;
    if (!dataset->load(a, &fa, &why) || !dataset->load(a + gap, &fb, &why)) return fail(why);
    if (!frame_pose(trajectory, fa, &pair.a.T_world_depth) ||
        !frame_pose(trajectory, fb, &pair.b.T_world_depth)) {
      std::fprintf(stderr, "calibrate-colour: frames %lld/%lld have no pose, pair skipped\n",
                   static_cast<long long>(fa.id), static_cast<long long>(fb.id));
      continue;
    }
    pair.a.colour = fa.colour;
    pair.a.depth = fa.depth;
    pair.b.colour = fb.colour;
    pair.b.depth = fb.depth;
    pairs.push_back(std::move(pair));
    progress.update(k + 1);
  }
  progress.finish();

  core::ColourCalibrationResult result;
  if (!core::calibrate_colour_camera(pairs, dataset->camera(), initial, {}, &result, &why))
    return fail(why);
  const std::string value = result.camera.to_string();
  std::printf("pairs %zu (frames %d apart), %zu depth samples, %d cost evaluations\n",
              pairs.size(), args.gap, result.samples, result.evaluations);
  std::printf("mean capped grey-level difference: %.3f with %s, %.3f with the estimate\n",
              result.initial_cost, had_initial ? "--colour-camera" : "colour registered to depth",
              result.final_cost);
  std::printf("colour camera: fx %.2f fy %.2f cx %.2f cy %.2f px, t (%.4f, %.4f, %.4f) m\n",
              result.camera.camera.fx, result.camera.camera.fy, result.camera.camera.cx,
              result.camera.camera.cy, result.camera.t_colour_depth.x(),
              result.camera.t_colour_depth.y(), result.camera.t_colour_depth.z());
  std::printf("--colour-camera %s\n", value.c_str());
  if (!args.out.empty()) {
    std::ofstream out(args.out);
    out << value << "\n";
    if (!out) return fail(args.out + ": cannot write");
  }
  return 0;
}

}  // namespace

void add_calibrate_colour_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "calibrate-colour",
      "Estimate the colour sensor of a recording whose colour is not registered to depth, from "
      "posed frames; prints the --colour-camera value (a given --colour-camera is the start)");
  auto args = std::make_shared<CalibrateArgs>();
  add_dataset_options(app, &args->dataset);
  app->add_option("--trajectory", args->trajectory,
                  "Depth-camera poses (TUM format) instead of the dataset's ground truth");
  app->add_option("--gap", args->gap, "Frames between the two views of a pair")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  app->add_option("--pairs", args->pairs, "View pairs, spread evenly over the frames")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  app->add_option("--out", args->out, "Also write the value to this file");
  commands->push_back({app, [args] { return run_calibrate(*args); }});
}

}  // namespace fslam::cli

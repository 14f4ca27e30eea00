// `fslam track`: tracking alone (preprocess -> feature-guided GICP -> keyframes) over a dataset,
// with a progress line, a per-stage timing summary and ATE when the dataset has ground truth.
#include <chrono>
#include <cstdio>
#include <future>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <tbb/global_control.h>

#include "commands.hpp"
#include "dataset_args.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/features/latent_features.hpp"
#include "fslam/core/eval/ate.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "fslam/core/tracking/tracker.hpp"
#include "fslam/server/config_options.hpp"

namespace fslam::cli {
namespace {

struct TrackArgs {
  DatasetArgs dataset;
  server::ConfigOptions config;  // --config, --set and the flags that are shorthands for one key
  std::string out;
  int threads = 1;
};

struct StageStats {
  std::vector<double> samples;
  void add(double v) { samples.push_back(v); }
  void print(const char* name) const {
    if (samples.empty()) return;
    const core::ErrorStats stats = core::summarize_errors(samples);  // median, mean
    std::printf("  %-14s median %7.2f ms   p99 %7.2f ms   mean %7.2f ms\n", name, stats.median,
                percentile(samples, 0.99), stats.mean);
  }
};

int run_track(const TrackArgs& args) {
  core::DatasetOptions options;
  std::string why;
  const std::unique_ptr<core::Dataset> dataset = open_dataset(args.dataset, &options, &why);
  if (!dataset) return fail(why);
  if (args.threads < 1) return fail("--threads must be >= 1");

  server::ServerConfig layered;  // track reads its tracker part; other keys do not apply
  if (!args.config.apply(&layered, &why)) return fail(why);
  core::TrackerConfig config = layered.pipeline.tracker;
  if (args.threads > 1) config.parallel = true;
  if (!config.is_valid(&why)) return fail("tracker config: " + why);
  // core has no hidden thread pools: the caller decides how many threads TBB may use.
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(args.threads));

  // Source and keyframe features for eq. feat_gicp: one latent per lattice cell of the frame.
  std::unique_ptr<core::LatentFeatures> features;
  if (layered.pipeline.features.enabled()) {
    features = core::LatentFeatures::create(layered.pipeline.features, &why);
    if (!features) return fail(why);
    std::fprintf(stderr, "features: %s\n", features->describe().c_str());
  }
  core::Tracker tracker(config);
  const std::size_t n = dataset->size();
  std::fprintf(stderr, "tracking %zu frames of %s (%s), %d thread(s)\n", n,
               dataset->root().c_str(), dataset->kind().c_str(), args.threads);

  core::Trajectory trajectory;
  StageStats preprocess, registration, map_update, total, load, encode;
  std::size_t keyframes = 0, lost = 0, recovered = 0;
  Progress progress("track", n);

  // Frames are decoded on a second thread while the current one is tracked.
  auto load_frame = [&](std::size_t i) {
    auto frame = std::make_shared<core::RgbdFrame>();
    std::string load_why;
    const auto t0 = std::chrono::steady_clock::now();
    if (!dataset->load(i, frame.get(), &load_why)) throw std::runtime_error(load_why);
    load.add(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    return frame;
  };
  std::future<std::shared_ptr<core::RgbdFrame>> next = std::async(std::launch::async, load_frame, 0);
  for (std::size_t i = 0; i < n; ++i) {
    const std::shared_ptr<core::RgbdFrame> frame = next.get();
    if (i + 1 < n) next = std::async(std::launch::async, load_frame, i + 1);
    if (i == 0 && frame->T_world_camera_gt) tracker.set_initial_pose(*frame->T_world_camera_gt);

    core::TrackingResult result;
    core::PlanarImage latent;
    if (features) {
      const auto t0 = std::chrono::steady_clock::now();
      const int stride = config.preprocess.stride;
      if (!features->latent_image(frame->colour, frame->camera.width / stride,
                                  frame->camera.height / stride, &latent, &why)) {
        return fail(why);
      }
      encode.add(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
    if (!tracker.track(*frame, &result, &why, features ? &latent : nullptr)) return fail(why);
    if (result.state == core::TrackingState::lost) {
      ++lost;
      std::fprintf(stderr, "\nframe %lld: %s\n", static_cast<long long>(frame->id),
                   result.message.c_str());
    } else if (result.state == core::TrackingState::recovered) {
      ++recovered;
      std::fprintf(stderr, "\nframe %lld: %s\n", static_cast<long long>(frame->id),
                   result.message.c_str());
    }
    keyframes += result.keyframe ? 1 : 0;
    if (i > 0) {  // the first frame only initialises the map
      preprocess.add(result.timings.preprocess_ms);
      registration.add(result.timings.registration_ms);
      map_update.add(result.timings.map_update_ms);
      total.add(result.timings.total_ms);
    }
    trajectory.push_back({frame->timestamp, result.T_world_camera});
    progress.update(i + 1);
  }
  progress.finish();

  if (!core::write_tum_trajectory(args.out, trajectory, &why)) return fail(why);
  std::printf("frames %zu, keyframes %zu, lost %zu, recovered %zu, local map %zu points\n", n,
              keyframes, lost, recovered, tracker.local_map().size());
  std::printf("per-frame timing (%d thread(s), frames after the first):\n", args.threads);
  preprocess.print("preprocess");
  registration.print("registration");
  map_update.print("map update");
  total.print("tracking total");
  load.print("decode (async)");
  if (features) encode.print("features");
  if (dataset->has_ground_truth()) {
    core::AteResult ate;
    if (!core::compute_ate(dataset->ground_truth(), trajectory, core::AteConfig{}, &ate, &why))
      return fail("ATE: " + why);
    std::printf("ATE RMSE %.4f m (mean %.4f, median %.4f, max %.4f) over %zu pairs, SE(3)\n",
                ate.rmse, ate.mean, ate.median, ate.max, ate.pairs);
  }
  std::printf("wrote %s\n", args.out.c_str());
  return 0;
}

}  // namespace

void add_track_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "track", "Track a dataset with feature-guided GICP against a local map (no mapping); "
               "prints timings and ATE when ground truth exists");
  auto args = std::make_shared<TrackArgs>();
  server::add_config_options(app, &args->config);
  add_dataset_options(app, &args->dataset, true, &args->config);
  app->add_option("--out", args->out, "Trajectory to write (TUM format, camera-to-world)")
      ->required();
  app->add_option("--threads", args->threads,
                  "Threads for the GICP reduction (1 = serial; > 1 sets tracker.parallel)")
      ->capture_default_str();
  server::add_setting_option(app, "--features", "features.autoencoder_path",
                             "Feature-guided GICP (eq. feat_gicp) with these autoencoder weights",
                             &args->config);
  server::add_setting_option(app, "--stride", "tracker.preprocess.stride",
                             "Image-lattice stride of the source points", &args->config);
  server::add_setting_option(app, "--voxel", "tracker.preprocess.voxel_size",
                             "Voxel size of the source points in metres, 0 = off", &args->config);
  server::add_setting_option(app, "--max-depth", "tracker.preprocess.max_depth",
                             "Depth beyond this many metres is ignored", &args->config);
  server::add_setting_flag(app, "--constant-velocity", "tracker.constant_velocity", "true",
                           "Start each registration from the constant-velocity prediction instead "
                           "of the last pose (docs/tracking.md says why it is off by default)",
                           &args->config);
  server::add_setting_flag(app, "--no-depth-noise", "tracker.preprocess.depth_noise.enabled",
                           "false",
                           "Give every point the unit-disc covariance instead of scaling it by the "
                           "depth sensor's noise at its depth (the scale-free GICP of earlier "
                           "versions)",
                           &args->config);
  commands->push_back({app, [args] { return run_track(*args); }});
}

}  // namespace fslam::cli

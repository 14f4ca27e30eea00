// `fslam track`: tracking alone (preprocess -> feature-guided GICP -> keyframes) over a dataset,
// with a progress line, a per-stage timing summary and ATE when the dataset has ground truth.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
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
#include "fslam/core/pipeline/loop_closure.hpp"
#include "fslam/core/pipeline/sequence_run.hpp"
#include "fslam/core/tracking/keyframe_policy.hpp"
#include "fslam/server/config_fields.hpp"
#include "fslam/server/config_options.hpp"

namespace fslam::cli {
namespace {

struct TrackArgs {
  DatasetArgs dataset;
  server::ConfigOptions config;  // --config, --set and the flags that are shorthands for one key
  std::string out;
  int threads = 1;
  int relocalise_every = 0;
  bool loop_closure = false;
};

// median, p99 and mean of one stage's per-frame times.
void print_stage(const char* name, const std::vector<double>& samples) {
  if (samples.empty()) return;
  const core::ErrorStats stats = core::summarize_errors(samples);  // median, mean
  std::printf("  %-14s median %7.2f ms   p99 %7.2f ms   mean %7.2f ms\n", name, stats.median,
              percentile(samples, 0.99), stats.mean);
}

void print_timings(const core::SequenceTracking& t, int threads, bool features) {
  std::vector<double> preprocess, registration, map_update, total;
  for (const core::TrackingTimings& timing : t.timings) {
    preprocess.push_back(timing.preprocess_ms);
    registration.push_back(timing.registration_ms);
    map_update.push_back(timing.map_update_ms);
    total.push_back(timing.total_ms);
  }
  std::printf("per-frame timing (%d thread(s), frames after the first):\n", threads);
  print_stage("preprocess", preprocess);
  print_stage("registration", registration);
  print_stage("map update", map_update);
  print_stage("tracking total", total);
  print_stage("decode (async)", t.load_ms);
  if (features) print_stage("features", t.features_ms);
}

// Issue 20's relocalisation benchmark: every n-th non-keyframe frame, with no prior pose, against
// the map and keyframes of the whole run; correct when within 5 cm / 5 degrees of its tracked pose.
bool evaluate_relocalisation(const core::Dataset& dataset, const core::Tracker& tracker,
                             const core::SequenceTracking& t, int every, std::string* why) {
  constexpr double kTranslation = 0.05, kRotationDeg = 5.0;
  std::vector<std::size_t> queries;
  for (std::size_t i = 1, n = 0; i < t.trajectory.size(); ++i)
    if (!t.keyframe[i] && n++ % static_cast<std::size_t>(every) == 0) queries.push_back(i);
  std::fprintf(stderr, "relocalising %zu frames against %zu described keyframes and a %zu-point map\n",
               queries.size(), tracker.relocaliser().size(), tracker.local_map().size());
  std::size_t accepted = 0, correct = 0, wrong = 0;
  std::vector<double> total_ms, describe_ms, search_ms;
  Progress progress("relocalise", queries.size());
  for (std::size_t q = 0; q < queries.size(); ++q) {
    const std::size_t i = queries[q];
    core::RgbdFrame frame;
    core::PreparedSource prepared;
    if (!dataset.load(t.frame_index[i], &frame, why) || !tracker.preprocess(frame, nullptr, &prepared, why))
      return false;
    const core::RelocalisationAttempt a = tracker.relocalise(frame, prepared);
    total_ms.push_back(prepared.preprocess_ms + a.describe_ms + a.time_ms);
    describe_ms.push_back(a.describe_ms);
    search_ms.push_back(a.time_ms);
    if (a.accepted) {
      ++accepted;
      const core::PoseMotion e = core::pose_motion(t.trajectory[i].T_world_camera, a.T_world_camera);
      const bool ok = e.translation <= kTranslation && e.rotation * 180.0 / M_PI <= kRotationDeg;
      ok ? ++correct : ++wrong;
      if (!ok)
        std::fprintf(stderr, "\nframe %lld: wrong acceptance, %.3f m / %.2f deg from its tracked pose (%s)\n",
                     static_cast<long long>(frame.id), e.translation, e.rotation * 180.0 / M_PI, a.message.c_str());
    }
    progress.update(q + 1);
  }
  progress.finish();
  const double n = std::max<double>(1.0, static_cast<double>(queries.size()));
  std::printf("relocalisation: %zu frames (every %d-th non-keyframe), accepted %zu, within 5 cm / 5 deg %zu "
              "(%.1f %%), wrong acceptances %zu (%.1f %%)\n",
              queries.size(), every, accepted, correct, 100.0 * correct / n, wrong, 100.0 * wrong / n);
  print_stage("reloc total", total_ms);
  print_stage("reloc describe", describe_ms);
  print_stage("reloc search", search_ms);
  return true;
}

int run_track(const TrackArgs& args) {
  core::DatasetOptions options;
  std::string why;
  const std::unique_ptr<core::Dataset> dataset = open_dataset(args.dataset, &options, &why);
  if (!dataset) return fail(why);
  if (args.threads < 1) return fail("--threads must be >= 1");
  if (args.relocalise_every < 0) return fail("--relocalise-every must be >= 0");
  if (args.relocalise_every > 0 && args.loop_closure)
    return fail("--relocalise-every measures against the tracked map; run it without --loop-closure");

  server::RunConfig layered = server::run_defaults();  // track reads its tracker part
  if (!args.config.apply(&layered, &why)) return fail(why);
  core::PipelineConfig config = layered.pipeline;
  config.mapping = false;  // tracking alone
  // --loop-closure runs after tracking here, with the loop_closure.* settings; not on a thread.
  const core::LoopClosureConfig loop_config = config.loop_closure;
  config.loop_closure.enabled = false;
  if (args.threads > 1) config.tracker.parallel = true;
  if (!config.tracker.is_valid(&why)) return fail("tracker config: " + why);
  // core has no hidden thread pools: the caller decides how many threads TBB may use.
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(args.threads));

  // Source and keyframe features for eq. feat_gicp: one latent per lattice cell of the frame.
  std::unique_ptr<core::LatentFeatures> features;
  if (config.features.enabled()) {
    features = core::LatentFeatures::create(config.features, &why);
    if (!features) return fail(why);
    std::fprintf(stderr, "features: %s\n", features->describe().c_str());
  }
  const bool with_features = features != nullptr && config.track_with_features;
  core::SlamPipeline pipeline(config, nullptr, std::move(features));
  const std::size_t n = dataset->size();
  std::fprintf(stderr, "tracking %zu frames of %s (%s), %d thread(s)\n", n,
               dataset->root().c_str(), dataset->kind().c_str(), args.threads);

  Progress progress("track", n);
  core::SequenceCallbacks callbacks;
  callbacks.on_frame = [&](std::size_t done, std::size_t) { progress.update(done); };
  callbacks.on_tracking_event = [](std::int64_t id, const core::TrackingResult& result) {
    std::fprintf(stderr, "\nframe %lld: %s\n", static_cast<long long>(id), result.message.c_str());
  };
  core::SequenceTracking t;
  if (!core::track_sequence(*dataset, &pipeline, core::SequenceRunConfig{}, callbacks, &t, &why)) {
    return fail(why);
  }
  progress.finish();

  // The last frame's distance from its ground truth: the tracker starts at the first frame's, so
  // on a loop path this is the end-to-start error.
  const auto last_error = [&](const core::Trajectory& trajectory) {
    const core::Trajectory truth = dataset->ground_truth();  // gt points into it
    const core::StampedPose* gt = core::nearest_pose(truth, trajectory.back().timestamp, 0.02);
    return gt ? (gt->T_world_camera.translation() - trajectory.back().T_world_camera.translation()).norm() : -1.0;
  };
  if (args.loop_closure) {
    const double before = dataset->has_ground_truth() ? last_error(t.trajectory) : -1.0;
    core::AteResult ate_before;
    if (dataset->has_ground_truth() &&
        !core::compute_ate(dataset->ground_truth(), t.trajectory, core::AteConfig{}, &ate_before, &why))
      return fail("ATE: " + why);
    core::LoopClosureResult loops;
    Progress loop_progress("loop closure", t.keyframes());
    if (!core::close_loops(*dataset, config.tracker, loop_config, &t, &loops, &why,
                           [&](std::size_t done, std::size_t) { loop_progress.update(done); }))
      return fail("loop closure: " + why);
    loop_progress.finish();
    std::printf("loop closure: %zu keyframes, %zu loop(s), %zu candidate(s) refused, %.1f s%s%s\n", loops.keyframes,
                loops.loops.size(), loops.rejected, loops.seconds, loops.loops.empty() ? "" : "; ",
                loops.loops.empty() ? "" : loops.graph.message.c_str());
    if (dataset->has_ground_truth())
      std::printf("before loop closure: ATE RMSE %.4f m, last frame %.4f m from its ground truth\n", ate_before.rmse,
                  before);
  }
  if (!core::write_tum_trajectory(args.out, t.trajectory, &why)) return fail(why);
  std::printf("frames %zu, keyframes %zu, lost %zu, recovered %zu, wide-baseline restarts %zu, local map %zu points\n",
              n, t.keyframes(), t.lost, t.recovered, t.wide_baseline, pipeline.tracker().local_map().size());
  print_timings(t, args.threads, with_features);
  if (dataset->has_ground_truth()) {
    core::AteResult ate;
    if (!core::compute_ate(dataset->ground_truth(), t.trajectory, core::AteConfig{}, &ate, &why))
      return fail("ATE: " + why);
    std::printf("ATE RMSE %.4f m (mean %.4f, median %.4f, max %.4f) over %zu pairs, SE(3)\n",
                ate.rmse, ate.mean, ate.median, ate.max, ate.pairs);
    if (args.loop_closure) std::printf("last frame %.4f m from its ground truth\n", last_error(t.trajectory));
  }
  if (args.relocalise_every > 0 &&
      !evaluate_relocalisation(*dataset, pipeline.tracker(), t, args.relocalise_every, &why))
    return fail("relocalisation: " + why);
  std::printf("wrote %s\n", args.out.c_str());
  return 0;
}

}  // namespace

void add_track_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "track", "Track a dataset with feature-guided GICP against a local map (no mapping); "
               "prints timings and ATE when ground truth exists");
  auto args = std::make_shared<TrackArgs>();
  server::add_config_options(app, &args->config, server::SettingsKind::run);
  add_dataset_options(app, &args->dataset, true, &args->config);
  app->add_option("--out", args->out, "Trajectory to write (TUM format, camera-to-world)")
      ->required();
  app->add_option("--threads", args->threads,
                  "Threads for the GICP reduction (1 = serial; > 1 sets tracker.parallel)")
      ->capture_default_str();
  app->add_option("--relocalise-every", args->relocalise_every,
                  "After tracking, relocalise every n-th non-keyframe frame with no prior pose against "
                  "the whole run's map and report accuracy and time (0 = off)")
      ->capture_default_str();
  app->add_flag("--loop-closure", args->loop_closure,
               "After tracking, find revisits among the keyframes, optimise their pose graph (Ceres) "
               "and correct the trajectory (docs/relocalisation.md)");
  server::add_setting_option(app, "--loop-gap", "loop_closure.min_frame_gap",
                             "Frames between a keyframe and an older one it may close a loop with", &args->config);
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

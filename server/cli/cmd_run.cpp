// `fslam run`: tracking and mapping together in one process (tracking on this thread, mapping
// on a second one; tracking never waits for mapping), then the outputs of docs/mapping.md:
// trajectory, map.ply, metrics.json and side-by-side renders.
#include <sys/resource.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>
#include <tbb/global_control.h>

#include "commands.hpp"
#include "dataset_args.hpp"
#include "fslam/server/render_images.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/error.hpp"
#include "fslam/core/eval/ate.hpp"
#include "fslam/core/eval/view_eval.hpp"
#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "fslam/core/pipeline/sequence_run.hpp"
#include "fslam/server/backend_factory.hpp"
#include "fslam/server/config_fields.hpp"
#include "fslam/server/config_options.hpp"
#include "fslam/server/mapping_thread.hpp"

namespace fslam::cli {
namespace {

namespace fs = std::filesystem;

struct RunArgs {
  DatasetArgs dataset;
  server::ConfigOptions config;  // --config, --set and the flags that are shorthands for one key
  std::string out;
  int refine = 0;
  double realtime_fps = 0.0;  // 0: as fast as it can
  int threads = 2;
  std::string resume;
  int renders = 4;
  std::string backend = "auto";
  int eval_every = 8;
  bool gt_poses = false;
};

double peak_rss_mib() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // ru_maxrss is KiB on Linux
}

nlohmann::json timing_json(const std::vector<double>& samples) {
  if (samples.empty()) return {{"count", 0}};
  const core::ErrorStats s = core::summarize_errors(samples);
  return {{"count", samples.size()},
          {"median_ms", s.median},
          {"p99_ms", percentile(samples, 0.99)},
          {"mean_ms", s.mean},
          {"max_ms", s.max}};
}

// Median and 10th / 90th percentiles of the finite samples (none: count 0).
nlohmann::json spread_json(const std::vector<double>& samples, double unit) {
  std::vector<double> finite;
  for (double v : samples)
    if (std::isfinite(v)) finite.push_back(v * unit);
  if (finite.empty()) return {{"count", 0}};
  return {{"count", finite.size()},
          {"p10", percentile(finite, 0.10)},
          {"median", percentile(finite, 0.5)},
          {"p90", percentile(finite, 0.90)}};
}

nlohmann::json views_json(const core::ViewScores& scores) {
  const core::ViewScore m = scores.mean();
  return {{"frames", scores.views.size()},
          {"psnr_db", m.psnr_db},
          {"ssim", m.ssim},
          {"depth_l1_cm", m.depth_l1_cm},
          {"depth_l1_median_cm", m.depth_l1_median_cm},
          {"depth_missing_fraction", m.depth_missing_fraction}};
}

void print_views(const char* label, const core::ViewScores& scores) {
  const core::ViewScore m = scores.mean();
  std::printf("%s %zu: PSNR %.2f dB, SSIM %.3f, depth L1 %.2f cm (median depth %.2f cm)\n", label,
              scores.views.size(), m.psnr_db, m.ssim, m.depth_l1_cm, m.depth_l1_median_cm);
}

// The input beside the render: colour, depth (turbo, 0-5 m), and the render's normals.
bool write_panel(const fs::path& folder, const core::RgbdFrame& frame, const core::RenderResult& rendered,
                 std::string* why) {
  const cv::Mat rgb = core::colour_to_rgb8(rendered.colour);
  const cv::Mat median = server::plane_to_mat(rendered.median_depth, 0);
  const cv::Mat nrm = server::normals_to_rgb8(rendered.median_depth, frame.camera.intrinsics());
  const double max_depth = 5.0;
  cv::Mat top, bottom, third, panel;
  cv::hconcat(frame.colour, rgb, top);
  cv::hconcat(server::depth_to_rgb8(frame.depth, max_depth), server::depth_to_rgb8(median, max_depth), bottom);
  const cv::Mat blank(frame.colour.rows, frame.colour.cols, CV_8UC3, cv::Scalar(0, 0, 0));
  cv::hconcat(blank, nrm, third);
  cv::vconcat(std::vector<cv::Mat>{top, bottom, third}, panel);
  const std::string name = "frame_" + std::to_string(frame.id) + ".png";
  return core::write_image((folder / "renders" / name).string(), panel, why);
}

// The pipeline's config from the settings layers, with the features it maps (null: none).
bool make_config(const RunArgs& args, core::PipelineConfig* config,
                 std::unique_ptr<core::LatentFeatures>* features, std::string* why) {
  server::RunConfig layered = server::run_defaults();
  if (!args.config.apply(&layered, why)) return false;
  *config = layered.pipeline;
  if (args.realtime_fps > 0.0) {
    config->realtime = true;
  } else if (config->realtime) {
    return core::fail(why, "realtime is set but fslam run needs the rate to pace the dataset at: add "
                           "--realtime FPS");
  }
  if (config->features.enabled()) {
    *features = core::LatentFeatures::create(config->features, why);
    if (!*features) return false;
    std::fprintf(stderr, "features: %s\n", (*features)->describe().c_str());
  }
  if (!config->is_valid(why)) return core::fail(why, "config: " + *why);
  return true;
}

// Timings the mapping thread reports, and the progress line once tracking is done.
struct MappingProgress {
  std::vector<double> keyframe_ms, features_ms;
  std::atomic<std::size_t> mapped{0};
  std::mutex mutex;
  std::unique_ptr<Progress> progress;  // once tracking is done: the keyframes left
  std::string error;
  void on_keyframe(const core::KeyframeReport& r) {
    keyframe_ms.push_back(r.refinement.insert_ms + r.refinement.optimise_ms + r.refinement.prune_ms);
    features_ms.push_back(r.features_ms);
    const std::size_t done = mapped.fetch_add(1) + 1;
    std::lock_guard<std::mutex> lock(mutex);
    if (progress) progress->update(done);
  }
  void start(std::size_t keyframes) {
    std::lock_guard<std::mutex> lock(mutex);
    // Keyframes still to map: those queued plus the one in progress (counted as left).
    progress = std::make_unique<Progress>("map", std::max<std::size_t>(keyframes, 1));
    progress->update(mapped.load());
  }
};

nlohmann::json metrics_json(const RunArgs& args, const core::Dataset& dataset,
                            const core::DatasetOptions& options, const core::PipelineConfig& config,
                            const core::SequenceRunResult& run, const MappingProgress& mapping) {
  const core::SequenceTracking& t = run.tracking;
  const std::size_t n = dataset.size();
  nlohmann::json metrics;
  metrics["dataset"] = {{"path", dataset.root()}, {"kind", dataset.kind()}, {"frames", n}};
  // Colour was resampled onto the depth pixels: the held-out images are the registered ones.
  if (options.colour_camera) metrics["dataset"]["colour_camera"] = options.colour_camera->to_string();
  metrics["mode"] = config.realtime ? "realtime" : "fast";
  metrics["mapping_poses"] = args.gt_poses ? "ground truth" : "tracked";
  if (config.realtime) metrics["realtime_fps"] = args.realtime_fps;
  metrics["threads"] = args.threads;
  metrics["held_out"] = views_json(run.held_out);
  metrics["held_out"]["rule"] = "every " + std::to_string(args.eval_every) +
                                "th non-keyframe frame; never used for training";
  metrics["keyframes"] = views_json(run.keyframes);
  metrics["depth_rendering"] =
      "depth_l1_cm: expected camera-plane depth, depth_l1_median_cm: median depth; pixels with "
      "valid sensor depth, holes count fully";
  metrics["map"] = {{"gaussians", run.map_gaussians},
                    {"keyframes", run.map_keyframes},
                    {"optimisation_steps", run.optimisation_steps}};
  if (std::isfinite(run.feature_error_online)) {
    metrics["decoded_features"] = {{"held_out_error_pretrained", run.feature_error_pretrained},
                                   {"held_out_error_online", run.feature_error_online},
                                   {"lora_steps", run.lora_steps},
                                   {"unit", "mean |decoded - encoder| per channel spread (loss_l1)"}};
  }
  metrics["timing"] = {{"slam_wall_s", run.slam_s},
                       {"frames_per_second", static_cast<double>(n) / run.slam_s},
                       {"tracking_wall_s", t.wall_s},
                       {"refine_s", run.refine_s},
                       {"tracking_per_frame", timing_json(t.track_ms)},
                       {"tracking_cpu_per_frame", timing_json(t.track_cpu_ms)},
                       {"tracking_features_per_frame", timing_json(t.features_ms)},
                       {"mapping_per_keyframe", timing_json(mapping.keyframe_ms)},
                       {"features_per_keyframe", timing_json(mapping.features_ms)}};
  metrics["registration"] = {{"inlier_ratio", spread_json(t.inlier_ratio, 1.0)},
                             {"rms_residual_mm", spread_json(t.rms_residual_m, 1000.0)},
                             {"mahalanobis", spread_json(t.mahalanobis, 1.0)},
                             {"feature_weight", spread_json(t.feature_weight, 1.0)},
                             {"note", "per frame at the registered pose, means over its inliers; mahalanobis: "
                                      "d^T C^-1 d (near-planar covariances: the distance off the "
                                      "target's surfaces); feature_weight: eq. feat_dist's "
                                      "similarity (1: identical features)"}};
  metrics["frames"] = {{"tracked", t.trajectory.size()}, {"lost", t.lost}, {"skipped", t.skipped},
                       {"keyframes", t.keyframes()}};
  metrics["memory"] = {{"peak_rss_mib", peak_rss_mib()}};
  if (run.loop_closure) {
    const core::LoopThreadStats& l = *run.loop_closure;
    metrics["loop_closure"] = {{"keyframes", l.keyframes}, {"loops", l.loops},   {"rejected", l.rejected},
                               {"solves", l.solves},       {"left_out", l.left_out}, {"last_solve_ms", l.last_solve_ms},
                               {"error", l.error}};
  }
  return metrics;
}

// The progress lines of a run's stages on stderr (refinement and evaluation from their start).
struct RunProgress {
  explicit RunProgress(std::size_t n) : frames("slam", n) {}
  Progress frames;
  std::optional<Progress> refine, evaluate;
};

int write_outputs(const RunArgs& args, const core::Dataset& dataset, const core::DatasetOptions& options,
                  const core::PipelineConfig& config, const core::SlamPipeline& pipeline,
                  const core::SequenceRunResult& run, const MappingProgress& mapping) {
  std::string why;
  const fs::path out(args.out);
  const core::SequenceTracking& t = run.tracking;
  if (!core::write_tum_trajectory((out / "trajectory.txt").string(), t.trajectory, &why)) return fail(why);
  if (!core::write_gaussian_ply((out / "map.ply").string(), pipeline.mapper().map(), &why)) return fail(why);
  // The online heads the map's latents were fitted through (the decoded L_feat), as a server saves
  // them with a map: decoding those latents needs these, not the pretrained ones.
  const std::shared_ptr<const core::FeatureAutoencoder> heads = pipeline.feature_heads();
  if (heads && !heads->save((out / "heads.fae").string(), &why)) return fail(why);
  nlohmann::json metrics = metrics_json(args, dataset, options, config, run, mapping);
  if (dataset.has_ground_truth()) {
    core::AteResult ate;
    if (core::compute_ate(dataset.ground_truth(), t.trajectory, core::AteConfig{}, &ate, &why)) {
      metrics["ate"] = {{"rmse_m", ate.rmse}, {"mean_m", ate.mean}, {"median_m", ate.median},
                        {"max_m", ate.max},   {"pairs", ate.pairs}, {"alignment", "SE3"}};
      std::printf("ATE RMSE %.4f m (mean %.4f) over %zu frames, SE(3)\n", ate.rmse, ate.mean,
                  ate.pairs);
    } else {
      std::fprintf(stderr, "ATE: %s\n", why.c_str());
    }
  }
  std::ofstream(out / "metrics.json") << metrics.dump(2) << "\n";
  const std::size_t n = dataset.size();
  std::printf("frames %zu (skipped %zu, lost %zu), keyframes %zu, map %zu Gaussians\n", n, t.skipped,
              t.lost, run.map_keyframes, run.map_gaussians);
  std::printf("SLAM wall time %.1f s = %.2f frames/s (%d thread(s)); peak RSS %.0f MiB\n", run.slam_s,
              static_cast<double>(n) / run.slam_s, args.threads, peak_rss_mib());
  if (run.loop_closure) {
    const core::LoopThreadStats& l = *run.loop_closure;
    std::printf("loop closure: %zu keyframes, %zu loop(s), %zu candidate(s) refused, %zu solve(s) (last %.0f ms)%s%s\n",
                l.keyframes, l.loops, l.rejected, l.solves, l.last_solve_ms, l.error.empty() ? "" : "; stopped: ",
                l.error.c_str());
  }
  print_views("held-out frames", run.held_out);
  print_views("keyframes", run.keyframes);
  if (std::isfinite(run.feature_error_online)) {
    std::printf("decoded features, held-out: error %.4f with the pretrained heads, %.4f after %lld LoRA steps\n",
                run.feature_error_pretrained, run.feature_error_online, static_cast<long long>(run.lora_steps));
  }
  std::printf("wrote %s/{trajectory.txt,map.ply,%smetrics.json,renders/}\n", args.out.c_str(), heads ? "heads.fae," : "");
  return 0;
}

int run_slam(const RunArgs& args) {
  core::DatasetOptions options;
  std::string why;
  const std::unique_ptr<core::Dataset> dataset = open_dataset(args.dataset, &options, &why);
  if (!dataset) return fail(why);
  if (args.threads < 1) return fail("--threads must be >= 1");
  if (args.realtime_fps < 0.0) return fail("--realtime must be > 0 frames per second");
  if (args.refine < 0) return fail("--refine must be >= 0");
  std::string notice;
  std::shared_ptr<const core::Rasterizer> rasterizer =
      server::make_rasterizer(args.backend, server::RasterUse::kMapping, &notice, &why);
  if (!rasterizer) return fail(why);
  if (!notice.empty()) std::fprintf(stderr, "%s\n", notice.c_str());
  core::PipelineConfig config;
  std::unique_ptr<core::LatentFeatures> features;
  if (!make_config(args, &config, &features, &why)) return fail(why);
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(args.threads));
  std::error_code ec;
  fs::create_directories(fs::path(args.out) / "renders", ec);
  if (ec) return fail("cannot create " + args.out + ": " + ec.message());

  core::SlamPipeline pipeline(config, rasterizer, std::move(features));
  if (!args.resume.empty()) {
    core::GaussianMap resumed;
    if (!core::read_gaussian_ply(args.resume, &resumed, &why)) return fail(why);
    resumed.feature_dim = std::min(resumed.feature_dim, pipeline.config().mapper.feature_dim);
    resumed.features.clear();
    if (!pipeline.mapper().set_map(resumed, &why)) return fail(args.resume + ": " + why);
    std::fprintf(stderr, "resumed %zu Gaussians from %s\n", resumed.size(), args.resume.c_str());
  }
  const std::size_t n = dataset->size();
  std::fprintf(stderr, "running SLAM on %zu frames of %s (%s), %d thread(s), %s\n", n,
               dataset->root().c_str(), dataset->kind().c_str(), args.threads,
               config.realtime ? ("real time at " + std::to_string(args.realtime_fps) + " fps").c_str()
                               : "as fast as it can");

  // In real time the tracker must keep a core to itself (a live sensor does not wait), so
  // mapping's parallel loops get one thread fewer; as fast as it can, they may use all.
  MappingProgress mapping_progress;
  const int mapping_threads = config.realtime ? std::max(1, args.threads - 1) : args.threads;
  server::MappingThread mapping(
      &pipeline, mapping_threads, config.realtime,
      [&](const core::KeyframeReport& r) { mapping_progress.on_keyframe(r); },
      [&](const std::string& mwhy) { mapping_progress.error = mwhy; });

  core::SequenceRunConfig run_config;
  run_config.realtime_fps = config.realtime ? args.realtime_fps : 0.0;
  run_config.ground_truth_poses = args.gt_poses;
  run_config.refine_steps = args.refine;
  run_config.eval_every = args.eval_every;
  run_config.renders = args.renders;
  RunProgress progress(n);
  core::SequenceCallbacks callbacks;
  callbacks.on_frame = [&](std::size_t done, std::size_t) { progress.frames.update(done); };
  callbacks.on_tracking_event = [](std::int64_t id, const core::TrackingResult& result) {
    if (result.state == core::TrackingState::lost)
      std::fprintf(stderr, "\nframe %lld: %s\n", static_cast<long long>(id), result.message.c_str());
  };
  callbacks.on_tracking_done = [&](const core::SequenceTracking& t, std::size_t queued) {
    progress.frames.finish();
    std::fprintf(stderr, "tracking done in %.1f s; mapping %zu queued keyframe(s)\n", t.wall_s, queued);
    mapping_progress.start(t.keyframes());
  };
  callbacks.wait_for_mapping = [&](std::string* mwhy) {
    mapping.finish_fairly();  // the run waits for it now: no longer background work
    mapping.join();
    if (mapping_progress.progress) mapping_progress.progress->finish();
    return mapping_progress.error.empty() || core::fail(mwhy, mapping_progress.error);
  };
  callbacks.on_refine = [&](int done, int total) {
    if (!progress.refine) progress.refine.emplace("refine", static_cast<std::size_t>(total));
    progress.refine->update(static_cast<std::size_t>(done));
  };
  callbacks.on_evaluated = [&](std::size_t done, std::size_t total) {
    if (progress.refine) progress.refine->finish(), progress.refine.reset();
    if (!progress.evaluate) progress.evaluate.emplace("evaluate", total);
    progress.evaluate->update(done);
    if (done == total) progress.evaluate->finish();
  };
  const fs::path out(args.out);
  callbacks.on_render = [&](const core::RgbdFrame& frame, const core::RenderResult& rendered, std::string* rwhy) {
    return write_panel(out, frame, rendered, rwhy);
  };
  core::SequenceRunResult run;
  if (!core::run_sequence(*dataset, &pipeline, *rasterizer, run_config, callbacks, &run, &why)) return fail(why);
  if (progress.refine) progress.refine->finish();
  return write_outputs(args, *dataset, options, config, pipeline, run, mapping_progress);
}

}  // namespace

void add_run_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "run", "Track and map a dataset (3DGS mapping on a second thread); writes the trajectory, "
             "map.ply, metrics.json and renders");
  auto args = std::make_shared<RunArgs>();
  server::add_config_options(app, &args->config, server::SettingsKind::run);
  add_dataset_options(app, &args->dataset, true, &args->config);
  app->add_option("--out", args->out, "Output folder")->required();
  app->add_option("--refine", args->refine, "Post-trajectory refinement steps (0 = off)")
      ->capture_default_str();
  app->add_option("--realtime", args->realtime_fps,
                  "Pace the input like a live sensor at this many frames per second; mapping "
                  "gets the time that is left (default: as fast as it can)");
  app->add_option("--threads", args->threads, "Threads for rendering and optimisation")
      ->capture_default_str();
  server::add_setting_option(app, "--features", "features.autoencoder_path",
                             "Distil image features into the Gaussians with these autoencoder weights "
                             "(deploy/make_builtin_autoencoder.sh)",
                             &args->config);
  server::add_setting_option(app, "--iterations", "mapper.iterations_per_keyframe",
                             "Gradient steps per keyframe", &args->config);
  server::add_setting_option(app, "--sh-degree", "mapper.sh_degree",
                             "Spherical-harmonics degree 0-3", &args->config);
  app->add_option("--resume", args->resume, "Start from a saved map.ply");
  app->add_option("--renders", args->renders, "Held-out frames rendered beside the input")
      ->capture_default_str();
  app->add_option("--backend", args->backend, "Compute backend: auto, cpu or cuda")
      ->capture_default_str();
  app->add_option("--eval-every", args->eval_every,
                  "Every n-th non-keyframe frame is held out for evaluation")
      ->capture_default_str();
  server::add_setting_option(app, "--prune-tracking", "mapper.prune_percentile_tracking",
                             "Importance-pruning percentile on tracking keyframes, 0..1",
                             &args->config);
  server::add_setting_option(app, "--prune-mapping", "mapper.prune_percentile_mapping",
                             "Importance-pruning percentile on mapping keyframes, 0..1",
                             &args->config);
  server::add_setting_option(app, "--training-scale", "mapper.training_scale",
                             "Training renders at this fraction of the input size", &args->config);
  server::add_setting_option(app, "--insert-stride", "mapper.insert_stride",
                             "Pixel stride of new Gaussians on the training image", &args->config);
  server::add_setting_flag(app, "--loop-closure", "loop_closure.enabled", "true",
                           "Loop closure during tracking on its own thread, moving the map's Gaussians "
                           "(docs/relocalisation.md)",
                           &args->config);
  app->add_flag("--ground-truth-poses", args->gt_poses,
                "Map and render at the ground-truth poses (tracking still runs and is scored): "
                "map quality without tracking drift");
  commands->push_back({app, [args] { return run_slam(*args); }});
}

}  // namespace fslam::cli

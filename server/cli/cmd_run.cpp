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
#include <future>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
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
#include "fslam/core/eval/image_metrics.hpp"
#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "fslam/core/mapping/image_losses.hpp"
#include "fslam/core/pipeline/slam_pipeline.hpp"
#include "fslam/server/backend_factory.hpp"
#include "fslam/server/config_options.hpp"
#include "fslam/server/mapping_thread.hpp"

namespace fslam::cli {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

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

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

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

struct EvalSet {
  // depth_l1_cm scores the expected camera-plane depth D (eq. blending with the planar depth),
  // the depth the losses train; depth_l1_median_cm the median depth (docs/evaluation.md).
  std::vector<double> psnr, ssim, depth_l1_cm, depth_l1_median_cm, depth_missing;
  nlohmann::json to_json() const {
    auto mean = [](const std::vector<double>& v) {
      double s = 0;
      for (double x : v) s += x;
      return v.empty() ? 0.0 : s / static_cast<double>(v.size());
    };
    return {{"frames", psnr.size()},
            {"psnr_db", mean(psnr)},
            {"ssim", mean(ssim)},
            {"depth_l1_cm", mean(depth_l1_cm)},
            {"depth_l1_median_cm", mean(depth_l1_median_cm)},
            {"depth_missing_fraction", mean(depth_missing)}};
  }
  void print(const char* label) const {
    const nlohmann::json j = to_json();
    std::printf("%s %zu: PSNR %.2f dB, SSIM %.3f, depth L1 %.2f cm (median depth %.2f cm)\n",
                label, psnr.size(), j["psnr_db"].get<double>(), j["ssim"].get<double>(),
                j["depth_l1_cm"].get<double>(), j["depth_l1_median_cm"].get<double>());
  }
};

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

  server::ServerConfig layered;  // run reads its pipeline part; server.* keys do not apply
  layered.pipeline = core::PipelineConfig{};  // offline by default (the server's is real-time)
  // Without features (no autoencoder weights) the Gaussians carry none; with them, the latent.
  layered.pipeline.mapper.feature_dim = 0;
  if (!args.config.apply(&layered, &why)) return fail(why);
  core::PipelineConfig config = layered.pipeline;
  if (args.realtime_fps > 0.0) {
    config.realtime = true;
  } else if (config.realtime) {
    return fail("realtime is set but fslam run needs the rate to pace the dataset at: add "
                "--realtime FPS");
  }
  std::unique_ptr<core::LatentFeatures> features;
  if (config.features.enabled()) {
    features = core::LatentFeatures::create(config.features, &why);
    if (!features) return fail(why);
    config.mapper.feature_dim = features->dim();
    std::fprintf(stderr, "features: %s\n", features->describe().c_str());
  }
  if (!config.is_valid(&why)) return fail("config: " + why);
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(args.threads));
  std::error_code ec;
  fs::create_directories(fs::path(args.out) / "renders", ec);
  if (ec) return fail("cannot create " + args.out + ": " + ec.message());

  core::SlamPipeline pipeline(config, rasterizer, std::move(features));
  if (!args.resume.empty()) {
    core::GaussianMap resumed;
    if (!core::read_gaussian_ply(args.resume, &resumed, &why)) return fail(why);
    resumed.feature_dim = std::min(resumed.feature_dim, config.mapper.feature_dim);
    resumed.features.clear();
    if (!pipeline.mapper().set_map(resumed, &why)) return fail(args.resume + ": " + why);
    std::fprintf(stderr, "resumed %zu Gaussians from %s\n", resumed.size(), args.resume.c_str());
  }
  const std::size_t n = dataset->size();
  std::fprintf(stderr, "running SLAM on %zu frames of %s (%s), %d thread(s), %s\n", n,
               dataset->root().c_str(), dataset->kind().c_str(), args.threads,
               config.realtime ? ("real time at " + std::to_string(args.realtime_fps) + " fps").c_str()
                               : "as fast as it can");

  // Mapping thread.
  std::vector<double> keyframe_ms, features_ms;
  std::atomic<std::size_t> mapped{0};
  std::mutex progress_mutex;
  std::unique_ptr<Progress> mapping_progress;  // once tracking is done: the keyframes left
  std::string mapping_error;
  const Clock::time_point start = Clock::now();
  // In real time the tracker must keep a core to itself (a live sensor does not wait), so
  // mapping's parallel loops get one thread fewer; as fast as it can, they may use all.
  const int mapping_threads = config.realtime ? std::max(1, args.threads - 1) : args.threads;
  server::MappingThread mapping(
      &pipeline, mapping_threads, config.realtime,
      [&](const core::KeyframeReport& r) {
        keyframe_ms.push_back(r.refinement.insert_ms + r.refinement.optimise_ms + r.refinement.prune_ms);
        features_ms.push_back(r.features_ms);
        const std::size_t done = mapped.fetch_add(1) + 1;
        std::lock_guard<std::mutex> lock(progress_mutex);
        if (mapping_progress) mapping_progress->update(done);
      },
      [&](const std::string& mwhy) { mapping_error = mwhy; });

  // Tracking on this thread, frames decoded one ahead on another.
  core::Trajectory trajectory;
  std::vector<std::size_t> frame_index;  // dataset index of each trajectory entry
  std::vector<bool> is_keyframe;
  std::vector<Eigen::Isometry3d> eval_poses;  // with --ground-truth-poses: where views are rendered
  std::vector<double> track_ms;
  std::vector<double> track_features_ms;  // the frame's latent for feature-guided GICP, in track_ms
  std::size_t lost = 0, skipped = 0;
  Progress progress("slam", n);
  auto load_frame = [&](std::size_t i) {
    auto frame = std::make_shared<core::RgbdFrame>();
    std::string load_why;
    if (!dataset->load(i, frame.get(), &load_why)) throw std::runtime_error(load_why);
    return frame;
  };
  std::future<std::shared_ptr<core::RgbdFrame>> next = std::async(std::launch::async, load_frame, 0);
  const double period_s = config.realtime ? 1.0 / args.realtime_fps : 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    std::shared_ptr<core::RgbdFrame> frame = next.get();
    if (i + 1 < n) next = std::async(std::launch::async, load_frame, i + 1);
    if (config.realtime) {
      // A live sensor: frame i arrives at start + i / fps. When the next frame has already
      // arrived, this one is stale and a live system would never see it: count it as skipped.
      const double now_s = std::chrono::duration<double>(Clock::now() - start).count();
      const double arrival = static_cast<double>(i) * period_s;
      if (now_s < arrival) {
        std::this_thread::sleep_for(std::chrono::duration<double>(arrival - now_s));
      } else if (i > 0 && now_s >= arrival + period_s) {
        ++skipped;
        progress.update(i + 1);
        continue;
      }
    }
    if (i == 0 && frame->T_world_camera_gt) pipeline.set_initial_pose(*frame->T_world_camera_gt);
    core::TrackingResult result;
    const Clock::time_point t0 = Clock::now();
    if (args.gt_poses && !frame->T_world_camera_gt) {
      pipeline.finish();
      mapping.join();
      return fail("--ground-truth-poses: frame " + std::to_string(frame->id) + " has no ground truth");
    }
    const Eigen::Isometry3d* mapping_pose = args.gt_poses ? &*frame->T_world_camera_gt : nullptr;
    if (!pipeline.process_frame(*frame, &result, &why, mapping_pose)) {
      pipeline.finish();
      mapping.join();
      return fail(why);
    }
    if (i > 0) track_ms.push_back(ms_between(t0, Clock::now()));
    if (i > 0 && result.timings.features_ms > 0) track_features_ms.push_back(result.timings.features_ms);
    if (result.state == core::TrackingState::lost) {
      ++lost;
      std::fprintf(stderr, "\nframe %lld: %s\n", static_cast<long long>(frame->id),
                   result.message.c_str());
    }
    trajectory.push_back({frame->timestamp, result.T_world_camera});
    if (args.gt_poses) eval_poses.push_back(*frame->T_world_camera_gt);
    frame_index.push_back(i);
    is_keyframe.push_back(result.keyframe);
    progress.update(i + 1);
  }
  progress.finish();
  const Clock::time_point tracking_done = Clock::now();
  pipeline.finish();
  std::fprintf(stderr, "tracking done in %.1f s; mapping %zu queued keyframe(s)\n",
               ms_between(start, tracking_done) / 1000.0, pipeline.queued_keyframes());
  {
    std::lock_guard<std::mutex> lock(progress_mutex);
    // Keyframes still to map: those queued plus the one in progress (counted as left).
    const std::size_t total = static_cast<std::size_t>(
        std::count(is_keyframe.begin(), is_keyframe.end(), true));
    mapping_progress = std::make_unique<Progress>("map", std::max<std::size_t>(total, 1));
    mapping_progress->update(mapped.load());
  }
  mapping.join();
  mapping_progress->finish();
  if (!mapping_error.empty()) return fail(mapping_error);
  const Clock::time_point mapping_done = Clock::now();
  if (args.refine > 0) {
    Progress refine_progress("refine", static_cast<std::size_t>(args.refine));
    if (!pipeline.refine(args.refine, &why, [&](int done, int) {
          refine_progress.update(static_cast<std::size_t>(done));
        })) {
      return fail(why);
    }
    refine_progress.finish();
  }
  const Clock::time_point refine_done = Clock::now();
  const double slam_s = ms_between(start, mapping_done) / 1000.0;

  // Outputs.
  const fs::path out(args.out);
  if (!core::write_tum_trajectory((out / "trajectory.txt").string(), trajectory, &why)) return fail(why);
  const core::GaussianMap& map = pipeline.mapper().map();
  if (!core::write_gaussian_ply((out / "map.ply").string(), map, &why)) return fail(why);

  nlohmann::json metrics;
  metrics["dataset"] = {{"path", dataset->root()}, {"kind", dataset->kind()}, {"frames", n}};
  // Colour was resampled onto the depth pixels: the held-out images are the registered ones.
  if (options.colour_camera) metrics["dataset"]["colour_camera"] = options.colour_camera->to_string();
  metrics["mode"] = config.realtime ? "realtime" : "fast";
  metrics["mapping_poses"] = args.gt_poses ? "ground truth" : "tracked";
  if (config.realtime) metrics["realtime_fps"] = args.realtime_fps;
  metrics["threads"] = args.threads;
  if (dataset->has_ground_truth()) {
    core::AteResult ate;
    if (core::compute_ate(dataset->ground_truth(), trajectory, core::AteConfig{}, &ate, &why)) {
      metrics["ate"] = {{"rmse_m", ate.rmse}, {"mean_m", ate.mean}, {"median_m", ate.median},
                        {"max_m", ate.max},   {"pairs", ate.pairs}, {"alignment", "SE3"}};
      std::printf("ATE RMSE %.4f m (mean %.4f) over %zu frames, SE(3)\n", ate.rmse, ate.mean,
                  ate.pairs);
    } else {
      std::fprintf(stderr, "ATE: %s\n", why.c_str());
    }
  }

  // Rendering metrics on held-out frames (every eval_every-th non-keyframe, never trained on)
  // and on the keyframes, from the final map at the tracked poses, full input resolution.
  EvalSet held_out, keyframes;
  std::vector<std::size_t> render_frames;
  std::size_t non_keyframes = 0;
  std::vector<std::pair<std::size_t, bool>> eval_list;  // trajectory entry, is held out
  for (std::size_t k = 0; k < trajectory.size(); ++k) {
    if (is_keyframe[k]) {
      eval_list.push_back({k, false});
    } else if (non_keyframes++ % static_cast<std::size_t>(args.eval_every) == 0) {
      eval_list.push_back({k, true});
    }
  }
  std::vector<std::size_t> held_out_entries;
  for (const auto& e : eval_list)
    if (e.second) held_out_entries.push_back(e.first);
  for (int r = 0; r < args.renders && !held_out_entries.empty(); ++r) {
    render_frames.push_back(held_out_entries[held_out_entries.size() * static_cast<std::size_t>(r) /
                                             static_cast<std::size_t>(args.renders)]);
  }
  core::RenderSettings settings = config.mapper.render;
  settings.features = false;
  Progress eval_progress("evaluate", eval_list.size());
  std::size_t evaluated = 0;
  for (const auto& [k, held] : eval_list) {
    core::RgbdFrame frame;
    if (!dataset->load(frame_index[k], &frame, &why)) return fail(why);
    core::RenderView view;
    view.camera = frame.camera;
    view.T_camera_world = (args.gt_poses ? eval_poses[k] : trajectory[k].T_world_camera).inverse();
    core::RenderResult rendered;
    if (!rasterizer->forward(map, view, settings, &rendered, &why)) return fail(why);
    cv::Mat rgb = server::colour_to_rgb8(rendered.colour);
    core::ImageMetricsConfig mc;
    double psnr = 0, ssim = 0;
    core::DepthL1Result depth, depth_median;
    const cv::Mat median = server::plane_to_mat(rendered.median_depth, 0);
    if (!core::compute_psnr(rgb, frame.colour, mc, &psnr, &why) ||
        !core::compute_ssim(rgb, frame.colour, mc, &ssim, &why) ||
        !core::compute_depth_l1(server::plane_to_mat(rendered.depth, 0), frame.depth, cv::Mat(),
                                &depth, &why) ||
        !core::compute_depth_l1(median, frame.depth, cv::Mat(), &depth_median, &why)) {
      return fail("metrics of frame " + std::to_string(frame.id) + ": " + why);
    }
    EvalSet& set = held ? held_out : keyframes;
    set.psnr.push_back(psnr);
    set.ssim.push_back(ssim);
    set.depth_l1_cm.push_back(depth.l1_cm);
    set.depth_l1_median_cm.push_back(depth_median.l1_cm);
    set.depth_missing.push_back(static_cast<double>(depth.missing_rendered) /
                                static_cast<double>(std::max<std::size_t>(1, depth.valid_pixels)));
    if (std::find(render_frames.begin(), render_frames.end(), k) != render_frames.end()) {
      const cv::Mat nrm = server::normals_to_rgb8(rendered.median_depth, frame.camera.intrinsics());
      const double max_depth = 5.0;
      cv::Mat top, bottom, panel;
      cv::hconcat(frame.colour, rgb, top);
      cv::hconcat(server::depth_to_rgb8(frame.depth, max_depth), server::depth_to_rgb8(median, max_depth), bottom);
      cv::Mat blank(frame.colour.rows, frame.colour.cols, CV_8UC3, cv::Scalar(0, 0, 0));
      cv::Mat third;
      cv::hconcat(blank, nrm, third);
      cv::vconcat(std::vector<cv::Mat>{top, bottom, third}, panel);
      const std::string name = "frame_" + std::to_string(frame.id) + ".png";
      if (!core::write_image((out / "renders" / name).string(), panel, &why)) return fail(why);
    }
    eval_progress.update(++evaluated);
  }
  eval_progress.finish();
  metrics["held_out"] = held_out.to_json();
  metrics["held_out"]["rule"] = "every " + std::to_string(args.eval_every) +
                                "th non-keyframe frame; never used for training";
  metrics["keyframes"] = keyframes.to_json();
  metrics["depth_rendering"] =
      "depth_l1_cm: expected camera-plane depth, depth_l1_median_cm: median depth; pixels with "
      "valid sensor depth, holes count fully";
  metrics["map"] = {{"gaussians", map.size()},
                    {"keyframes", pipeline.mapper().keyframe_count()},
                    {"optimisation_steps", pipeline.mapper().total_steps()}};
  metrics["timing"] = {{"slam_wall_s", slam_s},
                       {"frames_per_second", static_cast<double>(n) / slam_s},
                       {"tracking_wall_s", ms_between(start, tracking_done) / 1000.0},
                       {"refine_s", ms_between(mapping_done, refine_done) / 1000.0},
                       {"tracking_per_frame", timing_json(track_ms)},
                       {"tracking_features_per_frame", timing_json(track_features_ms)},
                       {"mapping_per_keyframe", timing_json(keyframe_ms)},
                       {"features_per_keyframe", timing_json(features_ms)}};
  metrics["frames"] = {{"tracked", trajectory.size()}, {"lost", lost}, {"skipped", skipped},
                       {"keyframes", std::count(is_keyframe.begin(), is_keyframe.end(), true)}};
  metrics["memory"] = {{"peak_rss_mib", peak_rss_mib()}};
  std::ofstream(out / "metrics.json") << metrics.dump(2) << "\n";

  std::printf("frames %zu (skipped %zu, lost %zu), keyframes %zu, map %zu Gaussians\n", n, skipped,
              lost, pipeline.mapper().keyframe_count(), map.size());
  std::printf("SLAM wall time %.1f s = %.2f frames/s (%d thread(s)); peak RSS %.0f MiB\n", slam_s,
              static_cast<double>(n) / slam_s, args.threads, peak_rss_mib());
  held_out.print("held-out frames");
  keyframes.print("keyframes");
  std::printf("wrote %s/{trajectory.txt,map.ply,metrics.json,renders/}\n", args.out.c_str());
  return 0;
}

}  // namespace

void add_run_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "run", "Track and map a dataset (3DGS mapping on a second thread); writes the trajectory, "
             "map.ply, metrics.json and renders");
  auto args = std::make_shared<RunArgs>();
  server::add_config_options(app, &args->config);
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
  app->add_flag("--ground-truth-poses", args->gt_poses,
                "Map and render at the ground-truth poses (tracking still runs and is scored): "
                "map quality without tracking drift");
  commands->push_back({app, [args] { return run_slam(*args); }});
}

}  // namespace fslam::cli

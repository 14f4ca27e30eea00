// `fslam segment-eval`: open-set segmentation of a saved feature map scored against a labelled
// sequence's instances (docs/evaluation.md, "Open-set segmentation"): promptless instances as
// Hungarian-matched mIoU over the evaluated views, and one click per visible object as mean
// mask IoU. Views are rendered at the tracked poses of frames the mapper did not train on.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <tuple>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>
#include <tbb/global_control.h>

#include "commands.hpp"
#include "dataset_args.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/eval/image_metrics.hpp"
#include "fslam/core/io/gaussian_ply.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "fslam/core/segmentation/segmentation.hpp"
#include "fslam/server/backend_factory.hpp"
#include "fslam/server/render_images.hpp"

namespace fslam::cli {
namespace {

namespace fs = std::filesystem;

struct SegmentEvalArgs {
  DatasetArgs dataset;
  std::string ply, trajectory, out;
  int every = 10, offset = 5;       // evaluated frames: positions offset, offset + every, ...
  double min_object_share = 0.01;   // clicks only on objects covering this share of the view
  int threads = 2;
  int overlays = 4;                 // views written to --out
  core::PromptlessConfig promptless;
  core::PromptConfig prompt;
};

// A fixed colour per id for overlays.
cv::Vec3b id_colour(int id) {
  if (id < 0) return {0, 0, 0};
  const unsigned h = static_cast<unsigned>(id) * 2654435761u;
  return {static_cast<uchar>(64 + (h & 0x7f)), static_cast<uchar>(64 + ((h >> 8) & 0x7f)),
          static_cast<uchar>(64 + ((h >> 16) & 0x7f))};
}

int run_segment_eval(const SegmentEvalArgs& args) {
  std::string why;
  core::DatasetOptions options;
  auto dataset = open_dataset(args.dataset, &options, &why);
  if (!dataset) return fail(why);
  core::GaussianMap map;
  if (!core::read_gaussian_ply(args.ply, &map, &why)) return fail(why);
  if (!core::has_features(map)) {
    return fail(args.ply + " carries no features: its latents are missing or all alike (run fslam run --features)");
  }
  core::Trajectory trajectory;
  if (!core::read_tum_trajectory(args.trajectory, &trajectory, &why)) return fail(why);
  if (args.every < 1 || args.offset < 0) return fail("--every must be >= 1 and --offset >= 0");
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(std::max(1, args.threads)));
  std::string notice;
  auto rasterizer = server::make_rasterizer("auto", server::RasterUse::kRender, &notice, &why);
  if (!rasterizer) return fail(why);
  if (!args.out.empty()) fs::create_directories(args.out);

  core::GaussianLabels labels;
  if (!core::cluster_instances(map, args.promptless, &labels, &why)) return fail(why);
  std::printf("map: %zu Gaussians, %d channels; promptless: %d instances\n", map.size(),
              map.feature_dim, labels.count);

  const core::PromptSelector prompts(map, args.prompt);  // one graph for every click
  core::InstanceOverlap overlap;
  core::InstanceMatchConfig match;
  match.predicted_none = -1;  // pixels no instance claims: misses
  std::vector<double> click_iou;
  nlohmann::json click_log = nlohmann::json::array();  // per click: where, and how it went
  std::size_t views = 0, failed_clicks = 0;
  for (std::size_t i = static_cast<std::size_t>(args.offset); i < dataset->size();
       i += static_cast<std::size_t>(args.every)) {
    cv::Mat truth;
    if (!dataset->load_labels(i, &truth, nullptr, &why) || truth.empty()) {
      return fail("frame " + std::to_string(i) + " has no instance labels: " + why);
    }
    const core::StampedPose* pose = core::nearest_pose(trajectory, dataset->timestamp(i));
    if (!pose) continue;  // untracked frame
    core::RenderView view;
    view.camera = dataset->camera();
    view.T_camera_world = pose->T_world_camera.inverse();
    cv::Mat ids;
    if (!core::render_labels(*rasterizer, map, labels, view, core::kMinObjectAlpha, &ids, &why)) return fail(why);
    if (truth.type() != CV_16UC1) truth.convertTo(truth, CV_16UC1);
    if (!core::accumulate_instance_overlap(ids, truth, match, &overlap, &why)) return fail(why);

    // One click per object covering enough of the view.
    std::vector<int> present;
    {
      std::map<int, int> area;
      for (int v = 0; v < truth.rows; ++v)
        for (int u = 0; u < truth.cols; ++u) ++area[truth.at<std::uint16_t>(v, u)];
      for (const auto& [id, n] : area)
        if (id != 0 && n >= args.min_object_share * truth.total()) present.push_back(id);
    }
    const bool write_overlays = !args.out.empty() && static_cast<int>(views) < args.overlays;
    std::vector<std::tuple<double, int, cv::Mat>> click_masks;  // (mask pixels, object id, mask) for the overlay
    std::vector<cv::Point> clicks;
    for (int id : present) {
      const cv::Mat object = truth == id;
      cv::Point at;
      if (!core::click_point(object, 2.0, &at)) continue;
      std::vector<std::uint8_t> selected;
      cv::Mat mask;
      std::string click_why;
      if (!prompts.select_by_points(*rasterizer, view, {{at.x, at.y}}, &selected, &click_why) ||
          !core::render_selection(*rasterizer, map, selected, view, core::kMinObjectAlpha, &mask, &why)) {
        ++failed_clicks;  // scored as IoU 0: the click found nothing
        click_iou.push_back(0.0);
        click_log.push_back({{"frame", i}, {"id", id}, {"u", at.x}, {"v", at.y}, {"iou", 0.0}});
        continue;
      }
      click_iou.push_back(std::max(0.0, core::mask_iou(mask, truth, id)));
      // Precision and recall of the mask tell over-growth from under-growth.
      const double in_mask = cv::countNonZero(mask), in_object = cv::countNonZero(object);
      if (write_overlays) {
        click_masks.push_back({in_mask, id, mask});
        clicks.push_back(at);
      }
      const double both = cv::countNonZero(mask & object);
      // The object the mask spills onto most, and that share of the mask: where a leak went.
      std::map<int, int> spill;
      for (int v = 0; v < truth.rows; ++v)
        for (int u = 0; u < truth.cols; ++u) {
          const int t = truth.at<std::uint16_t>(v, u);
          if (mask.at<std::uint8_t>(v, u) && t != id) ++spill[t];
        }
      std::pair<int, int> most{-1, 0};
      for (const auto& [t, n] : spill)
        if (n > most.second) most = {t, n};
      click_log.push_back({{"frame", i}, {"id", id}, {"u", at.x}, {"v", at.y}, {"iou", click_iou.back()},
                           {"precision", in_mask > 0 ? both / in_mask : 0.0},
                           {"recall", in_object > 0 ? both / in_object : 0.0},
                           {"spill_id", most.first},
                           {"spill_share", in_mask > 0 ? most.second / in_mask : 0.0}});
    }
    if (write_overlays) {
      core::RenderResult r;
      core::RenderSettings settings;
      settings.features = false;
      if (!rasterizer->forward(map, view, settings, &r, &why)) return fail(why);
      cv::Mat colour = server::colour_to_rgb8(r.colour), coded(ids.size(), CV_8UC3), truth_coded(ids.size(), CV_8UC3);
      for (int v = 0; v < ids.rows; ++v)
        for (int u = 0; u < ids.cols; ++u) {
          coded.at<cv::Vec3b>(v, u) = id_colour(ids.at<int>(v, u));
          truth_coded.at<cv::Vec3b>(v, u) = id_colour(truth.at<std::uint16_t>(v, u) + 1000);
        }
      cv::Mat blended, panel;
      cv::addWeighted(colour, 0.5, coded, 0.5, 0.0, blended);
      cv::hconcat(std::vector<cv::Mat>{colour, blended, truth_coded}, panel);
      char name[64];
      std::snprintf(name, sizeof name, "promptless_%06zu.png", i);
      if (!core::write_image((fs::path(args.out) / name).string(), panel, &why)) return fail(why);
      // One-click masks over the colour (each in its object's ground-truth colour, outlined; the
      // click is the ringed dot), beside the ground truth. Largest first, so where masks overlap
      // the smaller one shows.
      std::sort(click_masks.begin(), click_masks.end(),
                [](const auto& a, const auto& b) { return std::get<0>(a) > std::get<0>(b); });
      cv::Mat click_paint = cv::Mat::zeros(truth.size(), CV_8UC3);
      for (const auto& [pixels, id, mask] : click_masks) {
        click_paint.setTo(id_colour(id + 1000), mask);
        std::vector<std::vector<cv::Point>> outline;
        cv::findContours(mask.clone(), outline, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
        cv::drawContours(click_paint, outline, -1, cv::Scalar(0, 0, 0), 1);
      }
      cv::addWeighted(colour, 0.5, click_paint, 0.5, 0.0, blended);
      for (const cv::Point& at : clicks) {
        cv::circle(blended, at, 5, cv::Scalar(0, 0, 0), 2);
        cv::circle(blended, at, 3, cv::Scalar(255, 255, 255), cv::FILLED);
      }
      cv::hconcat(std::vector<cv::Mat>{blended, truth_coded}, panel);
      std::snprintf(name, sizeof name, "clicks_%06zu.png", i);
      if (!core::write_image((fs::path(args.out) / name).string(), panel, &why)) return fail(why);
    }
    ++views;
  }
  if (views == 0) return fail("no evaluated frame has a tracked pose in " + args.trajectory);
  const core::InstanceMatchResult score = core::match_instances(overlap);
  double click_mean = 0;
  for (double v : click_iou) click_mean += v;
  click_mean = click_iou.empty() ? 0.0 : click_mean / static_cast<double>(click_iou.size());
  std::printf("views %zu (every %d frames from %d)\n", views, args.every, args.offset);
  std::printf("promptless: mIoU %.3f, mAcc %.3f over %zu ground-truth instances (%d predicted, "
              "%zu unmatched)\n",
              score.miou, score.macc, score.iou.size(), labels.count, score.unmatched_predicted);
  std::printf("one click per object: mean IoU %.3f over %zu clicks (%zu found nothing)\n", click_mean,
              click_iou.size(), failed_clicks);
  if (!args.out.empty()) {
    nlohmann::json j;
    j["views"] = views;
    j["promptless"] = {{"miou", score.miou}, {"macc", score.macc}, {"instances_scored", score.iou.size()},
                       {"instances_predicted", labels.count}};
    nlohmann::json per;
    for (const auto& [id, iou] : score.iou) per[std::to_string(id)] = iou;
    j["promptless"]["iou_per_instance"] = per;
    j["one_click"] = {{"mean_iou", click_mean}, {"clicks", click_iou.size()}, {"failed", failed_clicks},
                      {"per_click", click_log}};
    std::ofstream(fs::path(args.out) / "segmentation.json") << j.dump(2) << "\n";
    std::printf("wrote %s/segmentation.json and overlays\n", args.out.c_str());
  }
  return 0;
}

}  // namespace

void add_segment_eval_command(CLI::App& root, CommandList* commands) {
  auto* app = root.add_subcommand(
      "segment-eval", "Score open-set segmentation of a feature map against a labelled sequence "
                      "(promptless mIoU, one-click IoU)");
  auto args = std::make_shared<SegmentEvalArgs>();
  add_dataset_options(app, &args->dataset);
  app->add_option("--ply", args->ply, "The map (fslam run --features ... writes map.ply)")->required();
  app->add_option("--trajectory", args->trajectory, "Poses of the map's frame (fslam run's trajectory.txt)")
      ->required();
  app->add_option("--every", args->every, "Evaluate every N-th frame ...")->capture_default_str();
  app->add_option("--offset", args->offset, "... starting at this position")->capture_default_str();
  app->add_option("--out", args->out, "Folder for segmentation.json and overlays of the first views (promptless_*.png, clicks_*.png)");
  app->add_option("--threads", args->threads, "Rendering threads")->capture_default_str();
  app->add_option("--feature-threshold", args->promptless.graph.feature_threshold,
                  "Promptless: RMS latent difference joining neighbours")
      ->capture_default_str();
  app->add_option("--prompt-threshold", args->prompt.graph.feature_threshold,
                  "Prompts: RMS latent difference to the prompt")
      ->capture_default_str();
  app->add_option("--prompt-adaptive", args->prompt.adaptive_threshold,
                  "Prompts: pick each prompt's threshold in [min, max] (else --prompt-threshold)")
      ->capture_default_str();
  app->add_option("--prompt-min-threshold", args->prompt.min_threshold, "Prompts: adaptive range, tightest threshold")
      ->capture_default_str();
  app->add_option("--prompt-max-threshold", args->prompt.max_threshold, "Prompts: adaptive range, loosest threshold")
      ->capture_default_str();
  app->add_option("--prompt-min-jump", args->prompt.min_jump,
                  "Prompts: growth ratio between thresholds that marks a leak")
      ->capture_default_str();
  app->add_option("--prompt-min-contrast", args->prompt.min_contrast,
                  "Prompts: a leak's additions lie at least this x the threshold from the region's mean latent")
      ->capture_default_str();
  app->add_option("--prompt-smooth", args->prompt.smooth_growth,
                  "Prompts: growth along one smooth surface is no leak")
      ->capture_default_str();
  app->add_option("--prompt-smooth-angle", args->prompt.smooth_max_angle_deg,
                  "Prompts: degrees between normals on one smooth surface")
      ->capture_default_str();
  app->add_option("--prompt-smooth-offset", args->prompt.smooth_max_offset,
                  "Prompts: metres off the tangent plane on one smooth surface")
      ->capture_default_str();
  app->add_option("--prompt-flat-ratio", args->prompt.flat_ratio,
                  "Prompts: smallest / middle scale below which a Gaussian has a normal")
      ->capture_default_str();
  app->add_option("--prompt-bend-ratio", args->prompt.bend_ratio,
                  "Prompts: across a bend or step a Gaussian joins within this x the threshold")
      ->capture_default_str();
  app->add_option("--prompt-fill-rounds", args->prompt.fill_rounds,
                  "Prompts: rounds of the refinement in 3D (a Gaussian joins when enough of its neighbours are in); 0 = none")
      ->capture_default_str();
  app->add_option("--prompt-fill-fraction", args->prompt.fill_fraction,
                  "Prompts: share of a Gaussian's neighbours inside the object that makes it join")
      ->capture_default_str();
  app->add_option("--prompt-min-jump-region", args->prompt.min_jump_region,
                  "Prompts: a jump counts only from a region of at least this many Gaussians")
      ->capture_default_str();
  app->add_option("--min-instance", args->promptless.min_instance_gaussians,
                  "Promptless: smaller regions merge into a neighbour")
      ->capture_default_str();
  commands->push_back({app, [args] { return run_segment_eval(*args); }});
}

}  // namespace fslam::cli

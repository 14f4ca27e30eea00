// `fslam segment-eval`: open-set segmentation of a saved feature map scored against a labelled
// sequence's instances (docs/evaluation.md, "Open-set segmentation"): promptless instances as
// Hungarian-matched mIoU over the evaluated views, and one click per visible object as mean
// mask IoU. Views are rendered at the tracked poses of frames the mapper did not train on.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
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
#include "fslam/core/eval/view_eval.hpp"
#include "fslam/core/segmentation/segmentation_eval.hpp"
#include "fslam/server/backend_factory.hpp"

namespace fslam::cli {
namespace {

namespace fs = std::filesystem;

struct SegmentEvalArgs {
  DatasetArgs dataset;
  std::string ply, trajectory, out;
  int threads = 2;
  int overlays = 4;  // views written to --out
  core::SegmentationEvalConfig eval;
};

// A fixed colour per id for overlays.
cv::Vec3b id_colour(int id) {
  if (id < 0) return {0, 0, 0};
  const unsigned h = static_cast<unsigned>(id) * 2654435761u;
  return {static_cast<uchar>(64 + (h & 0x7f)), static_cast<uchar>(64 + ((h >> 8) & 0x7f)),
          static_cast<uchar>(64 + ((h >> 16) & 0x7f))};
}

// promptless_<frame>.png: the render, its instances over it, the ground truth; clicks_<frame>.png:
// the one-click masks over the colour (each in its object's ground-truth colour, outlined; the
// click is the ringed dot) beside the ground truth.
bool write_overlays(const std::string& folder, const core::Rasterizer& rasterizer,
                    const core::GaussianMap& map, const core::SegmentationView& view, std::string* why) {
  core::RenderResult r;
  core::RenderSettings settings;
  settings.features = false;
  if (!rasterizer.forward(map, view.view, settings, &r, why)) return false;
  const cv::Mat& ids = view.instance_ids;
  const cv::Mat& truth = view.truth;
  cv::Mat colour = core::colour_to_rgb8(r.colour), coded(ids.size(), CV_8UC3), truth_coded(ids.size(), CV_8UC3);
  for (int v = 0; v < ids.rows; ++v)
    for (int u = 0; u < ids.cols; ++u) {
      coded.at<cv::Vec3b>(v, u) = id_colour(ids.at<int>(v, u));
      truth_coded.at<cv::Vec3b>(v, u) = id_colour(truth.at<std::uint16_t>(v, u) + 1000);
    }
  cv::Mat blended, panel;
  cv::addWeighted(colour, 0.5, coded, 0.5, 0.0, blended);
  cv::hconcat(std::vector<cv::Mat>{colour, blended, truth_coded}, panel);
  char name[64];
  std::snprintf(name, sizeof name, "promptless_%06zu.png", view.frame);
  if (!core::write_image((fs::path(folder) / name).string(), panel, why)) return false;
  // Largest mask first, so where masks overlap the smaller one shows.
  std::vector<const core::SegmentationView::Click*> clicks;
  for (const auto& c : view.clicks) clicks.push_back(&c);
  std::stable_sort(clicks.begin(), clicks.end(), [](const auto* a, const auto* b) {
    return cv::countNonZero(a->mask) > cv::countNonZero(b->mask);
  });
  cv::Mat click_paint = cv::Mat::zeros(truth.size(), CV_8UC3);
  for (const auto* c : clicks) {
    click_paint.setTo(id_colour(c->id + 1000), c->mask);
    std::vector<std::vector<cv::Point>> outline;
    cv::findContours(c->mask.clone(), outline, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
    cv::drawContours(click_paint, outline, -1, cv::Scalar(0, 0, 0), 1);
  }
  cv::addWeighted(colour, 0.5, click_paint, 0.5, 0.0, blended);
  for (const auto& c : view.clicks) {
    cv::circle(blended, c.at, 5, cv::Scalar(0, 0, 0), 2);
    cv::circle(blended, c.at, 3, cv::Scalar(255, 255, 255), cv::FILLED);
  }
  cv::hconcat(std::vector<cv::Mat>{blended, truth_coded}, panel);
  std::snprintf(name, sizeof name, "clicks_%06zu.png", view.frame);
  return core::write_image((fs::path(folder) / name).string(), panel, why);
}

nlohmann::json report_json(const core::SegmentationEvalResult& result) {
  nlohmann::json j;
  j["views"] = result.views;
  const core::InstanceMatchResult& score = result.promptless;
  j["promptless"] = {{"miou", score.miou}, {"macc", score.macc}, {"instances_scored", score.iou.size()},
                     {"instances_predicted", result.instances_predicted}};
  nlohmann::json per;
  for (const auto& [id, iou] : score.iou) per[std::to_string(id)] = iou;
  j["promptless"]["iou_per_instance"] = per;
  nlohmann::json clicks = nlohmann::json::array();  // per click: where, and how it went
  for (const core::ClickScore& c : result.clicks) {
    nlohmann::json one = {{"frame", c.frame}, {"id", c.id}, {"u", c.u}, {"v", c.v}, {"iou", c.iou}};
    if (c.found) {
      one["precision"] = c.precision;
      one["recall"] = c.recall;
      one["spill_id"] = c.spill_id;
      one["spill_share"] = c.spill_share;
    }
    clicks.push_back(one);
  }
  j["one_click"] = {{"mean_iou", result.click_mean_iou()}, {"clicks", result.clicks.size()},
                    {"failed", result.failed_clicks}, {"per_click", clicks}};
  return j;
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
  if (!args.eval.is_valid()) return fail("--every must be >= 1 and --offset >= 0");
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(std::max(1, args.threads)));
  std::string notice;
  auto rasterizer = server::make_rasterizer("auto", server::RasterUse::kRender, &notice, &why);
  if (!rasterizer) return fail(why);
  if (!args.out.empty()) fs::create_directories(args.out);

  int overlays = 0;
  core::SegmentationEvalResult result;
  const bool ok = core::evaluate_segmentation(
      *dataset, map, trajectory, *rasterizer, args.eval, &result, &why,
      [&](const core::SegmentationView& view, std::string* vwhy) {
        if (args.out.empty() || overlays >= args.overlays) return true;
        ++overlays;
        return write_overlays(args.out, *rasterizer, map, view, vwhy);
      });
  if (!ok) return fail(why);
  std::printf("map: %zu Gaussians, %d channels; promptless: %d instances\n", map.size(),
              map.feature_dim, result.instances_predicted);
  if (result.views == 0) return fail("no evaluated frame has a tracked pose in " + args.trajectory);
  const core::InstanceMatchResult& score = result.promptless;
  std::printf("views %zu (every %d frames from %d)\n", result.views, args.eval.every, args.eval.offset);
  std::printf("promptless: mIoU %.3f, mAcc %.3f over %zu ground-truth instances (%d predicted, "
              "%zu unmatched)\n",
              score.miou, score.macc, score.iou.size(), result.instances_predicted, score.unmatched_predicted);
  std::printf("one click per object: mean IoU %.3f over %zu clicks (%zu found nothing)\n",
              result.click_mean_iou(), result.clicks.size(), result.failed_clicks);
  if (!args.out.empty()) {
    std::ofstream(fs::path(args.out) / "segmentation.json") << report_json(result).dump(2) << "\n";
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
  app->add_option("--every", args->eval.every, "Evaluate every N-th frame ...")->capture_default_str();
  app->add_option("--offset", args->eval.offset, "... starting at this position")->capture_default_str();
  app->add_option("--out", args->out, "Folder for segmentation.json and overlays of the first views (promptless_*.png, clicks_*.png)");
  app->add_option("--threads", args->threads, "Rendering threads")->capture_default_str();
  app->add_option("--feature-threshold", args->eval.promptless.graph.feature_threshold,
                  "Promptless: RMS latent difference joining neighbours")
      ->capture_default_str();
  app->add_option("--prompt-threshold", args->eval.prompt.graph.feature_threshold,
                  "Prompts: RMS latent difference to the prompt")
      ->capture_default_str();
  app->add_option("--prompt-adaptive", args->eval.prompt.adaptive_threshold,
                  "Prompts: pick each prompt's threshold in [min, max] (else --prompt-threshold)")
      ->capture_default_str();
  app->add_option("--prompt-min-threshold", args->eval.prompt.min_threshold, "Prompts: adaptive range, tightest threshold")
      ->capture_default_str();
  app->add_option("--prompt-max-threshold", args->eval.prompt.max_threshold, "Prompts: adaptive range, loosest threshold")
      ->capture_default_str();
  app->add_option("--prompt-min-jump", args->eval.prompt.min_jump,
                  "Prompts: growth ratio between thresholds that marks a leak")
      ->capture_default_str();
  app->add_option("--prompt-min-contrast", args->eval.prompt.min_contrast,
                  "Prompts: a leak's additions lie at least this x the threshold from the region's mean latent")
      ->capture_default_str();
  app->add_option("--prompt-smooth", args->eval.prompt.smooth_growth,
                  "Prompts: growth along one smooth surface is no leak")
      ->capture_default_str();
  app->add_option("--prompt-smooth-angle", args->eval.prompt.smooth_max_angle_deg,
                  "Prompts: degrees between normals on one smooth surface")
      ->capture_default_str();
  app->add_option("--prompt-smooth-offset", args->eval.prompt.smooth_max_offset,
                  "Prompts: metres off the tangent plane on one smooth surface")
      ->capture_default_str();
  app->add_option("--prompt-flat-ratio", args->eval.prompt.flat_ratio,
                  "Prompts: smallest / middle scale below which a Gaussian has a normal")
      ->capture_default_str();
  app->add_option("--prompt-bend-ratio", args->eval.prompt.bend_ratio,
                  "Prompts: across a bend or step a Gaussian joins within this x the threshold")
      ->capture_default_str();
  app->add_option("--prompt-fill-rounds", args->eval.prompt.fill_rounds,
                  "Prompts: rounds of the refinement in 3D (a Gaussian joins when enough of its neighbours are in); 0 = none")
      ->capture_default_str();
  app->add_option("--prompt-fill-fraction", args->eval.prompt.fill_fraction,
                  "Prompts: share of a Gaussian's neighbours inside the object that makes it join")
      ->capture_default_str();
  app->add_option("--prompt-min-jump-region", args->eval.prompt.min_jump_region,
                  "Prompts: a jump counts only from a region of at least this many Gaussians")
      ->capture_default_str();
  app->add_option("--min-instance", args->eval.promptless.min_instance_gaussians,
                  "Promptless: smaller regions merge into a neighbour")
      ->capture_default_str();
  commands->push_back({app, [args] { return run_segment_eval(*args); }});
}

}  // namespace fslam::cli

#include "fslam/core/segmentation/segmentation_eval.hpp"

#include <algorithm>
#include <cstdint>
#include <map>
#include <utility>

#include <opencv2/core.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::core {
namespace {

// The ground-truth objects covering at least `min_share` of the view (0, the background, never).
std::vector<int> objects_in_view(const cv::Mat& truth, double min_share) {
  std::map<int, int> area;
  for (int v = 0; v < truth.rows; ++v)
    for (int u = 0; u < truth.cols; ++u) ++area[truth.at<std::uint16_t>(v, u)];
  std::vector<int> present;
  for (const auto& [id, n] : area)
    if (id != 0 && n >= min_share * static_cast<double>(truth.total())) present.push_back(id);
  return present;
}

// Precision and recall of a click's mask tell over-growth from under-growth; the object the mask
// spills onto most, and that share of the mask, say where a leak went.
void score_mask(const cv::Mat& mask, const cv::Mat& truth, ClickScore* click) {
  const cv::Mat object = truth == click->id;
  const double in_mask = cv::countNonZero(mask), in_object = cv::countNonZero(object);
  const double both = cv::countNonZero(mask & object);
  std::map<int, int> spill;
  for (int v = 0; v < truth.rows; ++v)
    for (int u = 0; u < truth.cols; ++u) {
      const int t = truth.at<std::uint16_t>(v, u);
      if (mask.at<std::uint8_t>(v, u) && t != click->id) ++spill[t];
    }
  std::pair<int, int> most{-1, 0};
  for (const auto& [t, n] : spill)
    if (n > most.second) most = {t, n};
  click->precision = in_mask > 0 ? both / in_mask : 0.0;
  click->recall = in_object > 0 ? both / in_object : 0.0;
  click->spill_id = most.first;
  click->spill_share = in_mask > 0 ? most.second / in_mask : 0.0;
}

// One click per object covering enough of the view: its mask against the object's labels.
bool click_objects(const PromptSelector& prompts, const Rasterizer& rasterizer, const GaussianMap& map,
                   const SegmentationEvalConfig& config, SegmentationView* view,
                   SegmentationEvalResult* out, std::string* why) {
  const cv::Mat& truth = view->truth;
  for (int id : objects_in_view(truth, config.min_object_share)) {
    cv::Point at;
    if (!click_point(truth == id, 2.0, &at)) continue;
    ClickScore click;
    click.frame = view->frame;
    click.id = id;
    click.u = at.x;
    click.v = at.y;
    std::vector<std::uint8_t> selected;
    cv::Mat mask;
    std::string click_why;
    if (!prompts.select_by_points(rasterizer, view->view, {{at.x, at.y}}, &selected, &click_why) ||
        !render_selection(rasterizer, map, selected, view->view, kMinObjectAlpha, &mask, why)) {
      ++out->failed_clicks;  // scored as IoU 0: the click found nothing
      out->clicks.push_back(click);
      continue;
    }
    click.found = true;
    click.iou = std::max(0.0, mask_iou(mask, truth, id));
    score_mask(mask, truth, &click);
    out->clicks.push_back(click);
    view->clicks.push_back({id, at, mask});
  }
  return true;
}

}  // namespace

bool SegmentationEvalConfig::is_valid(std::string* why) const {
  if (every < 1 || offset < 0) return fail(why, "every must be >= 1 and offset >= 0");
  return true;
}

double SegmentationEvalResult::click_mean_iou() const {
  double sum = 0.0;
  for (const ClickScore& c : clicks) sum += c.iou;
  return clicks.empty() ? 0.0 : sum / static_cast<double>(clicks.size());
}

bool evaluate_segmentation(const Dataset& dataset, const GaussianMap& map, const Trajectory& trajectory,
                           const Rasterizer& rasterizer, const SegmentationEvalConfig& config,
                           SegmentationEvalResult* out, std::string* why,
                           const std::function<bool(const SegmentationView&, std::string* why)>& on_view) {
  *out = SegmentationEvalResult();
  if (!config.is_valid(why)) return false;
  GaussianLabels labels;
  if (!cluster_instances(map, config.promptless, &labels, why)) return false;
  out->instances_predicted = labels.count;
  const PromptSelector prompts(map, config.prompt);  // one graph for every click
  InstanceOverlap overlap;
  InstanceMatchConfig match;
  match.predicted_none = -1;  // pixels no instance claims: misses
  for (std::size_t i = static_cast<std::size_t>(config.offset); i < dataset.size();
       i += static_cast<std::size_t>(config.every)) {
    SegmentationView view;
    view.frame = i;
    if (!dataset.load_labels(i, &view.truth, nullptr, why) || view.truth.empty()) {
      return fail(why, "frame " + std::to_string(i) + " has no instance labels: " + (why ? *why : ""));
    }
    const StampedPose* pose = nearest_pose(trajectory, dataset.timestamp(i));
    if (!pose) continue;  // untracked frame
    view.view.camera = dataset.camera();
    view.view.T_camera_world = pose->T_world_camera.inverse();
    if (!render_labels(rasterizer, map, labels, view.view, kMinObjectAlpha, &view.instance_ids, why)) return false;
    if (view.truth.type() != CV_16UC1) view.truth.convertTo(view.truth, CV_16UC1);
    if (!accumulate_instance_overlap(view.instance_ids, view.truth, match, &overlap, why)) return false;
    if (!click_objects(prompts, rasterizer, map, config, &view, out, why)) return false;
    if (on_view && !on_view(view, why)) return false;
    ++out->views;
  }
  out->promptless = match_instances(overlap);
  return true;
}

}  // namespace fslam::core

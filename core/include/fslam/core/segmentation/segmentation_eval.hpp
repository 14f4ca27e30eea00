// The open-set segmentation evaluation protocol (docs/evaluation.md, "Open-set segmentation"):
// a feature map scored against a labelled sequence's instances. Promptless instances as
// Hungarian-matched mIoU over the evaluated views, and one click per visible object as mean mask
// IoU. Views are rendered at the tracked poses of every `every`-th frame from `offset`.
#pragma once

#include <cstddef>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/eval/image_metrics.hpp"
#include "fslam/core/segmentation/segmentation.hpp"

namespace fslam::core {

struct SegmentationEvalConfig {
  int every = 10, offset = 5;      // evaluated frames: positions offset, offset + every, ...
  double min_object_share = 0.01;  // clicks only on objects covering this share of the view
  PromptlessConfig promptless;
  PromptConfig prompt;
  bool is_valid(std::string* why = nullptr) const;
};

// One click on one ground-truth object, and how its mask went.
struct ClickScore {
  std::size_t frame = 0;  // dataset position
  int id = 0;             // ground-truth instance
  int u = 0, v = 0;       // the click, pixels
  double iou = 0.0;       // 0 when the click selected nothing
  bool found = false;     // the click selected a mask (precision .. spill_share are set)
  double precision = 0.0, recall = 0.0;
  int spill_id = -1;         // the object the mask spills onto most, -1: none
  double spill_share = 0.0;  // that object's share of the mask
};

// One evaluated view, for pictures of it (on_view).
struct SegmentationView {
  std::size_t frame = 0;
  RenderView view;
  cv::Mat instance_ids;  // CV_32SC1 promptless instance per pixel, -1 none
  cv::Mat truth;         // CV_16UC1 ground-truth instance per pixel, 0 none
  struct Click {
    int id = 0;
    cv::Point at;
    cv::Mat mask;  // CV_8UC1
  };
  std::vector<Click> clicks;  // the clicks that selected a mask
};

struct SegmentationEvalResult {
  std::size_t views = 0;
  int instances_predicted = 0;  // promptless instances in the map
  InstanceMatchResult promptless;
  std::vector<ClickScore> clicks;
  std::size_t failed_clicks = 0;  // clicks that selected nothing (scored IoU 0)
  double click_mean_iou() const;
};

// Scores `map` (with features) seen from `trajectory` against `dataset`'s instance labels.
// on_view (optional): each evaluated view; false from it stops with its `why`. No view with a
// tracked pose is no failure: out->views is 0.
bool evaluate_segmentation(
    const Dataset& dataset, const GaussianMap& map, const Trajectory& trajectory,
    const Rasterizer& rasterizer, const SegmentationEvalConfig& config, SegmentationEvalResult* out,
    std::string* why,
    const std::function<bool(const SegmentationView&, std::string* why)>& on_view = nullptr);

}  // namespace fslam::core

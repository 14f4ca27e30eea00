// Segmentation scores (docs/evaluation.md, "Open-set segmentation"): predicted instance ids
// against ground-truth instance labels over a set of views, matched one-to-one by the Hungarian
// method on IoU, and mask IoU for prompted objects.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

namespace fslam::core {

// Pixel counts over the views added so far.
class InstanceConfusion {
 public:
  // predicted: CV_32SC1, -1 = no instance. truth: CV_16UC1 or CV_32SC1 instance ids, 0 =
  // unlabelled (ignored: neither scored nor counted against a prediction).
  bool add(const cv::Mat& predicted, const cv::Mat& truth, std::string* why);

  struct Score {
    double miou = 0.0;  // mean over scored ground-truth instances of IoU with the matched prediction
    double macc = 0.0;  // mean over them of the share of their pixels the matched prediction covers
    std::map<int, double> iou;        // ground-truth id -> IoU (0 when unmatched)
    std::map<int, int> matched;       // ground-truth id -> predicted id (absent when unmatched)
    std::size_t scored = 0;           // ground-truth instances scored
  };
  // Instances with fewer than min_pixels labelled pixels over all views are not scored.
  Score score(std::size_t min_pixels = 100) const;

 private:
  std::map<std::pair<int, int>, std::uint64_t> joint_;  // (truth, predicted) -> pixels
  std::map<int, std::uint64_t> truth_area_, predicted_area_;  // over labelled pixels only
};

// Minimum-cost one-to-one assignment of rows to columns (Hungarian / Kuhn-Munkres, O(n^3));
// cost: rows x cols, row-major. assignment[r] = column, or -1 when rows > cols leaves r out.
std::vector<int> hungarian_assignment(const std::vector<double>& cost, int rows, int cols);

// IoU of a binary mask (non-zero = in) with truth == id; -1 when both are empty.
double mask_iou(const cv::Mat& mask, const cv::Mat& truth, int id);

}  // namespace fslam::core

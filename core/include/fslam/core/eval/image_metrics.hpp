// Rendering and segmentation metrics: PSNR, SSIM, depth L1, mIoU / mAcc (confusion matrix) and
// Hungarian matching of predicted to ground-truth instances. docs/evaluation.md states the
// conventions; the per-pixel SSIM math lives in fslam/core/math/ssim.hpp.
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core/mat.hpp>

namespace fslam::core {

// ---- colour: PSNR and SSIM ----------------------------------------------------------------------

struct ImageMetricsConfig {
  // L, the value of white: 0 derives it from the pixel type (255 for CV_8U, 65535 for CV_16U,
  // 1 for CV_32F / CV_64F).
  double data_range = 0.0;
  int ssim_window = 11;     // pixels, odd
  double ssim_sigma = 1.5;  // pixels
};
bool validate(const ImageMetricsConfig& config, std::string* why);

// Both images: same size, same type (CV_8U, CV_16U, CV_32F or CV_64F, 1 to 4 channels).
// PSNR = 10 log10(L^2 / MSE), MSE over all pixels and channels; +infinity for identical images.
bool compute_psnr(const cv::Mat& rendered, const cv::Mat& reference,
                  const ImageMetricsConfig& config, double* psnr_db, std::string* why);

// Mean SSIM over all pixels and channels, each channel on its own, the Gaussian-weighted moments
// taken by a zero-padded 'same' convolution (3DGS convention); C1 = (0.01 L)^2, C2 = (0.03 L)^2.
// ssim_map (optional): CV_64FC(channels), the per-pixel values averaged into *ssim.
bool compute_ssim(const cv::Mat& rendered, const cv::Mat& reference,
                  const ImageMetricsConfig& config, double* ssim, std::string* why,
                  cv::Mat* ssim_map = nullptr);

// ---- depth --------------------------------------------------------------------------------------

struct DepthL1Result {
  double l1_cm = 0.0;                // mean |rendered - gt| over the valid pixels, centimetres
  std::size_t valid_pixels = 0;      // gt > 0 and finite (and inside the mask)
  std::size_t missing_rendered = 0;  // valid pixels whose rendered depth is <= 0 or not finite
};

// Depth maps CV_32FC1 or CV_64FC1 in metres, same size. A pixel counts when the ground truth is
// finite and > 0 and the optional mask (CV_8UC1, same size; empty = all pixels) is non-zero.
// Rendered-missing pixels (<= 0 or not finite) count, as rendered depth 0: a hole costs the full
// ground-truth depth, so a renderer cannot improve its score by leaving pixels empty.
// Fails when no pixel is valid.
bool compute_depth_l1(const cv::Mat& rendered_m, const cv::Mat& gt_m, const cv::Mat& mask,
                      DepthL1Result* result, std::string* why);

// ---- semantic segmentation: mIoU / mAcc ---------------------------------------------------------

struct SegmentationConfig {
  int num_classes = 0;      // classes are the labels 0 .. num_classes - 1
  int ignore_label = 255;   // ground-truth pixels with this label are skipped entirely
};
bool validate(const SegmentationConfig& config, std::string* why);

// Pixel counts: rows are ground-truth classes, columns predicted classes, plus a last column for
// predictions outside 0 .. num_classes - 1 (unlabelled, or the ignore label), which are wrong
// for the ground-truth class and a false positive for none. Accumulates over frames.
struct ConfusionMatrix {
  int num_classes = 0;
  std::vector<std::int64_t> counts;  // [num_classes, num_classes + 1] row-major

  explicit ConfusionMatrix(int classes = 0);
  std::int64_t at(int gt, int predicted) const;  // predicted == num_classes: the "none" column
};

// Label images: same size, CV_8UC1, CV_16UC1 or CV_32SC1. Ground-truth labels other than the
// ignore label must be classes. `confusion` must have been made for config.num_classes.
bool accumulate_confusion(const cv::Mat& predicted, const cv::Mat& gt,
                          const SegmentationConfig& config, ConfusionMatrix* confusion,
                          std::string* why);

struct SegmentationResult {
  // IoU_c = TP / (TP + FP + FN); mIoU averages it over the classes with TP + FP + FN > 0
  // (present in the ground truth or predicted). Acc_c = TP / (TP + FN), the class's recall; mAcc
  // averages it over the classes present in the ground truth. Fractions in [0, 1]; NaN when no
  // class qualifies (mmsegmentation's rule: per-class values of 0/0 are left out of the mean).
  double miou = 0.0;
  double macc = 0.0;
  double pixel_accuracy = 0.0;    // sum TP / all counted ground-truth pixels
  int classes_in_miou = 0;
  int classes_in_macc = 0;
  std::vector<double> iou;        // [num_classes], NaN where the class does not enter mIoU
  std::vector<double> accuracy;   // [num_classes], NaN where the class does not enter mAcc
};
SegmentationResult segmentation_metrics(const ConfusionMatrix& confusion);

// ---- promptless (instance) segmentation: Hungarian matching -------------------------------------

struct InstanceMatchConfig {
  int ignore_id = 0;  // ground-truth pixels with this id (unannotated / background) are skipped
  // Predicted pixels with this id belong to no instance: they count in the ground truth's area
  // (a miss) but match nothing. The default is no such id.
  int predicted_none = std::numeric_limits<int>::min();
};

// Pixel overlap between predicted instance ids and ground-truth instance ids, accumulated over
// all evaluated frames so that a predicted id is matched once for the whole sequence.
struct InstanceOverlap {
  std::map<std::pair<int, int>, std::int64_t> intersection;  // (pred id, gt id) -> pixels
  std::map<int, std::int64_t> predicted_area;                // pred id -> pixels on counted gt
  std::map<int, std::int64_t> gt_area;                       // gt id -> pixels
};

// Id images: same size, CV_8UC1, CV_16UC1 or CV_32SC1; any id value is an instance (the
// predicted ignore id too), only ground-truth pixels with ignore_id are skipped.
bool accumulate_instance_overlap(const cv::Mat& predicted_ids, const cv::Mat& gt_ids,
                                 const InstanceMatchConfig& config, InstanceOverlap* overlap,
                                 std::string* why);

struct InstanceMatchResult {
  std::map<int, int> gt_to_predicted;  // matched pairs only (a matched pair overlaps)
  std::map<int, double> iou;           // gt id -> IoU with its match, 0 when unmatched
  std::map<int, double> accuracy;      // gt id -> matched overlap / gt area, 0 when unmatched
  double miou = 0.0;  // mean over every ground-truth instance; NaN when there is none
  double macc = 0.0;  // same set of instances
  std::size_t unmatched_predicted = 0;
};

// One-to-one matching of predicted to ground-truth instances maximising the summed IoU
// (Hungarian algorithm); a pair with zero overlap is not a match.
InstanceMatchResult match_instances(const InstanceOverlap& overlap);

// IoU of a binary mask (non-zero = in) with gt_ids == id: -1 when both are empty.
double mask_iou(const cv::Mat& mask, const cv::Mat& gt_ids, int id);

// The simulated one-click prompt on a binary mask (CV_8UC1, non-zero = object): the pixel
// farthest from the object's outline, where the image border counts as outline (the mask is
// padded with background, as interactive-segmentation protocols do), so a click never lands on
// the edge where the view cuts the object. False when no pixel is at least `min_distance` px in.
bool click_point(const cv::Mat& mask, double min_distance, cv::Point* at);

// Minimum-cost assignment (Hungarian / Kuhn-Munkres, O(n^2 m)) on a rows x cols cost matrix
// (row-major, finite). Returns, for each row, its column, or -1 for rows left over when there
// are more rows than columns; every row is assigned when rows <= cols.
std::vector<int> solve_assignment(const std::vector<double>& cost, int rows, int cols);

}  // namespace fslam::core

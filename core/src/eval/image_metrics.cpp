#include "fslam/core/eval/image_metrics.hpp"

#include "fslam/core/error.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/core/math/ssim.hpp"

namespace fslam::core {
namespace {

std::string describe(const cv::Mat& m) {
  return std::to_string(m.cols) + "x" + std::to_string(m.rows) + " " +
         cv::typeToString(m.type());
}

bool check_pair(const cv::Mat& a, const cv::Mat& b, const char* what, std::string* why) {
  if (a.empty() || b.empty()) return fail(why, std::string(what) + ": empty image");
  if (a.size() != b.size() || a.type() != b.type())
    return fail(why, std::string(what) + ": rendered " + describe(a) + " and reference " +
                         describe(b) + " differ in size or type");
  return true;
}

bool check_colour(const cv::Mat& a, const cv::Mat& b, const ImageMetricsConfig& config,
                  const char* what, double* data_range, std::string* why) {
  if (!validate(config, why) || !check_pair(a, b, what, why)) return false;
  const int depth = a.depth();
  if (depth != CV_8U && depth != CV_16U && depth != CV_32F && depth != CV_64F)
    return fail(why, std::string(what) + ": unsupported pixel type " + describe(a) +
                         " (8-bit, 16-bit, float or double)");
  if (config.data_range > 0.0)
    *data_range = config.data_range;
  else
    *data_range = depth == CV_8U ? 255.0 : depth == CV_16U ? 65535.0 : 1.0;
  return true;
}

// Label or id images are read as int whatever their storage type.
bool check_labels(const cv::Mat& predicted, const cv::Mat& gt, const char* what,
                  std::string* why) {
  if (predicted.empty() || gt.empty()) return fail(why, std::string(what) + ": empty image");
  for (const cv::Mat* m : {&predicted, &gt})
    if (m->type() != CV_8UC1 && m->type() != CV_16UC1 && m->type() != CV_32SC1)
      return fail(why, std::string(what) + ": label image " + describe(*m) +
                           " must be CV_8UC1, CV_16UC1 or CV_32SC1");
  if (predicted.size() != gt.size())
    return fail(why, std::string(what) + ": predicted " + describe(predicted) +
                         " and ground truth " + describe(gt) + " differ in size");
  return true;
}

cv::Mat as_int(const cv::Mat& labels) {
  if (labels.type() == CV_32SC1) return labels;
  cv::Mat out;
  labels.convertTo(out, CV_32S);
  return out;
}

}  // namespace

bool validate(const ImageMetricsConfig& config, std::string* why) {
  if (!std::isfinite(config.data_range) || config.data_range < 0.0)
    return fail(why, "image metrics data_range must be >= 0 (0 derives it from the pixel type)");
  if (config.ssim_window < 1 || config.ssim_window % 2 == 0)
    return fail(why, "SSIM window must be a positive odd number of pixels, got " +
                         std::to_string(config.ssim_window));
  if (!std::isfinite(config.ssim_sigma) || !(config.ssim_sigma > 0.0))
    return fail(why, "SSIM sigma must be positive");
  return true;
}

bool compute_psnr(const cv::Mat& rendered, const cv::Mat& reference,
                  const ImageMetricsConfig& config, double* psnr_db, std::string* why) {
  double L = 0.0;
  if (!check_colour(rendered, reference, config, "PSNR", &L, why)) return false;
  cv::Mat a, b;
  rendered.convertTo(a, CV_64F);
  reference.convertTo(b, CV_64F);
  const double mse = cv::norm(a, b, cv::NORM_L2SQR) / static_cast<double>(a.total() * a.channels());
  *psnr_db = mse > 0.0 ? 10.0 * std::log10(L * L / mse) : std::numeric_limits<double>::infinity();
  return true;
}

bool compute_ssim(const cv::Mat& rendered, const cv::Mat& reference,
                  const ImageMetricsConfig& config, double* ssim, std::string* why,
                  cv::Mat* ssim_map) {
  double L = 0.0;
  if (!check_colour(rendered, reference, config, "SSIM", &L, why)) return false;
  // Values scaled to [0, 1] with C1, C2 for L = 1: SSIM is unchanged when x, y scale by k and
  // C1, C2 by k^2, and the moments stay well conditioned.
  cv::Mat x, y;
  rendered.convertTo(x, CV_64F, 1.0 / L);
  reference.convertTo(y, CV_64F, 1.0 / L);
  cv::Mat kernel(config.ssim_window, 1, CV_64F);  // [window] normalised Gaussian taps
  math::ssim_gaussian_window(config.ssim_window, config.ssim_sigma, kernel.ptr<double>());
  const double c1 = math::ssim_c1(1.0), c2 = math::ssim_c2(1.0);

  // Zero-padded 'same' convolution: out-of-image taps read 0 and keep their weight (3DGS's
  // F.conv2d(padding = window // 2)), so border windows see darker means.
  auto blur = [&](const cv::Mat& src) {
    cv::Mat dst;
    cv::sepFilter2D(src, dst, CV_64F, kernel, kernel, cv::Point(-1, -1), 0.0, cv::BORDER_CONSTANT);
    return dst;
  };
  std::vector<cv::Mat> xs, ys, maps;
  cv::split(x, xs);
  cv::split(y, ys);
  double sum = 0.0;
  for (std::size_t c = 0; c < xs.size(); ++c) {
    const cv::Mat mx = blur(xs[c]), my = blur(ys[c]);
    const cv::Mat mxx = blur(xs[c].mul(xs[c])), myy = blur(ys[c].mul(ys[c]));
    const cv::Mat mxy = blur(xs[c].mul(ys[c]));
    cv::Mat map(x.size(), CV_64FC1);
    for (int v = 0; v < x.rows; ++v)
      for (int u = 0; u < x.cols; ++u) {
        const double ux = mx.at<double>(v, u), uy = my.at<double>(v, u);
        const double s = math::ssim_from_moments(
            ux, uy, mxx.at<double>(v, u) - ux * ux, myy.at<double>(v, u) - uy * uy,
            mxy.at<double>(v, u) - ux * uy, c1, c2);
        map.at<double>(v, u) = s;
        sum += s;
      }
    maps.push_back(map);
  }
  *ssim = sum / static_cast<double>(x.total() * xs.size());
  if (ssim_map) cv::merge(maps, *ssim_map);
  return true;
}

bool compute_depth_l1(const cv::Mat& rendered_m, const cv::Mat& gt_m, const cv::Mat& mask,
                      DepthL1Result* result, std::string* why) {
  if (!check_pair(rendered_m, gt_m, "depth L1", why)) return false;
  if (rendered_m.type() != CV_32FC1 && rendered_m.type() != CV_64FC1)
    return fail(why, "depth L1: depth maps must be CV_32FC1 or CV_64FC1 in metres, got " +
                         describe(rendered_m));
  if (!mask.empty() && (mask.type() != CV_8UC1 || mask.size() != gt_m.size()))
    return fail(why, "depth L1: mask " + describe(mask) + " must be CV_8UC1 of the depth size");
  cv::Mat r, g;
  rendered_m.convertTo(r, CV_64F);
  gt_m.convertTo(g, CV_64F);
  DepthL1Result out;
  double sum = 0.0;
  for (int v = 0; v < g.rows; ++v)
    for (int u = 0; u < g.cols; ++u) {
      const double z_gt = g.at<double>(v, u);
      if (!std::isfinite(z_gt) || !(z_gt > 0.0) || (!mask.empty() && !mask.at<uchar>(v, u)))
        continue;
      double z = r.at<double>(v, u);
      if (!std::isfinite(z) || !(z > 0.0)) {
        z = 0.0;
        ++out.missing_rendered;
      }
      sum += std::abs(z - z_gt);
      ++out.valid_pixels;
    }
  if (out.valid_pixels == 0)
    return fail(why, "depth L1: no pixel has valid ground-truth depth" +
                         std::string(mask.empty() ? "" : " inside the mask"));
  out.l1_cm = 100.0 * sum / static_cast<double>(out.valid_pixels);
  *result = out;
  return true;
}

bool validate(const SegmentationConfig& config, std::string* why) {
  if (config.num_classes < 1)
    return fail(why, "segmentation needs num_classes >= 1, got " +
                         std::to_string(config.num_classes));
  if (config.ignore_label >= 0 && config.ignore_label < config.num_classes)
    return fail(why, "ignore label " + std::to_string(config.ignore_label) +
                         " is one of the classes 0.." + std::to_string(config.num_classes - 1));
  return true;
}

ConfusionMatrix::ConfusionMatrix(int classes)
    : num_classes(classes),
      counts(static_cast<std::size_t>(std::max(classes, 0)) *
                 static_cast<std::size_t>(std::max(classes, 0) + 1),
             0) {}

std::int64_t ConfusionMatrix::at(int gt, int predicted) const {
  return counts[static_cast<std::size_t>(gt) * static_cast<std::size_t>(num_classes + 1) +
                static_cast<std::size_t>(predicted)];
}

bool accumulate_confusion(const cv::Mat& predicted, const cv::Mat& gt,
                          const SegmentationConfig& config, ConfusionMatrix* confusion,
                          std::string* why) {
  if (!validate(config, why) || !check_labels(predicted, gt, "segmentation", why)) return false;
  if (confusion->num_classes != config.num_classes ||
      confusion->counts.size() != static_cast<std::size_t>(config.num_classes) *
                                      static_cast<std::size_t>(config.num_classes + 1))
    return fail(why, "confusion matrix is for " + std::to_string(confusion->num_classes) +
                         " classes, the config says " + std::to_string(config.num_classes));
  const cv::Mat p = as_int(predicted), g = as_int(gt);
  const int K = config.num_classes;
  // Validate the whole frame before counting, so a bad frame leaves the matrix untouched.
  for (int v = 0; v < g.rows; ++v)
    for (int u = 0; u < g.cols; ++u) {
      const int label = g.at<int>(v, u);
      if (label != config.ignore_label && (label < 0 || label >= K))
        return fail(why, "segmentation: ground-truth label " + std::to_string(label) + " at (" +
                             std::to_string(u) + ", " + std::to_string(v) +
                             ") is neither a class 0.." + std::to_string(K - 1) +
                             " nor the ignore label " + std::to_string(config.ignore_label));
    }
  for (int v = 0; v < g.rows; ++v)
    for (int u = 0; u < g.cols; ++u) {
      const int label = g.at<int>(v, u);
      if (label == config.ignore_label) continue;
      const int pred = p.at<int>(v, u);
      const int column = pred >= 0 && pred < K ? pred : K;
      ++confusion->counts[static_cast<std::size_t>(label) * static_cast<std::size_t>(K + 1) +
                          static_cast<std::size_t>(column)];
    }
  return true;
}

SegmentationResult segmentation_metrics(const ConfusionMatrix& confusion) {
  const int K = confusion.num_classes;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  SegmentationResult r;
  r.iou.assign(static_cast<std::size_t>(K), nan);
  r.accuracy.assign(static_cast<std::size_t>(K), nan);
  std::int64_t total = 0, correct = 0;
  double iou_sum = 0.0, acc_sum = 0.0;
  for (int c = 0; c < K; ++c) {
    const std::int64_t tp = confusion.at(c, c);
    std::int64_t gt_count = 0, predicted_count = 0;
    for (int k = 0; k <= K; ++k) gt_count += confusion.at(c, k);  // TP + FN
    for (int k = 0; k < K; ++k) predicted_count += confusion.at(k, c);  // TP + FP
    total += gt_count;
    correct += tp;
    const std::int64_t union_count = gt_count + predicted_count - tp;
    if (union_count > 0) {
      r.iou[static_cast<std::size_t>(c)] = static_cast<double>(tp) / static_cast<double>(union_count);
      iou_sum += r.iou[static_cast<std::size_t>(c)];
      ++r.classes_in_miou;
    }
    if (gt_count > 0) {
      r.accuracy[static_cast<std::size_t>(c)] = static_cast<double>(tp) / static_cast<double>(gt_count);
      acc_sum += r.accuracy[static_cast<std::size_t>(c)];
      ++r.classes_in_macc;
    }
  }
  r.miou = r.classes_in_miou ? iou_sum / r.classes_in_miou : nan;
  r.macc = r.classes_in_macc ? acc_sum / r.classes_in_macc : nan;
  r.pixel_accuracy = total ? static_cast<double>(correct) / static_cast<double>(total) : nan;
  return r;
}

bool accumulate_instance_overlap(const cv::Mat& predicted_ids, const cv::Mat& gt_ids,
                                 const InstanceMatchConfig& config, InstanceOverlap* overlap,
                                 std::string* why) {
  if (!check_labels(predicted_ids, gt_ids, "instance matching", why)) return false;
  const cv::Mat p = as_int(predicted_ids), g = as_int(gt_ids);
  for (int v = 0; v < g.rows; ++v)
    for (int u = 0; u < g.cols; ++u) {
      const int gt = g.at<int>(v, u);
      if (gt == config.ignore_id) continue;
      ++overlap->gt_area[gt];
      const int pred = p.at<int>(v, u);
      if (pred == config.predicted_none) continue;
      ++overlap->intersection[{pred, gt}];
      ++overlap->predicted_area[pred];
    }
  return true;
}

InstanceMatchResult match_instances(const InstanceOverlap& overlap) {
  std::vector<int> gt_ids, pred_ids;
  for (const auto& [id, area] : overlap.gt_area) gt_ids.push_back(id);
  for (const auto& [id, area] : overlap.predicted_area) pred_ids.push_back(id);
  std::map<int, int> pred_column;
  for (std::size_t j = 0; j < pred_ids.size(); ++j) pred_column[pred_ids[j]] = static_cast<int>(j);

  const int rows = static_cast<int>(gt_ids.size()), cols = static_cast<int>(pred_ids.size());
  std::vector<double> iou(static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols), 0.0);
  std::map<int, int> gt_row;
  for (int i = 0; i < rows; ++i) gt_row[gt_ids[static_cast<std::size_t>(i)]] = i;
  for (const auto& [key, inter] : overlap.intersection) {
    const auto [pred, gt] = key;
    const double uni = static_cast<double>(overlap.gt_area.at(gt) +
                                           overlap.predicted_area.at(pred) - inter);
    iou[static_cast<std::size_t>(gt_row[gt]) * static_cast<std::size_t>(cols) +
        static_cast<std::size_t>(pred_column[pred])] = static_cast<double>(inter) / uni;
  }

  // Maximise summed IoU = minimise summed (1 - IoU).
  std::vector<double> cost(iou.size());
  for (std::size_t k = 0; k < iou.size(); ++k) cost[k] = 1.0 - iou[k];
  const std::vector<int> assignment = solve_assignment(cost, rows, cols);

  InstanceMatchResult r;
  double iou_sum = 0.0, acc_sum = 0.0;
  for (int i = 0; i < rows; ++i) {
    const int gt = gt_ids[static_cast<std::size_t>(i)];
    const int j = assignment[static_cast<std::size_t>(i)];
    double value = 0.0, acc = 0.0;
    if (j >= 0) {
      const int pred = pred_ids[static_cast<std::size_t>(j)];
      const auto it = overlap.intersection.find({pred, gt});
      if (it != overlap.intersection.end() && it->second > 0) {
        r.gt_to_predicted[gt] = pred;
        value = iou[static_cast<std::size_t>(i) * static_cast<std::size_t>(cols) +
                    static_cast<std::size_t>(j)];
        acc = static_cast<double>(it->second) / static_cast<double>(overlap.gt_area.at(gt));
      }
    }
    r.iou[gt] = value;
    r.accuracy[gt] = acc;
    iou_sum += value;
    acc_sum += acc;
  }
  const double nan = std::numeric_limits<double>::quiet_NaN();
  r.miou = rows ? iou_sum / rows : nan;
  r.macc = rows ? acc_sum / rows : nan;
  r.unmatched_predicted = pred_ids.size() - r.gt_to_predicted.size();
  return r;
}

std::vector<int> solve_assignment(const std::vector<double>& cost, int rows, int cols) {
  if (rows <= 0) return {};
  if (cols <= 0) return std::vector<int>(static_cast<std::size_t>(rows), -1);
  if (rows > cols) {
    // The potentials method below needs rows <= cols: solve the transpose and invert it.
    std::vector<double> transposed(cost.size());
    for (int i = 0; i < rows; ++i)
      for (int j = 0; j < cols; ++j)
        transposed[static_cast<std::size_t>(j) * static_cast<std::size_t>(rows) +
                   static_cast<std::size_t>(i)] =
            cost[static_cast<std::size_t>(i) * static_cast<std::size_t>(cols) +
                 static_cast<std::size_t>(j)];
    const std::vector<int> col_to_row = solve_assignment(transposed, cols, rows);
    std::vector<int> row_to_col(static_cast<std::size_t>(rows), -1);
    for (int j = 0; j < cols; ++j) row_to_col[static_cast<std::size_t>(col_to_row[static_cast<std::size_t>(j)])] = j;
    return row_to_col;
  }
  // Shortest augmenting paths with row / column potentials u, v (Kuhn-Munkres in the
  // Jonker-Volgenant form); 1-based with column 0 as the virtual start.
  const auto n = static_cast<std::size_t>(rows), m = static_cast<std::size_t>(cols);
  const double inf = std::numeric_limits<double>::infinity();
  auto a = [&](std::size_t i, std::size_t j) { return cost[(i - 1) * m + (j - 1)]; };
  std::vector<double> u(n + 1, 0.0), v(m + 1, 0.0);
  std::vector<std::size_t> p(m + 1, 0), way(m + 1, 0);  // p[j]: row matched to column j
  for (std::size_t i = 1; i <= n; ++i) {
    p[0] = i;
    std::size_t j0 = 0;
    std::vector<double> minv(m + 1, inf);
    std::vector<bool> used(m + 1, false);
    do {
      used[j0] = true;
      const std::size_t i0 = p[j0];
      double delta = inf;
      std::size_t j1 = 0;
      for (std::size_t j = 1; j <= m; ++j) {
        if (used[j]) continue;
        const double reduced = a(i0, j) - u[i0] - v[j];
        if (reduced < minv[j]) {
          minv[j] = reduced;
          way[j] = j0;
        }
        if (minv[j] < delta) {
          delta = minv[j];
          j1 = j;
        }
      }
      for (std::size_t j = 0; j <= m; ++j) {
        if (used[j]) {
          u[p[j]] += delta;
          v[j] -= delta;
        } else {
          minv[j] -= delta;
        }
      }
      j0 = j1;
    } while (p[j0] != 0);
    do {
      const std::size_t j1 = way[j0];
      p[j0] = p[j1];
      j0 = j1;
    } while (j0 != 0);
  }
  std::vector<int> row_to_col(n, -1);
  for (std::size_t j = 1; j <= m; ++j)
    if (p[j] != 0) row_to_col[p[j] - 1] = static_cast<int>(j - 1);
  return row_to_col;
}

double mask_iou(const cv::Mat& mask, const cv::Mat& gt_ids, int id) {
  const cv::Mat g = as_int(gt_ids);
  std::int64_t inter = 0, uni = 0;
  for (int v = 0; v < g.rows; ++v)
    for (int u = 0; u < g.cols; ++u) {
      const bool m = mask.at<std::uint8_t>(v, u) != 0, t = g.at<int>(v, u) == id;
      inter += (m && t) ? 1 : 0;
      uni += (m || t) ? 1 : 0;
    }
  return uni == 0 ? -1.0 : static_cast<double>(inter) / static_cast<double>(uni);
}

bool click_point(const cv::Mat& mask, double min_distance, cv::Point* at) {
  cv::Mat padded, distance;
  cv::copyMakeBorder(mask != 0, padded, 1, 1, 1, 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::distanceTransform(padded, distance, cv::DIST_L2, 3);
  double best = 0.0;
  cv::Point where;
  cv::minMaxLoc(distance, nullptr, &best, nullptr, &where);
  if (best < min_distance) return false;
  *at = where - cv::Point(1, 1);
  return true;
}

}  // namespace fslam::core

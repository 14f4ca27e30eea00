#include "fslam/core/eval/segmentation_metrics.hpp"

#include <algorithm>
#include <limits>

#include "fslam/core/error.hpp"

namespace fslam::core {
namespace {

int truth_at(const cv::Mat& truth, int v, int u) {
  return truth.type() == CV_16UC1 ? truth.at<std::uint16_t>(v, u) : truth.at<int>(v, u);
}

}  // namespace

bool InstanceConfusion::add(const cv::Mat& predicted, const cv::Mat& truth, std::string* why) {
  if (predicted.type() != CV_32SC1) return fail(why, "segmentation score: predicted ids must be CV_32SC1");
  if (truth.type() != CV_16UC1 && truth.type() != CV_32SC1) {
    return fail(why, "segmentation score: ground-truth ids must be CV_16UC1 or CV_32SC1");
  }
  if (predicted.size() != truth.size()) return fail(why, "segmentation score: image sizes differ");
  for (int v = 0; v < truth.rows; ++v)
    for (int u = 0; u < truth.cols; ++u) {
      const int t = truth_at(truth, v, u);
      if (t == 0) continue;
      const int p = predicted.at<int>(v, u);
      ++truth_area_[t];
      if (p >= 0) {
        ++predicted_area_[p];
        ++joint_[{t, p}];
      }
    }
  return true;
}

InstanceConfusion::Score InstanceConfusion::score(std::size_t min_pixels) const {
  Score s;
  std::vector<int> truths, preds;
  for (const auto& [t, n] : truth_area_)
    if (n >= min_pixels) truths.push_back(t);
  for (const auto& [p, n] : predicted_area_) preds.push_back(p);
  if (truths.empty()) return s;
  const int rows = static_cast<int>(truths.size()), cols = static_cast<int>(preds.size());
  std::vector<double> iou(static_cast<std::size_t>(rows) * std::max(cols, 1), 0.0);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const auto it = joint_.find({truths[r], preds[c]});
      if (it == joint_.end()) continue;
      const double inter = static_cast<double>(it->second);
      const double uni = static_cast<double>(truth_area_.at(truths[r])) +
                         static_cast<double>(predicted_area_.at(preds[c])) - inter;
      iou[static_cast<std::size_t>(r) * cols + c] = inter / uni;
    }
  std::vector<int> assignment(static_cast<std::size_t>(rows), -1);
  if (cols > 0) {
    std::vector<double> cost(iou.size());
    for (std::size_t k = 0; k < cost.size(); ++k) cost[k] = -iou[k];
    assignment = hungarian_assignment(cost, rows, cols);
  }
  for (int r = 0; r < rows; ++r) {
    const int c = assignment[static_cast<std::size_t>(r)];
    double value = 0.0, acc = 0.0;
    if (c >= 0) {
      value = iou[static_cast<std::size_t>(r) * cols + c];
      const auto it = joint_.find({truths[r], preds[c]});
      if (it != joint_.end() && value > 0) {
        s.matched[truths[r]] = preds[c];
        acc = static_cast<double>(it->second) / static_cast<double>(truth_area_.at(truths[r]));
      }
    }
    s.iou[truths[r]] = value;
    s.miou += value;
    s.macc += acc;
  }
  s.scored = truths.size();
  s.miou /= static_cast<double>(rows);
  s.macc /= static_cast<double>(rows);
  return s;
}

std::vector<int> hungarian_assignment(const std::vector<double>& cost, int rows, int cols) {
  // Square n x n with zero-cost padding; potentials u, v and the matching p (e-maxx formulation).
  const int n = std::max(rows, cols);
  auto a = [&](int i, int j) -> double {  // 1-based
    return (i <= rows && j <= cols) ? cost[static_cast<std::size_t>(i - 1) * cols + (j - 1)] : 0.0;
  };
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double> u(n + 1, 0.0), v(n + 1, 0.0);
  std::vector<int> p(n + 1, 0), way(n + 1, 0);
  for (int i = 1; i <= n; ++i) {
    p[0] = i;
    int j0 = 0;
    std::vector<double> minv(n + 1, inf);
    std::vector<bool> used(n + 1, false);
    do {
      used[j0] = true;
      const int i0 = p[j0];
      double delta = inf;
      int j1 = 0;
      for (int j = 1; j <= n; ++j) {
        if (used[j]) continue;
        const double cur = a(i0, j) - u[i0] - v[j];
        if (cur < minv[j]) {
          minv[j] = cur;
          way[j] = j0;
        }
        if (minv[j] < delta) {
          delta = minv[j];
          j1 = j;
        }
      }
      for (int j = 0; j <= n; ++j) {
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
      const int j1 = way[j0];
      p[j0] = p[j1];
      j0 = j1;
    } while (j0 != 0);
  }
  std::vector<int> assignment(static_cast<std::size_t>(rows), -1);
  for (int j = 1; j <= n; ++j)
    if (p[j] >= 1 && p[j] <= rows && j <= cols) assignment[static_cast<std::size_t>(p[j] - 1)] = j - 1;
  return assignment;
}

double mask_iou(const cv::Mat& mask, const cv::Mat& truth, int id) {
  std::uint64_t inter = 0, uni = 0;
  for (int v = 0; v < truth.rows; ++v)
    for (int u = 0; u < truth.cols; ++u) {
      const bool m = mask.at<std::uint8_t>(v, u) != 0;
      const bool t = truth_at(truth, v, u) == id;
      inter += (m && t) ? 1 : 0;
      uni += (m || t) ? 1 : 0;
    }
  return uni == 0 ? -1.0 : static_cast<double>(inter) / static_cast<double>(uni);
}

}  // namespace fslam::core

#include "fslam/core/segmentation/label_rendering.hpp"

#include <algorithm>

#include "fslam/core/error.hpp"

namespace fslam::core {
namespace {

// A copy of the map's geometry and opacity (colour DC only) whose D feature channels the caller
// fills: rendering them gives per-pixel sums of blending weights per channel.
GaussianMap geometry_copy(const GaussianMap& map, int channels) {
  GaussianMap g;
  g.sh_degree = 0;
  g.feature_dim = channels;
  g.means = map.means;
  g.rotations = map.rotations;
  g.log_scales = map.log_scales;
  g.opacity_logits = map.opacity_logits;
  g.filter_3d = map.filter_3d;
  const int k = map.sh_per_gaussian();
  g.sh.resize(map.size() * 3);
  for (std::size_t i = 0; i < map.size(); ++i)
    for (int c = 0; c < 3; ++c) g.sh[i * 3 + c] = map.sh[i * static_cast<std::size_t>(k) + c];
  g.features.assign(map.size() * static_cast<std::size_t>(channels), 0.0f);
  return g;
}

}  // namespace

bool render_labels(const Rasterizer& rasterizer, const GaussianMap& map, const GaussianLabels& labels,
                   const RenderView& view, float min_alpha, cv::Mat* ids, std::string* why) {
  if (labels.label.size() != map.size()) return fail(why, "render labels: one label per Gaussian expected");
  constexpr int kChunk = 16;  // labels rendered per pass, as one-hot feature channels
  const int chunks = std::max(1, (labels.count + kChunk - 1) / kChunk);
  GaussianMap g = geometry_copy(map, kChunk);
  RenderSettings settings;
  settings.features = true;
  cv::Mat best(view.camera.height, view.camera.width, CV_32FC1, cv::Scalar(0));
  cv::Mat total(view.camera.height, view.camera.width, CV_32FC1, cv::Scalar(0));
  *ids = cv::Mat(view.camera.height, view.camera.width, CV_32SC1, cv::Scalar(-1));
  for (int chunk = 0; chunk < chunks; ++chunk) {
    std::fill(g.features.begin(), g.features.end(), 0.0f);
    for (std::size_t i = 0; i < map.size(); ++i) {
      const int c = labels.label[i] - chunk * kChunk;
      if (c >= 0 && c < kChunk) g.features[i * kChunk + static_cast<std::size_t>(c)] = 1.0f;
    }
    RenderResult r;
    if (!rasterizer.forward(g, view, settings, &r, why)) return false;
    for (int v = 0; v < view.camera.height; ++v)
      for (int u = 0; u < view.camera.width; ++u)
        for (int c = 0; c < kChunk; ++c) {
          const float w = r.features.at(c, v, u);
          total.at<float>(v, u) += w;
          if (w > best.at<float>(v, u)) {
            best.at<float>(v, u) = w;
            ids->at<int>(v, u) = chunk * kChunk + c;
          }
        }
  }
  ids->setTo(-1, total < min_alpha);
  return true;
}

bool render_selection(const Rasterizer& rasterizer, const GaussianMap& map,
                      const std::vector<std::uint8_t>& selected, const RenderView& view,
                      float min_alpha, cv::Mat* mask, std::string* why) {
  if (selected.size() != map.size()) return fail(why, "render selection: one flag per Gaussian expected");
  GaussianMap g = geometry_copy(map, 1);
  for (std::size_t i = 0; i < map.size(); ++i) g.features[i] = selected[i] ? 1.0f : 0.0f;
  RenderSettings settings;
  settings.features = true;
  RenderResult r;
  if (!rasterizer.forward(g, view, settings, &r, why)) return false;
  *mask = cv::Mat(view.camera.height, view.camera.width, CV_8UC1, cv::Scalar(0));
  for (int v = 0; v < view.camera.height; ++v)
    for (int u = 0; u < view.camera.width; ++u) {
      const float alpha = r.alpha.at(0, v, u), in = r.features.at(0, v, u);
      if (alpha >= min_alpha && in >= 0.5f * alpha) mask->at<std::uint8_t>(v, u) = 255;
    }
  return true;
}

}  // namespace fslam::core

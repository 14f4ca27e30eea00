// Rendering per-Gaussian segmentation into a view: instance labels as ids, a selection as a mask.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "fslam/core/map/gaussian_map.hpp"
#include "fslam/core/render/rasterizer.hpp"
#include "fslam/core/segmentation/instances.hpp"

namespace fslam::core {

// Renders per-pixel labels: the label whose Gaussians contribute the most opacity to the pixel,
// -1 where the accumulated opacity of labelled Gaussians is below min_alpha. ids: CV_32SC1.
bool render_labels(const Rasterizer& rasterizer, const GaussianMap& map, const GaussianLabels& labels,
                   const RenderView& view, float min_alpha, cv::Mat* ids, std::string* why);

// Renders a selection as a mask: 255 where the selected Gaussians make up most of the pixel's
// opacity and it is at least min_alpha opaque, else 0. mask: CV_8UC1.
bool render_selection(const Rasterizer& rasterizer, const GaussianMap& map,
                      const std::vector<std::uint8_t>& selected, const RenderView& view,
                      float min_alpha, cv::Mat* mask, std::string* why);

}  // namespace fslam::core

// A picture of an ATE result: top and side views of the ground truth and the aligned estimate,
// the estimate coloured by its ATE error, drawn with OpenCV into an RGB image.
#pragma once

#include <string>

#include <opencv2/core/mat.hpp>

#include "fslam/core/eval/ate.hpp"
#include "fslam/core/io/trajectory_io.hpp"

namespace fslam::core {

struct TrajectoryPlotConfig {
  int panel_size = 720;     // pixels, width and height of each view
  std::string title;        // first part of the title line; the ATE RMSE and pair count follow
};
bool validate(const TrajectoryPlotConfig& config, std::string* why);

// Views span the principal axes of the ground-truth positions (axis 1 the longest extent): the
// top view shows axes 1-2, the side view axes 1-3, both at the same metres per pixel.
// `ate` must come from compute_ate(gt, ...). Returns CV_8UC3 in RGB order (for write_image).
bool render_trajectory_plot(const Trajectory& gt, const AteResult& ate,
                            const TrajectoryPlotConfig& config, cv::Mat* rgb, std::string* why);

}  // namespace fslam::core

#include "fslam/core/eval/trajectory_plot.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "fslam/core/io/image_io.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

// A loop in the x-y plane with a little height change, and an estimate with a slow sideways
// error that grows to 5 cm.
void loop(Trajectory* gt, Trajectory* est) {
  for (int i = 0; i < 300; ++i) {
    const double s = 2.0 * 3.14159265358979323846 * i / 300.0;
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation() = Eigen::Vector3d(2.0 * std::cos(s), std::sin(s), 0.1 * std::sin(3.0 * s));
    gt->push_back({i / 30.0, T});
    T.translation().y() += 0.05 * i / 300.0;
    est->push_back({i / 30.0, T});
  }
}

TEST(TrajectoryPlot, DrawsBothViewsAndWritesPng) {
  Trajectory gt, est;
  loop(&gt, &est);
  AteResult ate;
  std::string why;
  ASSERT_TRUE(compute_ate(gt, est, AteConfig{}, &ate, &why)) << why;
  TrajectoryPlotConfig config;
  config.title = "loop";
  cv::Mat rgb;
  ASSERT_TRUE(render_trajectory_plot(gt, ate, config, &rgb, &why)) << why;
  ASSERT_EQ(rgb.type(), CV_8UC3);
  EXPECT_EQ(rgb.cols, 2 * config.panel_size + 150);
  EXPECT_GT(rgb.rows, config.panel_size);

  // Each view holds trajectory ink: strongly coloured pixels (the error colour map) in both
  // halves, not only grey grid and text.
  for (int half = 0; half < 2; ++half) {
    const cv::Mat view = rgb(cv::Rect(half * config.panel_size, 0, config.panel_size, rgb.rows));
    int coloured = 0;
    for (int v = 0; v < view.rows; ++v)
      for (int u = 0; u < view.cols; ++u) {
        const cv::Vec3b p = view.at<cv::Vec3b>(v, u);
        const int spread = std::max({p[0], p[1], p[2]}) - std::min({p[0], p[1], p[2]});
        coloured += spread > 80;
      }
    EXPECT_GT(coloured, 500) << "view " << half;
  }

  const auto path = test::fresh_temp_dir("plot") / "loop.png";
  ASSERT_TRUE(write_image(path.string(), rgb, &why)) << why;
  EXPECT_GT(std::filesystem::file_size(path), 10000u);
}

TEST(TrajectoryPlot, RejectsMismatchedInput) {
  Trajectory gt, est;
  loop(&gt, &est);
  AteResult ate;
  std::string why;
  ASSERT_TRUE(compute_ate(gt, est, AteConfig{}, &ate, &why)) << why;
  cv::Mat rgb;
  const Trajectory shorter(gt.begin(), gt.begin() + 10);
  EXPECT_FALSE(render_trajectory_plot(shorter, ate, TrajectoryPlotConfig{}, &rgb, &why));
  EXPECT_NE(why.find("another ground truth"), std::string::npos) << why;
  EXPECT_FALSE(render_trajectory_plot(gt, AteResult{}, TrajectoryPlotConfig{}, &rgb, &why));
  TrajectoryPlotConfig tiny;
  tiny.panel_size = 10;
  EXPECT_FALSE(render_trajectory_plot(gt, ate, tiny, &rgb, &why));
}

}  // namespace
}  // namespace fslam::core

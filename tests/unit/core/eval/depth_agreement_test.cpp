#include "fslam/core/eval/depth_agreement.hpp"

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/geometry/rgbd_frame.hpp"

namespace fslam::core {
namespace {

PinholeCamera small_camera() {
  PinholeCamera c;
  c.fx = c.fy = 80.0;
  c.cx = 39.5;
  c.cy = 29.5;
  c.width = 80;
  c.height = 60;
  return c;
}

// Depth (metres along the optical axis) of the world plane n . X = d seen from T_world_camera.
cv::Mat plane_depth(const PinholeCamera& c, const Eigen::Isometry3d& T_world_camera) {
  const Eigen::Vector3d n = Eigen::Vector3d(0.2, -0.3, 1.0).normalized();
  const double d = 2.5;
  cv::Mat depth(c.height, c.width, CV_32FC1);
  for (int v = 0; v < c.height; ++v)
    for (int u = 0; u < c.width; ++u) {
      const Eigen::Vector3d ray((u - c.cx) / c.fx, (v - c.cy) / c.fy, 1.0);
      const double z = (d - n.dot(T_world_camera.translation())) /
                       n.dot(T_world_camera.linear() * ray);
      depth.at<float>(v, u) = static_cast<float>(z);
    }
  return depth;
}

Eigen::Isometry3d camera_pose(double s) {  // a camera 1 m in front of the plane, moving and turning
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(0.05 * s, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(-0.03 * s, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.04 * s, 0.02 * s, 1.0 + 0.01 * s);
  return T;
}

TEST(DepthAgreement, TheTrueRelativePoseAgreesAndAWrongOneDoesNot) {
  const PinholeCamera c = small_camera();
  const Eigen::Isometry3d Ta = camera_pose(0.0), Tb = camera_pose(1.0);
  const cv::Mat a = plane_depth(c, Ta), b = plane_depth(c, Tb);
  DepthAgreementConfig config;
  config.stride = 2;
  DepthAgreement right, wrong;
  std::string why;
  ASSERT_TRUE(depth_agreement(a, b, c, Tb.inverse() * Ta, config, &right, &why)) << why;
  EXPECT_GT(right.samples, 800u);
  // Only the nearest-pixel lookup is left: up to half a pixel of the plane's depth slope, about
  // 7 mm per pixel here (1.6 m away at 80 px focal length, tilted ~20 degrees).
  EXPECT_LT(right.median_abs_m, 0.004);
  EXPECT_DOUBLE_EQ(right.inlier_fraction, 1.0);

  // 3 cm along the optical axis of b: every sample lands ~3 cm off the surface.
  Eigen::Isometry3d off = Eigen::Isometry3d::Identity();
  off.translation() = Eigen::Vector3d(0.0, 0.0, 0.03);
  ASSERT_TRUE(depth_agreement(a, b, c, off * Tb.inverse() * Ta, config, &wrong, &why)) << why;
  EXPECT_GT(wrong.median_abs_m, 0.025);
  EXPECT_LT(wrong.median_abs_m, 0.035);
  config.inlier_distance = 0.02;
  ASSERT_TRUE(depth_agreement(a, b, c, off * Tb.inverse() * Ta, config, &wrong, &why)) << why;
  EXPECT_LT(wrong.inlier_fraction, 0.05);
}

// A depth offset fixed to the pixels (here +15 mm over the left half of frame b) shows in the
// residual grid where the samples land, and only there; an invalid grid is refused.
TEST(DepthAgreement, ResidualGridMapsADepthOffsetFixedToThePixels) {
  const PinholeCamera c = small_camera();
  const Eigen::Isometry3d Ta = camera_pose(0.0), Tb = camera_pose(1.0);
  const cv::Mat a = plane_depth(c, Ta);
  cv::Mat b = plane_depth(c, Tb);
  for (int v = 0; v < c.height; ++v)
    for (int u = 0; u < c.width / 2; ++u) b.at<float>(v, u) += 0.015f;
  DepthAgreementConfig config;
  config.stride = 1;
  DepthResidualGrid grid;
  grid.cols = 2;
  grid.rows = 1;
  grid.depth_edges = {1.0, 3.0};  // the plane is about 1.7 m away: every sample in bin 1
  DepthAgreement result;
  std::string why;
  ASSERT_TRUE(depth_agreement(a, b, c, Tb.inverse() * Ta, config, &result, &why, &grid)) << why;
  EXPECT_GT(grid.count(1, 0, 0), 500u);
  EXPECT_GT(grid.count(1, 0, 1), 500u);
  EXPECT_EQ(grid.count(0, 0, 0) + grid.count(0, 0, 1) + grid.count(2, 0, 0) + grid.count(2, 0, 1), 0u);
  EXPECT_NEAR(grid.median(1, 0, 0, 100), 0.015, 0.004);  // metres; half a pixel of depth slope
  EXPECT_NEAR(grid.median(1, 0, 1, 100), 0.0, 0.004);
  EXPECT_TRUE(std::isnan(grid.median(0, 0, 0, 100)));  // no sample nearer than 1 m
  EXPECT_EQ(grid.count(1, 0, 0) + grid.count(1, 0, 1), result.samples);  // all within 5 cm

  DepthResidualGrid bad;
  bad.cols = 0;
  EXPECT_FALSE(depth_agreement(a, b, c, Tb.inverse() * Ta, config, &result, &why, &bad));
  EXPECT_NE(why.find("cols"), std::string::npos) << why;
  bad = DepthResidualGrid{};
  bad.depth_edges = {2.0, 1.0};
  EXPECT_FALSE(depth_agreement(a, b, c, Tb.inverse() * Ta, config, &result, &why, &bad));
  EXPECT_NE(why.find("increasing"), std::string::npos) << why;
}

TEST(DepthAgreement, MissingDepthIsSkippedAndBadInputIsAnError) {
  const PinholeCamera c = small_camera();
  const cv::Mat a = plane_depth(c, camera_pose(0.0));
  cv::Mat b = plane_depth(c, camera_pose(0.0));
  b(cv::Rect(0, 0, c.width / 2, c.height)).setTo(0.0f);             // left half missing
  b.at<float>(28, 60) = std::numeric_limits<float>::quiet_NaN();  // and one NaN
  const DepthAgreementConfig config;
  DepthAgreement full, half;
  std::string why;
  ASSERT_TRUE(depth_agreement(a, a, c, Eigen::Isometry3d::Identity(), config, &full, &why));
  ASSERT_TRUE(depth_agreement(a, b, c, Eigen::Isometry3d::Identity(), config, &half, &why));
  EXPECT_EQ(half.samples, full.samples / 2 - 1);
  EXPECT_LT(half.median_abs_m, 1e-6);

  EXPECT_FALSE(depth_agreement(a, cv::Mat::zeros(c.height, c.width, CV_32FC1), c,
                               Eigen::Isometry3d::Identity(), config, &half, &why));
  EXPECT_NE(why.find("no sample"), std::string::npos) << why;
  EXPECT_FALSE(depth_agreement(a, cv::Mat::zeros(c.height, c.width + 1, CV_32FC1), c,
                               Eigen::Isometry3d::Identity(), config, &half, &why));
  EXPECT_NE(why.find("81x60"), std::string::npos) << why;
  Eigen::Isometry3d nan_pose = Eigen::Isometry3d::Identity();
  nan_pose.translation().x() = std::nan("");
  EXPECT_FALSE(depth_agreement(a, a, c, nan_pose, config, &half, &why));
  DepthAgreementConfig bad;
  bad.stride = 0;
  EXPECT_FALSE(depth_agreement(a, a, c, Eigen::Isometry3d::Identity(), bad, &half, &why));
  PinholeCamera zero = c;
  zero.fx = 0.0;
  EXPECT_FALSE(depth_agreement(a, a, zero, Eigen::Isometry3d::Identity(), config, &half, &why));
}

// Frames of the plane along camera_pose(0.25 k), 30 Hz.
class PlaneSequence : public Dataset {
 public:
  explicit PlaneSequence(std::size_t n) : n_(n) {}
  std::string kind() const override { return "tum"; }
  const std::string& root() const override { return root_; }
  std::size_t size() const override { return n_; }
  const PinholeCamera& camera() const override { return camera_; }
  std::string camera_source() const override { return "test"; }
  double depth_scale() const override { return 1000.0; }
  bool load(std::size_t index, RgbdFrame* frame, std::string*) const override {
    frame->id = id(index);
    frame->timestamp = timestamp(index);
    frame->camera = camera_;
    frame->depth = plane_depth(camera_, pose(index));
    frame->colour = cv::Mat::zeros(camera_.height, camera_.width, CV_8UC3);
    return true;
  }
  std::int64_t id(std::size_t index) const override { return 100 + static_cast<std::int64_t>(index); }
  double timestamp(std::size_t index) const override { return 5.0 + index / 30.0; }
  bool has_ground_truth() const override { return true; }
  Trajectory ground_truth() const override {
    Trajectory t;
    for (std::size_t i = 0; i < n_; ++i) t.push_back({timestamp(i), pose(i)});
    return t;
  }
  static Eigen::Isometry3d pose(std::size_t i) { return camera_pose(0.25 * static_cast<double>(i)); }

 private:
  std::size_t n_;
  std::string root_ = "plane";
  PinholeCamera camera_ = small_camera();
};

TEST(DepthAgreement, StepsFindTheJumpOfAnEstimate) {
  const PlaneSequence sequence(8);
  const Trajectory gt = sequence.ground_truth();
  Trajectory est = gt;
  Eigen::Isometry3d jump = Eigen::Isometry3d::Identity();
  jump.translation() = Eigen::Vector3d(0.0, 0.0, 0.04);
  for (std::size_t i = 4; i < est.size(); ++i) est[i].T_world_camera = jump * est[i].T_world_camera;
  std::vector<DepthAgreementStep> steps;
  std::string why;
  std::size_t calls = 0;
  ASSERT_TRUE(depth_agreement_steps(sequence, gt, est, AssociationConfig{}, 1,
                                    DepthAgreementConfig{}, &steps, &why,
                                    [&](std::size_t done, std::size_t total) {
                                      EXPECT_EQ(done, ++calls);
                                      EXPECT_EQ(total, 7u);
                                    }))
      << why;
  ASSERT_EQ(steps.size(), 7u);
  for (std::size_t k = 0; k < steps.size(); ++k) {
    EXPECT_EQ(steps[k].frame_a, 100 + static_cast<std::int64_t>(k));
    EXPECT_EQ(steps[k].frame_b, steps[k].frame_a + 1);
    EXPECT_LT(steps[k].ground_truth.median_abs_m, 0.004) << k;
    if (k == 3)
      EXPECT_GT(steps[k].estimate.median_abs_m, 0.02);  // the step 103 -> 104 carries the jump
    else
      EXPECT_LT(steps[k].estimate.median_abs_m, 0.004) << k;
  }

  // Two frames apart: steps 2 -> 4 and 3 -> 5 straddle the jump.
  ASSERT_TRUE(depth_agreement_steps(sequence, gt, est, AssociationConfig{}, 2,
                                    DepthAgreementConfig{}, &steps, &why));
  ASSERT_EQ(steps.size(), 6u);
  for (std::size_t k = 0; k < steps.size(); ++k)
    EXPECT_EQ(steps[k].estimate.median_abs_m > 0.02, k == 2 || k == 3) << k;
}

TEST(DepthAgreement, StepsRefuseAnEstimateOfAnotherRecording) {
  const PlaneSequence sequence(4);
  Trajectory gt = sequence.ground_truth(), est = gt;
  for (auto& p : gt) p.timestamp += 100.0;
  for (auto& p : est) p.timestamp += 100.0;
  std::vector<DepthAgreementStep> steps;
  std::string why;
  EXPECT_FALSE(depth_agreement_steps(sequence, gt, est, AssociationConfig{}, 1,
                                     DepthAgreementConfig{}, &steps, &why));
  EXPECT_NE(why.find("no frame within"), std::string::npos) << why;
  EXPECT_FALSE(depth_agreement_steps(sequence, sequence.ground_truth(),
                                     sequence.ground_truth(), AssociationConfig{}, 4,
                                     DepthAgreementConfig{}, &steps, &why));
  EXPECT_NE(why.find("too few"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::core

// The tracker on the built-in synthetic room: accuracy, the keyframe rule (eq. keyframe_crit) on
// constructed motions, loss reporting and robustness to missing depth.
#include "fslam/core/tracking/tracker.hpp"

#include <cmath>

#include <gtest/gtest.h>

#include "fslam/core/eval/ate.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"

namespace fslam::core {
namespace {

constexpr double kDeg = M_PI / 180.0;

class TrackerOnSynthRoom : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    room_ = new SyntheticRoom(make_room(1));
    SynthOptions options;
    options.frames = 40;
    trajectory_ = new Trajectory(make_trajectory(*room_, options));
  }
  static void TearDownTestSuite() {
    delete room_;
    delete trajectory_;
  }

  // Half-resolution rendering keeps the suite fast; the tracker sees a 320x240 camera.
  static RgbdFrame frame_at(const Eigen::Isometry3d& T_world_camera, std::int64_t id) {
    const PinholeCamera camera = synth_default_camera().scaled(0.5);
    SynthView view = render_view(*room_, camera, T_world_camera);
    RgbdFrame frame;
    frame.id = id;
    frame.timestamp = static_cast<double>(id) / 30.0;
    frame.colour = view.colour;
    frame.depth = view.depth;
    frame.camera = camera;
    frame.T_world_camera_gt = T_world_camera;
    return frame;
  }

  static TrackerConfig config() {
    TrackerConfig c;
    c.preprocess.stride = 2;  // same point density as stride 4 at 640x480
    return c;
  }

  static SyntheticRoom* room_;
  static Trajectory* trajectory_;
};
SyntheticRoom* TrackerOnSynthRoom::room_ = nullptr;
Trajectory* TrackerOnSynthRoom::trajectory_ = nullptr;

double translation_error(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return (a.translation() - b.translation()).norm();
}
double rotation_error_deg(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return rotation_angle(a.linear().transpose() * b.linear()) / kDeg;
}

TEST_F(TrackerOnSynthRoom, FollowsTheHandheldTrajectory) {
  for (bool parallel : {false, true}) {
    TrackerConfig c = config();
    c.parallel = parallel;
    Tracker tracker(c);
    Trajectory estimate;
    for (std::size_t i = 0; i < trajectory_->size(); ++i) {
      const StampedPose& gt = (*trajectory_)[i];
      if (i == 0) tracker.set_initial_pose(gt.T_world_camera);
      TrackingResult result;
      std::string why;
      ASSERT_TRUE(tracker.track(frame_at(gt.T_world_camera, static_cast<std::int64_t>(i)), &result, &why)) << why;
      EXPECT_NE(result.state, TrackingState::lost) << "frame " << i << ": " << result.message;
      estimate.push_back({gt.timestamp, result.T_world_camera});
    }
    AteResult ate;
    std::string why;
    ASSERT_TRUE(compute_ate(*trajectory_, estimate, AteConfig{}, &ate, &why)) << why;
    EXPECT_LT(ate.rmse, 0.005) << "parallel " << parallel;  // metres, exact synthetic depth
    EXPECT_LT(translation_error(estimate.back().T_world_camera, trajectory_->back().T_world_camera), 0.01);
  }
}

TEST_F(TrackerOnSynthRoom, KeyframeRuleOnConstructedMotions) {
  const Eigen::Isometry3d T0 = (*trajectory_)[0].T_world_camera;
  auto moved = [&](const Eigen::Vector3d& t_camera, double yaw_deg) {
    Eigen::Isometry3d d = Eigen::Isometry3d::Identity();
    d.translation() = t_camera;
    d.linear() = so3_exp(Eigen::Vector3d(0.0, yaw_deg * kDeg, 0.0));
    return T0 * d;
  };
  Tracker tracker(config());
  tracker.set_initial_pose(T0);
  struct Step {
    Eigen::Isometry3d pose;
    bool keyframe;
  };
  // Thresholds: 5 cm, 3 degrees (eq. keyframe_crit), always measured from the last keyframe.
  const std::vector<Step> steps = {
      {T0, true},                                           // first frame
      {moved({0.02, 0.0, 0.0}, 0.0), false},                // 2 cm
      {moved({0.04, 0.0, 0.0}, 0.0), false},                // 4 cm
      {moved({0.07, 0.0, 0.0}, 0.0), true},                 // 7 cm from T0
      {moved({0.09, 0.0, 0.0}, 0.0), false},                // 2 cm from the last keyframe
      {moved({0.07, 0.0, 0.0}, 2.0), false},                // 2 degrees
      {moved({0.07, 0.0, 0.0}, 4.0), true},                 // 4 degrees
  };
  for (std::size_t i = 0; i < steps.size(); ++i) {
    TrackingResult result;
    std::string why;
    ASSERT_TRUE(tracker.track(frame_at(steps[i].pose, static_cast<std::int64_t>(i)), &result, &why)) << why;
    EXPECT_EQ(result.keyframe, steps[i].keyframe) << "step " << i;
    EXPECT_LT(translation_error(result.T_world_camera, steps[i].pose), 0.002) << "step " << i;
    EXPECT_LT(rotation_error_deg(result.T_world_camera, steps[i].pose), 0.1) << "step " << i;
  }
  EXPECT_EQ(tracker.keyframe_count(), 3u);
}

// Constant latents, 1 for the first keyframe and 2 for the second, 7 cm later: with the refresh
// every map point the second keyframe sees carries 2, without it those of the first keep 1.
TEST_F(TrackerOnSynthRoom, KeyframesRefreshTheFeaturesOfTheMapPointsTheySee) {
  const Eigen::Isometry3d T0 = (*trajectory_)[0].T_world_camera;
  const Eigen::Isometry3d T1 = T0 * Eigen::Translation3d(0.07, 0.0, 0.0);
  const RgbdFrame f0 = frame_at(T0, 0), f1 = frame_at(T1, 1);
  const int stride = config().preprocess.stride;
  auto latent = [&](float value) {
    return PlanarImage(f0.camera.width / stride, f0.camera.height / stride, 3, value);
  };
  // Map points the second keyframe sees from its tracked pose, as refresh_map_features decides
  // it (from the true pose, a point on a depth edge may round to the pixel beside it).
  auto seen_by_f1 = [&](const Eigen::Vector3f& mean_world, const Eigen::Isometry3d& T_tracked) {
    const Eigen::Vector3d p = T_tracked.inverse() * mean_world.cast<double>();
    if (!(p.z() > 0)) return false;
    const Eigen::Vector2d uv = f1.camera.project(p);
    const int u = static_cast<int>(std::floor(uv.x() + 0.5));
    const int v = static_cast<int>(std::floor(uv.y() + 0.5));
    if (u < 0 || v < 0 || u >= f1.depth.cols || v >= f1.depth.rows) return false;
    const float z = f1.depth.at<float>(v, u);
    return z > 0.0f && std::abs(z - p.z()) <= config().gicp.max_correspondence_distance;
  };
  for (bool refresh : {true, false}) {
    TrackerConfig c = config();
    c.refresh_features = refresh;
    Tracker tracker(c);
    tracker.set_initial_pose(T0);
    TrackingResult result;
    std::string why;
    const PlanarImage l0 = latent(1.0f), l1 = latent(2.0f);
    ASSERT_TRUE(tracker.track(f0, &result, &why, &l0)) << why;
    ASSERT_TRUE(tracker.track(f1, &result, &why, &l1)) << why;
    ASSERT_TRUE(result.keyframe);
    const GaussianPoints map = tracker.local_map().points();
    ASSERT_EQ(map.feature_dim, 3);
    std::size_t seen = 0, first = 0;
    for (std::size_t i = 0; i < map.size(); ++i) {
      const bool seen_again = seen_by_f1(map.means[i], result.T_world_camera);
      seen += seen_again ? 1 : 0;
      first += map.feature(i)[0] == 1.0f ? 1 : 0;
      if (refresh && seen_again) {
        ASSERT_EQ(map.feature(i)[0], 2.0f) << "point " << i;
      }
    }
    EXPECT_GT(seen, map.size() / 2);  // the two views overlap almost entirely
    if (refresh) {
      EXPECT_LT(first, map.size() / 10) << "few points are seen by the first view only";
    } else {
      EXPECT_GT(first, map.size() / 2) << "the first keyframe's points keep its features";
    }
  }
}

TEST_F(TrackerOnSynthRoom, HalfTheDepthMissingStillTracks) {
  Tracker tracker(config());
  tracker.set_initial_pose((*trajectory_)[0].T_world_camera);
  for (std::size_t i = 0; i < 12; ++i) {
    RgbdFrame frame = frame_at((*trajectory_)[i].T_world_camera, static_cast<std::int64_t>(i));
    if (i > 0) frame.depth(cv::Rect(0, 0, frame.depth.cols / 2, frame.depth.rows)).setTo(0.0f);
    TrackingResult result;
    std::string why;
    ASSERT_TRUE(tracker.track(frame, &result, &why)) << why;
    EXPECT_NE(result.state, TrackingState::lost) << i;
    EXPECT_LT(translation_error(result.T_world_camera, (*trajectory_)[i].T_world_camera), 0.005) << i;
  }
}

TEST_F(TrackerOnSynthRoom, LostFrameIsReportedAndTrackingResumes) {
  Tracker tracker(config());
  tracker.set_initial_pose((*trajectory_)[0].T_world_camera);
  for (std::size_t i = 0; i < 8; ++i) {
    RgbdFrame frame = frame_at((*trajectory_)[i].T_world_camera, static_cast<std::int64_t>(i));
    if (i == 4) frame.depth.setTo(0.0f);  // the sensor returns nothing for one frame
    TrackingResult result;
    std::string why;
    ASSERT_TRUE(tracker.track(frame, &result, &why)) << why;
    if (i == 4) {
      EXPECT_EQ(result.state, TrackingState::lost);
      EXPECT_FALSE(result.message.empty());
      EXPECT_FALSE(result.keyframe);
    } else {
      EXPECT_NE(result.state, TrackingState::lost) << i;
      EXPECT_LT(translation_error(result.T_world_camera, (*trajectory_)[i].T_world_camera), 0.005) << i;
    }
  }
}

TEST_F(TrackerOnSynthRoom, BadInputIsAnErrorNotAState) {
  Tracker tracker(config());
  RgbdFrame frame = frame_at((*trajectory_)[0].T_world_camera, 0);
  frame.camera.fx = 0.0;
  TrackingResult result;
  std::string why;
  EXPECT_FALSE(tracker.track(frame, &result, &why));
  EXPECT_FALSE(why.empty());
  TrackerConfig bad = config();
  bad.keyframe.translation = -1.0;
  EXPECT_FALSE(bad.is_valid(&why));
  EXPECT_NE(why.find("keyframe.translation"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::core

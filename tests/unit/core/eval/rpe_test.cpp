#include "fslam/core/eval/rpe.hpp"

#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "fslam/core/geometry/se3.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

constexpr double kPi = 3.14159265358979323846;

Eigen::Isometry3d step(double yaw_deg, double forward_m) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(yaw_deg * kPi / 180.0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(forward_m, 0.0, 0.0);
  return T;
}

// Ground truth drives straight, 0.1 m per frame at 10 Hz. The estimate chains a motion of
// 0.101 m and 1 degree of yaw per frame from an arbitrary start pose, so per frame
// E = G^-1 D = [Rz(1 deg), (0.001, 0, 0)]: 1 mm and 1 degree of drift per frame.
void drifting_pair(std::size_t n, Trajectory* gt, Trajectory* est) {
  Vector6d xi;
  xi << 0.3, -1.0, 2.0, 0.2, 0.1, -0.4;
  Eigen::Isometry3d Q = Eigen::Isometry3d::Identity(), P = se3_exp(xi);
  for (std::size_t i = 0; i < n; ++i) {
    gt->push_back({10.0 + 0.1 * static_cast<double>(i), Q});
    est->push_back({10.0 + 0.1 * static_cast<double>(i), P});
    Q = Q * step(0.0, 0.1);
    P = P * step(1.0, 0.101);
  }
}

// |trans(E)| over `frames` frames of drifting_pair: the estimate's chained steps
// sum_m 0.101 (cos m deg, sin m deg, 0), m = 0..frames-1, against 0.1 * frames straight ahead.
double expected_translation_error(int frames) {
  Eigen::Vector2d sum(-0.1 * frames, 0.0);
  for (int m = 0; m < frames; ++m)
    sum += 0.101 * Eigen::Vector2d(std::cos(m * kPi / 180.0), std::sin(m * kPi / 180.0));
  return sum.norm();
}

TEST(Rpe, KnownDriftPerFrame) {
  Trajectory gt, est;
  drifting_pair(50, &gt, &est);
  RpeResult r;
  std::string why;
  ASSERT_TRUE(compute_rpe(gt, est, RpeConfig{}, &r, &why)) << why;
  EXPECT_EQ(r.pairs, 49u);
  EXPECT_NEAR(r.translation.rmse, 0.001, 1e-9);  // metres
  EXPECT_NEAR(r.translation.max, 0.001, 1e-9);
  EXPECT_NEAR(r.translation.std, 0.0, 1e-9);
  EXPECT_NEAR(r.rotation.rmse, 1.0, 1e-7);  // degrees
  EXPECT_NEAR(r.rotation.min, 1.0, 1e-7);

  // Two frames: Q_rel = (0.2, 0, 0), P_rel = [Rz(2 deg), 0.101 (1 + cos 1deg, sin 1deg, 0)], so
  // trans(E) = (0.101 (1 + cos 1deg) - 0.2, 0.101 sin 1deg, 0) = (0.0019846, 0.0017627, 0),
  // |.| = 0.0026544 m, and 2 degrees.
  RpeConfig config;
  config.delta = 2;
  ASSERT_TRUE(compute_rpe(gt, est, config, &r, &why)) << why;
  const double expected = expected_translation_error(2);
  EXPECT_NEAR(expected, 0.0026544, 1e-7);
  EXPECT_EQ(r.pairs, 48u);
  EXPECT_NEAR(r.translation.mean, expected, 1e-9);
  EXPECT_NEAR(r.translation.max - r.translation.min, 0.0, 1e-9);
  EXPECT_NEAR(r.rotation.mean, 2.0, 1e-7);
  EXPECT_EQ(r.first.front(), 0u);
  EXPECT_EQ(r.second.front(), 2u);
}

TEST(Rpe, SecondsMatchFramesOnRegularStamps) {
  Trajectory gt, est;
  drifting_pair(40, &gt, &est);
  RpeConfig frames;
  frames.delta = 3;
  RpeConfig seconds;
  seconds.unit = RpeUnit::kSeconds;
  seconds.delta = 0.3;
  RpeResult a, b;
  std::string why;
  ASSERT_TRUE(compute_rpe(gt, est, frames, &a, &why)) << why;
  ASSERT_TRUE(compute_rpe(gt, est, seconds, &b, &why)) << why;
  EXPECT_EQ(a.pairs, 37u);
  EXPECT_EQ(b.pairs, a.pairs);  // the last pose pairs with t_last - 0.3, none beyond the end
  EXPECT_EQ(a.first, b.first);
  EXPECT_EQ(a.second, b.second);
  EXPECT_NEAR(b.translation.rmse, a.translation.rmse, 1e-12);
  EXPECT_NEAR(b.rotation.rmse, 3.0, 1e-7);
}

TEST(Rpe, SecondsSkipPairsAcrossTrackingGaps) {
  Trajectory gt, est;
  drifting_pair(40, &gt, &est);
  // Drop estimate frames 10..19: t = 10.0..10.9, then 12.0..13.9. With delta 0.5 s the tolerance
  // is max(0.02, 0.05) = 0.05 s. Frames 0..4 pair with 5..9 and frames 20..34 with 25..39; the
  // targets of frames 5..9 (11.0..11.4 s) fall in the gap, at least 0.1 s from any pose, and
  // those of 35..39 beyond the end: 5 + 15 pairs, each exactly 0.5 s long.
  Trajectory gapped;
  for (std::size_t i = 0; i < est.size(); ++i)
    if (i < 10 || i >= 20) gapped.push_back(est[i]);
  RpeConfig config;
  config.unit = RpeUnit::kSeconds;
  config.delta = 0.5;
  RpeResult r;
  std::string why;
  ASSERT_TRUE(compute_rpe(gt, gapped, config, &r, &why)) << why;
  EXPECT_EQ(r.pairs, 5u + 15u);
  for (std::size_t k = 0; k < r.pairs; ++k)
    EXPECT_NEAR(gapped[r.second[k]].timestamp - gapped[r.first[k]].timestamp, 0.5, 1e-9);
  EXPECT_NEAR(r.translation.rmse, expected_translation_error(5), 1e-9);
  EXPECT_NEAR(r.rotation.rmse, 5.0, 1e-7);
}

TEST(Rpe, InvariantToRigidMotionOfTheEstimate) {
  Trajectory gt, est;
  drifting_pair(30, &gt, &est);
  Vector6d xi;
  xi << 5.0, -3.0, 1.0, -0.7, 1.9, 0.3;
  const Eigen::Isometry3d T = se3_exp(xi);
  Trajectory moved = est;
  for (auto& p : moved) p.T_world_camera = T * p.T_world_camera;
  RpeResult a, b;
  std::string why;
  ASSERT_TRUE(compute_rpe(gt, est, RpeConfig{}, &a, &why)) << why;
  ASSERT_TRUE(compute_rpe(gt, moved, RpeConfig{}, &b, &why)) << why;
  EXPECT_NEAR(a.translation.rmse, b.translation.rmse, 1e-12);
  EXPECT_NEAR(a.rotation.rmse, b.rotation.rmse, 1e-9);
}

TEST(Rpe, ScaleCorrectsMonocularTranslation) {
  Trajectory gt, drifting, est;
  drifting_pair(30, &gt, &drifting);
  for (std::size_t i = 0; i < 30; ++i) {
    Eigen::Isometry3d T = gt[i].T_world_camera;
    T.translation() *= 0.25;  // a map at a quarter of the true scale
    est.push_back({gt[i].timestamp, T});
  }
  RpeConfig config;
  RpeResult r;
  std::string why;
  ASSERT_TRUE(compute_rpe(gt, est, config, &r, &why)) << why;
  EXPECT_NEAR(r.translation.rmse, 0.075, 1e-9);  // 0.1 m per frame seen as 0.025 m
  config.scale = 4.0;
  ASSERT_TRUE(compute_rpe(gt, est, config, &r, &why)) << why;
  EXPECT_NEAR(r.translation.rmse, 0.0, 1e-12);
  EXPECT_NEAR(r.rotation.rmse, 0.0, 1e-9);
}

TEST(Rpe, OnFr2DeskPairsEveryConsecutiveAssociatedFrame) {
  FSLAM_REQUIRE_DATA("evo_reference");
  Trajectory gt, est;
  std::string why;
  const auto dir = test::data_dir() / "evo_reference" / "traj";
  ASSERT_TRUE(read_tum_trajectory((dir / "fr2_desk_groundtruth.txt").string(), &gt, &why)) << why;
  ASSERT_TRUE(read_tum_trajectory((dir / "fr2_desk_ORB.txt").string(), &est, &why)) << why;
  RpeResult r;
  ASSERT_TRUE(compute_rpe(gt, est, RpeConfig{}, &r, &why)) << why;
  std::printf("fr2_desk ORB RPE (1 frame): pairs %zu trans rmse %.7f m rot rmse %.7f deg\n",
              r.pairs, r.translation.rmse, r.rotation.rmse);
  EXPECT_EQ(r.pairs, 2222u);  // 2223 associated poses
  // ORB-SLAM2 RGB-D on fr2/desk: millimetres and a fraction of a degree per frame.
  EXPECT_LT(r.translation.rmse, 0.01);
  EXPECT_LT(r.rotation.rmse, 1.0);
}

TEST(Rpe, RejectsBadConfigAndTooLargeDelta) {
  Trajectory gt, est;
  drifting_pair(5, &gt, &est);
  RpeResult r;
  std::string why;
  RpeConfig config;
  config.delta = 1.5;
  EXPECT_FALSE(compute_rpe(gt, est, config, &r, &why));
  EXPECT_NE(why.find("whole number"), std::string::npos) << why;
  config.delta = 5;
  EXPECT_FALSE(compute_rpe(gt, est, config, &r, &why));
  EXPECT_NE(why.find("smaller RPE delta"), std::string::npos) << why;
  config.delta = 1;
  config.scale = 0.0;
  EXPECT_FALSE(compute_rpe(gt, est, config, &r, &why));
}

}  // namespace
}  // namespace fslam::core

#include "fslam/core/eval/ate.hpp"

#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "fslam/core/geometry/se3.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

std::string traj_path(const char* name) {
  return (test::data_dir() / "evo_reference" / "traj" / name).string();
}

// A curved, rotating camera path: 200 poses at 30 Hz on a helix, 2 m across.
Trajectory helix(std::size_t n = 200) {
  Trajectory t;
  for (std::size_t i = 0; i < n; ++i) {
    const double s = static_cast<double>(i) / 30.0;
    Vector6d xi;
    xi << std::cos(s), std::sin(1.3 * s), 0.2 * s, 0.3 * std::sin(s), 0.1 * s, -0.2 * s;
    Eigen::Isometry3d T = se3_exp(xi);
    T.translation() = Eigen::Vector3d(std::cos(s), std::sin(1.3 * s), 0.2 * s);
    t.push_back({1000.0 + s, T});
  }
  return t;
}

TEST(AteStats, SummaryFollowsNumpyConventions) {
  // {1, 2, 3, 4}: mean 2.5, median (2 + 3) / 2 = 2.5, rmse sqrt(30 / 4) = 2.7386128,
  // population std sqrt(((1.5^2 + 0.5^2) * 2) / 4) = sqrt(1.25) = 1.1180340.
  const ErrorStats s = summarize_errors({4.0, 1.0, 3.0, 2.0});
  EXPECT_EQ(s.count, 4u);
  EXPECT_DOUBLE_EQ(s.mean, 2.5);
  EXPECT_DOUBLE_EQ(s.median, 2.5);
  EXPECT_NEAR(s.rmse, std::sqrt(7.5), 1e-12);
  EXPECT_NEAR(s.std, std::sqrt(1.25), 1e-12);
  EXPECT_DOUBLE_EQ(s.min, 1.0);
  EXPECT_DOUBLE_EQ(s.max, 4.0);
  EXPECT_DOUBLE_EQ(summarize_errors({3.0, 1.0, 2.0}).median, 2.0);  // odd count: the middle one
  EXPECT_EQ(summarize_errors({}).count, 0u);
}

TEST(Ate, ReproducesTumReferenceOnFr2Desk) {
  FSLAM_REQUIRE_DATA("evo_reference");
  Trajectory gt, est;
  std::string why;
  ASSERT_TRUE(read_tum_trajectory(traj_path("fr2_desk_groundtruth.txt"), &gt, &why)) << why;
  ASSERT_TRUE(read_tum_trajectory(traj_path("fr2_desk_ORB.txt"), &est, &why)) << why;
  AteResult r;
  ASSERT_TRUE(compute_ate(gt, est, AteConfig{}, &r, &why)) << why;
  std::printf("fr2_desk ORB vs groundtruth: pairs %zu rmse %.7f mean %.7f median %.7f std %.7f "
              "min %.7f max %.7f (m)\n",
              r.pairs, r.rmse, r.mean, r.median, r.std, r.min, r.max);
  // TUM evaluate_ate.py (data/README.md), printed to 6 decimals: +-2 um covers the rounding.
  constexpr double kTol = 2e-6;  // metres
  EXPECT_EQ(r.pairs, 2223u);
  EXPECT_NEAR(r.rmse, 0.008144, kTol);
  EXPECT_NEAR(r.mean, 0.007514, kTol);
  EXPECT_NEAR(r.median, 0.007432, kTol);
  EXPECT_NEAR(r.std, 0.003140, kTol);
  EXPECT_NEAR(r.min, 0.000332, kTol);
  EXPECT_NEAR(r.max, 0.024329, kTol);
  EXPECT_DOUBLE_EQ(r.scale, 1.0);
  EXPECT_NEAR(r.T_gt_est.linear().determinant(), 1.0, 1e-12);
  ASSERT_EQ(r.errors.size(), r.pairs);
  ASSERT_EQ(r.est_aligned.size(), r.pairs);
  for (std::size_t k = 1; k < r.pairs; ++k)
    ASSERT_LT(gt[r.gt_indices[k - 1]].timestamp, gt[r.gt_indices[k]].timestamp);
}

// Monocular keyframe trajectories (ORB-SLAM mono) have an arbitrary map scale: SE(3) cannot fit
// them, Sim(3) can. Returns {SE(3) result, Sim(3) result}.
std::pair<AteResult, AteResult> mono_ate(const char* gt_name, const char* est_name) {
  Trajectory gt, est;
  std::string why;
  EXPECT_TRUE(read_tum_trajectory(traj_path(gt_name), &gt, &why)) << why;
  EXPECT_TRUE(read_tum_trajectory(traj_path(est_name), &est, &why)) << why;
  AteConfig config;
  AteResult se3, sim3;
  EXPECT_TRUE(compute_ate(gt, est, config, &se3, &why)) << why;
  config.alignment = Alignment::kSim3;
  EXPECT_TRUE(compute_ate(gt, est, config, &sim3, &why)) << why;
  std::printf("%s: pairs %zu, SE(3) rmse %.7f m, Sim(3) rmse %.7f m, scale %.7f\n", est_name,
              sim3.pairs, se3.rmse, sim3.rmse, sim3.scale);
  EXPECT_EQ(se3.pairs, sim3.pairs);
  return {se3, sim3};
}

TEST(Ate, MonocularNeedsSim3) {
  FSLAM_REQUIRE_DATA("evo_reference");
  // fr1/xyz: the mono map happens to be near metric (scale ~1.11), so SE(3) is off by 2.4 cm and
  // Sim(3) brings it under 1 cm.
  const auto [se3, sim3] = mono_ate("freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-ORB_kf_mono.txt");
  EXPECT_EQ(sim3.pairs, 32u);
  EXPECT_LT(sim3.rmse, 0.5 * se3.rmse);
  EXPECT_LT(sim3.rmse, 0.012);  // metres
  EXPECT_GT(std::abs(sim3.scale - 1.0), 0.05);

  // fr2/desk: the mono map is at less than half scale; SE(3) is off by ~1 m, Sim(3) by < 1 cm.
  const auto [se3_desk, sim3_desk] = mono_ate("fr2_desk_groundtruth.txt", "fr2_desk_ORB_kf_mono.txt");
  EXPECT_LT(sim3_desk.rmse, 0.02 * se3_desk.rmse);
  EXPECT_LT(sim3_desk.rmse, 0.01);
  EXPECT_GT(sim3_desk.scale, 2.0);
}

TEST(Ate, Sim3RecoversScaledRotatedTranslatedCopy) {
  const Trajectory gt = helix();
  // est = S_est_gt * gt with scale 0.37: what a monocular system with an arbitrary map scale and
  // origin would report.
  const double s = 0.37;
  Vector6d xi;
  xi << 0.5, -2.0, 1.0, 0.4, -1.1, 0.7;
  const Eigen::Isometry3d T_est_gt = se3_exp(xi);
  Trajectory est;
  for (const auto& p : gt) {
    Eigen::Isometry3d T = T_est_gt * p.T_world_camera;
    T.translation() = T_est_gt.linear() * (s * p.T_world_camera.translation()) +
                      T_est_gt.translation();
    est.push_back({p.timestamp, T});
  }
  AteConfig config;
  config.alignment = Alignment::kSim3;
  AteResult r;
  std::string why;
  ASSERT_TRUE(compute_ate(gt, est, config, &r, &why)) << why;
  EXPECT_EQ(r.pairs, gt.size());
  EXPECT_LT(r.rmse, 1e-9);  // metres
  EXPECT_LT(r.max, 1e-9);
  EXPECT_NEAR(r.scale, 1.0 / s, 1e-9);
  // p_gt = T_gt_est (scale p_est) inverts p_est = R (s p_gt) + t.
  EXPECT_LT(rotation_angle(r.T_gt_est.linear() * T_est_gt.linear()), 1e-9);
  EXPECT_LT((r.T_gt_est.translation() + r.T_gt_est.linear() * T_est_gt.translation() / s).norm(),
            1e-9);

  config.alignment = Alignment::kSE3;
  AteResult rigid;
  ASSERT_TRUE(compute_ate(gt, est, config, &rigid, &why)) << why;
  EXPECT_GT(rigid.rmse, 0.1);  // without scale the 0.37x copy cannot fit
}

TEST(Ate, SE3RecoversRigidCopyThroughAssociation) {
  // Ground truth at 10 Hz (every third helix pose); the estimate holds every other ground-truth
  // pose, moved rigidly and stamped 7 ms late: all of them associate (7 ms < 20 ms).
  Trajectory gt;
  const Trajectory dense = helix(300);
  for (std::size_t i = 0; i < dense.size(); i += 3) gt.push_back(dense[i]);
  Vector6d xi;
  xi << -1.0, 0.3, 2.0, 1.2, 0.2, -0.5;
  const Eigen::Isometry3d T_est_gt = se3_exp(xi);
  Trajectory est;
  for (std::size_t i = 0; i < gt.size(); i += 2)
    est.push_back({gt[i].timestamp + 0.007, T_est_gt * gt[i].T_world_camera});
  AteResult r;
  std::string why;
  ASSERT_TRUE(compute_ate(gt, est, AteConfig{}, &r, &why)) << why;
  EXPECT_EQ(r.pairs, est.size());
  EXPECT_LT(r.rmse, 1e-9);
  EXPECT_TRUE((r.T_gt_est * T_est_gt).matrix().isIdentity(1e-9));
  for (std::size_t k = 0; k < r.pairs; ++k) EXPECT_EQ(r.gt_indices[k], 2 * r.est_indices[k]);

  // 25 ms late is beyond the 20 ms association limit (the neighbours are 75 ms away) unless
  // the offset compensates.
  for (auto& p : est) p.timestamp += 0.018;
  AteConfig config;
  EXPECT_FALSE(compute_ate(gt, est, config, &r, &why));
  EXPECT_NE(why.find("only 0 poses associated"), std::string::npos) << why;
  config.association.offset = -0.025;
  ASSERT_TRUE(compute_ate(gt, est, config, &r, &why)) << why;
  EXPECT_EQ(r.pairs, est.size());
  EXPECT_LT(r.rmse, 1e-9);
}

TEST(Ate, KnownResidualAfterAlignment) {
  // Square corners (+-1, +-1, 0) against an estimate with the diagonals lifted by +d and -d. The
  // cross-covariance has no z coupling, so the best rigid fit is the identity and every error
  // is exactly d: RMSE = mean = median = min = max = d, std 0.
  const double d = 0.01;  // metres
  const double corners[4][3] = {{1, 1, d}, {-1, -1, d}, {1, -1, -d}, {-1, 1, -d}};
  Trajectory gt, est;
  for (int i = 0; i < 4; ++i) {
    Eigen::Isometry3d G = Eigen::Isometry3d::Identity(), E = Eigen::Isometry3d::Identity();
    G.translation() = Eigen::Vector3d(corners[i][0], corners[i][1], 0.0);
    E.translation() = Eigen::Vector3d(corners[i][0], corners[i][1], corners[i][2]);
    gt.push_back({static_cast<double>(i), G});
    est.push_back({static_cast<double>(i), E});
  }
  AteResult r;
  std::string why;
  ASSERT_TRUE(compute_ate(gt, est, AteConfig{}, &r, &why)) << why;
  EXPECT_EQ(r.pairs, 4u);
  EXPECT_NEAR(r.rmse, d, 1e-12);
  EXPECT_NEAR(r.mean, d, 1e-12);
  EXPECT_NEAR(r.median, d, 1e-12);
  EXPECT_NEAR(r.min, d, 1e-12);
  EXPECT_NEAR(r.max, d, 1e-12);
  EXPECT_NEAR(r.std, 0.0, 1e-12);
  EXPECT_TRUE(r.T_gt_est.matrix().isIdentity(1e-12));
}

TEST(Ate, RejectsBadInput) {
  const Trajectory gt = helix(10);
  AteResult r;
  std::string why;
  AteConfig config;
  config.association.max_difference = 0.0;
  EXPECT_FALSE(compute_ate(gt, gt, config, &r, &why));
  EXPECT_NE(why.find("max_difference"), std::string::npos) << why;

  Trajectory two(gt.begin(), gt.begin() + 2);
  EXPECT_FALSE(compute_ate(gt, two, AteConfig{}, &r, &why));
  EXPECT_NE(why.find("only 2 poses associated"), std::string::npos) << why;

  Trajectory bad = gt;
  bad[3].T_world_camera.translation().x() = std::nan("");
  EXPECT_FALSE(compute_ate(gt, bad, AteConfig{}, &r, &why));
  EXPECT_NE(why.find("estimated pose 3"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::core

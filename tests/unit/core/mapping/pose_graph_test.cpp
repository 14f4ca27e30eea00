// The keyframe pose graph (Ceres): a drifted loop snaps back onto the truth once its loop edge is
// added; measurements it already agrees with leave it where it is; bad graphs are refused.
#include "fslam/core/mapping/pose_graph.hpp"

#include <cmath>

#include <gtest/gtest.h>

#include "fslam/core/geometry/se3.hpp"

namespace fslam::core {
namespace {

// 24 poses round a 2 m circle, looking along it.
std::vector<Eigen::Isometry3d> circle() {
  std::vector<Eigen::Isometry3d> poses;
  for (int i = 0; i < 24; ++i) {
    const double a = 2.0 * M_PI * i / 24.0;
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() = Eigen::Vector3d(std::cos(a), std::sin(a), 0.1 * std::sin(3 * a));
    poses.push_back(T);
  }
  return poses;
}

// Odometry that turns 0.4 degrees too far and moves 1 % too far per step: the drift of a tracker.
std::vector<Eigen::Isometry3d> drifted(const std::vector<Eigen::Isometry3d>& truth) {
  std::vector<Eigen::Isometry3d> out = {truth[0]};
  const Eigen::Matrix3d bias = Eigen::AngleAxisd(0.4 * M_PI / 180.0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  for (std::size_t i = 1; i < truth.size(); ++i) {
    Eigen::Isometry3d step = truth[i - 1].inverse() * truth[i];
    step.linear() = bias * step.linear();
    step.translation() *= 1.01;
    out.push_back(out.back() * step);
  }
  return out;
}

double max_error(const std::vector<Eigen::Isometry3d>& a, const std::vector<Eigen::Isometry3d>& b) {
  double e = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i) e = std::max(e, (a[i].translation() - b[i].translation()).norm());
  return e;
}

std::vector<PoseGraphEdge> odometry(const std::vector<Eigen::Isometry3d>& measured) {
  std::vector<PoseGraphEdge> edges;
  for (std::size_t i = 1; i < measured.size(); ++i) {
    PoseGraphEdge e;
    e.from = i - 1;
    e.to = i;
    e.T_from_to = measured[i - 1].inverse() * measured[i];
    edges.push_back(e);
  }
  return edges;
}

TEST(PoseGraph, ALoopEdgeRemovesTheDrift) {
  const std::vector<Eigen::Isometry3d> truth = circle();
  std::vector<Eigen::Isometry3d> poses = drifted(truth);
  std::vector<PoseGraphEdge> edges = odometry(poses);
  const double before = max_error(poses, truth);
  ASSERT_GT(before, 0.1) << "the drift the test removes";
  PoseGraphEdge loop;  // the revisit: the last pose measured against the first, exactly
  loop.from = 0;
  loop.to = truth.size() - 1;
  loop.T_from_to = truth[0].inverse() * truth.back();
  loop.loop = true;
  edges.push_back(loop);
  PoseGraphResult result;
  std::string why;
  ASSERT_TRUE(optimise_pose_graph(&poses, edges, 0, PoseGraphConfig{}, &result, &why)) << why;
  EXPECT_TRUE(result.converged) << result.message;
  EXPECT_LT(result.final_cost, result.initial_cost);
  const double after = max_error(poses, truth);
  EXPECT_LT(after, 0.35 * before) << "before " << before << " m, after " << after << " m";
  EXPECT_LT((poses.back().translation() - truth.back().translation()).norm(), 0.03);
  EXPECT_EQ((poses[0].translation() - truth[0].translation()).norm(), 0.0) << "the fixed node stays";
  for (const Eigen::Isometry3d& T : poses) EXPECT_TRUE(is_rigid(T.matrix(), 1e-9));
}

TEST(PoseGraph, AgreeingMeasurementsLeaveThePosesWhereTheyAre) {
  std::vector<Eigen::Isometry3d> poses = circle();
  const std::vector<Eigen::Isometry3d> truth = poses;
  PoseGraphResult result;
  std::string why;
  ASSERT_TRUE(optimise_pose_graph(&poses, odometry(truth), 3, PoseGraphConfig{}, &result, &why)) << why;
  EXPECT_LT(max_error(poses, truth), 1e-9);
}

TEST(PoseGraph, BadGraphsAreRefused) {
  std::vector<Eigen::Isometry3d> poses = circle();
  PoseGraphResult result;
  std::string why;
  std::vector<PoseGraphEdge> edges = odometry(poses);
  EXPECT_FALSE(optimise_pose_graph(&poses, edges, poses.size(), PoseGraphConfig{}, &result, &why));
  EXPECT_NE(why.find("fixed node"), std::string::npos) << why;
  edges.back().to = 99;
  EXPECT_FALSE(optimise_pose_graph(&poses, edges, 0, PoseGraphConfig{}, &result, &why));
  EXPECT_NE(why.find("does not join"), std::string::npos) << why;
  edges = odometry(poses);
  edges[0].translation_sigma = 0.0;
  EXPECT_FALSE(optimise_pose_graph(&poses, edges, 0, PoseGraphConfig{}, &result, &why));
  EXPECT_NE(why.find("sigmas"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::core

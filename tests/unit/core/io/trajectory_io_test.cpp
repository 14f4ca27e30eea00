#include "fslam/core/io/trajectory_io.hpp"

#include <fstream>

#include <gtest/gtest.h>

#include "fslam/core/geometry/se3.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

TEST(TrajectoryIo, WriteReadRoundTrip) {
  const auto dir = test::fresh_temp_dir("traj");
  Trajectory t;
  for (int i = 0; i < 5; ++i)
    t.push_back({0.1 * i, se3_exp((Vector6d() << i, -i, 0.5 * i, 0.1 * i, 0.2, -0.1 * i).finished())});
  std::string why;
  ASSERT_TRUE(write_tum_trajectory((dir / "t.txt").string(), t, &why)) << why;
  Trajectory back;
  ASSERT_TRUE(read_tum_trajectory((dir / "t.txt").string(), &back, &why)) << why;
  ASSERT_EQ(back.size(), t.size());
  for (std::size_t i = 0; i < t.size(); ++i) {
    EXPECT_NEAR(back[i].timestamp, t[i].timestamp, 1e-6);
    EXPECT_LT((back[i].T_world_camera.translation() - t[i].T_world_camera.translation()).norm(), 1e-8);
    EXPECT_LT(rotation_angle(back[i].T_world_camera.linear().transpose() * t[i].T_world_camera.linear()), 1e-8);
  }
}

TEST(TrajectoryIo, ErrorsNameFileAndLine) {
  const auto dir = test::fresh_temp_dir("bad");
  const auto path = (dir / "bad.txt").string();
  auto expect_error = [&](const std::string& content, const std::string& fragment) {
    std::ofstream(path) << content;
    Trajectory t;
    std::string why;
    EXPECT_FALSE(read_tum_trajectory(path, &t, &why)) << content;
    EXPECT_NE(why.find(path), std::string::npos) << why;
    EXPECT_NE(why.find(fragment), std::string::npos) << why;
  };
  expect_error("# c\n1.0 0 0 0 0 0 0\n", ":2: expected");
  expect_error("1.0 0 0 abc 0 0 0 1\n", "'abc' is not a number");
  expect_error("1.0 0 0 nan 0 0 0 1\n", "non-finite");
  expect_error("1.0 0 0 0 0 0 0 2\n", "quaternion norm");
  Trajectory t;
  std::string why;
  EXPECT_FALSE(read_tum_trajectory((dir / "missing.txt").string(), &t, &why));
  EXPECT_NE(why.find("missing.txt"), std::string::npos);
}

TEST(TrajectoryIo, AcceptsCommasTabsAndComments) {
  const auto dir = test::fresh_temp_dir("fmt");
  const auto path = (dir / "t.txt").string();
  std::ofstream(path) << "# header\n\n1.5,1,2,3,0,0,0,1\n2.5\t1\t2\t3\t0\t0\t0\t1\r\n";
  Trajectory t;
  std::string why;
  ASSERT_TRUE(read_tum_trajectory(path, &t, &why)) << why;
  ASSERT_EQ(t.size(), 2u);
  EXPECT_DOUBLE_EQ(t[1].timestamp, 2.5);
  EXPECT_DOUBLE_EQ(t[1].T_world_camera.translation().z(), 3.0);
}

}  // namespace
}  // namespace fslam::core

namespace fslam::core {
namespace {

TEST(TrajectoryIo, NearestPoseWithinTheTolerance) {
  Trajectory t(3);
  t[0].timestamp = 1.00;
  t[1].timestamp = 1.05;
  t[2].timestamp = 1.10;
  EXPECT_EQ(nearest_pose(t, 1.04), &t[1]);
  EXPECT_EQ(nearest_pose(t, 1.11), &t[2]);
  EXPECT_EQ(nearest_pose(t, 1.20), nullptr);  // 100 ms from the nearest
  const Trajectory empty;
  EXPECT_EQ(nearest_pose(empty, 1.0), nullptr);
}

}  // namespace
}  // namespace fslam::core

// Features for eq. feat_gicp: each source point takes the latent where it projects, and a
// keyframe refreshes the features of the map points it sees.
#include <gtest/gtest.h>
#include <opencv2/core/mat.hpp>

#include "fslam/core/tracking/point_features.hpp"

namespace fslam::core {
namespace {

// [2, 4, 6] latent with value c * 100 + y * 10 + x, and a 60x40 camera: 10 frame pixels per cell.
PlanarImage ramp_latent() {
  PlanarImage latent(6, 4, 2);
  for (int c = 0; c < 2; ++c)
    for (int y = 0; y < 4; ++y)
      for (int x = 0; x < 6; ++x) latent.at(c, y, x) = static_cast<float>(c * 100 + y * 10 + x);
  return latent;
}
PinholeCamera ramp_camera() { return PinholeCamera{50.0, 50.0, 29.5, 19.5, 60, 40}; }

TEST(PointFeatures, PointsTakeTheLatentWhereTheyProject) {
  const PlanarImage latent = ramp_latent();
  const PinholeCamera camera = ramp_camera();
  auto at_pixel = [&](double u, double v, double z) {
    return Eigen::Vector3f(static_cast<float>((u - camera.cx) * z / camera.fx),
                           static_cast<float>((v - camera.cy) * z / camera.fy), static_cast<float>(z));
  };
  GaussianPoints points;
  points.means = {at_pixel(24.5, 14.5, 2.0),   // centre of cell (2, 1)
                  at_pixel(29.5, 14.5, 1.0),   // halfway between cells (2, 1) and (3, 1)
                  at_pixel(-40.0, 100.0, 3.0), // outside the frame: clamped to cell (0, 3)
                  Eigen::Vector3f(0.1f, 0.1f, -1.0f)};  // behind the camera
  points.covariances.assign(points.means.size(), Eigen::Matrix3f::Identity());
  sample_point_features(latent, camera, &points);
  ASSERT_EQ(points.feature_dim, 2);
  ASSERT_TRUE(points.has_features());
  EXPECT_NEAR(points.feature(0)[0], 12.0f, 1e-4f);
  EXPECT_NEAR(points.feature(0)[1], 112.0f, 1e-4f);
  EXPECT_NEAR(points.feature(1)[0], 12.5f, 1e-4f);
  EXPECT_NEAR(points.feature(2)[1], 130.0f, 1e-4f);
  EXPECT_EQ(points.feature(3)[0], 0.0f);
  EXPECT_TRUE(points.is_consistent());
  // Spread: one-cell steps change both channels by 1 (along x) and 10 (along y), so an interior
  // point has (1 + 1 + 100 + 100) * 2 / 4 = 101. Far outside the frame every step lands on the
  // same clamped border cell (0), and points behind the camera get 0.
  ASSERT_EQ(points.feature_spread.size(), 4u);
  EXPECT_NEAR(points.feature_spread[0], 101.0f, 1e-3f);
  EXPECT_EQ(points.feature_spread[2], 0.0f);
  EXPECT_EQ(points.feature_spread[3], 0.0f);
}

// The gradient d f / d X: on the ramp one cell (10 px) moves channel c by 1 along x and 10 along y;
// the point at (24.5, 14.5) and z = 2 is at X = Y = -0.2 m, where du/dx = dv/dy = fx / z = 25 px/m,
// so d f / d X = (0.1 * 25, 1 * 25, -(0.1 * 50 * -0.2 + 1 * 50 * -0.2) / 4) = (2.5, 25, 2.75),
// and moving the point along its ray leaves the feature unchanged (G X = 0).
TEST(PointFeatures, GradientFollowsTheLatentThroughTheProjection) {
  const PlanarImage latent = ramp_latent();
  const PinholeCamera camera = ramp_camera();
  GaussianPoints points;
  points.means = {Eigen::Vector3f(-0.2f, -0.2f, 2.0f)};
  points.covariances.assign(1, Eigen::Matrix3f::Identity());
  sample_point_features(latent, camera, &points);
  EXPECT_FALSE(points.has_feature_gradient()) << "only on request";
  sample_point_features(latent, camera, &points, /*gradient=*/true);
  ASSERT_TRUE(points.has_feature_gradient());
  ASSERT_EQ(points.feature_gradient.size(), 2u * 3u);
  for (int c = 0; c < 2; ++c) {
    const Eigen::Vector3f G(&points.feature_gradient[3 * c]);
    EXPECT_NEAR(G.x(), 2.5f, 1e-4f) << "channel " << c;
    EXPECT_NEAR(G.y(), 25.0f, 1e-3f) << "channel " << c;
    EXPECT_NEAR(G.z(), 2.75f, 1e-3f) << "channel " << c;
    EXPECT_NEAR(G.dot(points.means[0]), 0.0f, 1e-4f) << "channel " << c;
  }
  EXPECT_TRUE(points.is_consistent());
  // A transformed copy is in another frame: the camera-frame gradient does not travel with it.
  EXPECT_FALSE(transformed(points, Eigen::Isometry3d::Identity()).has_feature_gradient());
}

TEST(PointFeatures, AUniformLatentHasNoSpread) {
  const PlanarImage latent(8, 6, 3, 0.7f);
  const PinholeCamera camera{60.0, 60.0, 31.5, 23.5, 64, 48};
  GaussianPoints points;
  points.means = {Eigen::Vector3f(0.1f, -0.2f, 1.5f), Eigen::Vector3f(-0.5f, 0.3f, 2.0f)};
  points.covariances.assign(2, Eigen::Matrix3f::Identity());
  sample_point_features(latent, camera, &points);
  for (std::size_t i = 0; i < points.size(); ++i) {
    EXPECT_NEAR(points.feature(i)[2], 0.7f, 1e-6f);
    EXPECT_EQ(points.feature_spread[i], 0.0f);
  }
}

TEST(PointFeatures, KeyframeRefreshesOnlyTheMapPointsItSees) {
  const PlanarImage latent = ramp_latent();
  const PinholeCamera camera = ramp_camera();
  // The keyframe sees a wall at 2 m, except in columns 40.. where the depth is missing.
  cv::Mat depth(40, 60, CV_32FC1, cv::Scalar(2.0f));
  depth.colRange(40, 60).setTo(0.0f);
  // Keyframe camera 1 m along world x, looking down world z.
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
  T_world_camera.translation() = Eigen::Vector3d(1.0, 0.0, 0.0);
  auto world_at_pixel = [&](double u, double v, double z) {
    const Eigen::Vector3d p((u - camera.cx) * z / camera.fx, (v - camera.cy) * z / camera.fy, z);
    return (T_world_camera * p).cast<float>().eval();
  };
  GaussianPoints map_points;
  map_points.means = {world_at_pixel(24.5, 14.5, 2.05),  // on the wall (5 cm): refreshed
                      world_at_pixel(14.5, 24.5, 2.5),   // behind the wall: occluded
                      world_at_pixel(44.5, 14.5, 2.0),   // where the keyframe has no depth
                      world_at_pixel(-40.0, 14.5, 2.0),  // outside the image
                      Eigen::Vector3f(1.0f, 0.0f, -1.0f)};  // behind the camera
  map_points.covariances.assign(map_points.means.size(), Eigen::Matrix3f::Identity());
  map_points.feature_dim = 2;
  map_points.features.assign(2 * map_points.means.size(), -1.0f);
  LocalMapConfig config;
  config.radius = 100.0f;
  LocalMap map(config);
  ASSERT_EQ(map.insert(map_points, Eigen::Vector3f::Zero()), map_points.size());

  EXPECT_EQ(refresh_map_features(latent, camera, depth, T_world_camera, 0.08f, &map), 1u);
  for (std::size_t i = 0; i < map_points.size(); ++i) {
    const TargetPoint* p = map.nearest(map_points.means[i], 1e-4f);
    ASSERT_NE(p, nullptr);
    const float expected0 = i == 0 ? 12.0f : -1.0f;  // cell (2, 1)
    const float expected1 = i == 0 ? 112.0f : -1.0f;
    EXPECT_NEAR(map.feature(*p)[0], expected0, 1e-4f) << "point " << i;
    EXPECT_NEAR(map.feature(*p)[1], expected1, 1e-4f) << "point " << i;
  }
  // A latent of another size leaves the map alone.
  EXPECT_EQ(refresh_map_features(PlanarImage(6, 4, 3, 7.0f), camera, depth, T_world_camera, 0.08f,
                                 &map),
            0u);
}

}  // namespace
}  // namespace fslam::core

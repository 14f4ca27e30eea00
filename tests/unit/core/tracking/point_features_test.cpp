// Source features for eq. feat_gicp: each point takes the latent where it projects.
#include <gtest/gtest.h>

#include "fslam/core/tracking/point_features.hpp"

namespace fslam::core {
namespace {

TEST(PointFeatures, PointsTakeTheLatentWhereTheyProject) {
  PlanarImage latent(6, 4, 2);  // [2, 4, 6]: value c * 100 + y * 10 + x
  for (int c = 0; c < 2; ++c)
    for (int y = 0; y < 4; ++y)
      for (int x = 0; x < 6; ++x) latent.at(c, y, x) = static_cast<float>(c * 100 + y * 10 + x);
  const PinholeCamera camera{50.0, 50.0, 29.5, 19.5, 60, 40};  // 10 frame pixels per latent cell
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
}

}  // namespace
}  // namespace fslam::core

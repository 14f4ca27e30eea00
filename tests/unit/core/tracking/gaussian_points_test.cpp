#include <cmath>
#include <limits>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "fslam/core/tracking/gaussian_points.hpp"

namespace fslam::core {
namespace {

GaussianPoints two_points() {
  GaussianPoints p;
  p.means = {Eigen::Vector3f(1.0f, 0.0f, 2.0f), Eigen::Vector3f(-0.5f, 0.25f, 1.0f)};
  // Discs with normals along z and x.
  p.covariances = {Eigen::Vector3f(1.0f, 1.0f, 1e-3f).asDiagonal(),
                   Eigen::Vector3f(1e-3f, 1.0f, 1.0f).asDiagonal()};
  return p;
}

TEST(GaussianPoints, ConsistencyChecksSizesAndFiniteness) {
  GaussianPoints p = two_points();
  std::string why;
  EXPECT_TRUE(p.is_consistent(&why)) << why;
  EXPECT_TRUE(GaussianPoints{}.is_consistent());

  GaussianPoints q = p;
  q.covariances.pop_back();
  EXPECT_FALSE(q.is_consistent(&why));
  EXPECT_NE(why.find("covariances"), std::string::npos) << why;

  q = p;
  q.opacities = {1.0f};
  EXPECT_FALSE(q.is_consistent(&why));
  EXPECT_NE(why.find("opacities"), std::string::npos) << why;

  q = p;
  q.opacities = {1.0f, 1.5f};
  EXPECT_FALSE(q.is_consistent(&why));

  q = p;
  q.feature_dim = 3;
  q.features = {1, 2, 3, 4, 5};
  EXPECT_FALSE(q.is_consistent(&why));
  EXPECT_NE(why.find("feature"), std::string::npos) << why;
  q.features = {1, 2, 3, 4, 5, 6};
  EXPECT_TRUE(q.is_consistent(&why)) << why;

  q = p;
  q.features = {1, 2};  // values without a dimension
  EXPECT_FALSE(q.is_consistent(&why));

  q = p;
  q.feature_spread = {0.5f};
  EXPECT_FALSE(q.is_consistent(&why));
  EXPECT_NE(why.find("feature spreads"), std::string::npos) << why;

  q = p;
  q.means[1].y() = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(q.is_consistent(&why));
  EXPECT_NE(why.find("mean 1"), std::string::npos) << why;

  q = p;
  q.covariances[0](2, 1) = std::numeric_limits<float>::infinity();
  EXPECT_FALSE(q.is_consistent(&why));
  EXPECT_NE(why.find("covariance 0"), std::string::npos) << why;
}

TEST(GaussianPoints, ClearAndReserve) {
  GaussianPoints p = two_points();
  p.opacities = {0.5f, 1.0f};
  p.feature_dim = 2;
  p.features = {1, 2, 3, 4};
  p.reserve(100);
  EXPECT_GE(p.means.capacity(), 100u);
  EXPECT_GE(p.covariances.capacity(), 100u);
  EXPECT_GE(p.opacities.capacity(), 100u);
  EXPECT_GE(p.features.capacity(), 200u);
  EXPECT_EQ(p.size(), 2u);
  p.clear();
  EXPECT_TRUE(p.empty());
  EXPECT_FALSE(p.has_opacities());
  EXPECT_FALSE(p.has_features());
  EXPECT_EQ(p.feature_dim, 0);
  EXPECT_TRUE(p.is_consistent());

  GaussianPoints geometry_only;
  geometry_only.reserve(10);
  EXPECT_FALSE(geometry_only.has_opacities());  // reserve does not switch optional arrays on
  EXPECT_EQ(geometry_only.opacities.capacity(), 0u);
}

TEST(GaussianPoints, TransformedMovesMeansAndRotatesCovariances) {
  GaussianPoints p = two_points();
  p.opacities = {0.25f, 0.75f};
  p.feature_dim = 1;
  p.features = {7.0f, 8.0f};
  p.feature_spread = {0.5f, 2.0f};
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.1, -0.2, 0.3);
  const GaussianPoints q = transformed(p, T);
  ASSERT_EQ(q.size(), 2u);
  EXPECT_TRUE(q.is_consistent());
  for (std::size_t i = 0; i < 2; ++i)
    EXPECT_TRUE(q.means[i].isApprox((T * p.means[i].cast<double>()).cast<float>(), 1e-6f));
  // A 90 degree turn about y swaps the x and z axes: the z-normal disc becomes an x-normal one.
  EXPECT_TRUE(q.covariances[0].isApprox(p.covariances[1], 1e-6f));
  EXPECT_TRUE(q.covariances[1].isApprox(p.covariances[0], 1e-6f));
  EXPECT_EQ(q.opacities, p.opacities);
  EXPECT_EQ(q.features, p.features);
  EXPECT_EQ(q.feature_dim, 1);
  EXPECT_EQ(q.feature_spread, p.feature_spread);

  const GaussianPoints back = transformed(q, T.inverse());
  for (std::size_t i = 0; i < 2; ++i) {
    EXPECT_TRUE(back.means[i].isApprox(p.means[i], 1e-6f));
    EXPECT_TRUE(back.covariances[i].isApprox(p.covariances[i], 1e-6f));
  }
}

}  // namespace
}  // namespace fslam::core

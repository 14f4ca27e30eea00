#include <algorithm>
#include <chrono>
#include <cmath>
#include <iostream>
#include <limits>
#include <random>
#include <set>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Eigenvalues>
#include <opencv2/core.hpp>

#include "fslam/core/compute/thread_clock.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/math/unproject.hpp"
#include "fslam/core/tracking/gaussian_points.hpp"
#include "fslam/core/tracking/preprocess.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

constexpr double kPi = 3.14159265358979323846;

PinholeCamera vga_camera() {
  PinholeCamera c;
  c.fx = 525.0;
  c.fy = 525.0;
  c.cx = 319.5;
  c.cy = 239.5;
  c.width = 640;
  c.height = 480;
  return c;
}

// A frame seeing the plane {X : normal . X = offset} (camera frame, metres) in every pixel.
RgbdFrame plane_frame(const Eigen::Vector3d& normal, double offset) {
  RgbdFrame frame;
  frame.camera = vga_camera();
  frame.depth = cv::Mat(frame.camera.height, frame.camera.width, CV_32FC1);  // [H, W] metres
  for (int v = 0; v < frame.depth.rows; ++v)
    for (int u = 0; u < frame.depth.cols; ++u) {
      const Eigen::Vector3d ray((u - frame.camera.cx) / frame.camera.fx,
                                (v - frame.camera.cy) / frame.camera.fy, 1.0);
      frame.depth.at<float>(v, u) = static_cast<float>(offset / normal.dot(ray));
    }
  return frame;
}

// Unit eigenvector of the smallest eigenvalue: the surface normal a covariance encodes.
Eigen::Vector3f covariance_normal(const Eigen::Matrix3f& covariance) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> solver(covariance);
  return solver.eigenvectors().col(0);
}

double angle_deg(const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
  const double c = std::abs(a.normalized().dot(b.normalized()));
  return std::acos(std::min(1.0, c)) * 180.0 / kPi;
}

// Stride 4 gives a 160x120 lattice on 640x480 images, the sizes these tests count in.
PreprocessConfig stride4_config() {
  PreprocessConfig config;
  config.stride = 4;
  return config;
}

GaussianPoints preprocess_or_fail(const RgbdFrame& frame, const PreprocessConfig& config,
                                  PreprocessStats* stats = nullptr) {
  GaussianPoints points;
  std::string why;
  EXPECT_TRUE(preprocess_frame(frame, config, &points, stats, &why)) << why;
  return points;
}

TEST(Preprocess, TiltedPlaneCovariancesAreDiscsAlongThePlane) {
  const Eigen::Vector3d normal = Eigen::Vector3d(0.3, -0.2, -1.0).normalized();
  const double offset = normal.dot(Eigen::Vector3d(0.0, 0.0, 2.5));
  const RgbdFrame frame = plane_frame(normal, offset);
  const PreprocessConfig config = stride4_config();
  PreprocessStats stats;
  const GaussianPoints points = preprocess_or_fail(frame, config, &stats);
  ASSERT_GT(points.size(), 15000u);
  std::string why;
  EXPECT_TRUE(points.is_consistent(&why)) << why;
  EXPECT_FALSE(points.has_opacities());
  EXPECT_FALSE(points.has_features());

  const Eigen::Vector3f n = normal.cast<float>();
  double worst_distance_m = 0.0, worst_angle_deg = 0.0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    worst_distance_m =
        std::max(worst_distance_m, std::abs(normal.dot(points.means[i].cast<double>()) - offset));
    worst_angle_deg =
        std::max(worst_angle_deg, angle_deg(covariance_normal(points.covariances[i]), n));
    // The unit disc, scaled by the depth noise at the point's depth.
    const float scale = config.depth_noise.covariance_scale(points.means[i].z());
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> solver(points.covariances[i] / scale);
    EXPECT_NEAR(solver.eigenvalues()(0), config.covariance.plane_epsilon, 1e-5);
    EXPECT_NEAR(solver.eigenvalues()(1), 1.0f, 1e-5);
    EXPECT_NEAR(solver.eigenvalues()(2), 1.0f, 1e-5);
  }
  EXPECT_LT(worst_distance_m, 1e-3);  // points lie on the plane to a millimetre
  EXPECT_LT(worst_angle_deg, 1.0);
}

TEST(Preprocess, DepthNoiseModelIsNguyenAxialSigma) {
  const DepthNoiseModel model;
  EXPECT_TRUE(model.is_valid());
  // Nguyen et al. (2012): 1.2 mm + 1.9 mm/m^2 (z - 0.4 m)^2.
  EXPECT_NEAR(model.sigma(1.0f), 0.0012 + 0.0019 * 0.36, 1e-7);
  EXPECT_NEAR(model.sigma(3.0f), 0.0012 + 0.0019 * 6.76, 1e-7);
  EXPECT_FLOAT_EQ(model.covariance_scale(model.reference_depth), 1.0f);
  float previous = 0.0f;  // the scale grows with depth beyond z0
  for (float z = 0.5f; z < 6.0f; z += 0.25f) {
    const float scale = model.covariance_scale(z);
    EXPECT_GT(scale, previous) << z;
    previous = scale;
  }
  DepthNoiseModel off;
  off.enabled = false;
  EXPECT_FLOAT_EQ(off.covariance_scale(3.0f), 1.0f);
}

// Two planes at 1 m and 3 m: the same unit-disc shape, sizes in the ratio of the squared noise.
TEST(Preprocess, CovariancesAreScaledByTheDepthNoise) {
  PreprocessConfig config = stride4_config();
  for (const float depth : {1.0f, 3.0f}) {
    const RgbdFrame frame = plane_frame(Eigen::Vector3d::UnitZ(), depth);
    for (const bool enabled : {true, false}) {
      config.depth_noise.enabled = enabled;
      const GaussianPoints points = preprocess_or_fail(frame, config);
      ASSERT_GT(points.size(), 0u);
      const float expected = enabled ? config.depth_noise.covariance_scale(depth) : 1.0f;
      for (std::size_t i = 0; i < points.size(); i += 97) {
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> solver(points.covariances[i]);
        EXPECT_NEAR(solver.eigenvalues()(0), config.covariance.plane_epsilon * expected,
                    1e-5 * expected);
        EXPECT_NEAR(solver.eigenvalues()(2), expected, 1e-5 * expected);
      }
    }
  }
  const DepthNoiseModel model;
  EXPECT_NEAR(model.covariance_scale(3.0f) / model.covariance_scale(1.0f),
              std::pow((0.0012 + 0.0019 * 6.76) / (0.0012 + 0.0019 * 0.36), 2.0), 1e-3);
}

TEST(Preprocess, StrideGivesTheLatticeCount) {
  const RgbdFrame frame = plane_frame(Eigen::Vector3d::UnitZ(), 2.0);
  PreprocessConfig config;
  for (const auto& [stride, expected] : std::vector<std::pair<int, std::size_t>>{
           {1, 640u * 480u}, {3, 214u * 160u}, {4, 160u * 120u}, {7, 92u * 69u}}) {
    config.stride = stride;
    PreprocessStats stats;
    const GaussianPoints points = preprocess_or_fail(frame, config, &stats);
    EXPECT_EQ(stats.valid_pixels, 640u * 480u) << "stride " << stride;
    EXPECT_EQ(stats.lattice_points, expected) << "stride " << stride;
    // Every lattice point of a full plane has enough neighbours, borders included.
    EXPECT_EQ(stats.output_points, expected) << "stride " << stride;
    EXPECT_EQ(points.size(), expected) << "stride " << stride;
  }
}

TEST(Preprocess, MissingDepthNeverProducesPoints) {
  RgbdFrame frame = plane_frame(Eigen::Vector3d::UnitZ(), 2.0);
  PreprocessConfig config;
  config.stride = 1;
  const float inf = std::numeric_limits<float>::infinity();
  const float bad[] = {0.0f,   std::numeric_limits<float>::quiet_NaN(), inf, -inf, -1.0f,
                       0.2f,  // below min_depth
                       7.0f,  // beyond max_depth
                       65.535f};
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> pick(0, static_cast<int>(std::size(bad)) - 1);
  for (int v = 0; v < frame.depth.rows; ++v)
    for (int u = 0; u < frame.depth.cols; ++u)
      if ((u * 7 + v * 13) % 5 == 0) frame.depth.at<float>(v, u) = bad[pick(rng)];  // scattered
  // One whole block of missing depth: its interior has no neighbours at all.
  frame.depth(cv::Rect(100, 100, 60, 60)).setTo(0.0f);
  std::size_t missing = 0;
  for (int v = 0; v < frame.depth.rows; ++v)
    for (int u = 0; u < frame.depth.cols; ++u) {
      const float z = frame.depth.at<float>(v, u);
      missing += (std::isfinite(z) && z > config.min_depth && z < config.max_depth) ? 0 : 1;
    }

  PreprocessStats stats;
  const GaussianPoints points = preprocess_or_fail(frame, config, &stats);
  EXPECT_EQ(stats.valid_pixels, 640u * 480u - missing);
  EXPECT_EQ(stats.lattice_points, stats.valid_pixels);
  ASSERT_GT(points.size(), 0u);
  for (const Eigen::Vector3f& p : points.means) {
    ASSERT_TRUE(p.allFinite());
    ASSERT_NEAR(p.z(), 2.0f, 1e-6f);  // only the plane's valid samples survive
    // The point's own pixel held a valid sample.
    const Eigen::Vector2d pixel = frame.camera.project(p.cast<double>());
    const int u = static_cast<int>(std::lround(pixel.x())),
              v = static_cast<int>(std::lround(pixel.y()));
    ASSERT_FLOAT_EQ(frame.depth.at<float>(v, u), 2.0f) << "pixel " << u << ", " << v;
  }
}

// PreprocessStats::valid_pixels counts exactly the samples math::depth_is_valid accepts, at
// the range bounds and on every special value.
TEST(Preprocess, ValidPixelCountUsesDepthIsValid) {
  PreprocessConfig config;
  const float inf = std::numeric_limits<float>::infinity();
  const float values[] = {0.0f,
                          -0.0f,
                          std::numeric_limits<float>::quiet_NaN(),
                          -std::numeric_limits<float>::quiet_NaN(),
                          inf,
                          -inf,
                          config.min_depth,
                          std::nextafter(config.min_depth, 1.0f),
                          config.max_depth,
                          std::nextafter(config.max_depth, 0.0f),
                          2.0f,
                          65.535f,
                          std::numeric_limits<float>::denorm_min(),
                          -1.0f};
  RgbdFrame frame = plane_frame(Eigen::Vector3d::UnitZ(), 2.0);
  std::size_t expected = 0;
  for (int v = 0; v < frame.depth.rows; ++v)
    for (int u = 0; u < frame.depth.cols; ++u) {
      const float z = values[(u + 3 * v) % std::size(values)];
      frame.depth.at<float>(v, u) = z;
      expected += math::depth_is_valid(z, config.min_depth, config.max_depth) ? 1 : 0;
    }
  PreprocessStats stats;
  preprocess_or_fail(frame, config, &stats);
  EXPECT_EQ(stats.valid_pixels, expected);
  EXPECT_GT(expected, 0u);
}

TEST(Preprocess, AllMissingGivesNoPoints) {
  RgbdFrame frame = plane_frame(Eigen::Vector3d::UnitZ(), 2.0);
  frame.depth.setTo(0.0f);
  PreprocessStats stats;
  const GaussianPoints points = preprocess_or_fail(frame, PreprocessConfig{}, &stats);
  EXPECT_TRUE(points.empty());
  EXPECT_EQ(stats.valid_pixels, 0u);
  EXPECT_EQ(stats.output_points, 0u);
}

TEST(Preprocess, DepthDiscontinuityIsNotANeighbour) {
  // Left half a wall at 2 m, right half a wall at 4 m: both fronto-parallel, so every normal is
  // the optical axis unless the neighbourhood mixed the two surfaces across the step.
  RgbdFrame frame = plane_frame(Eigen::Vector3d::UnitZ(), 2.0);
  frame.depth(cv::Rect(320, 0, 320, 480)).setTo(4.0f);
  const GaussianPoints points = preprocess_or_fail(frame, stride4_config());
  ASSERT_EQ(points.size(), 160u * 120u);
  for (std::size_t i = 0; i < points.size(); ++i)
    ASSERT_LT(angle_deg(covariance_normal(points.covariances[i]), Eigen::Vector3f::UnitZ()), 0.1)
        << "point " << points.means[i].transpose();
}

TEST(Preprocess, VoxelDownsamplingKeepsOneCentroidPerVoxel) {
  const RgbdFrame frame = plane_frame(Eigen::Vector3d::UnitZ(), 2.02);
  PreprocessConfig config;
  config.stride = 2;
  config.voxel_size = 0.05f;
  PreprocessStats stats;
  const GaussianPoints points = preprocess_or_fail(frame, config, &stats);
  EXPECT_EQ(stats.lattice_points, 320u * 240u);

  // The voxels the lattice points fall in, counted independently.
  std::set<std::tuple<int, int, int>> voxels;
  const auto key = [&](const Eigen::Vector3f& p) {
    return std::make_tuple(static_cast<int>(std::floor(p.x() / config.voxel_size)),
                           static_cast<int>(std::floor(p.y() / config.voxel_size)),
                           static_cast<int>(std::floor(p.z() / config.voxel_size)));
  };
  for (int v = 0; v < 480; v += 2)
    for (int u = 0; u < 640; u += 2)
      voxels.insert(key(frame.camera.unproject(Eigen::Vector2d(u, v), frame.depth.at<float>(v, u))
                            .cast<float>()));
  // Border voxels, partly filled, can lack neighbours; the interior must all be there.
  EXPECT_LE(points.size(), voxels.size());
  EXPECT_GT(points.size(), voxels.size() * 9 / 10);
  EXPECT_EQ(stats.output_points, points.size());
  std::set<std::tuple<int, int, int>> seen;
  for (std::size_t i = 0; i < points.size(); ++i) {
    EXPECT_TRUE(seen.insert(key(points.means[i])).second) << "two points in one voxel";
    EXPECT_NEAR(points.means[i].z(), 2.02f, 1e-5f);
    EXPECT_LT(angle_deg(covariance_normal(points.covariances[i]), Eigen::Vector3f::UnitZ()), 1.0);
  }
}

TEST(Preprocess, KnnCovariancesOnASphereAreRadial) {
  std::mt19937 rng(42);
  std::normal_distribution<float> gauss(0.0f, 1.0f);
  GaussianPoints points;
  const Eigen::Vector3f centre(0.5f, -0.2f, 3.0f);
  const float radius = 1.0f;
  for (int i = 0; i < 6000; ++i) {
    const Eigen::Vector3f d = Eigen::Vector3f(gauss(rng), gauss(rng), gauss(rng)).normalized();
    points.means.push_back(centre + radius * d);
  }
  // Isolated points far from the sphere: no neighbour within the gate, so they must go.
  for (int i = 0; i < 5; ++i) points.means.push_back(Eigen::Vector3f(10.0f + i, 0.0f, 0.0f));
  // Opacity and a 2-d feature that encode each point, to check rows stay aligned.
  points.feature_dim = 2;
  for (const Eigen::Vector3f& p : points.means) {
    points.opacities.push_back(std::clamp(0.5f + 0.1f * p.x(), 0.0f, 1.0f));
    points.features.push_back(p.y());
    points.features.push_back(p.z());
  }
  CovarianceConfig config;
  config.knn = 12;
  config.max_neighbour_distance = 0.2f;
  estimate_covariances_knn(config, &points);

  std::string why;
  ASSERT_TRUE(points.is_consistent(&why)) << why;
  EXPECT_EQ(points.size(), 6000u);
  ASSERT_EQ(points.features.size(), 2 * points.size());
  double worst = 0.0, sum = 0.0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f& p = points.means[i];
    ASSERT_LT((p - centre).norm(), 1.001f);
    ASSERT_FLOAT_EQ(points.opacities[i], std::clamp(0.5f + 0.1f * p.x(), 0.0f, 1.0f));
    ASSERT_FLOAT_EQ(points.feature(i)[0], p.y());
    ASSERT_FLOAT_EQ(points.feature(i)[1], p.z());
    const double a = angle_deg(covariance_normal(points.covariances[i]), p - centre);
    worst = std::max(worst, a);
    sum += a;
  }
  EXPECT_LT(worst, 5.0);
  EXPECT_LT(sum / points.size(), 1.5);
}

TEST(Preprocess, KnnOnTooFewPointsDropsThem) {
  GaussianPoints points;
  points.means = {Eigen::Vector3f(0, 0, 1), Eigen::Vector3f(0.01f, 0, 1),
                  Eigen::Vector3f(0, 0.01f, 1)};
  estimate_covariances_knn(CovarianceConfig{}, &points);  // min_neighbours 6 > 2 available
  EXPECT_TRUE(points.empty());
  EXPECT_TRUE(points.covariances.empty());
  estimate_covariances_knn(CovarianceConfig{}, &points);  // and an empty cloud is fine
  EXPECT_TRUE(points.empty());
}

TEST(Preprocess, RegularisationIsAUnitDiscAroundTheSmallestEigenvector) {
  const Eigen::Matrix3f R =
      Eigen::AngleAxisf(0.7f, Eigen::Vector3f(1.0f, 2.0f, -0.5f).normalized()).toRotationMatrix();
  const Eigen::Matrix3f raw =
      R * Eigen::Vector3f(4e-4f, 1e-6f, 2.5e-4f).asDiagonal() * R.transpose();
  const Eigen::Matrix3f reg = regularise_covariance(raw, 1e-3f);
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> solver(reg);
  EXPECT_NEAR(solver.eigenvalues()(0), 1e-3f, 1e-6f);
  EXPECT_NEAR(solver.eigenvalues()(1), 1.0f, 1e-5f);
  EXPECT_NEAR(solver.eigenvalues()(2), 1.0f, 1e-5f);
  EXPECT_LT(angle_deg(solver.eigenvectors().col(0), R.col(1)), 0.01);
  EXPECT_TRUE(reg.isApprox(reg.transpose()));
}

// The normal regularise_covariance keeps is the smallest-eigenvalue eigenvector Eigen's
// closed-form solver finds, over random surfaces, scales and conditioning.
TEST(Preprocess, RegularisationAgreesWithEigenComputeDirect) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  std::normal_distribution<float> gauss(0.0f, 1.0f);
  double worst = 0.0, worst_truth = 0.0, worst_reference_truth = 0.0;
  for (int trial = 0; trial < 20000; ++trial) {
    const Eigen::Matrix3f R = Eigen::Quaternionf(gauss(rng), gauss(rng), gauss(rng), gauss(rng))
                                  .normalized()
                                  .toRotationMatrix();
    // Spread: 1 mm to 10 cm; tangent anisotropy up to 10:1; normal/tangent ratio 1e-6 to 0.3.
    const float tangent = std::pow(10.0f, -3.0f + 2.0f * unit(rng));
    const float second = tangent * (0.1f + 0.9f * unit(rng));
    const float normal = second * std::pow(10.0f, -6.0f + 5.5f * unit(rng));
    const Eigen::Vector3f e(normal * normal, second * second, tangent * tangent);
    const Eigen::Matrix3f raw = R * e.asDiagonal() * R.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> reference;
    reference.computeDirect(raw);
    const Eigen::Vector3f n = covariance_normal(regularise_covariance(raw, 1e-3f));
    const double a = angle_deg(n, reference.eigenvectors().col(0));
    worst = std::max(worst, a);
    worst_truth = std::max(worst_truth, angle_deg(n, R.col(0)));
    worst_reference_truth =
        std::max(worst_reference_truth, angle_deg(reference.eigenvectors().col(0), R.col(0)));
    ASSERT_LT(a, 0.05) << "eigenvalues " << e.transpose();
  }
  std::cout << "worst angle to computeDirect " << worst << " deg, to the truth " << worst_truth
            << " deg (computeDirect's own: " << worst_reference_truth << " deg)\n";
  EXPECT_LT(worst_truth, 0.05);
  // Degenerate samples still give a finite, well-conditioned disc.
  for (const Eigen::Matrix3f& raw :
       {Eigen::Matrix3f(Eigen::Matrix3f::Zero()), Eigen::Matrix3f(Eigen::Matrix3f::Identity()),
        Eigen::Matrix3f(Eigen::Vector3f(1.0f, 2.0f, 3.0f) *
                        Eigen::Vector3f(1.0f, 2.0f, 3.0f).transpose())}) {
    const Eigen::Matrix3f reg = regularise_covariance(raw, 1e-3f);
    ASSERT_TRUE(reg.allFinite());
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> solver(reg);
    EXPECT_NEAR(solver.eigenvalues()(0), 1e-3f, 1e-5f);
    EXPECT_NEAR(solver.eigenvalues()(2), 1.0f, 1e-5f);
  }
}

TEST(Preprocess, BadInputIsAnError) {
  const RgbdFrame good = plane_frame(Eigen::Vector3d::UnitZ(), 2.0);
  GaussianPoints points;
  std::string why;

  RgbdFrame small = good;
  small.camera.width = 320;
  small.camera.height = 240;
  small.camera.cx = 159.5;
  small.camera.cy = 119.5;
  EXPECT_FALSE(preprocess_frame(small, PreprocessConfig{}, &points, nullptr, &why));
  EXPECT_NE(why.find("640x480"), std::string::npos) << why;

  RgbdFrame no_focal = good;
  no_focal.camera.fx = 0.0;
  why.clear();
  EXPECT_FALSE(preprocess_frame(no_focal, PreprocessConfig{}, &points, nullptr, &why));
  EXPECT_NE(why.find("intrinsics"), std::string::npos) << why;

  RgbdFrame millimetres = good;
  good.depth.convertTo(millimetres.depth, CV_16UC1, 1000.0);
  why.clear();
  EXPECT_FALSE(preprocess_frame(millimetres, PreprocessConfig{}, &points, nullptr, &why));
  EXPECT_NE(why.find("CV_32FC1"), std::string::npos) << why;

  RgbdFrame empty = good;
  empty.depth = cv::Mat();
  why.clear();
  EXPECT_FALSE(preprocess_frame(empty, PreprocessConfig{}, &points, nullptr, &why));
  EXPECT_FALSE(why.empty());

  PreprocessConfig bad;
  bad.stride = 0;
  why.clear();
  EXPECT_FALSE(preprocess_frame(good, bad, &points, nullptr, &why));
  EXPECT_NE(why.find("stride"), std::string::npos) << why;
}

TEST(Preprocess, ConfigValidationNamesTheField) {
  const auto message = [](const PreprocessConfig& c) {
    std::string why;
    EXPECT_FALSE(c.is_valid(&why));
    return why;
  };
  EXPECT_TRUE(PreprocessConfig{}.is_valid());
  PreprocessConfig c;
  c.min_depth = -1.0f;
  EXPECT_NE(message(c).find("min_depth"), std::string::npos);
  c = {};
  c.max_depth = 0.2f;
  EXPECT_NE(message(c).find("max_depth"), std::string::npos);
  c = {};
  c.max_depth = std::numeric_limits<float>::quiet_NaN();
  EXPECT_NE(message(c).find("max_depth"), std::string::npos);
  c = {};
  c.voxel_size = -0.1f;
  EXPECT_NE(message(c).find("voxel_size"), std::string::npos);
  c = {};
  c.voxel_size = 0.1f;  // the default 0.1 m gate is too narrow for 0.1 m voxels
  EXPECT_NE(message(c).find("covariance.max_neighbour_distance"), std::string::npos);
  c = {};
  c.covariance.knn = 3;
  EXPECT_NE(message(c).find("covariance.knn"), std::string::npos);
  c = {};
  c.covariance.min_neighbours = 1;
  EXPECT_NE(message(c).find("covariance.min_neighbours"), std::string::npos);
  c = {};
  c.covariance.window_radius = 0;
  EXPECT_NE(message(c).find("covariance.window_radius"), std::string::npos);
  c = {};
  c.covariance.min_neighbours = 9;
  c.covariance.window_radius = 1;  // 8 neighbours at most
  EXPECT_NE(message(c).find("covariance.window_radius"), std::string::npos);
  c = {};
  c.covariance.max_neighbour_distance = 0.0f;
  EXPECT_NE(message(c).find("covariance.max_neighbour_distance"), std::string::npos);
  c = {};
  c.covariance.plane_epsilon = 0.0f;
  EXPECT_NE(message(c).find("covariance.plane_epsilon"), std::string::npos);
  c = {};
  c.depth_noise.a = 0.0f;
  EXPECT_NE(message(c).find("depth_noise.a"), std::string::npos);
  c = {};
  c.depth_noise.reference_depth = -1.0f;
  EXPECT_NE(message(c).find("depth_noise.reference_depth"), std::string::npos);
  c.depth_noise.enabled = false;  // a disabled model is not checked
  EXPECT_TRUE(c.is_valid());
}

// A redkitchen frame (Kinect v1, 7-Scenes) at stride 4.
TEST(Preprocess, RedkitchenFrame) {
  FSLAM_REQUIRE_DATA("redkitchen");
  std::string why;
  const auto dataset = open_dataset((test::data_dir() / "redkitchen").string(), {}, &why);
  ASSERT_TRUE(dataset) << why;
  RgbdFrame frame;
  ASSERT_TRUE(dataset->load(100, &frame, &why)) << why;
  const PreprocessConfig config = stride4_config();
  PreprocessStats stats;
  const GaussianPoints points = preprocess_or_fail(frame, config, &stats);
  ASSERT_TRUE(points.is_consistent(&why)) << why;

  EXPECT_GT(stats.valid_pixels, 640u * 480u / 2);
  EXPECT_LE(stats.lattice_points, 160u * 120u);
  // The lattice samples the image uniformly: its valid fraction is the image's.
  EXPECT_NEAR(static_cast<double>(stats.lattice_points) / (160 * 120),
              static_cast<double>(stats.valid_pixels) / (640 * 480), 0.02);
  // Only isolated samples and thin slivers lack neighbours.
  EXPECT_GT(stats.output_points, stats.lattice_points * 95 / 100);
  EXPECT_LE(stats.output_points, stats.lattice_points);
  EXPECT_EQ(points.size(), stats.output_points);

  std::size_t good = 0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f& p = points.means[i];
    EXPECT_TRUE(p.z() > config.min_depth && p.z() < config.max_depth);
    // The unit disc before the depth-noise scale.
    const Eigen::Matrix3f c = points.covariances[i] / config.depth_noise.covariance_scale(p.z());
    if (!c.allFinite()) continue;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> solver(c);
    const Eigen::Vector3f e = solver.eigenvalues();
    good += (e(0) > 0.5f * config.covariance.plane_epsilon && e(2) < 1.01f &&
             e(2) / e(0) < 1.1f / config.covariance.plane_epsilon)
                ? 1
                : 0;
  }
  EXPECT_GE(good, points.size() * 95 / 100);
  std::cout << "redkitchen frame 100: " << stats.valid_pixels << " valid pixels, "
            << stats.lattice_points << " lattice points, " << stats.output_points
            << " Gaussian points, " << good << " well conditioned\n";
}

// Timing: the 600 redkitchen frames at the default config, one thread. Opt-in:
//   fslam_core_tests --gtest_also_run_disabled_tests --gtest_filter='*PreprocessTiming*'
TEST(DISABLED_PreprocessTiming, Redkitchen600Frames) {
  FSLAM_REQUIRE_DATA("redkitchen");
  std::string why;
  const auto dataset = open_dataset((test::data_dir() / "redkitchen").string(), {}, &why);
  ASSERT_TRUE(dataset) << why;
  for (const int stride : {4, 2}) {
    PreprocessConfig config;
    config.stride = stride;
    std::vector<double> wall_ms, cpu_ms;
    std::size_t total_points = 0;
    GaussianPoints points;
    PreprocessStats stats;
    for (std::size_t i = 0; i < dataset->size(); ++i) {
      RgbdFrame frame;
      ASSERT_TRUE(dataset->load(i, &frame, &why)) << why;
      const auto start = std::chrono::steady_clock::now();
      const double cpu_start = thread_cpu_ms();
      ASSERT_TRUE(preprocess_frame(frame, config, &points, &stats, &why)) << why;
      cpu_ms.push_back(thread_cpu_ms() - cpu_start);
      wall_ms.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
              .count());
      total_points += points.size();
    }
    std::sort(wall_ms.begin(), wall_ms.end());
    std::sort(cpu_ms.begin(), cpu_ms.end());
    std::cout << "preprocess stride " << stride << ", " << wall_ms.size() << " frames: wall median "
              << wall_ms[wall_ms.size() / 2] << " ms (p90 " << wall_ms[wall_ms.size() * 9 / 10]
              << "), thread CPU median " << cpu_ms[cpu_ms.size() / 2] << " ms (p90 "
              << cpu_ms[cpu_ms.size() * 9 / 10] << "), mean points "
              << total_points / wall_ms.size() << "\n";
  }
}

}  // namespace
}  // namespace fslam::core

#include "fslam/core/tracking/gicp.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <iostream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "fslam/core/compute/thread_clock.hpp"
#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/tracking/gicp_impl.hpp"
#include "fslam/core/tracking/kdtree_target.hpp"
#include "fslam/core/tracking/local_map.hpp"
#include "fslam/core/tracking/point_features.hpp"
#include "fslam/core/tracking/preprocess.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

// ---------------------------------------------------------------------------------------------
// Synthetic scenes

// A room seen from inside: floor z = 0 and four walls of a 3 m x 3 m x 2 m box centred on the
// origin, plus a sphere and a box standing on the floor (they fix z, roll and pitch together with
// the floor, and break the room's symmetries).
Eigen::Vector3f sample_room_point(std::mt19937& rng) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  constexpr float kHalf = 1.5f, kHeight = 2.0f;
  // Surfaces by area, m^2: floor 9, walls 4 x 6, sphere 4 pi 0.4^2, box top 0.3 and sides 1.54.
  const float areas[] = {9.0f, 24.0f, 2.01f, 0.3f, 1.54f};
  float total = 0.0f;
  for (float a : areas) total += a;
  float pick = u(rng) * total;
  int surface = 0;
  while (surface < 4 && pick > areas[surface]) pick -= areas[surface++];
  switch (surface) {
    case 0: return {kHalf * (2 * u(rng) - 1), kHalf * (2 * u(rng) - 1), 0.0f};
    case 1: {
      const float s = kHalf * (2 * u(rng) - 1), z = kHeight * u(rng);
      switch (static_cast<int>(u(rng) * 4.0f) % 4) {
        case 0: return {kHalf, s, z};
        case 1: return {-kHalf, s, z};
        case 2: return {s, kHalf, z};
        default: return {s, -kHalf, z};
      }
    }
    case 2: {
      std::normal_distribution<float> n(0.0f, 1.0f);
      Eigen::Vector3f d(n(rng), n(rng), n(rng));
      return Eigen::Vector3f(0.5f, 0.3f, 0.4f) + 0.4f * d.normalized();
    }
    case 3:  // box [-0.9, -0.4] x [-0.8, -0.2] x [0, 0.7]
      return {-0.9f + 0.5f * u(rng), -0.8f + 0.6f * u(rng), 0.7f};
    default: {
      const float z = 0.7f * u(rng);
      const float side = u(rng) * 2.2f;  // perimeter 2 * (0.5 + 0.6)
      if (side < 0.5f) return {-0.9f + side, -0.8f, z};
      if (side < 1.0f) return {-0.9f + (side - 0.5f), -0.2f, z};
      if (side < 1.6f) return {-0.9f, -0.8f + (side - 1.0f), z};
      return {-0.4f, -0.8f + (side - 1.6f), z};
    }
  }
}

CovarianceConfig test_covariance_config() {
  CovarianceConfig config;
  config.knn = 10;
  config.max_neighbour_distance = 0.25f;
  return config;
}

// `n` random room points with k-NN covariances (a few with too few neighbours are dropped).
GaussianPoints room_points(std::size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  GaussianPoints points;
  points.means.reserve(n);
  for (std::size_t i = 0; i < n; ++i) points.means.push_back(sample_room_point(rng));
  estimate_covariances_knn(test_covariance_config(), &points);
  return points;
}

void set_features(GaussianPoints* points, int dim, int hot) {
  points->feature_dim = dim;
  points->features.assign(points->size() * static_cast<std::size_t>(dim), 0.0f);
  for (std::size_t i = 0; i < points->size(); ++i)
    points->features[i * static_cast<std::size_t>(dim) + static_cast<std::size_t>(hot)] = 1.0f;
}

// Appends every point of `b` to `a` (both with or both without opacities and features).
void append(GaussianPoints* a, const GaussianPoints& b) {
  a->means.insert(a->means.end(), b.means.begin(), b.means.end());
  a->covariances.insert(a->covariances.end(), b.covariances.begin(), b.covariances.end());
  a->opacities.insert(a->opacities.end(), b.opacities.begin(), b.opacities.end());
  a->features.insert(a->features.end(), b.features.begin(), b.features.end());
}

// Eigen::Isometry3d of a random twist with rotation angle `deg` and translation `metres`.
Eigen::Isometry3d random_transform(std::mt19937& rng, double deg, double metres) {
  std::normal_distribution<double> n(0.0, 1.0);
  const Eigen::Vector3d axis = Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
  const Eigen::Vector3d dir = Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(deg / kRadToDeg, axis).toRotationMatrix();
  T.translation() = metres * dir;
  return T;
}

struct PoseError {
  double degrees;
  double metres;
};

PoseError pose_error(const Eigen::Isometry3d& estimate, const Eigen::Isometry3d& truth) {
  const Eigen::Isometry3d E = truth.inverse() * estimate;
  return {rotation_angle(E.linear()) * kRadToDeg, E.translation().norm()};
}

KdTreeTarget make_target(const GaussianPoints& points) {
  KdTreeTarget target;
  std::string why;
  EXPECT_TRUE(target.build(points, &why)) << why;
  return target;
}

// Settings the scene tests share: a wide correspondence radius so that 10 degree / 10 cm initial
// errors (up to ~0.4 m of displacement at the room's walls) still find correspondences.
GicpConfig scene_config() {
  GicpConfig config;
  config.max_iterations = 60;
  config.max_correspondence_distance = 0.5f;
  config.kernel = RobustKernel::none;
  config.translation_epsilon = 1e-6;
  config.rotation_epsilon = 1e-6;
  return config;
}

// ---------------------------------------------------------------------------------------------
// Both reductions

enum class Backend { serial, tbb };

std::string backend_name(const testing::TestParamInfo<Backend>& info) {
  return info.param == Backend::serial ? "Serial" : "Tbb";
}

// Small grain so that even the small test clouds are split into many tasks.
constexpr std::size_t kTestGrain = 64;

GicpResult run_align(Backend backend, const GaussianPoints& source, const KdTreeTarget& target,
                     const Eigen::Isometry3d& T_init, const GicpConfig& config) {
  if (backend == Backend::serial) return align(source, target, T_init, config, SerialReduction{});
  return align(source, target, T_init, config, TbbReduction{kTestGrain});
}

LinearSystem run_linearize(Backend backend, const GaussianPoints& source,
                           const KdTreeTarget& target, const Eigen::Isometry3d& T,
                           const GicpConfig& config) {
  if (backend == Backend::serial) return linearize(source, target, T, config, SerialReduction{});
  return linearize(source, target, T, config, TbbReduction{kTestGrain});
}

class GicpBackend : public testing::TestWithParam<Backend> {};

INSTANTIATE_TEST_SUITE_P(Reductions, GicpBackend, testing::Values(Backend::serial, Backend::tbb),
                         backend_name);

// ---------------------------------------------------------------------------------------------
// (1) Derivatives

TEST(GicpFactor, ResidualJacobianMatchesCentralDifferences) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  const double h = 1e-6;
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Isometry3d T = random_transform(rng, 40.0, 1.0);
    const Eigen::Vector3d p(u(rng), u(rng), u(rng)), mu(u(rng), u(rng), u(rng));
    const Eigen::Vector3d q = T * p;
    Matrix36d J;
    gicp_residual(mu, q, &J);
    Matrix36d numeric;
    for (int k = 0; k < 6; ++k) {
      Vector6d xi = Vector6d::Zero();
      xi[k] = h;
      Matrix36d unused;
      const Eigen::Vector3d plus = gicp_residual(mu, se3_exp(xi) * T * p, &unused);
      const Eigen::Vector3d minus = gicp_residual(mu, se3_exp(-xi) * T * p, &unused);
      numeric.col(k) = (plus - minus) / (2.0 * h);
    }
    EXPECT_LT((J - numeric).norm(), 1e-6 * std::max(1.0, J.norm())) << "trial " << trial;
  }
}

TEST(GicpFactor, RobustKernelsAreConsistentWithTheirWeights) {
  // The IRLS weight must be d rho / d m, so the weighted system is the true gradient.
  for (const RobustKernel kernel :
       {RobustKernel::none, RobustKernel::huber, RobustKernel::cauchy}) {
    for (const double m : {0.01, 0.5, 0.99, 1.5, 10.0, 400.0}) {
      const double h = 1e-6 * m;
      const double numeric =
          (robust_kernel(kernel, 1.0, m + h).cost - robust_kernel(kernel, 1.0, m - h).cost) /
          (2.0 * h);
      EXPECT_NEAR(robust_kernel(kernel, 1.0, m).weight, numeric, 1e-6)
          << "kernel " << static_cast<int>(kernel) << " m " << m;
    }
  }
  EXPECT_DOUBLE_EQ(robust_kernel(RobustKernel::huber, 2.0, 3.0).cost, 3.0);  // quadratic inside
  EXPECT_DOUBLE_EQ(robust_kernel(RobustKernel::huber, 2.0, 9.0).cost, 8.0);  // 2 k r - k^2
}

// With isotropic source covariances C does not depend on R, so for fixed correspondences the
// whole weighted objective has gradient 2 b: checks H/b assembly, weights and both reductions.
TEST_P(GicpBackend, SystemGradientMatchesCentralDifferencesOfCost) {
  GaussianPoints target_points = room_points(3000, 11);
  target_points.opacities.resize(target_points.size());
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u01(0.2f, 1.0f);
  for (float& a : target_points.opacities) a = u01(rng);
  set_features(&target_points, 3, 0);
  for (float& f : target_points.features) f += 0.3f * u01(rng);
  const KdTreeTarget target = make_target(target_points);

  GaussianPoints source = room_points(2000, 12);
  for (Eigen::Matrix3f& C : source.covariances) C = 0.01f * Eigen::Matrix3f::Identity();
  set_features(&source, 3, 0);
  const Eigen::Isometry3d T = random_transform(rng, 1.0, 0.01);

  GicpConfig config;
  config.max_correspondence_distance = 0.2f;
  config.kernel = RobustKernel::cauchy;
  config.kernel_scale = 0.5;
  config.feature_gamma = 2.0;
  const LinearSystem system = run_linearize(GetParam(), source, target, T, config);
  ASSERT_GT(system.inliers, source.size() / 2);

  // Central differences of the cost over the six perturbations (correspondences do not change).
  const auto numeric_gradient = [&](const GicpConfig& c) {
    const double h = 1e-7;
    Vector6d numeric;
    for (int k = 0; k < 6; ++k) {
      Vector6d xi = Vector6d::Zero();
      xi[k] = h;
      const LinearSystem plus = run_linearize(GetParam(), source, target, se3_exp(xi) * T, c);
      const LinearSystem minus = run_linearize(GetParam(), source, target, se3_exp(-xi) * T, c);
      EXPECT_EQ(plus.inliers, system.inliers);
      EXPECT_EQ(minus.inliers, system.inliers);
      numeric[k] = (plus.cost - minus.cost) / (2.0 * h);
    }
    return numeric;
  };
  const Vector6d numeric = numeric_gradient(config);
  EXPECT_LT((2.0 * system.b - numeric).norm(), 1e-5 * std::max(1.0, numeric.norm()))
      << "analytic " << (2.0 * system.b).transpose() << "\nnumeric  " << numeric.transpose();
  EXPECT_LT((system.H - system.H.transpose()).norm(), 1e-9 * system.H.norm());

  // The feature residual of eq. feat_gicp adds its own cost, and b stays half its gradient.
  source.feature_gradient.resize(source.size() * 3 * 3);
  std::normal_distribution<float> n01(0.0f, 1.0f);
  for (float& g : source.feature_gradient) g = 5.0f * n01(rng);
  source.feature_spread.assign(source.size(), 0.05f);
  config.feature_residual_weight = 0.7;
  const LinearSystem with = run_linearize(GetParam(), source, target, T, config);
  const Vector6d numeric_with = numeric_gradient(config);
  EXPECT_GT((with.b - system.b).norm(), 1e-3 * system.b.norm()) << "the residual term did nothing";
  EXPECT_LT((2.0 * with.b - numeric_with).norm(), 1e-5 * std::max(1.0, numeric_with.norm()))
      << "analytic " << (2.0 * with.b).transpose() << "\nnumeric  " << numeric_with.transpose();
  EXPECT_LT((with.H - with.H.transpose()).norm(), 1e-9 * with.H.norm());
}

// The feature residual of eq. feat_gicp constrains what geometry cannot: a frame of a flat wall
// and floor slid 2 cm along both (x) has no geometric restoring force along x, but the wall's
// texture, a latent ramp of 10 units per metre along x, brings it back.
TEST_P(GicpBackend, FeatureResidualRecoversASlideAlongAFlatSurface) {
  const PinholeCamera camera{100.0, 100.0, 39.5, 29.5, 80, 60};
  const double slide = 0.02;  // metres along x: the source camera sits here in the target's frame
  // A wall at z = 2 m and a floor at y = 0.3 m in front of it, both unbounded along x: any camera
  // on the x axis sees the same geometry, this point at pixel (u, v).
  auto surface_point = [&](int u, int v) -> Eigen::Vector3d {
    const Eigen::Vector3d ray((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0);
    const double t_wall = 2.0;
    const double t_floor = ray.y() > 1e-9 ? 0.3 / ray.y() : 1e9;
    return ray * std::min(t_wall, t_floor);
  };
  auto texture = [](const Eigen::Vector3d& world) { return static_cast<float>(10.0 * world.x()); };
  auto build = [&](double camera_x, bool with_latent, PlanarImage* latent) {
    GaussianPoints points;
    if (with_latent) *latent = PlanarImage(camera.width, camera.height, 1);
    for (int v = 0; v < camera.height; ++v)
      for (int u = 0; u < camera.width; ++u) {
        const Eigen::Vector3d p = surface_point(u, v);
        if (with_latent) latent->at(0, v, u) = texture(p + Eigen::Vector3d(camera_x, 0.0, 0.0));
        if (u % 2 == 0 && v % 2 == 0) points.means.push_back(p.cast<float>());
      }
    estimate_covariances_knn(test_covariance_config(), &points);
    return points;
  };
  PlanarImage latent;
  GaussianPoints source = build(slide, true, &latent);
  sample_point_features(latent, camera, &source, /*gradient=*/true);
  ASSERT_TRUE(source.has_feature_gradient());
  GaussianPoints target_points = build(0.0, false, nullptr);
  target_points.feature_dim = 1;
  for (const Eigen::Vector3f& p : target_points.means) target_points.features.push_back(texture(p.cast<double>()));
  const KdTreeTarget target = make_target(target_points);

  GicpConfig config = scene_config();
  config.max_correspondence_distance = 0.08f;
  const Eigen::Isometry3d truth(Eigen::Translation3d(slide, 0.0, 0.0));
  const Eigen::Isometry3d T_init = Eigen::Isometry3d::Identity();
  const GicpResult geometric = run_align(GetParam(), source, target, T_init, config);
  config.feature_residual_weight = 1.0;
  const GicpResult with = run_align(GetParam(), source, target, T_init, config);
  EXPECT_GT(std::abs(geometric.T_target_source.translation().x() - slide), 0.015)
      << "the scene constrains x without the feature residual";
  EXPECT_LT(pose_error(with.T_target_source, truth).metres, 1e-3);
  EXPECT_LT(pose_error(with.T_target_source, truth).degrees, 0.05);
}

// ---------------------------------------------------------------------------------------------
// (2) Recovering known transforms

TEST_P(GicpBackend, RecoversKnownTransformsInARoom) {
  const GaussianPoints world_target = room_points(12000, 21);
  const KdTreeTarget target = make_target(world_target);
  const GaussianPoints world_source = room_points(4000, 22);  // a different sampling
  std::mt19937 rng(23);
  const GicpConfig config = scene_config();
  for (int trial = 0; trial < 4; ++trial) {
    const double deg = 2.5 * (trial + 1), metres = 0.025 * (trial + 1);
    const Eigen::Isometry3d T_target_source = random_transform(rng, deg, metres);
    const GaussianPoints source = transformed(world_source, T_target_source.inverse());
    const GicpResult result =
        run_align(GetParam(), source, target, Eigen::Isometry3d::Identity(), config);
    const PoseError error = pose_error(result.T_target_source, T_target_source);
    EXPECT_TRUE(result.converged) << "trial " << trial;
    EXPECT_LT(error.degrees, 0.1) << "trial " << trial << " from " << deg << " deg";
    EXPECT_LT(error.metres, 1e-3) << "trial " << trial << " from " << metres << " m";
    EXPECT_GT(result.inlier_ratio, 0.99);
    EXPECT_LT(result.rms_residual, 0.05);
    EXPECT_TRUE(std::isfinite(result.condition_number));
    EXPECT_GT(result.condition_number, 1.0);
  }
}

// The condition number (the tracker's lost test) is that of a rotation about the camera, so it
// does not depend on where the world origin lies: the same registration 10 m from the origin
// gives the same figure (about the origin, H's rotation columns grow with the distance).
TEST_P(GicpBackend, ConditionNumberDoesNotDependOnTheWorldOrigin) {
  const GaussianPoints world_target = room_points(12000, 31);
  const GaussianPoints world_source = room_points(4000, 32);
  std::mt19937 rng(33);
  const Eigen::Isometry3d T_target_source = random_transform(rng, 2.0, 0.02);
  const GaussianPoints source = transformed(world_source, T_target_source.inverse());
  const GicpResult near = run_align(GetParam(), source, make_target(world_target), Eigen::Isometry3d::Identity(),
                                    scene_config());
  Eigen::Isometry3d shift = Eigen::Isometry3d::Identity();
  shift.translation() = Eigen::Vector3d(8.0, -6.0, 0.5);
  const GicpResult far = run_align(GetParam(), source, make_target(transformed(world_target, shift)), shift,
                                   scene_config());
  ASSERT_TRUE(near.converged && far.converged);
  EXPECT_LT(pose_error(far.T_target_source, shift * near.T_target_source).metres, 1e-4);
  EXPECT_NEAR(far.condition_number / near.condition_number, 1.0, 1e-3)
      << near.condition_number << " near the origin, " << far.condition_number << " 10 m from it";
}

// The tracker's target: the same solver against the voxel-hash local map (whose search radius is
// one voxel, so the initial errors are smaller).
TEST_P(GicpBackend, RecoversKnownTransformsAgainstALocalMap) {
  LocalMap map;
  ASSERT_GT(map.insert(room_points(12000, 24), Eigen::Vector3f(0.0f, 0.0f, 1.0f)), 10000u);
  const GaussianPoints world_source = room_points(4000, 25);
  std::mt19937 rng(26);
  GicpConfig config = scene_config();
  config.max_correspondence_distance = 0.1f;
  for (int trial = 0; trial < 3; ++trial) {
    const Eigen::Isometry3d T_target_source = random_transform(rng, 1.0, 0.03);
    const GaussianPoints source = transformed(world_source, T_target_source.inverse());
    const GicpResult result =
        GetParam() == Backend::serial
            ? align(source, map, Eigen::Isometry3d::Identity(), config, SerialReduction{})
            : align(source, map, Eigen::Isometry3d::Identity(), config, TbbReduction{kTestGrain});
    const PoseError error = pose_error(result.T_target_source, T_target_source);
    EXPECT_TRUE(result.converged) << "trial " << trial;
    EXPECT_LT(error.degrees, 0.1) << "trial " << trial;
    EXPECT_LT(error.metres, 1e-3) << "trial " << trial;
    EXPECT_GT(result.inlier_ratio, 0.99);
  }
}

// ---------------------------------------------------------------------------------------------
// (3) Serial and TBB agree

TEST(GicpReductions, SerialAndTbbGiveTheSameSolution) {
  const tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 2);
  const KdTreeTarget target = make_target(room_points(12000, 31));
  std::mt19937 rng(32);
  const Eigen::Isometry3d T_target_source = random_transform(rng, 8.0, 0.08);
  const GaussianPoints source = transformed(room_points(4000, 33), T_target_source.inverse());
  GicpConfig config = scene_config();
  config.kernel = RobustKernel::huber;
  const GicpResult serial =
      align(source, target, Eigen::Isometry3d::Identity(), config, SerialReduction{});
  const GicpResult parallel =
      align(source, target, Eigen::Isometry3d::Identity(), config, TbbReduction{kTestGrain});
  EXPECT_LT((serial.T_target_source.matrix() - parallel.T_target_source.matrix()).norm(), 1e-9);
  EXPECT_EQ(serial.inliers, parallel.inliers);
  EXPECT_EQ(serial.iterations, parallel.iterations);
  EXPECT_NEAR(serial.cost, parallel.cost, 1e-9 * serial.cost);
  EXPECT_LT((serial.H - parallel.H).norm(), 1e-9 * serial.H.norm());
  // The TBB reduction is deterministic: a second run is bit-identical.
  const GicpResult again =
      align(source, target, Eigen::Isometry3d::Identity(), config, TbbReduction{kTestGrain});
  EXPECT_EQ(again.T_target_source.matrix(), parallel.T_target_source.matrix());
}

// ---------------------------------------------------------------------------------------------
// (4) Feature and opacity weighting (eq. feat_gicp)

// The room plus a spurious copy of its floor 4 cm above the real one (within correspondence
// distance). The initial guess puts the source floor exactly on the spurious copy, so floor
// correspondences start on it; only the sphere and the box say otherwise in z.
struct AmbiguousFloorScene {
  GaussianPoints target_points;  // real room (features e0, opacity 1), then spurious floor
  GaussianPoints source;         // camera frame, features e0
  Eigen::Isometry3d T_target_source;
  Eigen::Isometry3d T_init;
};

AmbiguousFloorScene ambiguous_floor_scene(float spurious_opacity, int spurious_feature) {
  AmbiguousFloorScene scene;
  scene.target_points = room_points(12000, 41);
  scene.target_points.opacities.assign(scene.target_points.size(), 1.0f);
  set_features(&scene.target_points, 4, 0);

  GaussianPoints spurious;
  std::mt19937 rng(42);
  std::uniform_real_distribution<float> u(-1.45f, 1.45f);
  for (int i = 0; i < 4000; ++i) spurious.means.emplace_back(u(rng), u(rng), 0.04f);
  estimate_covariances_knn(test_covariance_config(), &spurious);
  spurious.opacities.assign(spurious.size(), spurious_opacity);
  set_features(&spurious, 4, spurious_feature);
  append(&scene.target_points, spurious);

  std::mt19937 pose_rng(43);
  scene.T_target_source = random_transform(pose_rng, 3.0, 0.03);
  GaussianPoints world_source = room_points(4000, 44);
  set_features(&world_source, 4, 0);
  scene.source = transformed(world_source, scene.T_target_source.inverse());
  scene.T_init = Eigen::Translation3d(0.0, 0.0, 0.04) * scene.T_target_source;
  return scene;
}

TEST_P(GicpBackend, FeaturesResolveASpuriousSurface) {
  const AmbiguousFloorScene scene = ambiguous_floor_scene(1.0f, 1);
  const KdTreeTarget target = make_target(scene.target_points);
  GicpConfig config = scene_config();
  config.max_correspondence_distance = 0.1f;
  config.use_opacity = false;
  config.feature_gamma = 5.0;  // orthogonal unit features, no spread: weight exp(-5 * 2 / 0.1)

  config.use_features = true;
  const GicpResult with = run_align(GetParam(), scene.source, target, scene.T_init, config);
  config.use_features = false;
  const GicpResult without = run_align(GetParam(), scene.source, target, scene.T_init, config);

  EXPECT_TRUE(with.features_used);
  EXPECT_FALSE(without.features_used);
  const PoseError e_with = pose_error(with.T_target_source, scene.T_target_source);
  const PoseError e_without = pose_error(without.T_target_source, scene.T_target_source);
  EXPECT_LT(e_with.metres, 1e-3);
  EXPECT_LT(e_with.degrees, 0.1);
  EXPECT_GT(e_without.metres, 1e-2) << "the scene is not ambiguous without features";
}

// align keeps each source point's feature similarity while its correspondence stays
// (FeatureSimilarityMemo): the same bits as Gauss-Newton on linearize, which computes every
// similarity afresh, in a scene whose floor correspondences move from the spurious copy to the
// real floor over the iterations.
TEST_P(GicpBackend, KeptFeatureSimilaritiesGiveTheSolutionOfFreshOnes) {
  const AmbiguousFloorScene scene = ambiguous_floor_scene(1.0f, 1);
  const KdTreeTarget target = make_target(scene.target_points);
  GicpConfig config = scene_config();
  config.max_correspondence_distance = 0.1f;
  config.kernel = RobustKernel::huber;
  config.use_features = true;
  config.feature_gamma = 0.5;  // a soft weight: the spurious floor still pulls a little
  const GicpResult kept = run_align(GetParam(), scene.source, target, scene.T_init, config);
  ASSERT_TRUE(kept.features_used);

  Eigen::Isometry3d T = scene.T_init;
  int iterations = 0;
  for (; iterations < config.max_iterations;) {
    const LinearSystem system = run_linearize(GetParam(), scene.source, target, T, config);
    Matrix6d H = system.H;
    H.diagonal() *= 1.0 + config.lm_lambda;
    const Vector6d delta = -Eigen::LDLT<Matrix6d>(H).solve(system.b);
    T = se3_exp(delta) * T;
    ++iterations;
    if (delta.head<3>().norm() < config.translation_epsilon && delta.tail<3>().norm() < config.rotation_epsilon)
      break;
  }
  EXPECT_GT(iterations, 3) << "correspondences had no iterations to change in";
  EXPECT_EQ(kept.iterations, iterations);
  EXPECT_EQ(kept.T_target_source.matrix(), T.matrix());
  EXPECT_LT(pose_error(kept.T_target_source, scene.T_target_source).metres, 1e-3);
}

TEST_P(GicpBackend, IdenticalFeaturesLeaveTheSolutionUnchanged) {
  const AmbiguousFloorScene scene = ambiguous_floor_scene(1.0f, 0);  // spurious floor, same feature
  const KdTreeTarget target = make_target(scene.target_points);
  GicpConfig config = scene_config();
  config.max_correspondence_distance = 0.1f;
  config.kernel = RobustKernel::huber;
  config.use_features = true;
  const GicpResult with = run_align(GetParam(), scene.source, target, scene.T_init, config);
  config.use_features = false;
  const GicpResult without = run_align(GetParam(), scene.source, target, scene.T_init, config);
  EXPECT_TRUE(with.features_used);
  EXPECT_EQ(with.T_target_source.matrix(), without.T_target_source.matrix());
  EXPECT_EQ(with.H, without.H);
  EXPECT_EQ(with.cost, without.cost);
  EXPECT_EQ(with.iterations, without.iterations);
}

// Eq. feat_dist on the scaled distance: every correspondence of a source on its own target
// weighs exp(-gamma ||df||^2 / (2 spread + noise)), so H is the featureless H times that.
TEST_P(GicpBackend, FeatureDistanceIsMeasuredInUnitsOfTheSpread) {
  GaussianPoints target_points = room_points(3000, 71);
  set_features(&target_points, 2, 0);
  const KdTreeTarget target = make_target(target_points);
  GicpConfig config = scene_config();
  config.feature_gamma = 0.5;
  config.feature_noise = 0.25;
  struct Case {
    float offset;  // in feature channel 1, so ||df||^2 = offset^2
    float spread;
  };
  // 1 / 0.25 and 4 / (2 * 0.375 + 0.25): the same scaled distance 4, the same weight exp(-2).
  for (const Case c : {Case{1.0f, 0.0f}, Case{2.0f, 0.375f}}) {
    GaussianPoints source = target_points;
    for (std::size_t i = 0; i < source.size(); ++i) source.features[2 * i + 1] = c.offset;
    source.feature_spread.assign(source.size(), c.spread);
    config.use_features = true;
    const LinearSystem with =
        run_linearize(GetParam(), source, target, Eigen::Isometry3d::Identity(), config);
    config.use_features = false;
    const LinearSystem without =
        run_linearize(GetParam(), source, target, Eigen::Isometry3d::Identity(), config);
    ASSERT_EQ(with.inliers, source.size());
    EXPECT_LT((with.H - std::exp(-2.0) * without.H).norm(), 1e-9 * without.H.norm())
        << "offset " << c.offset << ", spread " << c.spread;
    // The similarity is reported, per inlier, without changing what it weighs.
    EXPECT_NEAR(with.feature_weight_sum / static_cast<double>(with.inliers), std::exp(-2.0), 1e-9);
    EXPECT_EQ(without.feature_weight_sum, 0.0);
    EXPECT_EQ(with.mahalanobis_sum, without.mahalanobis_sum);
  }
}

// The registration's quality figures: a source on its own target lies on the target's surfaces
// (Mahalanobis ~0) with identical features (similarity 1); the same source moved 5 mm along +z
// has each point 5 mm off a target point, and the mean d^T C^-1 d is the mean of that over the
// correspondences' C, computed here directly.
TEST_P(GicpBackend, ReportsMeanFeatureSimilarityAndMahalanobis) {
  GaussianPoints target_points = room_points(3000, 71);
  set_features(&target_points, 2, 0);
  const KdTreeTarget target = make_target(target_points);
  GicpConfig config = scene_config();
  config.use_features = true;
  const GicpResult at_rest =
      run_align(GetParam(), target_points, target, Eigen::Isometry3d::Identity(), config);
  EXPECT_NEAR(at_rest.mean_feature_weight, 1.0, 1e-12);
  EXPECT_NEAR(at_rest.mean_mahalanobis, 0.0, 1e-6);
  config.use_features = false;
  const GicpResult without =
      run_align(GetParam(), target_points, target, Eigen::Isometry3d::Identity(), config);
  EXPECT_TRUE(std::isnan(without.mean_feature_weight)) << "no features, no similarity";
  Eigen::Isometry3d shifted = Eigen::Isometry3d::Identity();
  shifted.translation() = Eigen::Vector3d(0.0, 0.0, 0.005);  // metres
  const LinearSystem moved = run_linearize(GetParam(), target_points, target, shifted, config);
  ASSERT_GT(moved.inliers, 0u);
  double expected = 0.0;
  std::size_t inliers = 0;
  for (std::size_t i = 0; i < target_points.size(); ++i) {
    const Eigen::Vector3f q = target_points.means[i] + Eigen::Vector3f(0.0f, 0.0f, 0.005f);
    const TargetPoint* match = target.nearest(q, config.max_correspondence_distance, nullptr);
    if (match == nullptr) continue;
    const Eigen::Matrix3d C = (match->covariance + target_points.covariances[i]).cast<double>();
    const Eigen::Vector3d d = (q - match->mean).cast<double>();
    expected += d.dot(C.inverse() * d);
    ++inliers;
  }
  ASSERT_EQ(inliers, moved.inliers);
  EXPECT_GT(expected, 0.0);
  EXPECT_NEAR(moved.mahalanobis_sum, expected, 1e-4 * expected);
}

TEST_P(GicpBackend, LowOpacityTargetPointsLoseInfluence) {
  const AmbiguousFloorScene scene = ambiguous_floor_scene(0.001f, 0);  // same feature, faint
  const KdTreeTarget target = make_target(scene.target_points);
  GicpConfig config = scene_config();
  config.max_correspondence_distance = 0.1f;
  config.use_features = false;

  config.use_opacity = true;
  const GicpResult with = run_align(GetParam(), scene.source, target, scene.T_init, config);
  config.use_opacity = false;
  const GicpResult without = run_align(GetParam(), scene.source, target, scene.T_init, config);

  const PoseError e_with = pose_error(with.T_target_source, scene.T_target_source);
  const PoseError e_without = pose_error(without.T_target_source, scene.T_target_source);
  EXPECT_LT(e_with.metres, 1e-3);
  EXPECT_LT(e_with.degrees, 0.1);
  EXPECT_GT(e_without.metres, 1e-2);
}

TEST_P(GicpBackend, MismatchedFeatureSizesTurnTheFeatureTermOff) {
  GaussianPoints target_points = room_points(3000, 51);
  set_features(&target_points, 4, 0);
  const KdTreeTarget target = make_target(target_points);
  GaussianPoints source = room_points(1000, 52);
  set_features(&source, 3, 1);
  GicpConfig config = scene_config();
  const GicpResult result =
      run_align(GetParam(), source, target, Eigen::Isometry3d::Identity(), config);
  EXPECT_FALSE(result.features_used);
  config.use_features = false;
  const GicpResult plain =
      run_align(GetParam(), source, target, Eigen::Isometry3d::Identity(), config);
  EXPECT_EQ(result.T_target_source.matrix(), plain.T_target_source.matrix());
}

// ---------------------------------------------------------------------------------------------
// (5) Robust kernels

// 20 % of the source points are a ghost layer 2-6 cm in front of the surfaces they were sampled
// on (one-sided, so they bias a plain least-squares solution), all within correspondence range.
TEST_P(GicpBackend, RobustKernelLimitsOutlierInfluence) {
  const KdTreeTarget target = make_target(room_points(12000, 61));
  GaussianPoints world_source = room_points(4000, 62);
  std::mt19937 rng(63);
  std::uniform_real_distribution<float> offset(0.02f, 0.06f);
  const std::size_t outliers = world_source.size() / 5;
  for (std::size_t i = 0; i < outliers; ++i) {
    const std::size_t k = (i * 5) % world_source.size();  // spread over the surfaces
    // The surface normal is the covariance's smallest axis; push towards the room centre.
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> eig(world_source.covariances[k]);
    Eigen::Vector3f normal = eig.eigenvectors().col(0);
    const Eigen::Vector3f inward = Eigen::Vector3f(0.0f, 0.0f, 1.0f) - world_source.means[k];
    if (normal.dot(inward) < 0.0f) normal = -normal;
    world_source.means.push_back(world_source.means[k] + offset(rng) * normal);
    world_source.covariances.push_back(world_source.covariances[k]);
  }
  const Eigen::Isometry3d T_target_source = random_transform(rng, 5.0, 0.05);
  const GaussianPoints source = transformed(world_source, T_target_source.inverse());

  GicpConfig config = scene_config();
  config.max_correspondence_distance = 0.1f;
  const Eigen::Isometry3d T_init = Eigen::Translation3d(0.02, -0.02, 0.02) * T_target_source;

  config.kernel = RobustKernel::none;
  const PoseError plain = pose_error(
      run_align(GetParam(), source, target, T_init, config).T_target_source, T_target_source);
  config.kernel = RobustKernel::cauchy;
  config.kernel_scale = 0.1;
  const GicpResult robust = run_align(GetParam(), source, target, T_init, config);
  const PoseError cauchy = pose_error(robust.T_target_source, T_target_source);
  config.kernel = RobustKernel::huber;
  const PoseError huber = pose_error(
      run_align(GetParam(), source, target, T_init, config).T_target_source, T_target_source);

  EXPECT_TRUE(robust.converged);
  EXPECT_LT(cauchy.metres, 2e-3);
  EXPECT_LT(cauchy.degrees, 0.1);
  EXPECT_LT(huber.metres, plain.metres);
  EXPECT_GT(plain.metres, 2e-3) << "outliers that do not bias least squares test nothing";
}

// ---------------------------------------------------------------------------------------------
// (6) Degenerate input and validation

void expect_finite(const GicpResult& r) {
  EXPECT_TRUE(is_finite(r.T_target_source));
  EXPECT_TRUE(r.H.allFinite());
  EXPECT_FALSE(std::isnan(r.condition_number));
  EXPECT_TRUE(std::isfinite(r.rms_residual));
  EXPECT_TRUE(std::isfinite(r.cost));
}

TEST_P(GicpBackend, EmptySourceOrTargetDoesNotConverge) {
  std::mt19937 rng(71);
  const Eigen::Isometry3d T_init = random_transform(rng, 5.0, 0.1);
  const KdTreeTarget target = make_target(room_points(2000, 72));
  const KdTreeTarget empty_target;
  const GaussianPoints source = room_points(500, 73);
  const GicpConfig config;

  const GicpResult no_source = run_align(GetParam(), GaussianPoints{}, target, T_init, config);
  EXPECT_FALSE(no_source.converged);
  EXPECT_EQ(no_source.iterations, 0);
  EXPECT_EQ(no_source.inliers, 0u);
  EXPECT_EQ(no_source.inlier_ratio, 0.0);
  EXPECT_EQ(no_source.T_target_source.matrix(), T_init.matrix());
  expect_finite(no_source);

  const GicpResult no_target = run_align(GetParam(), source, empty_target, T_init, config);
  EXPECT_FALSE(no_target.converged);
  EXPECT_EQ(no_target.inliers, 0u);
  EXPECT_EQ(no_target.source_points, source.size());
  EXPECT_EQ(no_target.T_target_source.matrix(), T_init.matrix());
  expect_finite(no_target);
}

TEST_P(GicpBackend, NoCorrespondencesReturnsTheInitialPose) {
  const KdTreeTarget target = make_target(room_points(2000, 81));
  const GaussianPoints source = room_points(500, 82);
  const Eigen::Isometry3d T_far(Eigen::Translation3d(50.0, 0.0, 0.0));
  const GicpResult result = run_align(GetParam(), source, target, T_far, GicpConfig{});
  EXPECT_FALSE(result.converged);
  EXPECT_EQ(result.inliers, 0u);
  EXPECT_EQ(result.T_target_source.matrix(), T_far.matrix());
  EXPECT_EQ(result.condition_number, std::numeric_limits<double>::infinity());
  expect_finite(result);
}

TEST_P(GicpBackend, SingularCovariancesAreSkippedNotNaN) {
  GaussianPoints target_points = room_points(2000, 91);
  for (Eigen::Matrix3f& C : target_points.covariances) C.setZero();
  const KdTreeTarget target = make_target(target_points);
  GaussianPoints source = room_points(500, 92);
  for (Eigen::Matrix3f& C : source.covariances) C.setZero();
  const GicpResult result =
      run_align(GetParam(), source, target, Eigen::Isometry3d::Identity(), GicpConfig{});
  EXPECT_FALSE(result.converged);
  EXPECT_EQ(result.inliers, 0u);
  expect_finite(result);
}

TEST_P(GicpBackend, ZeroOpacityEverywhereDoesNotConverge) {
  GaussianPoints target_points = room_points(2000, 95);
  target_points.opacities.assign(target_points.size(), 0.0f);
  const KdTreeTarget target = make_target(target_points);
  const GaussianPoints source = room_points(500, 96);
  const Eigen::Isometry3d T_init(Eigen::Translation3d(0.01, 0.0, 0.0));
  const GicpResult result = run_align(GetParam(), source, target, T_init, GicpConfig{});
  EXPECT_FALSE(result.converged);
  EXPECT_EQ(result.T_target_source.matrix(), T_init.matrix());
  expect_finite(result);
}

TEST(GicpConfigValidation, ExplainsEachBadField) {
  std::string why;
  EXPECT_TRUE(GicpConfig{}.is_valid(&why)) << why;
  struct Case {
    void (*mutate)(GicpConfig*);
    const char* field;
  };
  const Case cases[] = {
      {[](GicpConfig* c) { c->max_iterations = 0; }, "max_iterations"},
      {[](GicpConfig* c) { c->max_correspondence_distance = 0.0f; }, "max_correspondence_distance"},
      {[](GicpConfig* c) { c->max_correspondence_distance = NAN; }, "max_correspondence_distance"},
      {[](GicpConfig* c) { c->kernel = static_cast<RobustKernel>(7); }, "kernel"},
      {[](GicpConfig* c) { c->kernel_scale = -1.0; }, "kernel_scale"},
      {[](GicpConfig* c) { c->translation_epsilon = 0.0; }, "translation_epsilon"},
      {[](GicpConfig* c) { c->rotation_epsilon = -1.0; }, "rotation_epsilon"},
      {[](GicpConfig* c) { c->lm_lambda = -1e-3; }, "lm_lambda"},
      {[](GicpConfig* c) { c->feature_gamma = INFINITY; }, "feature_gamma"},
      {[](GicpConfig* c) { c->feature_noise = 0.0; }, "feature_noise"},
      {[](GicpConfig* c) { c->feature_residual_weight = -1.0; }, "feature_residual_weight"},
      {[](GicpConfig* c) { c->feature_residual_weight = NAN; }, "feature_residual_weight"},
  };
  for (const Case& c : cases) {
    GicpConfig config;
    c.mutate(&config);
    why.clear();
    EXPECT_FALSE(config.is_valid(&why)) << c.field;
    EXPECT_NE(why.find(c.field), std::string::npos) << why;
    EXPECT_FALSE(config.is_valid(nullptr));
  }
}

TEST(GicpLinearSystem, AddsEveryField) {
  LinearSystem a, b;
  a.H.setIdentity();
  a.b.setConstant(1.0);
  a.cost = 2.0;
  a.squared_distance_sum = 3.0;
  a.feature_weight_sum = 5.0;
  a.mahalanobis_sum = 6.0;
  a.inliers = 4;
  b = a;
  b += a;
  EXPECT_EQ(b.H, 2.0 * Matrix6d::Identity());
  EXPECT_EQ(b.b, Vector6d::Constant(2.0));
  EXPECT_EQ(b.cost, 4.0);
  EXPECT_EQ(b.squared_distance_sum, 6.0);
  EXPECT_EQ(b.feature_weight_sum, 10.0);
  EXPECT_EQ(b.mahalanobis_sum, 12.0);
  EXPECT_EQ(b.inliers, 8u);
}

// ---------------------------------------------------------------------------------------------
// KdTreeTarget

GaussianPoints random_points(std::size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  GaussianPoints points;
  for (std::size_t i = 0; i < n; ++i) {
    points.means.emplace_back(u(rng), u(rng), u(rng));
    points.covariances.push_back(Eigen::Matrix3f::Identity() * (1.0f + static_cast<float>(i)));
  }
  return points;
}

std::ptrdiff_t brute_force_nearest(const GaussianPoints& points, const Eigen::Vector3f& q,
                                   float max_distance) {
  std::ptrdiff_t best = -1;
  float best_d2 = max_distance * max_distance;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const float d2 = (points.means[i] - q).squaredNorm();
    if (d2 <= best_d2 && (best < 0 || d2 < best_d2)) {
      best = static_cast<std::ptrdiff_t>(i);
      best_d2 = d2;
    }
  }
  return best;
}

TEST(KdTreeTarget, NearestMatchesBruteForceWithinRadius) {
  const GaussianPoints points = random_points(3000, 101);
  const KdTreeTarget target = make_target(points);
  ASSERT_EQ(target.size(), points.size());
  std::mt19937 rng(102);
  std::uniform_real_distribution<float> u(-1.2f, 1.2f);
  int found = 0;
  for (int k = 0; k < 2000; ++k) {
    const Eigen::Vector3f q(u(rng), u(rng), u(rng));
    const float radius = (k % 2 == 0) ? 0.05f : 0.2f;
    float d2 = -1.0f;
    const TargetPoint* p = target.nearest(q, radius, &d2);
    const std::ptrdiff_t expected = brute_force_nearest(points, q, radius);
    if (expected < 0) {
      EXPECT_EQ(p, nullptr);
      continue;
    }
    ++found;
    ASSERT_NE(p, nullptr);
    const std::size_t index = target.input_index(*p);
    EXPECT_EQ(p->mean, points.means[index]);
    EXPECT_EQ((points.means[index] - q).squaredNorm(),
              (points.means[static_cast<std::size_t>(expected)] - q).squaredNorm());
    EXPECT_FLOAT_EQ(d2, (p->mean - q).squaredNorm());
    EXPECT_EQ(p->covariance, points.covariances[index]);
  }
  EXPECT_GT(found, 500);
}

TEST(KdTreeTarget, RadiusIsInclusive) {
  GaussianPoints points;
  points.means = {Eigen::Vector3f(0.5f, 0.0f, 0.0f)};
  points.covariances = {Eigen::Matrix3f::Identity()};
  const KdTreeTarget target = make_target(points);
  EXPECT_NE(target.nearest(Eigen::Vector3f::Zero(), 0.5f), nullptr);
  EXPECT_EQ(target.nearest(Eigen::Vector3f::Zero(), 0.4999f), nullptr);
  EXPECT_EQ(target.nearest(Eigen::Vector3f::Zero(), 0.0f), nullptr);
  EXPECT_EQ(target.nearest(Eigen::Vector3f(NAN, 0.0f, 0.0f), 1.0f), nullptr);
}

TEST(KdTreeTarget, ConcurrentQueriesMatchSerialOnes) {
  // More threads than cores, so queries interleave on every core.
  const tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 4);
  tbb::task_arena arena(4);
  const KdTreeTarget target = make_target(random_points(20000, 111));
  std::mt19937 rng(112);
  std::uniform_real_distribution<float> u(-1.1f, 1.1f);
  std::vector<Eigen::Vector3f> queries(50000);
  for (Eigen::Vector3f& q : queries) q = Eigen::Vector3f(u(rng), u(rng), u(rng));
  std::vector<const TargetPoint*> serial(queries.size()), parallel(queries.size());
  for (std::size_t i = 0; i < queries.size(); ++i) serial[i] = target.nearest(queries[i], 0.1f);
  for (int repeat = 0; repeat < 3; ++repeat) {
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, queries.size(), 16),
                        [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t i = r.begin(); i != r.end(); ++i)
                            parallel[i] = target.nearest(queries[i], 0.1f);
                        });
    });
    EXPECT_EQ(serial, parallel);
  }
}

TEST(KdTreeTarget, CarriesOpacitiesAndFeatures) {
  GaussianPoints points = random_points(100, 121);
  points.opacities.resize(points.size());
  for (std::size_t i = 0; i < points.size(); ++i)
    points.opacities[i] = 0.01f * static_cast<float>(i);
  points.feature_dim = 2;
  for (std::size_t i = 0; i < points.size(); ++i) {
    points.features.push_back(static_cast<float>(i));
    points.features.push_back(-static_cast<float>(i));
  }
  KdTreeTarget target = make_target(points);
  EXPECT_EQ(target.feature_dim(), 2);
  for (std::size_t i = 0; i < points.size(); i += 7) {
    const TargetPoint* p = target.nearest(points.means[i], 1e-4f);
    ASSERT_NE(p, nullptr);
    EXPECT_EQ(target.input_index(*p), i);
    EXPECT_EQ(p->opacity, points.opacities[i]);
    EXPECT_EQ(target.feature(*p)[0], static_cast<float>(i));
    EXPECT_EQ(target.feature(*p)[1], -static_cast<float>(i));
  }
  // Moving keeps the tree valid; without opacities they read as 1.
  const KdTreeTarget moved = std::move(target);
  EXPECT_NE(moved.nearest(points.means[3], 1e-4f), nullptr);
  const KdTreeTarget plain = make_target(random_points(10, 122));
  EXPECT_EQ(plain.feature_dim(), 0);
  EXPECT_EQ(plain.point(0).opacity, 1.0f);
}

TEST(KdTreeTarget, RejectsInconsistentPointsAndStaysEmpty) {
  GaussianPoints points = random_points(10, 131);
  points.covariances.pop_back();
  KdTreeTarget target = make_target(random_points(10, 132));
  std::string why;
  EXPECT_FALSE(target.build(points, &why));
  EXPECT_NE(why.find("covariances"), std::string::npos) << why;
  EXPECT_TRUE(target.empty());
  EXPECT_EQ(target.nearest(Eigen::Vector3f::Zero(), 10.0f), nullptr);
}

// ---------------------------------------------------------------------------------------------
// Opt-in benchmark: one GICP iteration, 15k source points against a 60k
// KD-tree target, 1 and 2 threads. Run with --gtest_also_run_disabled_tests
// --gtest_filter='GicpBenchmark.DISABLED_*'.

// Reorders `points` (means and covariances only) along a Morton curve of 4 cm cells: spatially
// coherent like a frame's image-lattice order, unlike the random sampling order.
void sort_spatially(GaussianPoints* points) {
  const auto morton = [](const Eigen::Vector3f& p) {
    std::uint64_t code = 0;
    const auto cell = [&](float v) { return static_cast<std::uint64_t>((v + 10.0f) / 0.04f); };
    const std::uint64_t c[3] = {cell(p.x()), cell(p.y()), cell(p.z())};
    for (int bit = 0; bit < 21; ++bit)
      for (int axis = 0; axis < 3; ++axis) code |= ((c[axis] >> bit) & 1u) << (3 * bit + axis);
    return code;
  };
  std::vector<std::size_t> order(points->size());
  std::vector<std::uint64_t> codes(points->size());
  for (std::size_t i = 0; i < order.size(); ++i) {
    order[i] = i;
    codes[i] = morton(points->means[i]);
  }
  std::sort(order.begin(), order.end(),
            [&](std::size_t a, std::size_t b) { return codes[a] < codes[b]; });
  GaussianPoints sorted;
  for (std::size_t i : order) {
    sorted.means.push_back(points->means[i]);
    sorted.covariances.push_back(points->covariances[i]);
  }
  *points = sorted;
}

double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// Median milliseconds of one GICP iteration (linearise: associate + factors + reduce; solve the
// 6x6 step): serial wall and thread-CPU time, and TBB wall time on 2 threads.
template <typename Target>
std::string time_iteration(const GaussianPoints& source, const Target& target,
                           const Eigen::Isometry3d& T, const GicpConfig& config) {
  const auto iteration = [&](const auto& reduction) {
    const LinearSystem system = linearize(source, target, T, config, reduction);
    Vector6d delta;
    gicp_detail::solve_step(system, config.lm_lambda, &delta);
    EXPECT_GT(system.inliers, source.size() * 9 / 10);
  };
  const auto wall_ms = [](auto t0) {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  };
  std::vector<double> serial_wall, serial_cpu, tbb_wall;
  for (int k = 0; k < 31; ++k) {
    const auto t0 = std::chrono::steady_clock::now();
    const double c0 = thread_cpu_ms();
    iteration(SerialReduction{});
    serial_cpu.push_back(thread_cpu_ms() - c0);
    serial_wall.push_back(wall_ms(t0));
  }
  const tbb::global_control two(tbb::global_control::max_allowed_parallelism, 2);
  for (int k = 0; k < 31; ++k) {
    const auto t0 = std::chrono::steady_clock::now();
    iteration(TbbReduction{});
    tbb_wall.push_back(wall_ms(t0));
  }
  std::ostringstream s;
  s << "serial " << median(serial_wall) << " ms wall / " << median(serial_cpu)
    << " ms CPU, TBB 2 threads " << median(tbb_wall) << " ms wall";
  return s.str();
}

TEST(GicpBenchmark, DISABLED_IterationTime15kSourceAgainst60kTarget) {
  const GaussianPoints target_random = room_points(62000, 201);
  const GaussianPoints source_random = room_points(15500, 202);
  std::mt19937 rng(203);
  const Eigen::Isometry3d T = random_transform(rng, 1.0, 0.01);
  GicpConfig config;
  config.kernel = RobustKernel::huber;
  for (const int feature_dim : {0, 16}) {
    for (const bool coherent : {false, true}) {
      GaussianPoints target_points = target_random;
      GaussianPoints world_source = source_random;
      if (coherent) sort_spatially(&world_source);
      if (feature_dim > 0) {
        set_features(&target_points, feature_dim, 0);
        set_features(&world_source, feature_dim, 0);
      }
      const GaussianPoints source = transformed(world_source, T.inverse());
      const KdTreeTarget kdtree = make_target(target_points);
      LocalMap map;
      map.insert(target_points, Eigen::Vector3f(0.0f, 0.0f, 1.0f));
      std::cout << source.size() << " source points (" << (coherent ? "coherent" : "random")
                << " order), feature_dim " << feature_dim << ":\n  KdTreeTarget " << kdtree.size()
                << ": " << time_iteration(source, kdtree, T, config) << "\n  LocalMap "
                << map.size() << ": " << time_iteration(source, map, T, config) << "\n";
    }
  }
}

}  // namespace
}  // namespace fslam::core

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iostream>
#include <limits>
#include <map>
#include <random>
#include <thread>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/tracking/local_map.hpp"
#include "fslam/core/tracking/preprocess.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

// Points uniform in the cube [lo, hi]^3 with unit-disc covariances along z.
GaussianPoints random_cloud(std::size_t n, float lo, float hi, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> uniform(lo, hi);
  GaussianPoints cloud;
  for (std::size_t i = 0; i < n; ++i) {
    cloud.means.emplace_back(uniform(rng), uniform(rng), uniform(rng));
    cloud.covariances.push_back(Eigen::Vector3f(1.0f, 1.0f, 1e-3f).asDiagonal());
  }
  return cloud;
}

// A regular grid on the plane z = height, `spacing` metres apart, centred on `centre`.
GaussianPoints plane_grid(const Eigen::Vector2f& centre, float half_size, float spacing,
                          float height = 1.0f) {
  GaussianPoints cloud;
  const int n = static_cast<int>(std::round(2.0f * half_size / spacing));
  for (int i = 0; i <= n; ++i)
    for (int j = 0; j <= n; ++j) {
      cloud.means.emplace_back(centre.x() - half_size + i * spacing,
                               centre.y() - half_size + j * spacing, height);
      cloud.covariances.push_back(Eigen::Vector3f(1.0f, 1.0f, 1e-3f).asDiagonal());
    }
  return cloud;
}

struct BruteForce {
  float squared_distance = std::numeric_limits<float>::infinity();
  Eigen::Vector3f mean = Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN());
};

// Plain float arithmetic (not Eigen expressions) keeps this fast in unoptimised builds.
BruteForce brute_force(const std::vector<Eigen::Vector3f>& points, const Eigen::Vector3f& q) {
  BruteForce best;
  const float qx = q.x(), qy = q.y(), qz = q.z();
  std::size_t best_index = points.size();
  for (std::size_t i = 0; i < points.size(); ++i) {
    const float* p = points[i].data();
    const float dx = p[0] - qx, dy = p[1] - qy, dz = p[2] - qz;
    const float d2 = dx * dx + dy * dy + dz * dz;
    if (d2 < best.squared_distance) {
      best.squared_distance = d2;
      best_index = i;
    }
  }
  if (best_index < points.size()) best.mean = points[best_index];
  return best;
}

LocalMapConfig wide_config() {
  LocalMapConfig config;
  config.radius = 100.0f;  // keep everything
  config.min_point_distance = 0.0f;
  config.max_points_per_voxel = 1000;
  return config;
}

TEST(LocalMap, NearestEqualsBruteForce) {
  LocalMap map(wide_config());
  const GaussianPoints cloud = random_cloud(10000, -1.0f, 1.0f, 1);
  ASSERT_EQ(map.insert(cloud, Eigen::Vector3f::Zero()), cloud.size());
  EXPECT_EQ(map.size(), cloud.size());
  const std::vector<Eigen::Vector3f> stored = map.points().means;
  ASSERT_EQ(stored.size(), cloud.size());

  const GaussianPoints queries = random_cloud(2000, -1.1f, 1.1f, 2);
  for (const float max_distance : {0.05f, 0.08f, 0.1f}) {
    std::size_t hits = 0;
    for (const Eigen::Vector3f& q : queries.means) {
      const BruteForce expected = brute_force(stored, q);
      float d2 = -1.0f;
      const TargetPoint* found = map.nearest(q, max_distance, &d2);
      if (expected.squared_distance <= max_distance * max_distance) {
        ASSERT_NE(found, nullptr) << "query " << q.transpose();
        EXPECT_EQ(found->mean, expected.mean);  // the same point, exactly
        // The same distance up to summation order (nearest() computes it in vector lanes).
        EXPECT_FLOAT_EQ(d2, expected.squared_distance);
        ++hits;
      } else {
        EXPECT_EQ(found, nullptr) << "query " << q.transpose() << " max " << max_distance;
        EXPECT_EQ(d2, -1.0f);  // untouched on a miss
      }
    }
    EXPECT_GT(hits, queries.size() / 10) << "max_distance " << max_distance;  // both branches
    EXPECT_LT(hits, queries.size()) << "max_distance " << max_distance;
  }
}

TEST(LocalMap, NearestIsNullBeyondMaxDistance) {
  LocalMap map(wide_config());
  EXPECT_EQ(map.nearest(Eigen::Vector3f::Zero(), 0.1f), nullptr);  // empty map
  GaussianPoints one;
  one.means = {Eigen::Vector3f(0.95f, 0.0f, 1.0f)};  // near a voxel face: found from the next one
  one.covariances = {Eigen::Matrix3f::Identity()};
  map.insert(one, Eigen::Vector3f::Zero());
  const Eigen::Vector3f q(1.0f, 0.0f, 1.0f);
  EXPECT_EQ(map.nearest(q, 0.04f), nullptr);
  float d2 = 0.0f;
  const TargetPoint* p = map.nearest(q, 0.06f, &d2);
  ASSERT_NE(p, nullptr);
  EXPECT_NEAR(d2, 0.05f * 0.05f, 1e-6f);
  EXPECT_EQ(p->mean, one.means[0]);
  // Beyond voxel_size the search is clamped to it (the 27-voxel neighbourhood is exact only
  // up to one voxel edge).
  EXPECT_EQ(map.nearest(Eigen::Vector3f(0.95f, 0.0f, 1.15f), 1.0f), nullptr);
  EXPECT_NE(map.nearest(Eigen::Vector3f(0.95f, 0.0f, 1.09f), 1.0f), nullptr);
  EXPECT_EQ(map.nearest(q, -1.0f), nullptr);
}

TEST(LocalMap, ThinningBoundsDensity) {
  LocalMapConfig config;
  config.min_point_distance = 0.01f;
  config.fuse = false;  // fusion moves stored points; without it the spacing is exact
  config.radius = 100.0f;
  LocalMap map(config);
  const GaussianPoints dense = plane_grid(Eigen::Vector2f(0.05f, 0.0f), 0.15f, 0.002f);  // 2 mm
  const std::size_t inserted = map.insert(dense, Eigen::Vector3f::Zero());
  EXPECT_EQ(inserted, map.size());
  EXPECT_LT(map.size(), dense.size() / 10);
  const std::vector<Eigen::Vector3f> stored = map.points().means;
  for (std::size_t i = 0; i < stored.size(); ++i)
    for (std::size_t j = i + 1; j < stored.size(); ++j)
      ASSERT_GE((stored[i] - stored[j]).norm(), config.min_point_distance) << i << ", " << j;
  std::map<std::tuple<int, int, int>, int> per_voxel;
  for (const Eigen::Vector3f& p : stored)
    ++per_voxel[{static_cast<int>(std::floor(p.x() / config.voxel_size)),
                 static_cast<int>(std::floor(p.y() / config.voxel_size)),
                 static_cast<int>(std::floor(p.z() / config.voxel_size))}];
  for (const auto& [key, count] : per_voxel) EXPECT_LE(count, config.max_points_per_voxel);
  EXPECT_EQ(map.voxel_count(), per_voxel.size());
  // The same keyframe again adds nothing.
  EXPECT_EQ(map.insert(dense, Eigen::Vector3f::Zero()), 0u);
}

TEST(LocalMap, MaxPointsPerVoxel) {
  LocalMapConfig config = wide_config();
  config.max_points_per_voxel = 5;
  LocalMap map(config);
  const GaussianPoints cloud = random_cloud(5000, 0.0f, 0.3f, 3);  // 27 voxels, ~185 points each
  map.insert(cloud, Eigen::Vector3f::Zero());
  EXPECT_EQ(map.voxel_count(), 27u);
  EXPECT_EQ(map.size(), 27u * 5u);
}

TEST(LocalMap, DropsVoxelsOutsideTheRadius) {
  LocalMapConfig config = wide_config();
  config.radius = 2.0f;
  LocalMap map(config);
  GaussianPoints line;
  for (int i = -500; i <= 500; ++i) {
    line.means.emplace_back(0.01f * i + 0.005f, 0.05f, 0.05f);  // x in [-5, 5] m
    line.covariances.push_back(Eigen::Matrix3f::Identity());
  }
  map.insert(line, Eigen::Vector3f::Zero());
  const float half_diagonal = 0.5f * std::sqrt(3.0f) * config.voxel_size;
  const auto check = [&](const Eigen::Vector3f& camera) {
    std::size_t inside = 0;
    for (const Eigen::Vector3f& p : map.points().means)
      EXPECT_LE((p - camera).norm(), config.radius + half_diagonal);
    for (const Eigen::Vector3f& p : line.means) {
      if ((p - camera).norm() >= config.radius - half_diagonal) continue;
      ++inside;
      EXPECT_NE(map.nearest(p, 0.001f), nullptr) << "dropped " << p.transpose();
    }
    EXPECT_GT(inside, 300u);
  };
  check(Eigen::Vector3f::Zero());
  EXPECT_LT(map.size(), 420u);
  // A later keyframe elsewhere: only what is near it stays.
  map.insert(line, Eigen::Vector3f(2.5f, 0.0f, 0.0f));
  check(Eigen::Vector3f(2.5f, 0.0f, 0.0f));
  map.insert(GaussianPoints{}, Eigen::Vector3f(0.0f, 50.0f, 0.0f));
  EXPECT_EQ(map.size(), 0u);
  EXPECT_EQ(map.voxel_count(), 0u);
}

// Features [x, y, z, tag] and opacity tag/100 for each point, so that every stored row can be
// checked against the point it belongs to.
void add_attributes(GaussianPoints* cloud, float tag) {
  cloud->feature_dim = 4;
  cloud->features.clear();
  cloud->opacities.clear();
  for (const Eigen::Vector3f& p : cloud->means) {
    cloud->features.insert(cloud->features.end(), {p.x(), p.y(), p.z(), tag});
    cloud->opacities.push_back(tag / 100.0f);
  }
}

void expect_attributes_match(const LocalMap& map) {
  const GaussianPoints all = map.points();
  ASSERT_EQ(all.size(), map.size());
  ASSERT_EQ(all.feature_dim, 4);
  ASSERT_EQ(all.features.size(), 4 * all.size());
  for (std::size_t i = 0; i < all.size(); ++i) {
    const float* f = all.feature(i);
    ASSERT_EQ(Eigen::Vector3f(f[0], f[1], f[2]), all.means[i]);
    ASSERT_FLOAT_EQ(all.opacities[i], f[3] / 100.0f);
    const TargetPoint* p = map.nearest(all.means[i], 0.0f);
    ASSERT_NE(p, nullptr);
    ASSERT_EQ(map.feature(*p)[0], all.means[i].x());
    ASSERT_EQ(map.feature(*p)[3], f[3]);
  }
}

TEST(LocalMap, CarriesFeaturesAndOpacities) {
  LocalMap map(wide_config());
  GaussianPoints cloud = random_cloud(2000, 0.0f, 1.0f, 4);
  add_attributes(&cloud, 42.0f);
  map.insert(cloud, Eigen::Vector3f::Zero());
  EXPECT_EQ(map.feature_dim(), 4);
  expect_attributes_match(map);

  // Without opacities every stored point is fully opaque.
  LocalMap plain(wide_config());
  plain.insert(random_cloud(100, 0.0f, 1.0f, 5), Eigen::Vector3f::Zero());
  EXPECT_EQ(plain.feature_dim(), 0);
  EXPECT_EQ(plain.feature_rows_stored(), 0u);
  for (const float a : plain.points().opacities) EXPECT_EQ(a, 1.0f);
  EXPECT_FALSE(plain.points().has_features());
}

TEST(LocalMap, UpdateFeaturesRewritesTheRowsOfStoredPoints) {
  LocalMap map(wide_config());
  GaussianPoints cloud = random_cloud(500, 0.0f, 1.0f, 11);
  add_attributes(&cloud, 1.0f);
  map.insert(cloud, Eigen::Vector3f::Zero());
  // Retag the points with x < 0.5; the others and every mean stay as they were.
  std::size_t visited = 0;
  map.update_features([&](const TargetPoint& p, float* feature) {
    ++visited;
    ASSERT_EQ(feature[0], p.mean.x());
    if (p.mean.x() < 0.5f) feature[3] = 2.0f;
  });
  EXPECT_EQ(visited, map.size());
  const GaussianPoints all = map.points();
  for (std::size_t i = 0; i < all.size(); ++i) {
    const float* f = all.feature(i);
    ASSERT_EQ(Eigen::Vector3f(f[0], f[1], f[2]), all.means[i]);
    ASSERT_EQ(f[3], all.means[i].x() < 0.5f ? 2.0f : 1.0f);
  }

  LocalMap plain(wide_config());
  plain.insert(random_cloud(100, 0.0f, 1.0f, 12), Eigen::Vector3f::Zero());
  plain.update_features([](const TargetPoint&, float*) { FAIL() << "a map without features"; });
}

TEST(LocalMap, FeatureStorageIsCompactedAsVoxelsDrop) {
  LocalMapConfig config;
  config.radius = 1.5f;
  config.fuse = false;  // the rows hold each point's mean, which fusion would move
  LocalMap map(config);
  for (int k = 0; k < 30; ++k) {
    // Each keyframe sees a new patch 3 m from the last, so the previous one is dropped.
    const Eigen::Vector2f centre(3.0f * k, 0.0f);
    GaussianPoints patch = plane_grid(centre, 0.5f, 0.02f);
    add_attributes(&patch, static_cast<float>(k));
    map.insert(patch, Eigen::Vector3f(centre.x(), centre.y(), 0.0f));
    ASSERT_GT(map.size(), 0u);
    EXPECT_LE(map.feature_rows_stored(), 2 * map.size()) << "keyframe " << k;
    expect_attributes_match(map);
    for (const Eigen::Vector3f& p : map.points().means) ASSERT_NEAR(p.x(), centre.x(), 0.51f);
  }
  // Overlapping keyframes: some voxels stay, some drop, offsets must survive compaction.
  for (int k = 0; k < 40; ++k) {
    const Eigen::Vector2f centre(100.0f + 0.4f * k, 0.0f);
    GaussianPoints patch = plane_grid(centre, 0.8f, 0.03f);
    add_attributes(&patch, static_cast<float>(k));
    map.insert(patch, Eigen::Vector3f(centre.x(), centre.y(), 0.0f));
    EXPECT_LE(map.feature_rows_stored(), 2 * map.size()) << "keyframe " << k;
    expect_attributes_match(map);
  }
}

TEST(LocalMap, FeatureDimensionMismatchDropsFeatures) {
  LocalMap map(wide_config());
  GaussianPoints a = random_cloud(100, 0.0f, 1.0f, 6);
  add_attributes(&a, 1.0f);
  map.insert(a, Eigen::Vector3f::Zero());
  EXPECT_EQ(map.feature_dim(), 4);
  GaussianPoints b = random_cloud(100, 0.0f, 1.0f, 7);
  b.feature_dim = 2;
  b.features.assign(200, 0.5f);
  map.insert(b, Eigen::Vector3f::Zero());
  EXPECT_EQ(map.feature_dim(), 0);
  EXPECT_EQ(map.feature_rows_stored(), 0u);
  EXPECT_EQ(map.size(), 200u);
  EXPECT_FALSE(map.points().has_features());
  // Features do not come back while the map holds featureless points ...
  map.insert(a, Eigen::Vector3f::Zero());
  EXPECT_EQ(map.feature_dim(), 0);
  // ... but an emptied map adopts the next insertion's dimension.
  map.clear();
  EXPECT_EQ(map.size(), 0u);
  map.insert(b, Eigen::Vector3f::Zero());
  EXPECT_EQ(map.feature_dim(), 2);
}

GaussianPoints one_point(const Eigen::Vector3f& mean, const Eigen::Matrix3f& covariance) {
  GaussianPoints cloud;
  cloud.means = {mean};
  cloud.covariances = {covariance};
  return cloud;
}

TEST(LocalMap, ARepeatedObservationIsFusedAsTheProductOfTheGaussians) {
  LocalMapConfig config;  // min_point_distance 1 cm, fuse on
  LocalMap map(config);
  // Two discs seen from different sides: a plane z = 1 (normal sigma 1 mm) and a tilted one.
  const Eigen::Vector3f a(0.05f, 0.05f, 1.000f), b(0.052f, 0.049f, 1.006f);
  const Eigen::Matrix3f cov_a = Eigen::Vector3f(1e-2f, 1e-2f, 1e-6f).asDiagonal();
  const Eigen::Matrix3f R = Eigen::AngleAxisf(0.5f, Eigen::Vector3f::UnitX()).toRotationMatrix();
  const Eigen::Matrix3f cov_b = R * Eigen::Vector3f(4e-2f, 4e-2f, 4e-6f).asDiagonal() * R.transpose();
  ASSERT_EQ(map.insert(one_point(a, cov_a), Eigen::Vector3f::Zero()), 1u);
  EXPECT_EQ(map.insert(one_point(b, cov_b), Eigen::Vector3f::Zero()), 0u);  // fused, not added
  ASSERT_EQ(map.size(), 1u);
  // The product by hand, in double.
  const Eigen::Matrix3d ia = cov_a.cast<double>().inverse(), ib = cov_b.cast<double>().inverse();
  const Eigen::Matrix3d cov = (ia + ib).inverse();
  const Eigen::Vector3d mean = cov * (ia * a.cast<double>() + ib * b.cast<double>());
  const GaussianPoints stored = map.points();
  EXPECT_LT((stored.means[0].cast<double>() - mean).norm(), 1e-6);  // metres
  EXPECT_LT((stored.covariances[0].cast<double>() - cov).norm(), 1e-3 * cov.norm());
  // The fused point is more certain along both discs' normals than either observation.
  const Eigen::Vector3d n_b = R.col(2).cast<double>();
  EXPECT_LT(n_b.dot(cov * n_b), n_b.dot(cov_b.cast<double>() * n_b));
  EXPECT_LT(cov(2, 2), cov_a(2, 2));
  // Found where it now is, exactly.
  float d2 = -1.0f;
  ASSERT_NE(map.nearest(stored.means[0], 0.0f, &d2), nullptr);
  EXPECT_EQ(d2, 0.0f);

  // Fusion off: the first observation stays as it was.
  config.fuse = false;
  LocalMap first(config);
  first.insert(one_point(a, cov_a), Eigen::Vector3f::Zero());
  first.insert(one_point(b, cov_b), Eigen::Vector3f::Zero());
  ASSERT_EQ(first.size(), 1u);
  EXPECT_EQ(first.points().means[0], a);
  EXPECT_EQ(first.points().covariances[0], cov_a);

  // Stored as a map Gaussian that holds its mean: the same product's covariance, the mean
  // where it was; inserted as an observation (no origins, or PointOrigin::observation), fused.
  LocalMap held(LocalMapConfig{});
  held.insert(one_point(a, cov_a), Eigen::Vector3f::Zero(), {PointOrigin::map_gaussian});
  held.insert(one_point(b, cov_b), Eigen::Vector3f::Zero());
  ASSERT_EQ(held.size(), 1u);
  EXPECT_EQ(held.points().means[0], a);
  EXPECT_LT((held.points().covariances[0].cast<double>() - cov).norm(), 1e-3 * cov.norm());
  LocalMap moved(LocalMapConfig{});
  moved.insert(one_point(a, cov_a), Eigen::Vector3f::Zero(), {PointOrigin::observation});
  moved.insert(one_point(b, cov_b), Eigen::Vector3f::Zero());
  EXPECT_LT((moved.points().means[0].cast<double>() - mean).norm(), 1e-6);  // metres
}

TEST(LocalMap, AFusedPointThatCrossesIntoTheNextVoxelMovesThere) {
  LocalMapConfig config;
  config.radius = 100.0f;
  LocalMap map(config);
  // Stored at x = 9.95 cm (voxel 0), observed again at 10.4 cm with 100x the certainty: the
  // fused mean (~10.4 cm) lies in voxel 1, with its feature row and opacity.
  const Eigen::Matrix3f loose = Eigen::Matrix3f::Identity() * 1e-4f;
  GaussianPoints first = one_point(Eigen::Vector3f(0.0995f, 0.05f, 0.05f), loose);
  first.means.push_back(Eigen::Vector3f(0.03f, 0.05f, 0.05f));  // a neighbour in voxel 0
  first.covariances.push_back(loose);
  add_attributes(&first, 7.0f);
  ASSERT_EQ(map.insert(first, Eigen::Vector3f::Zero()), 2u);
  GaussianPoints again = one_point(Eigen::Vector3f(0.104f, 0.05f, 0.05f), loose * 0.01f);
  add_attributes(&again, 9.0f);
  EXPECT_EQ(map.insert(again, Eigen::Vector3f::Zero()), 0u);
  ASSERT_EQ(map.size(), 2u);
  EXPECT_EQ(map.voxel_count(), 2u);
  const Eigen::Vector3f fused = (Eigen::Vector3f(0.0995f, 0.05f, 0.05f) + 100.0f * again.means[0]) / 101.0f;
  float d2 = -1.0f;
  const TargetPoint* p = map.nearest(Eigen::Vector3f(0.15f, 0.05f, 0.05f), 0.1f, &d2);
  ASSERT_NE(p, nullptr);
  EXPECT_NEAR(p->mean.x(), fused.x(), 1e-6f);
  EXPECT_NEAR(p->covariance(0, 0), 1e-4f / 101.0f, 1e-9f);
  EXPECT_EQ(map.feature(*p)[3], 7.0f);  // the stored point's feature row goes with it
  EXPECT_FLOAT_EQ(p->opacity, 0.07f);
  // The point left behind in voxel 0 is still found, and nothing else is.
  const TargetPoint* q = map.nearest(Eigen::Vector3f(0.0f, 0.05f, 0.05f), 0.05f);
  ASSERT_NE(q, nullptr);
  EXPECT_EQ(q->mean.x(), 0.03f);
  EXPECT_EQ(map.nearest(Eigen::Vector3f(0.0995f, 0.05f, 0.05f), 0.004f), nullptr);
}

TEST(LocalMap, NearestEqualsBruteForceAfterFusion) {
  LocalMapConfig config;
  config.radius = 100.0f;
  config.min_point_distance = 0.02f;  // many fusions, many of them across voxel faces
  LocalMap map(config);
  for (std::uint32_t k = 0; k < 6; ++k) map.insert(random_cloud(3000, 0.0f, 0.4f, 20 + k), {});
  const std::vector<Eigen::Vector3f> stored = map.points().means;
  ASSERT_EQ(stored.size(), map.size());
  const GaussianPoints queries = random_cloud(1000, -0.05f, 0.45f, 40);
  for (const Eigen::Vector3f& q : queries.means) {
    const BruteForce expected = brute_force(stored, q);
    const TargetPoint* found = map.nearest(q, 0.05f);
    if (expected.squared_distance <= 0.05f * 0.05f) {
      ASSERT_NE(found, nullptr) << q.transpose();
      EXPECT_EQ(found->mean, expected.mean);
    } else {
      EXPECT_EQ(found, nullptr);
    }
  }
}

TEST(LocalMap, ConcurrentReadersSeeTheSameAnswers) {
  LocalMap map(wide_config());
  map.insert(random_cloud(20000, -1.0f, 1.0f, 8), Eigen::Vector3f::Zero());
  const GaussianPoints queries = random_cloud(20000, -1.0f, 1.0f, 9);
  std::vector<const TargetPoint*> serial(queries.size());
  for (std::size_t i = 0; i < queries.size(); ++i) serial[i] = map.nearest(queries.means[i], 0.08f);
  std::vector<const TargetPoint*> a(queries.size()), b(queries.size());
  const auto run = [&](std::vector<const TargetPoint*>* out) {
    for (std::size_t i = 0; i < queries.size(); ++i)
      (*out)[i] = map.nearest(queries.means[i], 0.08f);
  };
  std::thread ta(run, &a), tb(run, &b);
  ta.join();
  tb.join();
  EXPECT_EQ(a, serial);
  EXPECT_EQ(b, serial);
}

TEST(LocalMap, ConfigValidationNamesTheField) {
  const auto message = [](const LocalMapConfig& c) {
    std::string why;
    EXPECT_FALSE(c.is_valid(&why));
    return why;
  };
  EXPECT_TRUE(LocalMapConfig{}.is_valid());
  LocalMapConfig c;
  c.voxel_size = 0.0f;
  EXPECT_NE(message(c).find("voxel_size"), std::string::npos);
  c = {};
  c.min_point_distance = 0.2f;
  EXPECT_NE(message(c).find("min_point_distance"), std::string::npos);
  c = {};
  c.max_points_per_voxel = 0;
  EXPECT_NE(message(c).find("max_points_per_voxel"), std::string::npos);
  c = {};
  c.radius = std::numeric_limits<float>::infinity();
  EXPECT_NE(message(c).find("radius"), std::string::npos);
}

// nearest() throughput, one thread. Opt-in:
//   fslam_core_tests --gtest_also_run_disabled_tests --gtest_filter='*LocalMapTiming*'
// The fastest of 20 passes over the queries (a frame's GICP iterations): on a shared machine
// the minimum is the estimate least disturbed by other processes.
double time_queries_ns(const LocalMap& map, const std::vector<Eigen::Vector3f>& queries,
                       float max_distance, std::size_t* hits) {
  double best_ns = std::numeric_limits<double>::infinity();
  for (int pass = 0; pass < 20; ++pass) {
    *hits = 0;
    const auto start = std::chrono::steady_clock::now();
    for (const Eigen::Vector3f& q : queries) *hits += map.nearest(q, max_distance) ? 1 : 0;
    best_ns = std::min(
        best_ns,
        std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - start).count());
  }
  return best_ns / static_cast<double>(queries.size());
}

TEST(DISABLED_LocalMapTiming, NearestRandomCloud) {
  LocalMap map(LocalMapConfig{});
  map.insert(random_cloud(200000, -2.0f, 2.0f, 10), Eigen::Vector3f::Zero());
  const GaussianPoints queries = random_cloud(20000, -2.0f, 2.0f, 11);
  std::size_t hits = 0;
  const double ns = time_queries_ns(map, queries.means, 0.08f, &hits);
  std::cout << "random: " << map.size() << " points in " << map.voxel_count() << " voxels, " << ns
            << " ns/query, " << hits << " / " << queries.size() << " hits\n";
}

TEST(DISABLED_LocalMapTiming, NearestRedkitchen) {
  FSLAM_REQUIRE_DATA("redkitchen");
  std::string why;
  const auto dataset = open_dataset((test::data_dir() / "redkitchen").string(), {}, &why);
  ASSERT_TRUE(dataset) << why;
  LocalMap map(LocalMapConfig{});
  const PreprocessConfig config;
  double insert_ms = 0.0;
  for (const std::size_t i : {0u, 20u, 40u, 60u, 80u, 100u}) {  // keyframes
    RgbdFrame frame;
    ASSERT_TRUE(dataset->load(i, &frame, &why)) << why;
    GaussianPoints points;
    ASSERT_TRUE(preprocess_frame(frame, config, &points, nullptr, &why)) << why;
    const Eigen::Isometry3d& T = *frame.T_world_camera_gt;
    const GaussianPoints world = transformed(points, T);
    const auto start = std::chrono::steady_clock::now();
    map.insert(world, T.translation().cast<float>());
    insert_ms +=
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  }
  RgbdFrame frame;
  ASSERT_TRUE(dataset->load(105, &frame, &why)) << why;
  GaussianPoints points;
  ASSERT_TRUE(preprocess_frame(frame, config, &points, nullptr, &why)) << why;
  const GaussianPoints queries = transformed(points, *frame.T_world_camera_gt);
  std::size_t hits = 0;
  const double ns = time_queries_ns(map, queries.means, 0.08f, &hits);
  std::cout << "redkitchen: " << map.size() << " points in " << map.voxel_count() << " voxels, "
            << ns << " ns/query, " << hits << " / " << queries.size() << " hits; insert "
            << insert_ms / 6.0 << " ms per keyframe\n";
}

}  // namespace
}  // namespace fslam::core

// The GICP target made from the Gaussian map (map_target.hpp; paper eq. gicp_sets, feat_gicp):
// which Gaussians become target points and with what covariance, opacity and features; and the
// tracker registering against such a target while the keyframes the "mapper" has not mapped yet
// bridge the gap (Tracker::set_map_target).
#include "fslam/core/tracking/map_target.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <memory>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "fslam/core/eval/ate.hpp"
#include "fslam/core/math/splat_math.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"
#include "fslam/core/tracking/tracker.hpp"

namespace fslam::core {
namespace {

float logit_of(float p) { return std::log(p / (1.0f - p)); }

// A Gaussian at `mean`, rotated by `q` (w, x, y, z), scales s (metres), opacity p, feature value f.
void add(GaussianMap* map, Eigen::Vector3f mean, const float q[4], Eigen::Vector3f s, float p, float f) {
  const float log_s[3] = {std::log(s.x()), std::log(s.y()), std::log(s.z())};
  std::vector<float> sh(static_cast<std::size_t>(map->sh_per_gaussian()), 0.0f);
  std::vector<float> feature(static_cast<std::size_t>(map->feature_dim), f);
  map->push_back(mean.data(), q, log_s, logit_of(p), sh.data(), feature.data(), 0.0f);
}

// Renders the room at `gt` as frame `id` and tracks it; the prepared source stays in `source`.
void track_view(Tracker* tracker, const SyntheticRoom& room, const PinholeCamera& camera,
                const StampedPose& gt, std::int64_t id, PreparedSource* source, TrackingResult* result) {
  RgbdFrame frame;
  frame.id = id;
  frame.timestamp = gt.timestamp;
  const SynthView view = render_view(room, camera, gt.T_world_camera);
  frame.colour = view.colour;
  frame.depth = view.depth;
  frame.camera = camera;
  std::string why;
  ASSERT_TRUE(tracker->preprocess(frame, nullptr, source, &why)) << why;
  ASSERT_TRUE(tracker->track_prepared(frame, *source, result, &why, nullptr)) << why;
}

TEST(MapTarget, KeepsOpaqueGaussiansInRangeMostOpaqueFirstWithTheirFeatures) {
  GaussianMap map;
  map.feature_dim = 4;
  const float identity[4] = {1, 0, 0, 0};
  add(&map, {0.0f, 0.0f, 1.0f}, identity, {0.02f, 0.02f, 0.002f}, 0.5f, 1.0f);
  add(&map, {0.1f, 0.0f, 1.0f}, identity, {0.02f, 0.02f, 0.002f}, 0.95f, 2.0f);
  add(&map, {0.2f, 0.0f, 1.0f}, identity, {0.02f, 0.02f, 0.002f}, 0.05f, 3.0f);  // too transparent
  add(&map, {5.0f, 0.0f, 1.0f}, identity, {0.02f, 0.02f, 0.002f}, 0.9f, 4.0f);   // out of range
  MapTargetConfig config;
  PreprocessConfig preprocess;
  preprocess.depth_noise.enabled = false;  // covariances as the shape alone
  const GaussianPoints target = map_target_points(map, Eigen::Vector3f::Zero(), 2.0f, config, preprocess);
  ASSERT_EQ(target.size(), 2u);
  EXPECT_NEAR(target.means[0].x(), 0.1f, 1e-6f);  // the more opaque first
  EXPECT_NEAR(target.opacities[0], 0.95f, 1e-5f);
  EXPECT_NEAR(target.opacities[1], 0.5f, 1e-5f);
  ASSERT_EQ(target.feature_dim, 4);
  ASSERT_EQ(target.features.size(), 8u);
  EXPECT_FLOAT_EQ(target.features[0], 2.0f);
  EXPECT_FLOAT_EQ(target.features[4], 1.0f);
}

TEST(MapTarget, CovarianceIsAUnitDiscAcrossTheGaussiansThinnestAxis) {
  GaussianMap map;
  map.feature_dim = 0;
  // Thinnest axis = local z, rotated 90 degrees about x: the disc's normal is world -y or +y.
  const Eigen::Quaternionf rot(Eigen::AngleAxisf(static_cast<float>(M_PI / 2), Eigen::Vector3f::UnitX()));
  const float q[4] = {rot.w(), rot.x(), rot.y(), rot.z()};
  add(&map, {0.0f, 0.0f, 1.0f}, q, {0.03f, 0.01f, 0.001f}, 0.9f, 0.0f);
  PreprocessConfig preprocess;
  preprocess.depth_noise.enabled = false;
  for (bool unit : {true, false}) {
    MapTargetConfig config;
    config.covariance = unit ? MapTargetCovariance::disc : MapTargetCovariance::shape;
    const GaussianPoints target = map_target_points(map, Eigen::Vector3f::Zero(), 2.0f, config, preprocess);
    ASSERT_EQ(target.size(), 1u);
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> eig(target.covariances[0]);
    EXPECT_NEAR(std::abs(eig.eigenvectors().col(0).y()), 1.0f, 1e-4f) << "unit discs " << unit;
    // Across: plane_epsilon, or the Gaussian's own (0.001 / 0.03)^2 where that is thicker.
    const float across = unit ? preprocess.covariance.plane_epsilon
                              : std::max(preprocess.covariance.plane_epsilon, (0.001f / 0.03f) * (0.001f / 0.03f));
    EXPECT_NEAR(eig.eigenvalues()(0), across, 1e-6f) << "unit discs " << unit;
    EXPECT_NEAR(eig.eigenvalues()(2), 1.0f, 1e-5f);
    // In-plane: equal with unit discs; the 3:1 elongation (9:1 in variance) kept without.
    EXPECT_NEAR(eig.eigenvalues()(1), unit ? 1.0f : 1.0f / 9.0f, 1e-4f) << "unit discs " << unit;
  }
}

// weight_by_observations: a point two depth views see weighs as two observations (covariance
// halved); one hidden behind a nearer surface in a view, or outside it, is not counted there.
TEST(MapTarget, ObservationWeightCountsTheViewsWhoseDepthSeesThePoint) {
  PinholeCamera camera;
  camera.fx = camera.fy = 100.0;
  camera.cx = camera.cy = 31.5;
  camera.width = camera.height = 64;
  // Two cameras at the origin and 10 cm to the side, both looking down +z at a wall 2 m away;
  // in the second, the left half of the image sees a box 1 m away instead.
  ObservingDepth a{camera, Eigen::Isometry3d::Identity(), cv::Mat(64, 64, CV_32FC1, cv::Scalar(2.0f))};
  ObservingDepth b{camera, Eigen::Isometry3d(Eigen::Translation3d(0.1, 0.0, 0.0)),
                   cv::Mat(64, 64, CV_32FC1, cv::Scalar(2.0f))};
  b.depth.colRange(0, 32).setTo(cv::Scalar(1.0f));
  GaussianPoints points;
  const Eigen::Matrix3f cov = Eigen::Vector3f(1.0f, 1.0f, 0.001f).asDiagonal();
  points.means = {{0.4f, 0.0f, 2.0f},    // right of both images' centres: seen by both
                  {-0.1f, 0.0f, 2.0f},   // behind the box in b: seen by a only
                  {0.15f, 0.0f, 2.05f},  // 5 cm off both depths: seen by neither at 3 cm
                  {2.0f, 0.0f, 2.0f}};   // outside both images
  points.covariances.assign(points.means.size(), cov);
  points.opacities.assign(points.means.size(), 1.0f);
  EXPECT_EQ(weight_by_observations({a, b}, 0.03f, &points), (std::vector<int>{2, 1, 0, 0}));
  EXPECT_TRUE(points.covariances[0].isApprox(cov / 2.0f));
  EXPECT_TRUE(points.covariances[1].isApprox(cov));
  EXPECT_TRUE(points.covariances[2].isApprox(cov));
  EXPECT_TRUE(points.covariances[3].isApprox(cov));
  // With a gate that takes the 5 cm, the third point is seen by both.
  points.covariances.assign(points.means.size(), cov);
  weight_by_observations({a, b}, 0.08f, &points);
  EXPECT_TRUE(points.covariances[2].isApprox(cov / 2.0f));
}

// covariance: neighbours ignores each Gaussian's own shape: Gaussians on the plane z = 1 whose
// thinnest axes all lie in the plane get the plane's disc (normal z) from where their means lie,
// and an isolated Gaussian (fewer neighbours than min_neighbours) is no target.
TEST(MapTarget, NeighbourCovarianceIsThePlaneOfTheMeansNotTheGaussiansShape) {
  GaussianMap map;
  map.feature_dim = 0;
  const float q[4] = {1.0f, 0.0f, 0.0f, 0.0f};
  for (int y = 0; y < 5; ++y)
    for (int x = 0; x < 5; ++x)  // thinnest axis local x: in the plane, the wrong normal
      add(&map, {0.01f * static_cast<float>(x), 0.01f * static_cast<float>(y), 1.0f}, q,
          {0.001f, 0.01f, 0.01f}, 0.9f, 0.0f);
  add(&map, {1.0f, 1.0f, 1.0f}, q, {0.001f, 0.01f, 0.01f}, 0.9f, 0.0f);  // 1.4 m from the rest
  PreprocessConfig preprocess;
  preprocess.depth_noise.enabled = false;
  MapTargetConfig config;
  const GaussianPoints discs = map_target_points(map, Eigen::Vector3f::Zero(), 3.0f, config, preprocess);
  ASSERT_EQ(discs.size(), 26u);
  config.covariance = MapTargetCovariance::neighbours;
  const GaussianPoints target = map_target_points(map, Eigen::Vector3f::Zero(), 3.0f, config, preprocess);
  ASSERT_EQ(target.size(), 25u);
  for (std::size_t i = 0; i < target.size(); ++i) {
    EXPECT_LT(target.means[i].x(), 0.5f) << "the isolated Gaussian was kept";
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> eig(target.covariances[i]);
    EXPECT_NEAR(std::abs(eig.eigenvectors().col(0).z()), 1.0f, 1e-4f) << i;
    EXPECT_NEAR(eig.eigenvalues()(0), preprocess.covariance.plane_epsilon, 1e-6f) << i;
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> own(discs.covariances[i]);
    EXPECT_NEAR(std::abs(own.eigenvectors().col(0).x()), 1.0f, 1e-4f) << "disc normal is the thinnest axis";
  }
}

// A Gaussian-target tracker whose two frames are both keyframes.
TrackerConfig bridge_test_config() {
  TrackerConfig config;
  config.preprocess.stride = 2;
  config.target = TrackingTarget::gaussians;
  config.keyframe.translation = 1e-6;  // both frames are keyframes
  config.keyframe.rotation_deg = 1e-6;
  return config;
}

// Two views of the synthetic room tracked as keyframes 7 and 8 by a Gaussian-target tracker with
// no map version yet (each keyframe's world points in `raw`), and a target that has the left half
// of the first keyframe's surface (x < median, world), 2 mm off and with ten times the
// covariance, made as SlamPipeline makes targets (no fusing).
void track_two_keyframes_and_make_half_target(Tracker* tracker, const TrackerConfig& config,
                                              std::vector<GaussianPoints>* raw, LocalMap* target) {
  const SyntheticRoom room = make_room(1);
  SynthOptions options;
  options.frames = 2;
  const Trajectory trajectory = make_trajectory(room, options);
  const PinholeCamera camera = synth_default_camera().scaled(0.25);
  tracker->set_initial_pose(trajectory[0].T_world_camera);
  for (std::size_t i = 0; i < 2; ++i) {
    PreparedSource source;
    TrackingResult result;
    ASSERT_NO_FATAL_FAILURE(
        track_view(tracker, room, camera, trajectory[i], static_cast<std::int64_t>(7 + i), &source, &result));
    ASSERT_TRUE(result.keyframe) << "frame " << i;
    raw->push_back(transformed(source.points, result.T_world_camera));
  }
  const GaussianPoints& first = raw->front();
  ASSERT_GT(first.size(), 100u);
  std::vector<float> xs;
  for (const Eigen::Vector3f& m : first.means) xs.push_back(m.x());
  std::nth_element(xs.begin(), xs.begin() + static_cast<std::ptrdiff_t>(xs.size() / 2), xs.end());
  const float median_x = xs[xs.size() / 2];
  GaussianPoints half;
  for (std::size_t i = 0; i < first.size(); ++i) {
    if (first.means[i].x() >= median_x) continue;
    half.means.push_back(first.means[i] + Eigen::Vector3f(0.0f, 0.0f, 0.002f));
    half.covariances.push_back(10.0f * first.covariances[i]);
  }
  LocalMapConfig local = config.local_map;
  local.fuse = false;
  *target = LocalMap(local);
  target->insert(half, trajectory[0].T_world_camera.translation().cast<float>(),
                 std::vector<PointOrigin>(half.size(), PointOrigin::map_gaussian));
}

// The bridge fuses the keyframes into the target copy as the point map fuses re-observations:
// a keyframe point within min_point_distance of a map Gaussian adds its information to that
// Gaussian (as the mapper's observation weight will count the keyframe once it is mapped) and
// never moves its mean; the points the target lacks are added and fused among themselves.
TEST(MapTarget, BridgeCountsReobservedGaussiansAndFillsWhatTheTargetLacks) {
  const TrackerConfig config = bridge_test_config();
  Tracker tracker(config);
  std::vector<GaussianPoints> raw;  // each keyframe's points in the world, as the tracker got them
  LocalMap target;
  ASSERT_NO_FATAL_FAILURE(track_two_keyframes_and_make_half_target(&tracker, config, &raw, &target));
  const GaussianPoints& first = raw.front();
  const LocalMapConfig& local = config.local_map;
  const GaussianPoints target_points = target.points();
  tracker.set_map_target(target, 6);  // neither keyframe is in this version: both bridged

  // Every Gaussian is where the target had it, and the re-observed ones carry more information
  // (each keyframe sees this surface 2 mm from a Gaussian: the first keyframe's point divides
  // the tenfold covariance by about 11 in the normal's direction) ...
  const LocalMap& bridged = tracker.local_map();
  std::size_t reobserved = 0;
  for (std::size_t i = 0; i < target_points.size(); ++i) {
    const TargetPoint* p = bridged.nearest(target_points.means[i], 1e-5f);
    ASSERT_NE(p, nullptr) << "target point " << i << " moved";
    EXPECT_EQ(p->origin, PointOrigin::map_gaussian) << "target point " << i;
    const float before = target_points.covariances[i].trace(), after = p->covariance.trace();
    EXPECT_LE(after, before * (1.0f + 1e-4f)) << "target point " << i;
    reobserved += after < 0.5f * before;
  }
  EXPECT_GT(reobserved, target_points.size() / 2) << reobserved << " of " << target_points.size();
  // ... and every other point is the keyframes' (none a Gaussian), where the target has
  // nothing within min_point_distance, with the second keyframe's re-observations of the
  // first's surface fused into it (their means averaged), not dropped.
  const auto is_raw = [&](const Eigen::Vector3f& m) {
    for (const GaussianPoints& kf : raw)
      for (const Eigen::Vector3f& r : kf.means)
        if ((r - m).norm() < 1e-6f) return true;
    return false;
  };
  const GaussianPoints all = bridged.points();
  std::size_t added = 0, fused = 0;
  for (std::size_t i = 0; i < all.size(); ++i) {
    if (target.nearest(all.means[i], 1e-5f) != nullptr) continue;  // a target point
    ++added;
    EXPECT_EQ(bridged.nearest(all.means[i], 1e-5f)->origin, PointOrigin::observation) << "bridge point " << i;
    EXPECT_EQ(target.nearest(all.means[i], 0.5f * local.min_point_distance), nullptr)
        << "bridge point " << i << " on a target point";
    fused += !is_raw(all.means[i]);
  }
  EXPECT_EQ(all.size(), target_points.size() + added);
  EXPECT_GT(added, first.size() / 3) << "the right half is bridged";
  EXPECT_GT(fused, added / 4) << fused << " of " << added << " bridge points fused";
}

// The mapping thread bridges the keyframes it knows of into the target it builds
// (SlamPipeline::publish_map_target) and the tracker only the newer ones: whichever side bridges
// a keyframe, the tracker registers against the same points, each keyframe fused once.
TEST(MapTarget, BridgingSplitBetweenBuilderAndTrackerGivesTheSameTarget) {
  const TrackerConfig config = bridge_test_config();
  const auto points_of = [](const LocalMap& map) {
    GaussianPoints p = map.points();
    std::vector<std::size_t> order(p.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
      return std::lexicographical_compare(p.means[a].data(), p.means[a].data() + 3, p.means[b].data(),
                                          p.means[b].data() + 3);
    });
    std::vector<std::pair<Eigen::Vector3f, Eigen::Matrix3f>> sorted;
    for (std::size_t i : order) sorted.emplace_back(p.means[i], p.covariances[i]);
    return sorted;
  };
  const auto expect_same = [](const auto& a, const auto& b, const char* what) {
    ASSERT_EQ(a.size(), b.size()) << what;
    for (std::size_t i = 0; i < a.size(); ++i) {
      EXPECT_LT((a[i].first - b[i].first).norm(), 1e-7f) << what << ": point " << i;
      EXPECT_LT((a[i].second - b[i].second).norm(), 1e-7f * b[i].second.norm()) << what << ": point " << i;
    }
  };

  Tracker tracker(config);
  std::vector<GaussianPoints> raw;
  LocalMap target;
  ASSERT_NO_FATAL_FAILURE(track_two_keyframes_and_make_half_target(&tracker, config, &raw, &target));
  const std::deque<KeyframePoints> unmapped = tracker.unmapped_keyframes();
  ASSERT_EQ(unmapped.size(), 2u);
  ASSERT_EQ(unmapped[0].frame_id, 7);
  ASSERT_EQ(unmapped[1].frame_id, 8);

  tracker.set_map_target(target, 6);  // the tracker bridges both keyframes
  const auto by_tracker = points_of(tracker.local_map());
  ASSERT_GT(by_tracker.size(), target.size());

  // The builder bridges both, or only the first (it had not seen the second yet).
  for (const std::int64_t builder_through : {std::int64_t{8}, std::int64_t{7}}) {
    LocalMap built = target;
    built.set_fuse(config.local_map.fuse);
    std::deque<KeyframePoints> known;
    for (const KeyframePoints& kf : unmapped)
      if (kf.frame_id <= builder_through) known.push_back(kf);
    EXPECT_EQ(bridge_keyframes(known, 6, &built), builder_through);
    tracker.set_map_target(built, 6, builder_through);
    expect_same(points_of(tracker.local_map()), by_tracker, builder_through == 8 ? "builder both" : "builder first");
  }

  // A keyframe bridged twice would count twice: the tracker must not re-bridge what the builder did.
  LocalMap built = target;
  built.set_fuse(config.local_map.fuse);
  bridge_keyframes(unmapped, 6, &built);
  tracker.set_map_target(built, 6);
  const auto twice = points_of(tracker.local_map());
  double trace_twice = 0.0, trace_once = 0.0;
  for (const auto& p : twice) trace_twice += p.second.trace();
  for (const auto& p : by_tracker) trace_once += p.second.trace();
  EXPECT_LT(trace_twice, 0.9 * trace_once) << "fusing each keyframe twice shrinks the covariances";
  // Nothing newer than after_id: nothing inserted.
  LocalMap untouched = target;
  EXPECT_EQ(bridge_keyframes(unmapped, 8, &untouched), 8);
  EXPECT_EQ(untouched.size(), target.size());
}

// The tracker follows the synthetic room against targets made from a Gaussian map that a stand-in
// mapper builds from every keyframe's observed surface, published one keyframe late (the bridge:
// the keyframe the map does not contain yet is added from the tracker's own points).
TEST(MapTarget, TrackerFollowsTheRoomAgainstAMapPublishedOneKeyframeLate) {
  const SyntheticRoom room = make_room(1);
  SynthOptions options;
  options.frames = 40;
  const Trajectory trajectory = make_trajectory(room, options);
  const PinholeCamera camera = synth_default_camera().scaled(0.5);
  TrackerConfig config;
  config.preprocess.stride = 2;
  config.target = TrackingTarget::gaussians;
  Tracker tracker(config);
  GaussianMap map;
  map.feature_dim = 0;
  std::vector<std::pair<std::int64_t, GaussianPoints>> pending;  // keyframes "being mapped"
  Trajectory estimate;
  std::size_t keyframes = 0;
  for (std::size_t i = 0; i < trajectory.size(); ++i) {
    const StampedPose& gt = trajectory[i];
    if (i == 0) tracker.set_initial_pose(gt.T_world_camera);
    PreparedSource source;
    TrackingResult result;
    ASSERT_NO_FATAL_FAILURE(track_view(&tracker, room, camera, gt, static_cast<std::int64_t>(i), &source, &result));
    ASSERT_NE(result.state, TrackingState::lost) << "frame " << i << ": " << result.message;
    estimate.push_back({gt.timestamp, result.T_world_camera});
    if (!result.keyframe) continue;
    ++keyframes;
    // The previous keyframe is mapped now: its surface enters the map as discs, and the target
    // made from the map replaces the tracker's (the new keyframe stays in the bridge).
    if (!pending.empty()) {
      const auto& [id, points] = pending.back();
      for (std::size_t k = 0; k < points.size(); ++k) {
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> eig(points.covariances[k]);
        Eigen::Matrix3f R = eig.eigenvectors().rowwise().reverse();  // thinnest axis last (z)
        if (R.determinant() < 0) R.col(0) = -R.col(0);
        const Eigen::Quaternionf q(R);
        const float rotation[4] = {q.w(), q.x(), q.y(), q.z()};
        add(&map, points.means[k], rotation, {0.01f, 0.01f, 0.001f}, 0.9f, 0.0f);
      }
      LocalMapConfig local = config.local_map;
      local.fuse = false;
      LocalMap target(local);
      const Eigen::Vector3f centre = result.T_world_camera.translation().cast<float>();
      const GaussianPoints discs = map_target_points(map, centre, local.radius, config.map_target, config.preprocess);
      target.insert(discs, centre, std::vector<PointOrigin>(discs.size(), PointOrigin::map_gaussian));
      tracker.set_map_target(target, id);
    }
    pending.emplace_back(static_cast<std::int64_t>(i), transformed(source.points, result.T_world_camera));
  }
  EXPECT_GE(keyframes, 3u) << "the map target was replaced at least twice";
  AteResult ate;
  std::string why;
  ASSERT_TRUE(compute_ate(trajectory, estimate, AteConfig{}, &ate, &why)) << why;
  EXPECT_LT(ate.rmse, 0.005);  // metres, exact synthetic depth (as against the point map)
}

}  // namespace
}  // namespace fslam::core

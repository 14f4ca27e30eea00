#include "fslam/core/pipeline/loop_closure.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>

#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/error.hpp"
#include "fslam/core/pipeline/sequence_run.hpp"
#include "fslam/core/tracking/gicp_impl.hpp"
#include "fslam/core/tracking/kdtree_target.hpp"

namespace fslam::core {

bool LoopClosureConfig::is_valid(std::string* why) const {
  if (candidates < 1) return fail(why, "loop closure: candidates must be >= 1");
  if (!(min_verified_inlier_ratio >= 0.0 && min_verified_inlier_ratio <= 1.0))
    return fail(why, "loop closure: min_verified_inlier_ratio must be in [0, 1]");
  if (verification_points < 100) return fail(why, "loop closure: verification_points must be >= 100");
  if (max_keyframes < 2) return fail(why, "loop closure: max_keyframes must be >= 2");
  if (!(odometry_translation_sigma > 0.0 && odometry_rotation_sigma > 0.0 && loop_translation_sigma > 0.0 &&
        loop_rotation_sigma > 0.0))
    return fail(why, "loop closure: sigmas must be > 0");
  return graph.is_valid(why);
}

namespace {

// Every k-th point of `points` (means, covariances, opacities; no features), so that at most
// `limit` remain: what loop closure keeps of a keyframe to verify later revisits against.
GaussianPoints subsample_points(const GaussianPoints& points, std::size_t limit) {
  const std::size_t step = points.size() <= limit ? 1 : (points.size() + limit - 1) / limit;
  GaussianPoints out;
  out.reserve(points.size() / step + 1);
  for (std::size_t i = 0; i < points.size(); i += step) {
    out.means.push_back(points.means[i]);
    out.covariances.push_back(points.covariances[i]);
    if (points.has_opacities()) out.opacities.push_back(points.opacities[i]);
  }
  return out;
}

// The closer's place index keeps every keyframe: its ids are node indices, and a revisit is
// exactly what it looks for.
RelocaliserConfig every_keyframe(RelocaliserConfig config) {
  config.revisit_translation = 0.0;
  config.revisit_rotation_deg = 0.0;
  return config;
}

}  // namespace

LoopCloser::LoopCloser(const LoopClosureConfig& config, const TrackerConfig& tracker_config)
    : config_(config), tracker_config_(tracker_config), places_(every_keyframe(tracker_config.relocalisation)) {}

std::size_t LoopCloser::index_at_or_before(std::int64_t id) const {
  const auto it = std::upper_bound(nodes_.begin(), nodes_.end(), id,
                                   [](std::int64_t v, const Node& n) { return v < n.id; });
  return it == nodes_.begin() ? nodes_.size() : static_cast<std::size_t>(it - nodes_.begin()) - 1;
}

Eigen::Isometry3d LoopCloser::correction(std::int64_t id) const {
  const std::size_t i = index_at_or_before(id);
  if (i == nodes_.size()) return Eigen::Isometry3d::Identity();
  return nodes_[i].T_map * nodes_[i].T_odom.inverse();
}

Eigen::Isometry3d LoopCloser::newest_correction() const {
  if (nodes_.empty()) return Eigen::Isometry3d::Identity();
  return nodes_.back().T_map * nodes_.back().T_odom.inverse();
}

std::vector<std::pair<std::int64_t, Eigen::Isometry3d>> LoopCloser::corrected_poses() const {
  std::vector<std::pair<std::int64_t, Eigen::Isometry3d>> out;
  out.reserve(nodes_.size());
  for (const Node& n : nodes_) out.emplace_back(n.id, n.T_map);
  return out;
}

bool LoopCloser::add(LoopKeyframe keyframe, LoopEvent* event, std::string* why) {
  const auto t0 = std::chrono::steady_clock::now();
  *event = LoopEvent{};
  if (!nodes_.empty() && keyframe.id <= nodes_.back().id) {
    return fail(why, "loop closure: keyframe " + std::to_string(keyframe.id) + " after keyframe " +
                         std::to_string(nodes_.back().id));
  }
  if (nodes_.size() >= config_.max_keyframes) return true;
  const std::size_t n = nodes_.size();
  // Kept as a later revisit's verification target: subsampled (the inlier ratio is a fraction).
  const GaussianPoints points = subsample_points(keyframe.points, config_.verification_points);
  // The nodes far enough back are a prefix: positions grow with the node index.
  while (far_enough_ < n && nodes_[far_enough_].position + static_cast<std::int64_t>(config_.min_frame_gap) <=
                                keyframe.position)
    ++far_enough_;
  if (far_enough_ > 0 && !keyframe.description.empty()) {
    const std::vector<std::int64_t> similar =
        places_.similar_keyframes(keyframe.description, static_cast<std::size_t>(config_.candidates),
                                  static_cast<std::int64_t>(far_enough_), std::numeric_limits<std::int64_t>::max());
    for (const std::int64_t j : similar) {
      Eigen::Isometry3d T_guess;
      std::size_t inliers = 0;
      if (!places_.pose_from_keyframe(keyframe.description, j, &T_guess, &inliers)) continue;
      // Verification: this keyframe's points against the older keyframe's, from the guess (both in
      // the tracker's world, so that the edge is independent of earlier corrections).
      const Node& older = nodes_[static_cast<std::size_t>(j)];
      KdTreeTarget target;
      if (!target.build(older.points_odom)) continue;
      const GicpResult g = align(keyframe.points, target, T_guess, tracker_config_.gicp, SerialReduction{});
      if (!verifies(tracker_config_.relocalisation, T_guess, g, config_.min_verified_inlier_ratio)) {
        ++event->rejected;
        ++rejected_;
        continue;
      }
      PoseGraphEdge loop;
      loop.from = static_cast<std::size_t>(j);
      loop.to = n;
      loop.T_from_to = older.T_odom.inverse() * g.T_target_source;  // this keyframe in the older one's frame
      loop.translation_sigma = config_.loop_translation_sigma;
      loop.rotation_sigma = config_.loop_rotation_sigma;
      loop.loop = true;
      loop_edges_.push_back(loop);
      loops_.emplace_back(older.id, keyframe.id);
      event->older_id = older.id;
      break;  // one loop edge per keyframe
    }
  }
  Node node;
  node.id = keyframe.id;
  node.position = keyframe.position;
  node.T_odom = keyframe.T_odom_camera;
  // Until a solve moves it, a new keyframe keeps the newest correction (trusted odometry since).
  node.T_map = newest_correction() * keyframe.T_odom_camera;
  node.points_odom = transformed(points, keyframe.T_odom_camera);
  nodes_.push_back(std::move(node));
  places_.add_keyframe(static_cast<std::int64_t>(n), keyframe.T_odom_camera, std::move(keyframe.description));
  if (event->older_id >= 0) {
    if (!solve(&event->graph, why)) return false;
    event->solved = true;
  }
  event->ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

bool LoopCloser::solve(PoseGraphResult* result, std::string* why) {
  std::vector<PoseGraphEdge> edges = loop_edges_;
  for (std::size_t i = 1; i < nodes_.size(); ++i) {
    PoseGraphEdge odometry;
    odometry.from = i - 1;
    odometry.to = i;
    odometry.T_from_to = nodes_[i - 1].T_odom.inverse() * nodes_[i].T_odom;
    odometry.translation_sigma = config_.odometry_translation_sigma;
    odometry.rotation_sigma = config_.odometry_rotation_sigma;
    edges.push_back(odometry);
  }
  // From the current estimate; the first keyframe anchors the world.
  std::vector<Eigen::Isometry3d> poses;
  poses.reserve(nodes_.size());
  for (const Node& n : nodes_) poses.push_back(n.T_map);
  if (!optimise_pose_graph(&poses, edges, 0, config_.graph, result, why)) return false;
  for (std::size_t i = 0; i < nodes_.size(); ++i) nodes_[i].T_map = poses[i];
  return true;
}

bool close_loops(const Dataset& dataset, const TrackerConfig& tracker_config, const LoopClosureConfig& config,
                 SequenceTracking* tracking, LoopClosureResult* result, std::string* why,
                 const std::function<void(std::size_t, std::size_t)>& on_progress) {
  if (!config.is_valid(why) || !tracker_config.is_valid(why)) return false;
  const auto t0 = std::chrono::steady_clock::now();
  *result = LoopClosureResult{};
  SequenceTracking& t = *tracking;
  if (t.keyframe.size() != t.trajectory.size() || t.frame_index.size() != t.trajectory.size())
    return fail(why, "loop closure: the tracking record's arrays disagree in length");
  std::vector<std::size_t> nodes;  // entries of `tracking` that are keyframes
  for (std::size_t i = 0; i < t.keyframe.size(); ++i)
    if (t.keyframe[i]) nodes.push_back(i);
  result->keyframes = nodes.size();
  LoopClosureConfig unbounded = config;
  unbounded.max_keyframes = std::max(config.max_keyframes, nodes.size());
  LoopCloser closer(unbounded, tracker_config);
  const Tracker prepare(tracker_config);
  for (std::size_t n = 0; n < nodes.size(); ++n) {
    const std::size_t entry = nodes[n];
    RgbdFrame frame;
    PreparedSource prepared;
    LoopKeyframe kf;
    if (!dataset.load(t.frame_index[entry], &frame, why) || !prepare.preprocess(frame, nullptr, &prepared, why) ||
        !describe_frame(frame, tracker_config.relocalisation, tracker_config.preprocess.min_depth,
                        tracker_config.preprocess.max_depth, &kf.description, why))
      return false;
    kf.id = static_cast<std::int64_t>(n);  // node ids: entries of `nodes`
    kf.position = static_cast<std::int64_t>(t.frame_index[entry]);
    kf.T_odom_camera = t.trajectory[entry].T_world_camera;
    kf.points = std::move(prepared.points);
    LoopEvent event;
    if (!closer.add(std::move(kf), &event, why)) return false;
    if (event.solved) result->graph = event.graph;
    if (on_progress) on_progress(n + 1, nodes.size());
  }
  result->rejected = closer.rejected();
  for (const auto& [older, newer] : closer.loops())
    result->loops.emplace_back(t.frame_index[nodes[static_cast<std::size_t>(older)]],
                               t.frame_index[nodes[static_cast<std::size_t>(newer)]]);
  if (!result->loops.empty()) {
    // Every frame moves with the keyframe at or before it (frames before the first keep their pose).
    std::size_t n = 0;
    for (std::size_t i = 0; i < t.trajectory.size(); ++i) {
      while (n + 1 < nodes.size() && nodes[n + 1] <= i) ++n;
      if (nodes.empty() || nodes[n] > i) continue;
      t.trajectory[i].T_world_camera = closer.correction(static_cast<std::int64_t>(n)) * t.trajectory[i].T_world_camera;
    }
  }
  result->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

}  // namespace fslam::core

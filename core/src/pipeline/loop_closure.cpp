#include "fslam/core/pipeline/loop_closure.hpp"

#include <chrono>
#include <cmath>
#include <limits>
#include <memory>

#include "fslam/core/error.hpp"
#include "fslam/core/tracking/gicp_impl.hpp"
#include "fslam/core/tracking/kdtree_target.hpp"
#include "fslam/core/tracking/relocaliser.hpp"

namespace fslam::core {

bool LoopClosureConfig::is_valid(std::string* why) const {
  if (candidates < 1) return fail(why, "loop closure: candidates must be >= 1");
  if (!(min_verified_inlier_ratio >= 0.0 && min_verified_inlier_ratio <= 1.0))
    return fail(why, "loop closure: min_verified_inlier_ratio must be in [0, 1]");
  if (!(odometry_translation_sigma > 0.0 && odometry_rotation_sigma > 0.0 && loop_translation_sigma > 0.0 &&
        loop_rotation_sigma > 0.0))
    return fail(why, "loop closure: sigmas must be > 0");
  return graph.is_valid(why);
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

  // One pass over the keyframes: each is described, matched against the older ones outside the
  // gap, then added to the database.
  const Tracker prepare(tracker_config);
  Relocaliser places(tracker_config.relocalisation);
  std::vector<GaussianPoints> points_world(nodes.size());
  std::vector<PoseGraphEdge> edges;
  std::size_t far_enough = 0;  // nodes [0, far_enough) are min_frame_gap or more frames older
  for (std::size_t n = 0; n < nodes.size(); ++n) {
    const std::size_t entry = nodes[n];
    const Eigen::Isometry3d& T_world_k = t.trajectory[entry].T_world_camera;
    RgbdFrame frame;
    PreparedSource prepared;
    FrameDescription description;
    if (!dataset.load(t.frame_index[entry], &frame, why) || !prepare.preprocess(frame, nullptr, &prepared, why) ||
        !describe_frame(frame, tracker_config.relocalisation, tracker_config.preprocess.min_depth,
                        tracker_config.preprocess.max_depth, &description, why))
      return false;
    // Node ids in the database are node indices; the gap is in dataset positions, which grow
    // with the node index, so the nodes far enough back are a prefix.
    while (far_enough < n && t.frame_index[nodes[far_enough]] + config.min_frame_gap <= t.frame_index[entry])
      ++far_enough;
    if (far_enough > 0) {
      const std::vector<std::int64_t> similar = places.similar_keyframes(
          description, static_cast<std::size_t>(config.candidates), static_cast<std::int64_t>(far_enough),
          std::numeric_limits<std::int64_t>::max());
      for (std::int64_t j : similar) {
        Eigen::Isometry3d T_guess;
        std::size_t inliers = 0;
        if (!places.pose_from_keyframe(description, j, &T_guess, &inliers)) continue;
        // Verification: this keyframe's points against the older keyframe's, from the guess.
        KdTreeTarget target;
        if (!target.build(points_world[static_cast<std::size_t>(j)])) continue;
        const GicpResult g = align(prepared.points, target, T_guess, tracker_config.gicp, SerialReduction{});
        if (!verifies(tracker_config.relocalisation, T_guess, g, config.min_verified_inlier_ratio)) {
          ++result->rejected;
          continue;
        }
        PoseGraphEdge loop;
        loop.from = static_cast<std::size_t>(j);
        loop.to = n;
        // g.T_target_source: this keyframe in the older keyframe's (drifted) world.
        loop.T_from_to = t.trajectory[nodes[loop.from]].T_world_camera.inverse() * g.T_target_source;
        loop.translation_sigma = config.loop_translation_sigma;
        loop.rotation_sigma = config.loop_rotation_sigma;
        loop.loop = true;
        edges.push_back(loop);
        result->loops.emplace_back(t.frame_index[nodes[loop.from]], t.frame_index[entry]);
        break;  // one loop edge per keyframe
      }
    }
    points_world[n] = transformed(prepared.points, T_world_k);
    places.add_keyframe(static_cast<std::int64_t>(n), T_world_k, std::move(description));
    if (on_progress) on_progress(n + 1, nodes.size());
  }

  if (!result->loops.empty()) {
    std::vector<Eigen::Isometry3d> before, after;
    for (std::size_t n = 0; n < nodes.size(); ++n) before.push_back(t.trajectory[nodes[n]].T_world_camera);
    for (std::size_t n = 1; n < nodes.size(); ++n) {
      PoseGraphEdge odometry;
      odometry.from = n - 1;
      odometry.to = n;
      odometry.T_from_to = before[n - 1].inverse() * before[n];
      odometry.translation_sigma = config.odometry_translation_sigma;
      odometry.rotation_sigma = config.odometry_rotation_sigma;
      edges.push_back(odometry);
    }
    after = before;
    if (!optimise_pose_graph(&after, edges, 0, config.graph, &result->graph, why)) return false;
    // Every frame moves with the keyframe at or before it.
    std::size_t n = 0;
    for (std::size_t i = 0; i < t.trajectory.size(); ++i) {
      while (n + 1 < nodes.size() && nodes[n + 1] <= i) ++n;
      if (nodes.empty() || nodes[n] > i) continue;  // before the first keyframe: the world's origin
      t.trajectory[i].T_world_camera = after[n] * before[n].inverse() * t.trajectory[i].T_world_camera;
    }
  }
  result->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

}  // namespace fslam::core

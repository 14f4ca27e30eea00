// Global relocalisation (issue 20): find a frame's pose in a map with no prior pose.
//
//   place recognition: a global descriptor per keyframe (a blurred, zero-mean thumbnail of its
//     grey image, unit norm), the nearest keyframes by FLANN;
//   candidate poses: ORB keypoints with depth, matched to each candidate keyframe's (Hamming,
//     ratio test), a rigid 3D-3D transform by RANSAC over three-point Umeyama fits;
//   verification: GICP of the frame's source points against the map from each candidate pose,
//     accepted only when it converges with most of the points on the map near the candidate.
// The same place recognition is what a loop closer searches (docs/relocalisation.md).
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "fslam/core/geometry/rgbd_frame.hpp"
#include "fslam/core/tracking/gicp.hpp"
#include "fslam/core/tracking/gaussian_points.hpp"
#include "fslam/core/tracking/local_map.hpp"

namespace fslam::core {

struct RelocaliserConfig {
  bool enabled = true;               // keyframes are described and lost frames relocalised
  int orb_features = 500;            // ORB keypoints per frame
  int thumbnail_width = 32;          // global descriptor: thumbnail of this width (4:3 height)
  int candidates = 5;                // keyframes place recognition proposes
  double ratio_test = 0.8;           // Lowe's ratio on Hamming distances
  int ransac_iterations = 200;
  double inlier_distance = 0.05;     // metres between a matched pair under the candidate pose
  std::size_t min_inliers = 15;      // RANSAC inliers a candidate needs
  // Verification: GICP from the candidate against the map must keep this share of the source
  // points as inliers, and move the candidate by at most these (a far move means another basin).
  double min_verified_inlier_ratio = 0.6;
  double max_verified_translation = 0.10;  // metres
  double max_verified_rotation_deg = 10.0;
  std::size_t max_keyframes = 2000;  // described keyframes kept (oldest dropped)
  // A keyframe within both of a described keyframe's pose replaces it (the nearest), so that the
  // descriptions grow with the poses covered, not with time (a camera going back and forth);
  // 0: keep every keyframe. As the mapper's stored keyframes (mapper.revisit_*).
  double revisit_translation = 0.02;  // metres
  double revisit_rotation_deg = 2.0;
  bool is_valid(std::string* why = nullptr) const;
};

// The verification rule: GICP from T_candidate converged, kept at least min_inlier_ratio of the
// source points and moved the candidate by at most config's max_verified_* (the loop closer
// applies it between keyframes with its own ratio).
bool verifies(const RelocaliserConfig& config, const Eigen::Isometry3d& T_candidate, const GicpResult& gicp,
              double min_inlier_ratio);

// What relocalisation needs of one frame: its keypoints in the camera frame and its global
// descriptor.
struct FrameDescription {
  cv::Mat descriptors;                  // [K, 32] CV_8UC1, ORB
  std::vector<Eigen::Vector3f> points;  // [K] camera frame, metres
  std::vector<float> global;            // [thumbnail pixels], zero mean, unit norm
  bool empty() const { return points.empty(); }
};

// A keyframe as relocalisation keeps it: saved with a map (core/io/keyframe_file.hpp), so that a
// camera can find itself in the map again after a restart.
struct DescribedKeyframe {
  std::int64_t id = 0;
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
  FrameDescription description;
};

// ORB keypoints with depth in [min_depth, max_depth] and the thumbnail descriptor of `frame`.
bool describe_frame(const RgbdFrame& frame, const RelocaliserConfig& config, float min_depth,
                    float max_depth, FrameDescription* out, std::string* why);

// One relocalisation attempt: what it tried, how long it took, whether it was accepted.
struct RelocalisationAttempt {
  bool accepted = false;
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();  // when accepted
  std::int64_t keyframe_id = -1;   // the keyframe the accepted (or best) candidate came from
  std::size_t candidates = 0;      // keyframes place recognition proposed
  std::size_t matches = 0;         // ORB matches with the best candidate keyframe
  std::size_t inliers = 0;         // its RANSAC inliers
  GicpResult verification;         // GICP of the best verified candidate
  double describe_ms = 0.0;        // describing the frame (zero when the caller had it)
  double time_ms = 0.0;            // search, RANSAC and verification
  std::string message;             // one line for logs
};

// One thread at a time: the FLANN index is built lazily inside the const queries.
class Relocaliser {
 public:
  explicit Relocaliser(const RelocaliserConfig& config);

  // Adds a keyframe at T_world_camera. Keyframes without keypoints are skipped.
  void add_keyframe(std::int64_t id, const Eigen::Isometry3d& T_world_camera, FrameDescription description);
  void add_keyframe(DescribedKeyframe keyframe) {
    add_keyframe(keyframe.id, keyframe.T_world_camera, std::move(keyframe.description));
  }
  // Copies of the keyframes kept, oldest first (what a map saves, keyframe_file.hpp).
  std::vector<DescribedKeyframe> keyframes() const { return {keyframes_.begin(), keyframes_.end()}; }
  // The keyframe added last (null when none is kept).
  const DescribedKeyframe* newest() const { return keyframes_.empty() ? nullptr : &keyframes_.back(); }
  // The id of the described keyframe the newest one replaced (revisit_*), if it replaced one.
  std::optional<std::int64_t> newest_replaced() const { return newest_replaced_; }
  // Place recognition: up to `count` keyframe ids, most similar first, skipping those whose id
  // is in [exclude_from, exclude_to] (a loop closer excludes the recent ones).
  std::vector<std::int64_t> similar_keyframes(const FrameDescription& query, std::size_t count,
                                              std::int64_t exclude_from = 1,
                                              std::int64_t exclude_to = 0) const;
  // Relocalises the frame (`source`: its camera-frame points as Tracker::preprocess makes them)
  // against `map` with `gicp`'s settings; the attempt says whether and where.
  RelocalisationAttempt relocalise(const FrameDescription& query, const GaussianPoints& source,
                                   const LocalMap& map, const GicpConfig& gicp) const;

  // The frame's pose from its ORB matches to one keyframe (RANSAC, no verification): the
  // tracker's wide-baseline initial guess. False when the keyframe is unknown or too few match.
  bool pose_from_keyframe(const FrameDescription& query, std::int64_t keyframe_id,
                          Eigen::Isometry3d* T_world_camera, std::size_t* inliers) const;

  std::size_t size() const { return keyframes_.size(); }
  // The keyframe whose pose is nearest `T_world_camera`: camera centres' distance plus
  // kNearestMetresPerRadian times the rotation between them; none when no keyframe is kept.
  std::optional<std::int64_t> nearest_keyframe(const Eigen::Isometry3d& T_world_camera) const;
  static constexpr double kNearestMetresPerRadian = 0.5;
  void clear();

 private:
  struct Entry : DescribedKeyframe {
    std::vector<Eigen::Vector3f> points_world;  // [K] description.points in the world frame
  };
  struct Index;  // FLANN over the global descriptors, rebuilt when keyframes changed
  const Entry* find(std::int64_t id) const;
  bool candidate_pose(const FrameDescription& query, const Entry& kf, Eigen::Isometry3d* T_world_camera,
                      std::size_t* matches, std::size_t* inliers) const;

  RelocaliserConfig config_;
  std::deque<Entry> keyframes_;
  std::optional<std::int64_t> newest_replaced_;
  mutable std::shared_ptr<Index> index_;
};

}  // namespace fslam::core

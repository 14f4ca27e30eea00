#include "fslam/core/tracking/relocaliser.hpp"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <random>
#include <sstream>

#include <flann/flann.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/core/compute/thread_clock.hpp"
#include "fslam/core/error.hpp"
#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/tracking/gicp_impl.hpp"
#include "fslam/core/tracking/keyframe_policy.hpp"

namespace fslam::core {
namespace {

// Three matched points closer than this to each other's line fit a pose badly.
constexpr double kMinSampleSpread = 0.05;  // metres, the smallest triangle height of a sample

struct RansacFit {
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
  std::vector<int> inliers;  // indices into the match list
};

Eigen::Isometry3d rigid_fit(const std::vector<Eigen::Vector3f>& from, const std::vector<Eigen::Vector3f>& to,
                            const std::vector<int>& use) {
  Eigen::Matrix3Xd a(3, use.size()), b(3, use.size());
  for (std::size_t i = 0; i < use.size(); ++i) {
    a.col(static_cast<Eigen::Index>(i)) = from[use[i]].cast<double>();
    b.col(static_cast<Eigen::Index>(i)) = to[use[i]].cast<double>();
  }
  Eigen::Isometry3d T;
  T.matrix() = Eigen::umeyama(a, b, false);
  return T;
}

bool spread_enough(const Eigen::Vector3f& a, const Eigen::Vector3f& b, const Eigen::Vector3f& c) {
  const Eigen::Vector3f ab = b - a, ac = c - a;
  const float base = std::max(ab.norm(), ac.norm());
  return base > 0.0f && ab.cross(ac).norm() / base > kMinSampleSpread;
}

// Rigid T with to[i] ~ T from[i] for most pairs: RANSAC over three-point fits, refitted on the
// inliers of the best one.
RansacFit ransac(const std::vector<Eigen::Vector3f>& from, const std::vector<Eigen::Vector3f>& to,
                 const RelocaliserConfig& config) {
  RansacFit best;
  const int n = static_cast<int>(from.size());
  if (n < 3) return best;
  std::mt19937 rng(1);  // deterministic: the same frame relocalises the same way
  std::uniform_int_distribution<int> pick(0, n - 1);
  const float gate2 = static_cast<float>(config.inlier_distance * config.inlier_distance);
  const auto inliers_of = [&](const Eigen::Isometry3d& T) {
    const Eigen::Matrix3f R = T.linear().cast<float>();
    const Eigen::Vector3f t = T.translation().cast<float>();
    std::vector<int> in;
    for (int i = 0; i < n; ++i)
      if ((R * from[i] + t - to[i]).squaredNorm() < gate2) in.push_back(i);
    return in;
  };
  for (int it = 0; it < config.ransac_iterations; ++it) {
    const int i = pick(rng), j = pick(rng), k = pick(rng);
    if (i == j || j == k || i == k) continue;
    if (!spread_enough(from[i], from[j], from[k]) || !spread_enough(to[i], to[j], to[k])) continue;
    const Eigen::Isometry3d T = rigid_fit(from, to, {i, j, k});
    std::vector<int> in = inliers_of(T);
    if (in.size() > best.inliers.size()) best = {T, std::move(in)};
  }
  if (best.inliers.size() >= 3) {
    const Eigen::Isometry3d T = rigid_fit(from, to, best.inliers);
    std::vector<int> in = inliers_of(T);
    if (in.size() >= best.inliers.size()) best = {T, std::move(in)};
  }
  return best;
}

}  // namespace

bool verifies(const RelocaliserConfig& config, const Eigen::Isometry3d& T_candidate, const GicpResult& gicp,
              double min_inlier_ratio) {
  const PoseMotion moved = pose_motion(T_candidate, gicp.T_target_source);
  return gicp.converged && is_finite(gicp.T_target_source) && gicp.inlier_ratio >= min_inlier_ratio &&
         moved.translation <= config.max_verified_translation &&
         moved.rotation * 180.0 / M_PI <= config.max_verified_rotation_deg;
}

bool RelocaliserConfig::is_valid(std::string* why) const {
  if (orb_features < 16) return fail(why, "relocalisation.orb_features must be >= 16");
  if (thumbnail_width < 8 || thumbnail_width > 256)
    return fail(why, "relocalisation.thumbnail_width must be in [8, 256]");
  if (candidates < 1) return fail(why, "relocalisation.candidates must be >= 1");
  if (!(ratio_test > 0.0 && ratio_test <= 1.0)) return fail(why, "relocalisation.ratio_test must be in (0, 1]");
  if (ransac_iterations < 1) return fail(why, "relocalisation.ransac_iterations must be >= 1");
  if (!(inlier_distance > 0.0)) return fail(why, "relocalisation.inlier_distance must be > 0");
  if (min_inliers < 3) return fail(why, "relocalisation.min_inliers must be >= 3");
  if (!(min_verified_inlier_ratio >= 0.0 && min_verified_inlier_ratio <= 1.0))
    return fail(why, "relocalisation.min_verified_inlier_ratio must be in [0, 1]");
  if (!(max_verified_translation > 0.0) || !(max_verified_rotation_deg > 0.0))
    return fail(why, "relocalisation.max_verified_translation and max_verified_rotation_deg must be > 0");
  if (max_keyframes < 1) return fail(why, "relocalisation.max_keyframes must be >= 1");
  if (!(revisit_translation >= 0.0) || !(revisit_rotation_deg >= 0.0))
    return fail(why, "relocalisation.revisit_translation and revisit_rotation_deg must be >= 0 (0: keep every keyframe)");
  return true;
}

bool describe_frame(const RgbdFrame& frame, const RelocaliserConfig& config, float min_depth,
                    float max_depth, FrameDescription* out, std::string* why) {
  if (frame.colour.empty() || frame.colour.type() != CV_8UC3)
    return fail(why, "relocalisation: colour must be a non-empty CV_8UC3 image");
  if (frame.depth.size() != frame.colour.size() || frame.depth.type() != CV_32FC1)
    return fail(why, "relocalisation: depth must be CV_32FC1 of the colour image's size");
  if (!frame.camera.is_valid(why)) return false;
  *out = FrameDescription{};
  cv::Mat grey;
  cv::cvtColor(frame.colour, grey, cv::COLOR_RGB2GRAY);

  // Keypoints with depth, in the camera frame.
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  cv::Ptr<cv::ORB> orb = cv::ORB::create(config.orb_features);
  orb->detectAndCompute(grey, cv::noArray(), keypoints, descriptors);
  std::vector<int> keep;
  for (int i = 0; i < static_cast<int>(keypoints.size()); ++i) {
    const int u = static_cast<int>(std::lround(keypoints[i].pt.x)), v = static_cast<int>(std::lround(keypoints[i].pt.y));
    if (u < 0 || v < 0 || u >= frame.depth.cols || v >= frame.depth.rows) continue;
    const float z = frame.depth.at<float>(v, u);
    if (!(z >= min_depth && z <= max_depth)) continue;
    out->points.push_back(frame.camera.unproject({keypoints[i].pt.x, keypoints[i].pt.y}, z).cast<float>());
    keep.push_back(i);
  }
  out->descriptors.create(static_cast<int>(keep.size()), descriptors.cols > 0 ? descriptors.cols : 32, CV_8UC1);
  for (std::size_t i = 0; i < keep.size(); ++i) descriptors.row(keep[i]).copyTo(out->descriptors.row(static_cast<int>(i)));

  // The thumbnail: area-averaged, blurred so that small shifts of view change it smoothly.
  const int w = config.thumbnail_width, h = std::max(1, (config.thumbnail_width * 3) / 4);
  cv::Mat small, blurred;
  cv::resize(grey, small, cv::Size(w, h), 0, 0, cv::INTER_AREA);
  small.convertTo(small, CV_32FC1);
  cv::GaussianBlur(small, blurred, cv::Size(0, 0), 1.0);
  out->global.assign(blurred.begin<float>(), blurred.end<float>());
  double mean = 0.0, norm2 = 0.0;
  for (float g : out->global) mean += g;
  mean /= static_cast<double>(out->global.size());
  for (float& g : out->global) {
    g -= static_cast<float>(mean);
    norm2 += static_cast<double>(g) * g;
  }
  const float inv = norm2 > 0.0 ? static_cast<float>(1.0 / std::sqrt(norm2)) : 0.0f;
  for (float& g : out->global) g *= inv;
  return true;
}

struct Relocaliser::Index {
  std::vector<float> data;  // [keyframes, dim] row-major
  std::vector<std::int64_t> ids;
  std::size_t dim = 0;
  std::unique_ptr<flann::Index<flann::L2<float>>> flann;
};

Relocaliser::Relocaliser(const RelocaliserConfig& config) : config_(config) {}

void Relocaliser::clear() {
  keyframes_.clear();
  index_.reset();
  newest_replaced_.reset();
}

void Relocaliser::add_keyframe(std::int64_t id, const Eigen::Isometry3d& T_world_camera,
                               FrameDescription description) {
  if (description.empty() || description.global.empty()) return;
  Entry e{{id, T_world_camera, std::move(description)}, {}};
  const Eigen::Matrix3f R = T_world_camera.linear().cast<float>();
  const Eigen::Vector3f t = T_world_camera.translation().cast<float>();
  e.points_world.reserve(e.description.points.size());
  for (const Eigen::Vector3f& p : e.description.points) e.points_world.push_back(R * p + t);
  index_.reset();  // a copy of this relocaliser may still share the old one
  newest_replaced_.reset();
  // The described keyframe this one revisits, if any, makes way for it: the newest description
  // of a pose is kept, at the back like every new one.
  const auto revisited = find_revisited(keyframes_.begin(), keyframes_.end(), T_world_camera,
                                        config_.revisit_translation, config_.revisit_rotation_deg,
                                        [](const Entry& k) { return k.T_world_camera; });
  if (revisited != keyframes_.end()) {
    newest_replaced_ = revisited->id;
    keyframes_.erase(revisited);
  }
  keyframes_.push_back(std::move(e));
  while (keyframes_.size() > config_.max_keyframes) keyframes_.pop_front();
}

const Relocaliser::Entry* Relocaliser::find(std::int64_t id) const {
  for (const Entry& e : keyframes_)
    if (e.id == id) return &e;
  return nullptr;
}

std::optional<std::int64_t> Relocaliser::nearest_keyframe(const Eigen::Isometry3d& T_world_camera) const {
  std::optional<std::int64_t> best;
  double best_cost = std::numeric_limits<double>::infinity();
  for (const Entry& e : keyframes_) {
    const Eigen::AngleAxisd turn(e.T_world_camera.linear().transpose() * T_world_camera.linear());
    const double cost = (e.T_world_camera.translation() - T_world_camera.translation()).norm() +
                        kNearestMetresPerRadian * std::abs(turn.angle());
    if (cost < best_cost) best_cost = cost, best = e.id;
  }
  return best;
}

std::vector<std::int64_t> Relocaliser::similar_keyframes(const FrameDescription& query, std::size_t count,
                                                         std::int64_t exclude_from, std::int64_t exclude_to) const {
  std::vector<std::int64_t> out;
  if (keyframes_.empty() || query.global.empty() || count == 0) return out;
  if (!index_) {
    auto index = std::make_shared<Index>();
    index->dim = keyframes_.front().description.global.size();
    for (const Entry& e : keyframes_) {
      if (e.description.global.size() != index->dim) continue;
      index->data.insert(index->data.end(), e.description.global.begin(), e.description.global.end());
      index->ids.push_back(e.id);
    }
    flann::Matrix<float> rows(index->data.data(), index->ids.size(), index->dim);
    index->flann = std::make_unique<flann::Index<flann::L2<float>>>(rows, flann::KDTreeIndexParams(4));
    index->flann->buildIndex();
    index_ = std::move(index);
  }
  if (query.global.size() != index_->dim) return out;
  std::size_t excluded = 0;
  for (std::int64_t id : index_->ids) excluded += id >= exclude_from && id <= exclude_to;
  const std::size_t k = std::min(index_->ids.size(), count + excluded);
  if (k == 0) return out;
  std::vector<float> q(query.global);
  std::vector<int> indices(k);
  std::vector<float> distances(k);
  flann::Matrix<float> qm(q.data(), 1, index_->dim);
  flann::Matrix<int> im(indices.data(), 1, k);
  flann::Matrix<float> dm(distances.data(), 1, k);
  flann::SearchParams params(512);  // checks: exact for maps of a few hundred keyframes
  index_->flann->knnSearch(qm, im, dm, k, params);
  for (std::size_t i = 0; i < k && out.size() < count; ++i) {
    if (indices[i] < 0) continue;
    const std::int64_t id = index_->ids[static_cast<std::size_t>(indices[i])];
    if (id >= exclude_from && id <= exclude_to) continue;
    out.push_back(id);
  }
  return out;
}

bool Relocaliser::candidate_pose(const FrameDescription& query, const Entry& kf, Eigen::Isometry3d* T_world_camera,
                                 std::size_t* matches, std::size_t* inliers) const {
  *matches = *inliers = 0;
  if (query.descriptors.rows < 2 || kf.description.descriptors.rows < 2) return false;
  // 3D-3D matches: query camera point -> keyframe world point.
  std::vector<std::vector<cv::DMatch>> knn;
  cv::BFMatcher(cv::NORM_HAMMING).knnMatch(query.descriptors, kf.description.descriptors, knn, 2);
  std::vector<Eigen::Vector3f> from, to;
  for (const auto& m : knn) {
    if (m.size() < 2 || m[0].distance > config_.ratio_test * m[1].distance) continue;
    from.push_back(query.points[static_cast<std::size_t>(m[0].queryIdx)]);
    to.push_back(kf.points_world[static_cast<std::size_t>(m[0].trainIdx)]);
  }
  *matches = from.size();
  if (from.size() < config_.min_inliers) return false;
  const RansacFit fit = ransac(from, to, config_);
  *inliers = fit.inliers.size();
  *T_world_camera = fit.T_world_camera;
  return fit.inliers.size() >= config_.min_inliers;
}

bool Relocaliser::pose_from_keyframe(const FrameDescription& query, std::int64_t keyframe_id,
                                     Eigen::Isometry3d* T_world_camera, std::size_t* inliers) const {
  const Entry* kf = find(keyframe_id);
  std::size_t matches = 0;
  return kf != nullptr && candidate_pose(query, *kf, T_world_camera, &matches, inliers);
}

RelocalisationAttempt Relocaliser::relocalise(const FrameDescription& query, const GaussianPoints& source,
                                              const LocalMap& map, const GicpConfig& gicp) const {
  const double t0 = steady_ms();
  RelocalisationAttempt a;
  const std::vector<std::int64_t> ids =
      similar_keyframes(query, static_cast<std::size_t>(config_.candidates));
  a.candidates = ids.size();
  double best_ratio = -1.0;
  for (std::int64_t id : ids) {
    const Entry* kf = find(id);
    Eigen::Isometry3d T_candidate;
    std::size_t matches = 0, inliers = 0;
    if (kf == nullptr || !candidate_pose(query, *kf, &T_candidate, &matches, &inliers)) continue;
    // Verification against the map (eq. gicp_pose from the candidate).
    const GicpResult g = align(source, map, T_candidate, gicp, SerialReduction{});
    const bool verified = verifies(config_, T_candidate, g, config_.min_verified_inlier_ratio);
    if (verified || g.inlier_ratio > best_ratio) {  // the report names the best candidate
      best_ratio = g.inlier_ratio;
      a.keyframe_id = id;
      a.matches = matches;
      a.inliers = inliers;
      a.verification = g;
    }
    if (verified) {
      a.accepted = true;
      a.T_world_camera = g.T_target_source;
      break;
    }
  }
  a.time_ms = steady_ms() - t0;
  std::ostringstream line;
  line << "relocalisation " << (a.accepted ? "accepted" : "failed") << ": " << a.candidates
       << " candidate keyframe(s), best " << a.keyframe_id << " with " << a.matches << " matches, " << a.inliers
       << " RANSAC inliers, GICP inliers " << std::lround(100.0 * a.verification.inlier_ratio) << " %, "
       << std::fixed << std::setprecision(1) << a.time_ms + a.describe_ms << " ms";
  a.message = line.str();
  return a;
}

}  // namespace fslam::core

#include "fslam/core/pipeline/slam_pipeline.hpp"

#include <algorithm>
#include <chrono>
#include <stdexcept>
#include <utility>

#include "fslam/core/error.hpp"
#include "fslam/core/tracking/keyframe_policy.hpp"

namespace fslam::core {

bool PipelineConfig::is_valid(std::string* why) const {
  if (!tracker.is_valid(why) || !mapper.is_valid(why)) return false;
  if (min_iterations_when_behind < 0 || idle_iterations < 0 || max_idle_iterations < 0) {
    return fail(why, "pipeline: iteration counts must be >= 0");
  }
  if (tracking_encoder_input != 0) {
    BuiltinFeatureConfig tracking;
    tracking.input_width = tracking.input_height = tracking_encoder_input;
    if (features.encoder.backend != FeatureBackend::builtin)
      return fail(why, "pipeline: tracking_encoder_input applies to the builtin encoder only (0 for onnx)");
    if (!tracking.is_valid(why)) return fail(why, "pipeline: tracking_encoder_input: " + (why ? *why : std::string()));
  }
  if (max_queued_keyframes < 0) return fail(why, "pipeline: max_queued_keyframes must be >= 0 (0: no bound)");
  if (loop_closure.enabled) {
    if (!loop_closure.is_valid(why)) return false;
    if (!tracker.relocalisation.enabled)
      return fail(why, "loop_closure.enabled needs tracker.relocalisation.enabled (its place recognition)");
    if (tracker.target != TrackingTarget::points)
      return fail(why, "loop_closure.enabled needs tracker.target points (the tracker keeps its own world; "
                       "the Gaussian target would move under it)");
  }
  return features.is_valid(why);
}

namespace {

// Map Gaussians that at least this many of the mapper's stored keyframes see hold their means in
// the tracker's target copy; the others are fused with re-observations like observations
// (docs/tracking.md "Re-observed Gaussians counted").
constexpr int kMinViewsToHoldMean = 2;

// The Gaussians' latent width is the autoencoder's (its weights file carries it), 0 without
// features: never a second copy to keep equal by hand.
PipelineConfig with_feature_width(PipelineConfig config, const LatentFeatures* features) {
  config.mapper.feature_dim = features != nullptr ? features->dim() : 0;
  return config;
}

}  // namespace

SlamPipeline::SlamPipeline(const PipelineConfig& config,
                           std::shared_ptr<const Rasterizer> rasterizer,
                           std::unique_ptr<LatentFeatures> features)
    : config_(with_feature_width(config, features.get())),
      tracker_(config_.tracker),
      mapper_(config_.mapper, std::move(rasterizer)),
      features_(std::move(features)),
      pyramids_(std::make_shared<PyramidPool>()) {
  // The decoded L_feat runs through the heads of the autoencoder that makes the latents.
  if (features_ && config_.mapper.feature_loss == MapperConfig::FeatureLoss::decoded) {
    std::string why;
    if (!mapper_.set_feature_decoder(features_->autoencoder(), &why)) throw std::logic_error(why);
  }
  if (config_.loop_closure.enabled) {
    // Wakes the mapping thread for the moves (the lock orders the wake after its predicate check).
    loop_ = std::make_unique<LoopThread>(config_.loop_closure, config_.tracker, [this] {
      { std::lock_guard<std::mutex> lock(mutex_); }
      wake_.notify_all();
    });
  }
}

SlamPipeline::~SlamPipeline() = default;

// Pyramids handed back when their last holder drops them (the prepared frame, or the mapper
// once it has its latent), so that encoding reuses ~17 MB buffers instead of zeroing and
// faulting in fresh ones (measured: 10-20 % of the tracking thread).
class SlamPipeline::PyramidPool {
 public:
  static std::shared_ptr<FeaturePyramid> acquire(const std::shared_ptr<PyramidPool>& pool) {
    std::unique_ptr<FeaturePyramid> p;
    {
      std::lock_guard<std::mutex> lock(pool->mutex_);
      if (!pool->free_.empty()) {
        p = std::move(pool->free_.back());
        pool->free_.pop_back();
      }
    }
    if (!p) p = std::make_unique<FeaturePyramid>();
    return std::shared_ptr<FeaturePyramid>(p.release(), [weak = std::weak_ptr<PyramidPool>(pool)](FeaturePyramid* raw) {
      std::unique_ptr<FeaturePyramid> owned(raw);
      if (const auto pool = weak.lock()) {
        std::lock_guard<std::mutex> lock(pool->mutex_);
        if (pool->free_.size() < kMaxFree) pool->free_.push_back(std::move(owned));
      }
    });
  }

 private:
  static constexpr std::size_t kMaxFree = 4;
  std::mutex mutex_;
  std::vector<std::unique_ptr<FeaturePyramid>> free_;
};

bool SlamPipeline::encode_for_tracking(const cv::Mat& colour, const PinholeCamera& camera,
                                       std::shared_ptr<FeaturePyramid>* pyramid, PlanarImage* latent,
                                       std::string* why) {
  if (!tracking_features_) {
    LatentFeaturesConfig tracking = config_.features;
    if (config_.tracking_encoder_input > 0) {
      tracking.encoder.builtin.input_width = tracking.encoder.builtin.input_height = config_.tracking_encoder_input;
    }
    tracking_features_ = LatentFeatures::create(tracking, why);
    if (!tracking_features_) return false;
  }
  *pyramid = PyramidPool::acquire(pyramids_);
  const int stride = config_.tracker.preprocess.stride;
  return tracking_features_->encode(colour, pyramid->get(), why) &&
         tracking_features_->latent_image(**pyramid, camera.width / stride, camera.height / stride, latent, why);
}

void SlamPipeline::warm_up() {
  if (!features_ || !config_.track_with_features || tracking_features_) return;
  PinholeCamera camera;
  camera.width = 640;
  camera.height = 480;
  const cv::Mat blank(camera.height, camera.width, CV_8UC3, cv::Scalar(128, 128, 128));
  std::shared_ptr<FeaturePyramid> pyramid;
  PlanarImage latent;
  std::string why;
  encode_for_tracking(blank, camera, &pyramid, &latent, &why);
}

bool SlamPipeline::prepare_frame(RgbdFrame frame, PreparedFrame* out, std::string* why) {
  out->frame = std::move(frame);
  out->latent = PlanarImage();
  out->pyramid.reset();
  out->features_ms = 0.0;
  // The frame's latent, one per lattice cell of the tracker's source points (eq. feat_dist).
  if (features_ && config_.track_with_features) {
    const auto t0 = std::chrono::steady_clock::now();
    // Encoded once: the tracker samples the latent on its lattice, and a keyframe hands the
    // pyramid on to the mapper for its latent target (unless tracking_encoder_input encodes
    // frames at another input than the mapper's: the mapper then encodes the keyframe itself).
    if (!encode_for_tracking(out->frame.colour, out->frame.camera, &out->pyramid, &out->latent, why)) return false;
    out->features_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
  // Depth -> source Gaussians with their features (eq. gicp_sets).
  return tracker_.preprocess(out->frame, out->latent.empty() ? nullptr : &out->latent, &out->source, why);
}

bool SlamPipeline::track_prepared(PreparedFrame&& prepared, TrackingResult* result, std::string* why,
                                  const Eigen::Isometry3d* mapping_pose) {
  const RgbdFrame& frame = prepared.frame;
  if (loop_ && mapping_pose != nullptr) {
    return fail(why, "loop closure moves keyframes from their tracked poses: not with mapping poses given");
  }
  if (config_.tracker.target == TrackingTarget::gaussians && !tracker_.localising()) {
    // The newest map target, if the mapper built one since the last frame (never waited for).
    std::unique_ptr<LocalMap> target;
    std::int64_t last_keyframe = -1;
    std::int64_t bridged = -1;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      if (config_.tracker.map_target.wait_for_mapper && keyframe_awaited_ >= 0) {
        map_target_published_.wait_for(lock, std::chrono::seconds(120),
                                       [&] { return map_target_keyframe_ >= keyframe_awaited_; });
        keyframe_awaited_ = -1;
      }
      if (map_target_serial_ != map_target_taken_) {
        target = std::move(map_target_);
        last_keyframe = map_target_keyframe_;
        bridged = map_target_bridged_;
        map_target_taken_ = map_target_serial_;
      }
    }
    if (target) tracker_.set_map_target(std::move(*target), last_keyframe, bridged);
  }
  // The trajectory starts where the recording's ground truth does, when it has one.
  if (tracker_.keyframe_count() == 0 && frame.T_world_camera_gt) tracker_.set_initial_pose(*frame.T_world_camera_gt);
  // Register and decide on a keyframe (eq. feat_gicp, keyframe_crit).
  if (!tracker_.track_prepared(frame, prepared.source, result, why,
                               prepared.latent.empty() ? nullptr : &prepared.latent)) {
    return false;
  }
  result->timings.features_ms = prepared.features_ms;
  const DescribedKeyframe* described = tracker_.relocaliser().newest();
  const bool is_described = result->keyframe && described != nullptr && described->id == frame.id;
  if (is_described) {
    std::lock_guard<std::mutex> lock(mutex_);
    // The copy follows the relocaliser's set: a revisiting keyframe replaces the one it revisits.
    if (const std::optional<std::int64_t> replaced = tracker_.relocaliser().newest_replaced()) {
      const auto it = std::find_if(described_.begin(), described_.end(),
                                   [&](const DescribedKeyframe& kf) { return kf.id == *replaced; });
      if (it != described_.end()) described_.erase(it);
    }
    described_.push_back(*described);
    while (described_.size() > config_.tracker.relocalisation.max_keyframes) described_.pop_front();
  }
  const Eigen::Isometry3d T_odom = result->T_world_camera;  // the tracker's world
  if (loop_) {
    if (is_described) {
      LoopKeyframe kf;
      kf.id = kf.position = frame.id;
      kf.T_odom_camera = T_odom;
      kf.description = described->description;
      kf.points = prepared.source.points;
      loop_->add(std::move(kf));
    }
    result->T_map_odom = loop_->map_from_odom();
    result->T_world_camera = result->T_map_odom * T_odom;
  }
  if (result->keyframe && config_.mapping && config_.tracker.target == TrackingTarget::gaussians) {
    std::lock_guard<std::mutex> lock(mutex_);
    bridge_ = tracker_.unmapped_keyframes();  // shared points: copies pointers, not points
  }
  // Tracking frames never grow the map; keyframes go to the mapper without waiting for it.
  if (result->keyframe && config_.mapping) {
    QueuedKeyframe queued;
    MapperKeyframe& kf = queued.keyframe;
    kf.frame_id = frame.id;
    kf.T_world_camera = mapping_pose != nullptr ? *mapping_pose : result->T_world_camera;
    queued.T_odom = T_odom;
    kf.camera = frame.camera;
    kf.colour = frame.colour;
    kf.depth = frame.depth;
    if (config_.mapper.insert_from == MapperConfig::InsertFrom::source) {
      kf.source_world = transformed(prepared.source.points, kf.T_world_camera);
      kf.source_stride = config_.tracker.preprocess.stride;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      // With a keyframe already waiting with its pyramid (mapping behind), this one goes without
      // and the mapper encodes its colour itself: at most two pyramids wait for the mapper.
      const bool pyramid_waiting = std::any_of(queue_.begin(), queue_.end(),
                                               [](const QueuedKeyframe& q) { return q.pyramid != nullptr; });
      if (!pyramid_waiting && tracking_pyramid_is_mappers()) queued.pyramid = std::move(prepared.pyramid);
      queue_.push_back(std::move(queued));
      bound_queue_locked();
      keyframe_awaited_ = frame.id;
    }
    wake_.notify_one();
  }
  return true;
}

bool SlamPipeline::process_frame(const RgbdFrame& frame, TrackingResult* result,
                                 std::string* why, const Eigen::Isometry3d* mapping_pose) {
  PreparedFrame prepared;
  return prepare_frame(frame, &prepared, why) &&
         track_prepared(std::move(prepared), result, why, mapping_pose);
}

bool SlamPipeline::start_in(const GaussianMap& map, std::uint64_t version_number,
                            std::vector<DescribedKeyframe> keyframes, StartMode mode,
                            const FeatureAutoencoder* heads, std::string* why) {
  if (mode == StartMode::extend) {
    mapper_.versions().continue_after(version_number);
    if (heads != nullptr && !mapper_.continue_feature_decoder(*heads, why)) return false;
    if (!mapper_.set_map(map, why)) return false;  // publishes the first version, with the heads
    const auto n = static_cast<std::int64_t>(keyframes.size());
    for (std::int64_t i = 0; i < n; ++i) keyframes[static_cast<std::size_t>(i)].id = i - n;
  }
  const TrackerConfig& t = config_.tracker;
  tracker_.start_in(localisation_target(map, t.local_map, t.map_target, t.preprocess), std::move(keyframes), mode);
  if (mode == StartMode::extend) {  // kept with the map: the relocaliser's, as it bounded them
    const std::vector<DescribedKeyframe> kept = tracker_.relocaliser().keyframes();
    std::lock_guard<std::mutex> lock(mutex_);
    described_.assign(kept.begin(), kept.end());
  }
  return true;
}

std::vector<DescribedKeyframe> SlamPipeline::described_keyframes() const {
  std::vector<DescribedKeyframe> out;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    out.assign(described_.begin(), described_.end());
  }
  // In the map's world, where the Gaussians they are saved with lie.
  if (loop_) for (DescribedKeyframe& kf : out) kf.T_world_camera = loop_->map_pose(kf.id, kf.T_world_camera);
  return out;
}

std::optional<LoopThreadStats> SlamPipeline::loop_closure_stats() const {
  if (!loop_) return std::nullopt;
  return loop_->stats();
}

Eigen::Isometry3d SlamPipeline::loop_correction(std::int64_t frame_id) const {
  return loop_ ? loop_->correction(frame_id) : Eigen::Isometry3d::Identity();
}

void SlamPipeline::apply_loop_moves() {
  if (!loop_) return;
  const std::vector<std::pair<std::int64_t, Eigen::Isometry3d>> moves = loop_->take_moves();
  if (!moves.empty()) mapper_.move_keyframes(moves);
}

std::size_t SlamPipeline::publish_map_target(const MapperKeyframe& kf) {
  // Built here, on the mapping thread, bridge included, so that tracking only takes it and
  // bridges the keyframes it made since (set_map_target).
  LocalMapConfig config = config_.tracker.local_map;
  config.fuse = false;  // Gaussians are not observations to average
  config.min_point_distance = std::min(config_.tracker.map_target.min_point_distance, config.voxel_size);
  const Eigen::Vector3f centre = kf.T_world_camera.translation().cast<float>();
  auto target = std::make_unique<LocalMap>(config);
  GaussianPoints points = map_target_points(mapper_.map(), centre, config.radius, config_.tracker.map_target,
                                            config_.tracker.preprocess);
  std::vector<PointOrigin> origins(points.size(), PointOrigin::map_gaussian);
  if (config_.tracker.map_target.observation_weight) {
    std::vector<ObservingDepth> views;  // the stored keyframes' depth (pixels shared)
    for (const KeyframeImages& kf : *mapper_.published_keyframe_images()) {
      if (kf.depth.empty()) continue;
      views.push_back({kf.input_camera.scaled(static_cast<double>(kf.depth.cols) / kf.input_camera.width),
                       kf.T_world_camera, kf.depth});
    }
    const std::vector<int> seen =
        weight_by_observations(views, config_.tracker.gicp.max_correspondence_distance, &points);
    // A Gaussian fewer than two stored keyframes see was fitted to one view, and lately (the
    // first mapping rounds move means most): the tracker's copy fuses it with re-observations
    // as an observation. One that several views fitted holds where the mapper put it.
    for (std::size_t k = 0; k < seen.size(); ++k)
      if (seen[k] < kMinViewsToHoldMean) origins[k] = PointOrigin::observation;
  }
  target->insert(points, centre, origins);
  std::deque<KeyframePoints> bridge;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    bridge = bridge_;
  }
  target->set_fuse(config_.tracker.local_map.fuse);  // the bridge's points fuse as the tracker's
  const std::int64_t bridged = bridge_keyframes(bridge, kf.frame_id, target.get());
  std::lock_guard<std::mutex> lock(mutex_);
  map_target_ = std::move(target);
  map_target_keyframe_ = kf.frame_id;
  map_target_bridged_ = bridged;
  ++map_target_serial_;
  map_target_published_.notify_all();
  return static_cast<std::size_t>(std::count_if(
      bridge.begin(), bridge.end(), [&](const KeyframePoints& b) { return b.frame_id > kf.frame_id; }));
}

bool SlamPipeline::tracking_pyramid_is_mappers() const {
  const BuiltinFeatureConfig& mapper = config_.features.encoder.builtin;
  return config_.tracking_encoder_input == 0 ||
         (mapper.input_width == config_.tracking_encoder_input && mapper.input_height == config_.tracking_encoder_input);
}

void SlamPipeline::bound_queue_locked() {
  const std::size_t bound = static_cast<std::size_t>(config_.max_queued_keyframes);
  if (!config_.realtime || bound == 0 || queue_.size() <= bound) return;
  // The waiting keyframe (never the oldest, the mapper's next) that moved least from the one
  // before it, in units of the keyframe thresholds (eq. keyframe_crit): what the map loses least by.
  const KeyframeConfig& kc = config_.tracker.keyframe;
  const auto redundancy = [&](std::size_t i) {
    return motion_in_thresholds(pose_motion(queue_[i - 1].keyframe.T_world_camera, queue_[i].keyframe.T_world_camera),
                                kc.translation, kc.rotation_deg);
  };
  std::size_t drop = 1;
  double least = redundancy(1);
  for (std::size_t i = 2; i < queue_.size(); ++i) {
    const double r = redundancy(i);
    if (r < least) least = r, drop = i;
  }
  queue_.erase(queue_.begin() + static_cast<std::ptrdiff_t>(drop));
  ++keyframes_left_out_;
}

std::uint64_t SlamPipeline::keyframes_left_out() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return keyframes_left_out_;
}

void SlamPipeline::finish() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    finished_ = true;
  }
  if (loop_) loop_->finish();
  wake_.notify_all();
}

std::size_t SlamPipeline::queued_keyframes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return queue_.size();
}

bool SlamPipeline::run_mapping(const std::function<void(const KeyframeReport&)>& on_keyframe,
                               std::string* why) {
  int idle_done = 0;  // idle iterations since the newest keyframe was mapped
  // Loop closure's keyframe moves wake this thread too; it finishes once the loop thread has.
  const auto moves_waiting = [&] { return loop_ && loop_->has_moves(); };
  const auto loop_done = [&] { return !loop_ || loop_->done(); };
  for (;;) {
    apply_loop_moves();  // between steps, never during one
    QueuedKeyframe queued;
    std::size_t waiting = 0;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      if (config_.realtime) {
        // Idle time goes to more optimisation while nothing waits.
        while (queue_.empty() && !finished_ && !moves_waiting()) {
          if (mapper_.keyframe_count() == 0 || idle_done >= config_.max_idle_iterations ||
              config_.idle_iterations == 0) {
            wake_.wait(lock, [&] { return !queue_.empty() || finished_ || moves_waiting(); });
            continue;
          }
          const int step = std::min(config_.idle_iterations, config_.max_idle_iterations - idle_done);
          lock.unlock();
          if (!mapper_.optimise(step, why)) return false;
          idle_done += step;
          lock.lock();
        }
      } else {
        wake_.wait(lock, [&] { return !queue_.empty() || finished_ || moves_waiting(); });
      }
      if (queue_.empty()) {
        if (moves_waiting()) continue;
        if (!loop_done()) {  // finished: the loop thread works through its last keyframes
          wake_.wait(lock, [&] { return loop_done() || moves_waiting(); });
          continue;
        }
        lock.unlock();
        apply_loop_moves();
        return true;  // finished and drained
      }
      queued = std::move(queue_.front());
      idle_done = 0;
      queue_.pop_front();
      waiting = queue_.size();
    }
    int iterations = config_.mapper.iterations_per_keyframe;
    if (config_.realtime && waiting > 0) {
      iterations = std::max(config_.min_iterations_when_behind,
                            iterations / static_cast<int>(1 + waiting));
    }
    mapper_.set_iterations_per_keyframe(iterations);
    MapperKeyframe& kf = queued.keyframe;
    // Where loop closure puts the keyframe now (it may have moved since it was tracked).
    if (loop_) {
      const Eigen::Isometry3d T = loop_->map_pose(kf.frame_id, queued.T_odom);
      if (!kf.source_world.empty()) kf.source_world = transformed(kf.source_world, T * kf.T_world_camera.inverse());
      kf.T_world_camera = T;
    }
    KeyframeReport report;
    report.frame_id = kf.frame_id;
    if (features_) {
      // The latent target of L_feat (eq. modeling_losses) at the mapper's training resolution.
      const auto t0 = std::chrono::steady_clock::now();
      const PinholeCamera training = kf.camera.scaled(config_.mapper.training_scale);
      if (!queued.pyramid) {
        queued.pyramid = PyramidPool::acquire(pyramids_);
        if (!features_->encode(kf.colour, queued.pyramid.get(), why)) return false;
      }
      if (!features_->latent_image(*queued.pyramid, training.width, training.height, &kf.feature_target, why)) {
        return false;
      }
      // The decoded L_feat's target: the pyramid at sample pixels (seeded by the frame id).
      if (const FeatureAutoencoder* decoder = mapper_.feature_decoder();
          decoder != nullptr &&
          !observe_features(*queued.pyramid, training.width, training.height, config_.mapper.feature_samples,
                            static_cast<std::uint32_t>(kf.frame_id), decoder->input_mean(),
                            decoder->input_std(), &kf.feature_observation, why)) {
        return false;
      }
      queued.pyramid.reset();  // back to the pool
      report.features_ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    }
    if (!mapper_.add_keyframe(kf, &report.refinement, why)) return false;
    if (config_.tracker.target == TrackingTarget::gaussians) report.bridged_keyframes = publish_map_target(kf);
    report.map_size = mapper_.map().size();
    report.queue_depth = waiting;
    if (on_keyframe) on_keyframe(report);
  }
}

}  // namespace fslam::core

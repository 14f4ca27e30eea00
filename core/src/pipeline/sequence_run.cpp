#include "fslam/core/pipeline/sequence_run.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <future>
#include <memory>
#include <optional>
#include <stdexcept>
#include <thread>
#include <utility>

#include "fslam/core/compute/thread_clock.hpp"
#include "fslam/core/error.hpp"

namespace fslam::core {
namespace {

using Clock = std::chrono::steady_clock;

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// Frames of a dataset in order, each decoded on a helper thread while the one before it is
// processed: the one place the frame prefetch lives.
class FramePrefetch {
 public:
  explicit FramePrefetch(const Dataset& dataset) : dataset_(dataset) {
    if (dataset_.size() > 0) next_ = std::async(std::launch::async, &FramePrefetch::load, this, 0);
  }
  ~FramePrefetch() {
    if (next_.valid()) next_.wait();
  }
  // Frame i (called for i = 0, 1, ... in order); false with `why` when it failed to decode.
  bool take(std::size_t i, RgbdFrame* frame, double* load_ms, std::string* why) {
    Loaded loaded = next_.get();
    if (i + 1 < dataset_.size()) next_ = std::async(std::launch::async, &FramePrefetch::load, this, i + 1);
    if (!loaded.ok) return fail(why, loaded.why);
    *frame = std::move(loaded.frame);
    *load_ms = loaded.ms;
    return true;
  }

 private:
  struct Loaded {
    RgbdFrame frame;
    bool ok = false;
    std::string why;
    double ms = 0.0;
  };
  Loaded load(std::size_t i) const {
    Loaded out;
    const Clock::time_point t0 = Clock::now();
    out.ok = dataset_.load(i, &out.frame, &out.why);
    out.ms = ms_between(t0, Clock::now());
    return out;
  }
  const Dataset& dataset_;
  std::future<Loaded> next_;
};

// The trajectory entries scored from the final map: every keyframe, and every eval_every-th
// non-keyframe (held out: never trained on); `true` marks the held-out ones.
std::vector<std::pair<std::size_t, bool>> views_to_evaluate(const SequenceTracking& t, int eval_every) {
  std::vector<std::pair<std::size_t, bool>> list;
  std::size_t non_keyframes = 0;
  for (std::size_t k = 0; k < t.trajectory.size(); ++k) {
    if (t.keyframe[k]) {
      list.push_back({k, false});
    } else if (non_keyframes++ % static_cast<std::size_t>(eval_every) == 0) {
      list.push_back({k, true});
    }
  }
  return list;
}

// `count` held-out entries spread evenly over the sequence.
std::vector<std::size_t> views_to_render(const std::vector<std::pair<std::size_t, bool>>& list, int count) {
  std::vector<std::size_t> held_out, chosen;
  for (const auto& [k, held] : list)
    if (held) held_out.push_back(k);
  for (int r = 0; r < count && !held_out.empty(); ++r) {
    chosen.push_back(held_out[held_out.size() * static_cast<std::size_t>(r) / static_cast<std::size_t>(count)]);
  }
  return chosen;
}

// The decoded L_feat on held-out views: the map's latent rendered at the mapper's training
// resolution, decoded by the pretrained heads and by the online-adapted ones, against the encoder.
class DecodedFeatureError {
 public:
  explicit DecodedFeatureError(SlamPipeline* pipeline) : pipeline_(*pipeline) {}
  bool add(const RgbdFrame& frame, const Eigen::Isometry3d& pose, std::string* why) {
    const FeatureAutoencoder* online = pipeline_.mapper().feature_decoder();
    LatentFeatures* features = pipeline_.features();
    if (online == nullptr || features == nullptr || pipeline_.mapper().map().empty()) return true;
    const MapperConfig& mc = pipeline_.mapper().config();
    RenderView view;
    view.camera = frame.camera.scaled(mc.training_scale);
    view.T_camera_world = pose.inverse();
    FeatureObservation obs;
    if (!features->encode(frame.colour, &pyramid_, why) ||
        !observe_features(pyramid_, view.camera.width, view.camera.height, mc.feature_samples,
                          static_cast<std::uint32_t>(frame.id), online->input_mean(), online->input_std(), &obs, why)) {
      return false;
    }
    const double before = pipeline_.mapper().decoded_feature_error(view, obs, features->autoencoder(), why);
    const double after = pipeline_.mapper().decoded_feature_error(view, obs, *online, why);
    if (!std::isfinite(before) || !std::isfinite(after)) return false;
    before_ += before, after_ += after, ++views_;
    return true;
  }
  void write(SequenceRunResult* out) const {
    if (views_ == 0) return;
    out->feature_error_pretrained = before_ / views_;
    out->feature_error_online = after_ / views_;
    out->lora_steps = pipeline_.mapper().feature_decoder()->online_steps();
  }

 private:
  SlamPipeline& pipeline_;
  FeaturePyramid pyramid_;
  double before_ = 0, after_ = 0;
  int views_ = 0;
};

bool evaluate_views(const Dataset& dataset, SlamPipeline& pipeline, const Rasterizer& rasterizer,
                    const SequenceRunConfig& config, const SequenceCallbacks& callbacks,
                    SequenceRunResult* out, std::string* why) {
  const SequenceTracking& t = out->tracking;
  const auto list = views_to_evaluate(t, config.eval_every);
  const std::vector<std::size_t> render = views_to_render(list, config.renders);
  RenderSettings settings = pipeline.config().mapper.render;
  settings.features = false;
  const GaussianMap& map = pipeline.mapper().map();
  std::size_t evaluated = 0;
  DecodedFeatureError feature_error(&pipeline);
  for (const auto& [k, held] : list) {
    RgbdFrame frame;
    if (!dataset.load(t.frame_index[k], &frame, why)) return false;
    const Eigen::Isometry3d& pose = config.ground_truth_poses ? t.mapping_poses[k] : t.trajectory[k].T_world_camera;
    ViewScore score;
    RenderResult rendered;
    if (!evaluate_view(rasterizer, map, frame, pose, settings, &score, why, &rendered)) return false;
    (held ? out->held_out : out->keyframes).views.push_back(score);
    if (held && !feature_error.add(frame, pose, why)) return false;
    if (callbacks.on_render && std::find(render.begin(), render.end(), k) != render.end() &&
        !callbacks.on_render(frame, rendered, why)) {
      return false;
    }
    if (callbacks.on_evaluated) callbacks.on_evaluated(++evaluated, list.size());
  }
  feature_error.write(out);
  return true;
}

}  // namespace

bool SequenceRunConfig::is_valid(std::string* why) const {
  if (realtime_fps < 0.0) return fail(why, "the real-time rate must be > 0 frames per second");
  if (refine_steps < 0) return fail(why, "refinement steps must be >= 0");
  if (eval_every < 1) return fail(why, "every n-th frame held out needs n >= 1");
  if (renders < 0) return fail(why, "the number of rendered views must be >= 0");
  return true;
}

std::size_t SequenceTracking::keyframes() const {
  return static_cast<std::size_t>(std::count(keyframe.begin(), keyframe.end(), true));
}

bool track_sequence(const Dataset& dataset, SlamPipeline* pipeline, const SequenceRunConfig& config,
                    const SequenceCallbacks& callbacks, SequenceTracking* out, std::string* why) {
  *out = SequenceTracking();
  if (!config.is_valid(why)) return false;
  const std::size_t n = dataset.size();
  const bool paced = config.realtime_fps > 0.0;
  const double period_s = paced ? 1.0 / config.realtime_fps : 0.0;
  FramePrefetch frames(dataset);
  const Clock::time_point start = Clock::now();
  for (std::size_t i = 0; i < n; ++i) {
    RgbdFrame frame;
    double load_ms = 0.0;
    if (!frames.take(i, &frame, &load_ms, why)) return false;
    out->load_ms.push_back(load_ms);
    if (paced) {
      // A live sensor: frame i arrives at start + i / fps. When the next frame has already
      // arrived, this one is stale and a live system would never see it: count it as skipped.
      const double now_s = std::chrono::duration<double>(Clock::now() - start).count();
      const double arrival = static_cast<double>(i) * period_s;
      if (now_s < arrival) {
        std::this_thread::sleep_for(std::chrono::duration<double>(arrival - now_s));
      } else if (i > 0 && now_s >= arrival + period_s) {
        ++out->skipped;
        if (callbacks.on_frame) callbacks.on_frame(i + 1, n);
        continue;
      }
    }
    if (config.ground_truth_poses && !frame.T_world_camera_gt) {
      return fail(why, "mapping at ground-truth poses: frame " + std::to_string(frame.id) + " has no ground truth");
    }
    const std::optional<Eigen::Isometry3d> mapping_pose =
        config.ground_truth_poses ? frame.T_world_camera_gt : std::nullopt;
    TrackingResult result;
    const Clock::time_point t0 = Clock::now();
    const double cpu0 = thread_cpu_ms();
    if (!pipeline->process_frame(frame, &result, why, mapping_pose ? &*mapping_pose : nullptr)) return false;
    if (i > 0) {  // the first frame only initialises the map
      out->track_ms.push_back(ms_between(t0, Clock::now()));
      out->track_cpu_ms.push_back(thread_cpu_ms() - cpu0);
      if (result.timings.features_ms > 0) out->features_ms.push_back(result.timings.features_ms);
      out->timings.push_back(result.timings);
      out->inlier_ratio.push_back(result.gicp.inlier_ratio);
      out->rms_residual_m.push_back(result.gicp.rms_residual);
      out->mahalanobis.push_back(result.gicp.mean_mahalanobis);
      out->feature_weight.push_back(result.gicp.mean_feature_weight);
    }
    out->wide_baseline += result.wide_baseline;
    if (result.state == TrackingState::lost || result.state == TrackingState::recovered) {
      ++(result.state == TrackingState::lost ? out->lost : out->recovered);
      if (callbacks.on_tracking_event) callbacks.on_tracking_event(frame.id, result);
    }
    out->trajectory.push_back({frame.timestamp, result.T_world_camera});
    if (mapping_pose) out->mapping_poses.push_back(*mapping_pose);
    out->frame_index.push_back(i);
    out->keyframe.push_back(result.keyframe);
    out->frame_id.push_back(frame.id);
    out->map_from_odom.push_back(result.T_map_odom);
    if (callbacks.on_frame) callbacks.on_frame(i + 1, n);
  }
  out->wall_s = ms_between(start, Clock::now()) / 1000.0;
  return true;
}

bool run_sequence(const Dataset& dataset, SlamPipeline* pipeline, const Rasterizer& rasterizer,
                  const SequenceRunConfig& config, const SequenceCallbacks& callbacks,
                  SequenceRunResult* out, std::string* why) {
  *out = SequenceRunResult();
  const Clock::time_point start = Clock::now();
  const bool tracked = track_sequence(dataset, pipeline, config, callbacks, &out->tracking, why);
  pipeline->finish();
  if (!tracked) {
    std::string ignored;  // the tracking failure is the one reported
    if (callbacks.wait_for_mapping) callbacks.wait_for_mapping(&ignored);
    return false;
  }
  if (callbacks.on_tracking_done) callbacks.on_tracking_done(out->tracking, pipeline->queued_keyframes());
  if (callbacks.wait_for_mapping && !callbacks.wait_for_mapping(why)) return false;
  if (pipeline->config().loop_closure.enabled && callbacks.wait_for_mapping) {
    // Loop closure is done with mapping: every frame moves with the keyframe at or before it
    // into the final map's world (the poses as reported carry the correction of their time).
    SequenceTracking& t = out->tracking;
    for (std::size_t k = 0; k < t.trajectory.size(); ++k) {
      t.trajectory[k].T_world_camera =
          pipeline->loop_correction(t.frame_id[k]) * t.map_from_odom[k].inverse() * t.trajectory[k].T_world_camera;
    }
  }
  const Clock::time_point mapping_done = Clock::now();
  out->slam_s = ms_between(start, mapping_done) / 1000.0;
  if (config.refine_steps > 0 && !pipeline->refine(config.refine_steps, why, callbacks.on_refine)) return false;
  out->refine_s = ms_between(mapping_done, Clock::now()) / 1000.0;
  const Mapper& mapper = pipeline->mapper();
  out->map_gaussians = mapper.map().size();
  out->loop_closure = pipeline->loop_closure_stats();
  out->map_keyframes = mapper.keyframe_count();
  out->optimisation_steps = mapper.total_steps();
  return evaluate_views(dataset, *pipeline, rasterizer, config, callbacks, out, why);
}

}  // namespace fslam::core

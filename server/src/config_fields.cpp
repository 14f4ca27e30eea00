#include "fslam/server/config_fields.hpp"

#include <algorithm>
#include <charconv>
#include <string_view>
#include <system_error>
#include <type_traits>
#include <utility>

#include <yaml-cpp/yaml.h>

#include "fslam/core/error.hpp"

namespace fslam::server {
namespace {

using core::fail;

// ---- text <-> value, one codec per supported type ---------------------------------------------

template <class T, class Enable = void>
struct Codec;

template <>
struct Codec<bool> {
  static constexpr const char* kTypeName = "BOOL";
  static bool parse(const std::string& text, bool* value, std::string* why) {
    if (text != "true" && text != "false")
      return fail(why, "expected true or false, got '" + text + "'");
    *value = text == "true";
    return true;
  }
  static std::string format(bool value) { return value ? "true" : "false"; }
};

template <>
struct Codec<std::string> {
  static constexpr const char* kTypeName = "TEXT";
  static bool parse(const std::string& text, std::string* value, std::string*) {
    *value = text;
    return true;
  }
  static std::string format(const std::string& value) { return value; }
};

// Integers and floating point through from_chars / to_chars: the whole text must parse, and
// to_chars' shortest form parses back to the identical value (a printed config re-loads exactly).
template <class T>
struct Codec<T, std::enable_if_t<std::is_arithmetic_v<T> && !std::is_same_v<T, bool>>> {
  static constexpr const char* kTypeName =
      std::is_floating_point_v<T> ? "FLOAT" : (std::is_signed_v<T> ? "INT" : "UINT");
  static bool parse(const std::string& text, T* value, std::string* why) {
    const char* expected = std::is_floating_point_v<T> ? "a number"
                           : std::is_signed_v<T>       ? "an integer"
                                                       : "a non-negative integer";
    T parsed{};
    const char* end = text.data() + text.size();
    const auto [ptr, ec] = std::from_chars(text.data(), end, parsed);
    if (ec == std::errc::result_out_of_range) return fail(why, "'" + text + "' is out of range");
    if (ec != std::errc() || ptr != end || text.empty())
      return fail(why, std::string("expected ") + expected + ", got '" + text + "'");
    *value = parsed;
    return true;
  }
  static std::string format(T value) {
    char buffer[64];
    const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
    return std::string(buffer, result.ptr);
  }
};

// Enums by name; the names live here, not in core (core has no text formats).
template <class E>
using EnumNames = std::vector<std::pair<E, std::string>>;

template <class E>
struct EnumCodec {
  EnumNames<E> names;
  std::string type_name() const {
    std::string joined;
    for (const auto& [value, name] : names) joined += (joined.empty() ? "" : "|") + name;
    return joined;
  }
  bool parse(const std::string& text, E* value, std::string* why) const {
    for (const auto& [v, name] : names)
      if (name == text) return (*value = v, true);
    return fail(why, "expected one of " + type_name() + ", got '" + text + "'");
  }
  std::string format(E value) const {
    for (const auto& [v, name] : names)
      if (v == value) return name;
    return std::to_string(static_cast<long long>(value));  // out of range: is_valid says so
  }
};

const EnumNames<core::FeatureBackend> kFeatureBackends = {{core::FeatureBackend::builtin, "builtin"},
                                                          {core::FeatureBackend::onnx, "onnx"}};

const EnumNames<core::TrackingTarget> kTrackingTargets = {{core::TrackingTarget::points, "points"},
                                                          {core::TrackingTarget::gaussians, "gaussians"}};
const EnumNames<core::MapperConfig::InsertFrom> kInsertFrom = {
    {core::MapperConfig::InsertFrom::lattice, "lattice"}, {core::MapperConfig::InsertFrom::source, "source"}};
const EnumNames<core::MapperConfig::FeatureLoss> kFeatureLoss = {
    {core::MapperConfig::FeatureLoss::decoded, "decoded"}, {core::MapperConfig::FeatureLoss::latent, "latent"}};
const EnumNames<core::MapTargetCovariance> kMapTargetCovariances = {
    {core::MapTargetCovariance::disc, "disc"},
    {core::MapTargetCovariance::shape, "shape"},
    {core::MapTargetCovariance::neighbours, "neighbours"}};
const EnumNames<core::RobustKernel> kRobustKernels = {{core::RobustKernel::none, "none"},
                                                      {core::RobustKernel::huber, "huber"},
                                                      {core::RobustKernel::cauchy, "cauchy"}};

// ---- the table builder -----------------------------------------------------------------------

// The members of one sub-struct, keyed "<prefix>.<name>". `access` is a generic lambda
// (auto& config) -> auto& that reaches the sub-struct from a Config, const or not.
template <class Config, class Access>
class Section {
 public:
  Section(SettingsTable<Config>* fields, std::string prefix, Access access)
      : fields_(fields), prefix_(std::move(prefix)), access_(access) {}

  template <class S, class T>
  void add(const char* name, T S::*member) const {
    fields_->push_back(
        {key(name), Codec<T>::kTypeName,
         [access = access_, member](Config* c, const std::string& text, std::string* why) {
           return Codec<T>::parse(text, &(access(*c).*member), why);
         },
         [access = access_, member](const Config& c) {
           return Codec<T>::format(access(c).*member);
         }});
  }

  template <class S, class E>
  void add(const char* name, E S::*member, const EnumNames<E>& names) const {
    const EnumCodec<E> codec{names};
    fields_->push_back(
        {key(name), codec.type_name(),
         [access = access_, member, codec](Config* c, const std::string& text,
                                           std::string* why) {
           return codec.parse(text, &(access(*c).*member), why);
         },
         [access = access_, member, codec](const Config& c) {
           return codec.format(access(c).*member);
         }});
  }

 private:
  std::string key(const char* name) const { return prefix_.empty() ? name : prefix_ + "." + name; }
  SettingsTable<Config>* fields_;
  std::string prefix_;
  Access access_;
};

template <class Config, class Access>
Section<Config, Access> section(SettingsTable<Config>* fields, std::string prefix, Access access) {
  return Section<Config, Access>(fields, std::move(prefix), access);
}

// `table`'s settings on the `Part` that `access` reaches inside an `Outer`, under the same keys.
template <class Outer, class Part, class Access>
void add_nested(SettingsTable<Outer>* fields, const SettingsTable<Part>& table, Access access) {
  for (const Setting<Part>& s : table) {
    fields->push_back({s.key, s.type_name,
                       [access, set = s.set](Outer* c, const std::string& text, std::string* why) {
                         return set(&access(*c), text, why);
                       },
                       [access, get = s.get](const Outer& c) { return get(access(c)); }});
  }
}

// ---- core::PipelineConfig --------------------------------------------------------------------

void add_pipeline_fields(SettingsTable<core::PipelineConfig>* f) {
  using Pipeline = core::PipelineConfig;
  const auto pipeline = section(f, "", [](auto& c) -> auto& { return c; });
  pipeline.add("realtime", &Pipeline::realtime);
  pipeline.add("min_iterations_when_behind", &Pipeline::min_iterations_when_behind);
  pipeline.add("idle_iterations", &Pipeline::idle_iterations);
  pipeline.add("max_idle_iterations", &Pipeline::max_idle_iterations);
  pipeline.add("max_queued_keyframes", &Pipeline::max_queued_keyframes);
  pipeline.add("track_with_features", &Pipeline::track_with_features);
  pipeline.add("tracking_encoder_input", &Pipeline::tracking_encoder_input);

  using Tracker = core::TrackerConfig;
  const auto tracker = section(f, "tracker", [](auto& c) -> auto& { return c.tracker; });
  tracker.add("constant_velocity", &Tracker::constant_velocity);
  tracker.add("refresh_features", &Tracker::refresh_features);
  tracker.add("wide_baseline_inlier_ratio", &Tracker::wide_baseline_inlier_ratio);
  tracker.add("parallel", &Tracker::parallel);
  tracker.add("target", &Tracker::target, kTrackingTargets);

  using Preprocess = core::PreprocessConfig;
  const auto pre = section(f, "tracker.preprocess",
                           [](auto& c) -> auto& { return c.tracker.preprocess; });
  pre.add("min_depth", &Preprocess::min_depth);
  pre.add("max_depth", &Preprocess::max_depth);
  pre.add("stride", &Preprocess::stride);
  pre.add("voxel_size", &Preprocess::voxel_size);

  using Covariance = core::CovarianceConfig;
  const auto cov = section(f, "tracker.preprocess.covariance",
                           [](auto& c) -> auto& { return c.tracker.preprocess.covariance; });
  cov.add("min_neighbours", &Covariance::min_neighbours);
  cov.add("knn", &Covariance::knn);
  cov.add("window_radius", &Covariance::window_radius);
  cov.add("max_neighbour_distance", &Covariance::max_neighbour_distance);
  cov.add("plane_epsilon", &Covariance::plane_epsilon);

  using DepthNoise = core::DepthNoiseModel;
  const auto noise = section(f, "tracker.preprocess.depth_noise",
                             [](auto& c) -> auto& { return c.tracker.preprocess.depth_noise; });
  noise.add("enabled", &DepthNoise::enabled);
  noise.add("a", &DepthNoise::a);
  noise.add("b", &DepthNoise::b);
  noise.add("z0", &DepthNoise::z0);
  noise.add("reference_depth", &DepthNoise::reference_depth);

  using LocalMap = core::LocalMapConfig;
  const auto local = section(f, "tracker.local_map",
                             [](auto& c) -> auto& { return c.tracker.local_map; });
  local.add("voxel_size", &LocalMap::voxel_size);
  local.add("min_point_distance", &LocalMap::min_point_distance);
  local.add("fuse", &LocalMap::fuse);
  local.add("max_points_per_voxel", &LocalMap::max_points_per_voxel);
  local.add("radius", &LocalMap::radius);

  using MapTarget = core::MapTargetConfig;
  const auto map_target = section(f, "tracker.map_target",
                                  [](auto& c) -> auto& { return c.tracker.map_target; });
  map_target.add("min_opacity", &MapTarget::min_opacity);
  map_target.add("min_point_distance", &MapTarget::min_point_distance);
  map_target.add("covariance", &MapTarget::covariance, kMapTargetCovariances);
  map_target.add("wait_for_mapper", &MapTarget::wait_for_mapper);
  map_target.add("observation_weight", &MapTarget::observation_weight);

  using Gicp = core::GicpConfig;
  const auto gicp = section(f, "tracker.gicp", [](auto& c) -> auto& { return c.tracker.gicp; });
  gicp.add("max_iterations", &Gicp::max_iterations);
  gicp.add("max_correspondence_distance", &Gicp::max_correspondence_distance);
  gicp.add("kernel", &Gicp::kernel, kRobustKernels);
  gicp.add("kernel_scale", &Gicp::kernel_scale);
  gicp.add("translation_epsilon", &Gicp::translation_epsilon);
  gicp.add("rotation_epsilon", &Gicp::rotation_epsilon);
  gicp.add("lm_lambda", &Gicp::lm_lambda);
  gicp.add("use_opacity", &Gicp::use_opacity);
  gicp.add("use_features", &Gicp::use_features);
  gicp.add("feature_gamma", &Gicp::feature_gamma);
  gicp.add("feature_noise", &Gicp::feature_noise);
  gicp.add("feature_residual_weight", &Gicp::feature_residual_weight);

  using Keyframe = core::KeyframeConfig;
  const auto keyframe = section(f, "tracker.keyframe",
                                [](auto& c) -> auto& { return c.tracker.keyframe; });
  keyframe.add("translation", &Keyframe::translation);
  keyframe.add("rotation_deg", &Keyframe::rotation_deg);
  keyframe.add("rms_residual", &Keyframe::rms_residual);

  using Loss = core::TrackingLossConfig;
  const auto loss = section(f, "tracker.loss", [](auto& c) -> auto& { return c.tracker.loss; });
  loss.add("min_inlier_ratio", &Loss::min_inlier_ratio);
  loss.add("min_inliers", &Loss::min_inliers);
  loss.add("max_condition_number", &Loss::max_condition_number);
  loss.add("recovery_keyframes", &Loss::recovery_keyframes);

  using Reloc = core::RelocaliserConfig;
  const auto reloc = section(f, "tracker.relocalisation",
                             [](auto& c) -> auto& { return c.tracker.relocalisation; });
  reloc.add("enabled", &Reloc::enabled);
  reloc.add("orb_features", &Reloc::orb_features);
  reloc.add("thumbnail_width", &Reloc::thumbnail_width);
  reloc.add("candidates", &Reloc::candidates);
  reloc.add("ratio_test", &Reloc::ratio_test);
  reloc.add("ransac_iterations", &Reloc::ransac_iterations);
  reloc.add("inlier_distance", &Reloc::inlier_distance);
  reloc.add("min_inliers", &Reloc::min_inliers);
  reloc.add("min_verified_inlier_ratio", &Reloc::min_verified_inlier_ratio);
  reloc.add("max_verified_translation", &Reloc::max_verified_translation);
  reloc.add("max_verified_rotation_deg", &Reloc::max_verified_rotation_deg);
  reloc.add("max_keyframes", &Reloc::max_keyframes);
  reloc.add("revisit_translation", &Reloc::revisit_translation);
  reloc.add("revisit_rotation_deg", &Reloc::revisit_rotation_deg);

  using Loop = core::LoopClosureConfig;
  const auto loop = section(f, "loop_closure", [](auto& c) -> auto& { return c.loop_closure; });
  loop.add("enabled", &Loop::enabled);
  loop.add("min_frame_gap", &Loop::min_frame_gap);
  loop.add("candidates", &Loop::candidates);
  loop.add("min_verified_inlier_ratio", &Loop::min_verified_inlier_ratio);
  loop.add("verification_points", &Loop::verification_points);
  loop.add("max_keyframes", &Loop::max_keyframes);
  loop.add("odometry_translation_sigma", &Loop::odometry_translation_sigma);
  loop.add("odometry_rotation_sigma", &Loop::odometry_rotation_sigma);
  loop.add("loop_translation_sigma", &Loop::loop_translation_sigma);
  loop.add("loop_rotation_sigma", &Loop::loop_rotation_sigma);
}

// The mapper's settings and the latent features' (mapper.*, features.*), in the table after the
// pipeline's and the tracker's.
void add_mapper_fields(SettingsTable<core::PipelineConfig>* f) {
  using Mapper = core::MapperConfig;
  const auto mapper = section(f, "mapper", [](auto& c) -> auto& { return c.mapper; });
  mapper.add("sh_degree", &Mapper::sh_degree);
  // feature_dim is not a setting: the autoencoder's weights file carries the latent width and
  // SlamPipeline takes it from there (0 without features).
  mapper.add("training_scale", &Mapper::training_scale);
  mapper.add("refine_scale", &Mapper::refine_scale);
  mapper.add("insert_stride", &Mapper::insert_stride);
  mapper.add("max_gaussians", &Mapper::max_gaussians);
  mapper.add("revisit_translation", &Mapper::revisit_translation);
  mapper.add("max_stored_keyframes", &Mapper::max_stored_keyframes);
  mapper.add("revisit_rotation_deg", &Mapper::revisit_rotation_deg);
  mapper.add("insert_from", &Mapper::insert_from, kInsertFrom);
  mapper.add("source_min_distance", &Mapper::source_min_distance);
  mapper.add("feature_loss", &Mapper::feature_loss, kFeatureLoss);
  mapper.add("feature_samples", &Mapper::feature_samples);
  mapper.add("new_alpha", &Mapper::new_alpha);
  mapper.add("new_depth_margin", &Mapper::new_depth_margin);
  mapper.add("new_depth_relative", &Mapper::new_depth_relative);
  mapper.add("min_depth", &Mapper::min_depth);
  mapper.add("max_depth", &Mapper::max_depth);
  mapper.add("initial_opacity", &Mapper::initial_opacity);
  mapper.add("initial_scale_factor", &Mapper::initial_scale_factor);
  mapper.add("initial_thickness", &Mapper::initial_thickness);
  mapper.add("iterations_per_keyframe", &Mapper::iterations_per_keyframe);
  mapper.add("newest_keyframe_probability", &Mapper::newest_keyframe_probability);
  mapper.add("prune_percentile_tracking", &Mapper::prune_percentile_tracking);
  mapper.add("prune_percentile_mapping", &Mapper::prune_percentile_mapping);
  mapper.add("prune_new_only", &Mapper::prune_new_only);
  mapper.add("mapping_keyframe_translation", &Mapper::mapping_keyframe_translation);
  mapper.add("mapping_keyframe_rotation_deg", &Mapper::mapping_keyframe_rotation_deg);
  mapper.add("min_opacity", &Mapper::min_opacity);
  mapper.add("max_scale", &Mapper::max_scale);
  mapper.add("filter_3d_factor", &Mapper::filter_3d_factor);
  mapper.add("seed", &Mapper::seed);

  // RenderSettings::background is a colour triple, not a scalar: not in the table.
  using Render = core::RenderSettings;
  const auto render = section(f, "mapper.render", [](auto& c) -> auto& { return c.mapper.render; });
  render.add("near_plane", &Render::near_plane);
  render.add("features", &Render::features);

  using Rates = core::GaussianLearningRates;
  const auto lr = section(f, "mapper.learning_rates",
                          [](auto& c) -> auto& { return c.mapper.learning_rates; });
  lr.add("means", &Rates::means);
  lr.add("means_decay_steps", &Rates::means_decay_steps);
  lr.add("means_decay_floor", &Rates::means_decay_floor);
  lr.add("sh_dc", &Rates::sh_dc);
  lr.add("sh_rest", &Rates::sh_rest);
  lr.add("opacity", &Rates::opacity);
  lr.add("log_scales", &Rates::log_scales);
  lr.add("rotations", &Rates::rotations);
  lr.add("features", &Rates::features);

  using Weights = core::MappingLossWeights;
  const auto weights = section(f, "mapper.loss", [](auto& c) -> auto& { return c.mapper.loss; });
  weights.add("rgb_l1", &Weights::rgb_l1);
  weights.add("rgb_ssim", &Weights::rgb_ssim);
  weights.add("feature_l1", &Weights::feature_l1);
  weights.add("depth_l1", &Weights::depth_l1);
  weights.add("depth_pcc", &Weights::depth_pcc);
  weights.add("normal", &Weights::normal);
  weights.add("erank_lambda_0", &Weights::erank_lambda_0);
  weights.add("erank_lambda_max", &Weights::erank_lambda_max);
  weights.add("erank_ramp_steps", &Weights::erank_ramp_steps);
  weights.add("erank_epsilon", &Weights::erank_epsilon);
  weights.add("thin", &Weights::thin);

  using Features = core::LatentFeaturesConfig;
  const auto features = section(f, "features", [](auto& c) -> auto& { return c.features; });
  features.add("autoencoder_path", &Features::autoencoder_path);
  features.add("grid_step", &Features::grid_step);
  using Encoder = core::FeatureEncoderConfig;
  const auto encoder = section(f, "features.encoder", [](auto& c) -> auto& { return c.features.encoder; });
  encoder.add("backend", &Encoder::backend, kFeatureBackends);
  using Builtin = core::BuiltinFeatureConfig;
  const auto builtin = section(f, "features.encoder.builtin",
                               [](auto& c) -> auto& { return c.features.encoder.builtin; });
  builtin.add("input_width", &Builtin::input_width);
  builtin.add("input_height", &Builtin::input_height);
  using Onnx = core::OnnxFeatureConfig;
  const auto onnx = section(f, "features.encoder.onnx",
                            [](auto& c) -> auto& { return c.features.encoder.onnx; });
  onnx.add("model_path", &Onnx::model_path);
  onnx.add("input_width", &Onnx::input_width);
  onnx.add("input_height", &Onnx::input_height);

  using Pcc = core::PccConfig;
  const auto pcc = section(f, "mapper.loss.pcc", [](auto& c) -> auto& { return c.mapper.loss.pcc; });
  pcc.add("block", &Pcc::block);
  pcc.add("min_valid_pixels", &Pcc::min_valid_pixels);
  pcc.add("min_std", &Pcc::min_std);
}

// ---- dataset.*: ServerConfig's and RunConfig's ---------------------------------------------

template <class Config>
void add_dataset_fields(SettingsTable<Config>* f) {
  const auto dataset = section(f, "dataset", [](auto& c) -> auto& { return c.dataset; });
  dataset.add("intrinsics", &DatasetSettings::intrinsics);
  dataset.add("colour_camera", &DatasetSettings::colour_camera);
}

// ---- ServerConfig's own settings (server.*) --------------------------------------------------
// Kept apart from the pipeline's: new server fields are added here. `domain` is deliberately not
// a setting: it picks the DDS network, a deployment choice made on the command line (--domain).

void add_server_fields(SettingsTable<ServerConfig>* f) {
  const auto server = section(f, "server", [](auto& c) -> auto& { return c; });
  server.add("prefix", &ServerConfig::prefix);
  server.add("frame_policy", &ServerConfig::frame_policy);
  server.add("instance", &ServerConfig::instance);
  server.add("map_group", &ServerConfig::map_group);
  server.add("health_file", &ServerConfig::health_file);
  server.add("queue_capacity", &ServerConfig::queue_capacity);
  server.add("mapping_threads", &ServerConfig::mapping_threads);
  server.add("pipelined_tracking", &ServerConfig::pipelined_tracking);
  server.add("status_period_ms", &ServerConfig::status_period_ms);
  server.add("map_dir", &ServerConfig::map_dir);
  server.add("load_maps_at_start", &ServerConfig::load_maps_at_start);
  server.add("save_maps_at_shutdown", &ServerConfig::save_maps_at_shutdown);
  server.add("query_threads", &ServerConfig::query_threads);
  server.add("query_queue_capacity", &ServerConfig::query_queue_capacity);
  server.add("max_render_pixels", &ServerConfig::max_render_pixels);
  server.add("max_sessions", &ServerConfig::max_sessions);
  server.add("max_maps", &ServerConfig::max_maps);
  server.add("max_prompts", &ServerConfig::max_prompts);
  server.add("max_refine_steps", &ServerConfig::max_refine_steps);
  server.add("min_free_disk_mb", &ServerConfig::min_free_disk_mb);
  server.add("session_lease_s", &ServerConfig::session_lease_s);
  server.add("max_session_fps", &ServerConfig::max_session_fps);
  server.add("max_client_requests_per_s", &ServerConfig::max_client_requests_per_s);
  server.add("grounding_model", &ServerConfig::grounding_model);
  server.add("grounding_input_size", &ServerConfig::grounding_input_size);
  server.add("grounding_box_threshold", &ServerConfig::grounding_box_threshold);
  add_dataset_fields(f);
  // Last, so that the printed configuration keeps the order of the keys before it.
  const auto compute = section(f, "compute", [](auto& c) -> auto& { return c.compute; });
  compute.add("backend", &ComputeSettings::backend);
}

// ---- ros2: the ROS 2 bridge (ros2_config.hpp, docs/ros2.md) -----------------------------------

void add_ros2_fields(std::vector<ConfigField>* f) {
  const auto ros2 = section(f, "ros2", [](auto& c) -> auto& { return c.ros2; });
  ros2.add("enabled", &Ros2Config::enabled);
  ros2.add("colour_topic", &Ros2Config::colour_topic);
  ros2.add("colour_transport", &Ros2Config::colour_transport);
  ros2.add("depth_topic", &Ros2Config::depth_topic);
  ros2.add("camera_info_topic", &Ros2Config::camera_info_topic);
  ros2.add("reliability", &Ros2Config::reliability);
  ros2.add("stamp_tolerance_ms", &Ros2Config::stamp_tolerance_ms);
  ros2.add("session", &Ros2Config::session);
  ros2.add("map", &Ros2Config::map);
  ros2.add("frame_policy", &Ros2Config::frame_policy);
  ros2.add("pose_topic", &Ros2Config::pose_topic);
  ros2.add("path_topic", &Ros2Config::path_topic);
  ros2.add("tf_topic", &Ros2Config::tf_topic);
  ros2.add("map_frame", &Ros2Config::map_frame);
  ros2.add("camera_frame", &Ros2Config::camera_frame);
}

// ---- lookup and messages ---------------------------------------------------------------------

std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t substitution = diagonal + (a[i - 1] == b[j - 1] ? 0 : 1);
      diagonal = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, substitution});
    }
  }
  return row[b.size()];
}

// The key a typo or an old short name most likely meant: one that ends in `.key` (the names
// `fslam run --set` took before the table), else the closest by edit distance if close enough.
template <class Config>
std::string nearest_key(const SettingsTable<Config>& table, const std::string& key) {
  std::string best;
  std::size_t best_distance = key.size() / 3 + 2;
  for (const Setting<Config>& field : table) {
    const std::string& k = field.key;
    if (k.size() > key.size() && k.compare(k.size() - key.size(), key.size(), key) == 0 &&
        k[k.size() - key.size() - 1] == '.')
      return k;
    const std::size_t d = edit_distance(key, k);
    if (d < best_distance) best = k, best_distance = d;
  }
  return best;
}

template <class Config>
bool is_group(const SettingsTable<Config>& table, const std::string& key) {
  const std::string prefix = key + ".";
  for (const Setting<Config>& field : table)
    if (field.key.compare(0, prefix.size(), prefix) == 0) return true;
  return false;
}

template <class Config>
std::string unknown_setting(const SettingsTable<Config>& table, const std::string& key) {
  if (is_group(table, key)) return "'" + key + "' is a group of settings, not one value";
  const std::string nearest = nearest_key(table, key);
  return "unknown setting '" + key + "'" + (nearest.empty() ? "" : " (did you mean " + nearest + "?)");
}

template <class Config>
bool load_map(const YAML::Node& map, const std::string& prefix, const std::string& path,
              Config* config, std::string* why) {
  const SettingsTable<Config>& table = settings_of(config);
  for (const auto& item : map) {
    const std::string key = prefix + item.first.Scalar();
    const YAML::Node& value = item.second;
    const std::string where = path + ":" + std::to_string(item.first.Mark().line + 1) + ": ";
    const bool group = is_group(table, key);
    if (value.IsMap() && group) {
      if (!load_map(value, key + ".", path, config, why)) return false;
    } else if (value.IsNull() && group) {
      // A group whose entries are all commented out sets nothing.
    } else if (!find_setting(table, key)) {
      return fail(why, where + unknown_setting(table, key));
    } else if (value.IsNull()) {
      return fail(why, where + "'" + key + "' has no value");
    } else if (!value.IsScalar()) {
      return fail(why, where + "'" + key + "' takes one value, not " +
                           (value.IsMap() ? "a map" : "a list"));
    } else if (std::string reason; !set_config_value(config, key, value.Scalar(), &reason)) {
      return fail(why, where + reason);
    }
  }
  return true;
}

}  // namespace

const SettingsTable<core::PipelineConfig>& pipeline_settings() {
  static const SettingsTable<core::PipelineConfig> fields = [] {
    SettingsTable<core::PipelineConfig> f;
    add_pipeline_fields(&f);
    add_mapper_fields(&f);
    return f;
  }();
  return fields;
}

const SettingsTable<RunConfig>& run_settings() {
  static const SettingsTable<RunConfig> fields = [] {
    SettingsTable<RunConfig> f;
    add_nested(&f, pipeline_settings(), [](auto& c) -> auto& { return c.pipeline; });
    add_dataset_fields(&f);
    return f;
  }();
  return fields;
}

const std::vector<ConfigField>& config_fields() {
  static const std::vector<ConfigField> fields = [] {
    std::vector<ConfigField> f;
    add_nested(&f, pipeline_settings(), [](auto& c) -> auto& { return c.pipeline; });
    add_server_fields(&f);
    add_ros2_fields(&f);
    return f;
  }();
  return fields;
}

template <class Config>
const Setting<Config>* find_setting(const SettingsTable<Config>& table, const std::string& key) {
  for (const Setting<Config>& field : table)
    if (field.key == key) return &field;
  return nullptr;
}

template <class Config>
bool set_config_value(Config* config, const std::string& key, const std::string& value,
                      std::string* why) {
  const SettingsTable<Config>& table = settings_of(config);
  const Setting<Config>* field = find_setting(table, key);
  if (!field) return fail(why, unknown_setting(table, key));
  std::string reason;
  if (!field->set(config, value, &reason)) return fail(why, key + ": " + reason);
  return true;
}

template <class Config>
bool set_config_assignment(Config* config, const std::string& assignment, std::string* why) {
  const auto eq = assignment.find('=');
  if (eq == std::string::npos) return fail(why, "expected key=value, got '" + assignment + "'");
  return set_config_value(config, assignment.substr(0, eq), assignment.substr(eq + 1), why);
}

template <class Config>
bool load_config_file(const std::string& path, Config* config, std::string* why) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    return fail(why, path + ": cannot read the file");
  } catch (const YAML::Exception& e) {
    return fail(why, path + ":" + std::to_string(e.mark.line + 1) + ": " + e.msg);
  }
  if (root.IsNull()) return true;  // empty, or only comments: overrides nothing
  if (!root.IsMap()) return fail(why, path + ": expected a map of settings at the top level");
  return load_map(root, "", path, config, why);
}

template <class Config>
std::string effective_config_yaml(const Config& config) {
  YAML::Node root(YAML::NodeType::Map);
  for (const Setting<Config>& field : settings_of(&config)) {
    YAML::Node node = root;
    std::size_t begin = 0;
    for (std::size_t dot; (dot = field.key.find('.', begin)) != std::string::npos; begin = dot + 1)
      node.reset(node[field.key.substr(begin, dot - begin)]);
    node[field.key.substr(begin)] = field.get(config);
  }
  YAML::Emitter out;
  out << root;
  return std::string(out.c_str()) + "\n";
}

// The three tables' instantiations.
#define FSLAM_SETTINGS_FUNCTIONS(Config)                                                        \
  template const Setting<Config>* find_setting(const SettingsTable<Config>&, const std::string&); \
  template bool set_config_value(Config*, const std::string&, const std::string&, std::string*); \
  template bool set_config_assignment(Config*, const std::string&, std::string*);               \
  template bool load_config_file(const std::string&, Config*, std::string*);                    \
  template std::string effective_config_yaml(const Config&);
FSLAM_SETTINGS_FUNCTIONS(core::PipelineConfig)
FSLAM_SETTINGS_FUNCTIONS(RunConfig)
FSLAM_SETTINGS_FUNCTIONS(ServerConfig)
#undef FSLAM_SETTINGS_FUNCTIONS

}  // namespace fslam::server

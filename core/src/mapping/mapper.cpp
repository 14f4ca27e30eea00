#include "fslam/core/mapping/mapper.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <unordered_set>
#include <utility>

#include <opencv2/imgproc.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/tracking/keyframe_policy.hpp"

namespace fslam::core {
namespace {

double ms_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

// Quaternion (w, x, y, z) of a rotation whose third column is the unit vector n.
void rotation_to_normal(const Eigen::Vector3f& n, float q[4]) {
  const Eigen::Quaternionf rot = Eigen::Quaternionf::FromTwoVectors(Eigen::Vector3f::UnitZ(), n);
  q[0] = rot.w();
  q[1] = rot.x();
  q[2] = rot.y();
  q[3] = rot.z();
}

float logit(float p) { return std::log(p / (1.0f - p)); }

}  // namespace

bool MapperConfig::is_valid(std::string* why) const {
  if (sh_degree < 0 || sh_degree > kMaxShDegree) return fail(why, "mapper: sh_degree must be 0..3");
  if (feature_dim < 0) return fail(why, "mapper: feature_dim must be >= 0");
  if (max_gaussians < 0) return fail(why, "mapper: max_gaussians must be >= 0 (0: no bound)");
  if (!(revisit_translation >= 0.0) || !(revisit_rotation_deg >= 0.0))
    return fail(why, "mapper: revisit_translation and revisit_rotation_deg must be >= 0 (0: keep every keyframe)");
  if (max_stored_keyframes < 3) return fail(why, "mapper: max_stored_keyframes must be >= 3");
  if (!(training_scale > 0.0 && training_scale <= 1.0)) {
    return fail(why, "mapper: training_scale must be in (0, 1]");
  }
  if (!(refine_scale >= 0.0 && refine_scale <= 1.0)) {
    return fail(why, "mapper: refine_scale must be in [0, 1] (0: refine at training_scale)");
  }
  if (insert_stride < 1) return fail(why, "mapper: insert_stride must be >= 1");
  if (!(initial_opacity > 0.0f && initial_opacity < 1.0f)) {
    return fail(why, "mapper: initial_opacity must be in (0, 1)");
  }
  if (iterations_per_keyframe < 0) return fail(why, "mapper: iterations_per_keyframe must be >= 0");
  if (feature_samples < 1) return fail(why, "mapper: feature_samples must be >= 1");
  if (!(prune_percentile_tracking >= 0.0 && prune_percentile_tracking < 1.0 &&
        prune_percentile_mapping >= 0.0 && prune_percentile_mapping < 1.0)) {
    return fail(why, "mapper: pruning percentiles must be in [0, 1)");
  }
  if (!(min_depth > 0.0f && max_depth > min_depth)) return fail(why, "mapper: bad depth range");
  if (learning_rates.means_decay_steps < 0)
    return fail(why, "mapper: learning_rates.means_decay_steps must be >= 0 (0: a constant rate)");
  if (!(learning_rates.means_decay_floor > 0.0f && learning_rates.means_decay_floor <= 1.0f))
    return fail(why, "mapper: learning_rates.means_decay_floor must be in (0, 1]");
  return validate(loss.pcc, why);
}

Mapper::Mapper(const MapperConfig& config, std::shared_ptr<const Rasterizer> rasterizer)
    : config_(config), rasterizer_(std::move(rasterizer)), rng_(config.seed) {
  map_.sh_degree = config_.sh_degree;
  map_.feature_dim = config_.feature_dim;
  adam_ = make_gaussian_adam(map_, config_.learning_rates);
}

bool Mapper::store(const MapperKeyframe& keyframe, StoredKeyframe* out, std::string* why) const {
  std::string reason;
  if (!keyframe.camera.is_valid(&reason)) return fail(why, "keyframe: " + reason);
  const cv::Size size(keyframe.camera.width, keyframe.camera.height);
  if (keyframe.colour.type() != CV_8UC3 || keyframe.colour.size() != size) {
    return fail(why, "keyframe: colour must be CV_8UC3 of the camera's size");
  }
  if (keyframe.depth.type() != CV_32FC1 || keyframe.depth.size() != size) {
    return fail(why, "keyframe: depth must be CV_32FC1 of the camera's size");
  }
  if (!keyframe.T_world_camera.matrix().allFinite()) return fail(why, "keyframe: non-finite pose");
  const PinholeCamera cam = keyframe.camera.scaled(config_.training_scale);
  if (!keyframe.feature_target.empty() &&
      (keyframe.feature_target.width != cam.width || keyframe.feature_target.height != cam.height ||
       keyframe.feature_target.channels != config_.feature_dim)) {
    return fail(why, "keyframe: feature target must be [D, h, w] at the training resolution");
  }
  if (!keyframe.feature_observation.empty() &&
      (keyframe.feature_observation.width != cam.width || keyframe.feature_observation.height != cam.height ||
       (decoder_ && keyframe.feature_observation.channels != decoder_->input_dim()))) {
    return fail(why, "keyframe: feature observation must be of the training image, with the decoder's channels");
  }
  out->frame_id = keyframe.frame_id;
  out->input_camera = keyframe.camera;
  out->feature_target = keyframe.feature_target;
  out->feature_observation = keyframe.feature_observation;
  cv::Mat colour, depth;
  cv::resize(keyframe.colour, colour, cv::Size(cam.width, cam.height), 0, 0, cv::INTER_AREA);
  // Nearest neighbour: averaging depth across an edge invents surfaces that are not there.
  cv::resize(keyframe.depth, depth, cv::Size(cam.width, cam.height), 0, 0, cv::INTER_NEAREST);
  if (!make_view(colour, depth, cam, keyframe.T_world_camera, out, why)) return false;
  // The refinement's (and a saved map's) images, kept as 8-bit colour and float depth.
  if (config_.refine_scale > config_.training_scale) {
    const PinholeCamera rcam = keyframe.camera.scaled(config_.refine_scale);
    cv::resize(keyframe.colour, out->refine_colour, cv::Size(rcam.width, rcam.height), 0, 0,
               cv::INTER_AREA);
    cv::resize(keyframe.depth, out->refine_depth, cv::Size(rcam.width, rcam.height), 0, 0,
               cv::INTER_NEAREST);
  } else {
    out->refine_colour = colour;
    out->refine_depth = depth;
  }
  return true;
}

bool Mapper::restore_keyframes(const std::vector<KeyframeImages>& images, std::string* why) {
  if (!keyframes_.empty()) return fail(why, "restore keyframes: the mapper already stores keyframes");
  std::vector<StoredKeyframe> restored;
  restored.reserve(images.size());
  for (std::size_t i = 0; i < images.size(); ++i) {
    const KeyframeImages& k = images[i];
    const std::string what = "restore keyframes: keyframe " + std::to_string(i) + ": ";
    std::string reason;
    if (!k.input_camera.is_valid(&reason)) return fail(why, what + reason);
    const PinholeCamera kept = k.input_camera.scaled(kept_scale());
    const cv::Size size(kept.width, kept.height);
    if (k.colour.type() != CV_8UC3 || k.depth.type() != CV_32FC1 || k.colour.size() != size ||
        k.depth.size() != size) {
      return fail(why, what + "colour (8-bit RGB) and depth (float) must be " + std::to_string(kept.width) + "x" +
                           std::to_string(kept.height) + ", the input camera at the mapper's kept scale " +
                           std::to_string(kept_scale()));
    }
    if (!k.T_world_camera.matrix().allFinite()) return fail(why, what + "non-finite pose");
    StoredKeyframe kf;
    kf.frame_id = static_cast<std::int64_t>(i) - static_cast<std::int64_t>(images.size());  // -n..-1
    kf.input_camera = k.input_camera;
    const PinholeCamera cam = k.input_camera.scaled(config_.training_scale);
    cv::Mat colour, depth;
    cv::resize(k.colour, colour, cv::Size(cam.width, cam.height), 0, 0, cv::INTER_AREA);
    cv::resize(k.depth, depth, cv::Size(cam.width, cam.height), 0, 0, cv::INTER_NEAREST);
    if (!make_view(colour, depth, cam, k.T_world_camera, &kf, why)) return false;
    kf.refine_colour = k.colour;
    kf.refine_depth = k.depth;
    restored.push_back(std::move(kf));
  }
  keyframes_ = std::move(restored);
  while (keyframes_.size() > config_.max_stored_keyframes) drop_most_redundant_keyframe();
  publish();
  return true;
}

bool Mapper::make_view(const cv::Mat& colour, const cv::Mat& depth, const PinholeCamera& cam,
                       const Eigen::Isometry3d& T_world_camera, StoredKeyframe* out,
                       std::string* why) const {
  out->view.camera = cam;
  out->view.T_camera_world = T_world_camera.inverse();
  out->colour = PlanarImage(cam.width, cam.height, 3);
  out->depth = PlanarImage(cam.width, cam.height, 1);
  for (int v = 0; v < cam.height; ++v) {
    const cv::Vec3b* c = colour.ptr<cv::Vec3b>(v);
    const float* d = depth.ptr<float>(v);
    for (int u = 0; u < cam.width; ++u) {
      for (int k = 0; k < 3; ++k) out->colour.at(k, v, u) = c[u][k] / 255.0f;
      const float z = d[u];
      out->depth.at(0, v, u) =
          (std::isfinite(z) && z > config_.min_depth && z < config_.max_depth) ? z : 0.0f;
    }
  }
  return depth_to_normals(out->depth, cam.intrinsics(), &out->normals, why);
}

// The keyframe at refine_scale from the images it keeps, its feature target resampled
// bilinearly from the training resolution.
bool Mapper::refine_view(const StoredKeyframe& kf, StoredKeyframe* out, std::string* why) const {
  out->frame_id = kf.frame_id;
  out->input_camera = kf.input_camera;
  const PinholeCamera cam = kf.input_camera.scaled(config_.refine_scale);
  if (!make_view(kf.refine_colour, kf.refine_depth, cam, kf.view.T_camera_world.inverse(), out,
                 why)) {
    return false;
  }
  out->feature_observation = kf.feature_observation;  // its pixels are scaled onto the view in step
  out->feature_target = PlanarImage();
  if (!kf.feature_target.empty()) {
    const PlanarImage& t = kf.feature_target;
    out->feature_target = PlanarImage(cam.width, cam.height, t.channels);
    for (int c = 0; c < t.channels; ++c) {
      const cv::Mat plane(t.height, t.width, CV_32FC1, const_cast<float*>(t.plane(c)));
      cv::Mat dst(cam.height, cam.width, CV_32FC1, out->feature_target.plane(c));
      cv::resize(plane, dst, dst.size(), 0, 0, cv::INTER_LINEAR);
    }
  }
  return true;
}

// Gaussians where the map does not explain the keyframe: low rendered opacity, or a rendered
// surface behind the observed one (something new in front).
bool Mapper::covered(const RenderResult& rendered, int u, int v, float z) const {
  const float alpha = rendered.alpha.at(0, v, u);
  const float median = rendered.median_depth.at(0, v, u);
  return alpha >= config_.new_alpha && median > 0.0f &&
         median - z <= config_.new_depth_margin + config_.new_depth_relative * z;
}

void Mapper::insert_one(const StoredKeyframe& kf, int u, int v, const Eigen::Vector3f& p_world,
                        const Eigen::Vector3f& n_world, float sigma_plane, float sigma_normal, float z,
                        std::vector<float>* sh) {
  float q[4];
  rotation_to_normal(n_world, q);  // a disc: the normal's sign does not matter
  const float log_scale[3] = {std::log(sigma_plane), std::log(sigma_plane), std::log(sigma_normal)};
  for (int c = 0; c < 3; ++c) (*sh)[c] = rgb_to_sh_dc(kf.colour.at(c, v, u));
  std::vector<float> f;
  if (!kf.feature_target.empty()) {
    f.resize(static_cast<std::size_t>(config_.feature_dim));
    for (int c = 0; c < config_.feature_dim; ++c) f[c] = kf.feature_target.at(c, v, u);
  }
  const float mean[3] = {p_world.x(), p_world.y(), p_world.z()};
  // Mip-Splatting 3D filter from the sensor's sampling rate at this depth (refined by refine()):
  // the input image's focal length, not the reduced training one, so that the filter does not
  // blur renders at the input resolution.
  const float fx_input = static_cast<float>(kf.view.camera.fx) / static_cast<float>(config_.training_scale);
  const float filter = config_.filter_3d_factor * (z / fx_input) * (z / fx_input);
  map_.push_back(mean, q, log_scale, logit(config_.initial_opacity), sh->data(),
                 f.empty() ? nullptr : f.data(), filter);
  anchor_.push_back(kf.frame_id);
}

std::size_t Mapper::insert_gaussians(const StoredKeyframe& kf, const MapperKeyframe& input, bool* at_capacity) {
  const std::size_t capacity = config_.max_gaussians > 0 ? static_cast<std::size_t>(config_.max_gaussians)
                                                         : std::numeric_limits<std::size_t>::max();
  const auto full = [&] { return *at_capacity = map_.size() >= capacity; };
  const int W = kf.view.camera.width, H = kf.view.camera.height;
  RenderResult rendered;
  const bool have_map = !map_.empty();
  const bool from_source = config_.insert_from == MapperConfig::InsertFrom::source && !input.source_world.empty();
  if (have_map && !from_source) {
    RenderSettings settings = config_.render;
    settings.features = false;
    std::string why;
    if (!rasterizer_->forward(map_, kf.view, settings, &rendered, &why)) return 0;
  }
  const Eigen::Isometry3d T_world_camera = kf.view.T_camera_world.inverse();
  const Eigen::Matrix3f R = T_world_camera.rotation().cast<float>();
  const Eigen::Vector3f t = T_world_camera.translation().cast<float>();
  const float fx = static_cast<float>(kf.view.camera.fx);
  const float fy = static_cast<float>(kf.view.camera.fy);
  const float cx = static_cast<float>(kf.view.camera.cx);
  const float cy = static_cast<float>(kf.view.camera.cy);
  const int K = sh_coefficients(config_.sh_degree);
  std::vector<float> sh(static_cast<std::size_t>(3 * K), 0.0f);
  const std::size_t before = map_.size();
  if (from_source) {
    // The tracker's source Gaussians where the map does not explain the keyframe yet: mean as
    // observed, the disc across the covariance's thinnest axis, in-plane sigma from the source
    // lattice's spacing on the surface.
    const GaussianPoints& src = input.source_world;
    const Eigen::Matrix3f Rt = R.transpose();
    // Cells of source_min_distance that hold a Gaussian mean (new ones included).
    const float inv_cell = 1.0f / config_.source_min_distance;
    auto cell_of = [&](const float* p) {
      const auto c = [&](float x) { return static_cast<std::int64_t>(std::floor(x * inv_cell)) & 0x1FFFFF; };
      return (c(p[0]) << 42) | (c(p[1]) << 21) | c(p[2]);
    };
    std::unordered_set<std::int64_t> occupied;
    occupied.reserve(map_.size() * 2);
    for (std::size_t i = 0; i < map_.size(); ++i) occupied.insert(cell_of(&map_.means[3 * i]));
    const float fx_input = fx / static_cast<float>(config_.training_scale);
    for (std::size_t i = 0; i < src.size(); ++i) {
      const Eigen::Vector3f p_cam = Rt * (src.means[i] - t);
      const float z = p_cam.z();
      if (!(z >= config_.min_depth && z <= config_.max_depth)) continue;
      const int u = static_cast<int>(std::lround(fx * p_cam.x() / z + cx));
      const int v = static_cast<int>(std::lround(fy * p_cam.y() / z + cy));
      if (u < 0 || v < 0 || u >= W || v >= H) continue;
      if (!occupied.insert(cell_of(src.means[i].data())).second) continue;
      if (full()) break;
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> eig(src.covariances[i]);
      const Eigen::Vector3f n = eig.eigenvectors().col(0);  // smallest eigenvalue first
      const float slant = std::max(0.25f, std::abs((Rt * n).dot(p_cam.normalized())));
      const float sigma = config_.initial_scale_factor * static_cast<float>(input.source_stride) * z / fx_input;
      insert_one(kf, u, v, src.means[i], n, sigma / std::sqrt(slant), sigma * config_.initial_thickness, z, &sh);
    }
  } else {
    const int stride = config_.insert_stride;
    for (int v = stride / 2; v < H && !full(); v += stride) {
      for (int u = stride / 2; u < W && !full(); u += stride) {
        const float z = kf.depth.at(0, v, u);
        if (z <= 0.0f) continue;
        if (have_map && covered(rendered, u, v, z)) continue;
        Eigen::Vector3f n_cam(kf.normals.at(0, v, u), kf.normals.at(1, v, u), kf.normals.at(2, v, u));
        if (n_cam.squaredNorm() < 0.5f) continue;  // no surface estimate: isolated or edge sample
        const Eigen::Vector3f p_cam((u - cx) * z / fx, (v - cy) * z / fy, z);
        // The lattice spacing on the surface: stride pixels at depth z, stretched by the slant.
        const float slant = std::max(0.25f, std::abs(n_cam.dot(p_cam.normalized())));
        const float sigma = config_.initial_scale_factor * stride * z / fx;
        insert_one(kf, u, v, R * p_cam + t, R * n_cam, sigma / std::sqrt(slant),
                   sigma * config_.initial_thickness, z, &sh);
      }
    }
  }
  const std::size_t added = map_.size() - before;
  adam_.grow(added);
  importance_.resize(map_.size(), 0.0f);
  seen_.resize(map_.size(), 0);
  new_in_round_.assign(map_.size(), 0);
  std::fill(new_in_round_.begin() + static_cast<std::ptrdiff_t>(before), new_in_round_.end(), 1);
  return added;
}

std::size_t Mapper::sample_keyframe(bool uniform) {
  const std::size_t n = keyframes_.size();
  if (!uniform) {
    std::bernoulli_distribution newest(config_.newest_keyframe_probability);
    if (newest(rng_)) return n - 1;
  }
  std::uniform_int_distribution<std::size_t> any(0, n - 1);
  return any(rng_);
}

// One gradient step on eq. total_loss for one keyframe's view.
bool Mapper::step(const StoredKeyframe& kf, MappingLosses* losses, std::string* why) {
  const MappingLossWeights& w = config_.loss;
  RenderSettings settings = config_.render;
  const bool decoded = decoded_features(kf);
  const bool features = (decoded || !kf.feature_target.empty()) && map_.feature_dim > 0 && w.feature_l1 > 0;
  settings.features = features;
  RenderResult r;
  if (!rasterizer_->forward(map_, kf.view, settings, &r, why)) return false;
  RenderGradients g;
  MappingLosses l;
  // L_rgb (eq. modeling_losses): lambda_1 L1 + lambda_2 (1 - SSIM).
  if (!l1_loss(r.colour, kf.colour, nullptr, w.rgb_l1, &l.rgb_l1, &g.colour, why)) return false;
  if (!ssim_loss(r.colour, kf.colour, nullptr, w.rgb_ssim, &l.rgb_ssim, &g.colour, why)) return false;
  // L_feat (eq. modeling_losses): lambda_f L1 of the decoded latent against the encoder's
  // pyramid (decoded), or of the latent against phi(u) (latent).
  if (features && decoded &&
      !decoded_feature_loss(kf, r.features, w.feature_l1, &l.feature_l1, &g.features, why)) {
    return false;
  }
  if (features && !decoded &&
      !l1_loss(r.features, kf.feature_target, nullptr, w.feature_l1, &l.feature_l1, &g.features, why)) {
    return false;
  }
  // L_depth: lambda_d L1 + lambda_pcc (1 - patch-wise Pearson) on the camera-plane depth.
  if (!depth_l1_loss(r.depth, kf.depth, nullptr, w.depth_l1, &l.depth_l1, &g.depth, why)) return false;
  if (w.depth_pcc > 0 &&
      !pcc_loss(r.depth, kf.depth, nullptr, w.pcc, w.depth_pcc, &l.depth_pcc, &g.depth, why)) {
    return false;
  }
  // L_nrm: cosine terms between normals of expected / median depth and the observed normals.
  if (w.normal > 0) {
    const math::Intrinsics k = kf.view.camera.intrinsics();
    PlanarImage n_exp, n_med, g_n_exp, g_n_med;
    if (!depth_to_normals(r.depth, k, &n_exp, why) ||
        !depth_to_normals(r.median_depth, k, &n_med, why) ||
        !normal_consistency_loss(n_exp, kf.normals, nullptr, w.normal, &l.normal_expected,
                                 &g_n_exp, why) ||
        !normal_consistency_loss(n_med, kf.normals, nullptr, w.normal, &l.normal_median,
                                 &g_n_med, why) ||
        !depth_to_normals_backward(r.depth, k, g_n_exp, &g.depth, why) ||
        !depth_to_normals_backward(r.median_depth, k, g_n_med, &g.median_depth, why)) {
      return false;
    }
  }
  grads_.reset(map_);
  if (!rasterizer_->backward(map_, kf.view, settings, r, g, &grads_, why)) return false;
  // L_erank (eq. erank_loss with the ramp of eq. lambda_ramp) and L_thin (eq. thin_loss).
  const double lambda_e =
      erank_lambda(static_cast<int>(step_), w.erank_lambda_0, w.erank_lambda_max, w.erank_ramp_steps);
  if (lambda_e > 0 &&
      !erank_loss(map_.log_scales, lambda_e, w.erank_epsilon, &l.erank, &grads_.log_scales, why)) {
    return false;
  }
  if (w.thin > 0 && !thin_loss(map_.log_scales, w.thin, &l.thin, &grads_.log_scales, why)) {
    return false;
  }
  // Eq. sem_importance, accumulated over the round; lambda_c = lambda_f = 1 relative to the
  // already weighted losses.
  for (std::size_t i = 0; i < map_.size(); ++i) {
    importance_[i] += grads_.importance_rgb[i] + grads_.importance_feature[i];
  }
  // Only the Gaussians this view sees are stepped: Adam's momentum must not drift the rest.
  for (std::size_t i = 0; i < map_.size(); ++i) seen_[i] |= r.visible[i];
  GaussianMap grad_map;
  grad_map.sh_degree = map_.sh_degree;
  grad_map.feature_dim = map_.feature_dim;
  grad_map.means = std::move(grads_.means);
  grad_map.rotations = std::move(grads_.rotations);
  grad_map.log_scales = std::move(grads_.log_scales);
  grad_map.opacity_logits = std::move(grads_.opacity_logits);
  grad_map.sh = std::move(grads_.sh);
  grad_map.features = std::move(grads_.features);
  step_gaussian_adam(&adam_, &map_, grad_map, &r.visible);
  if (features && decoded) decoder_->step_online();  // the heads' LoRA, with its warm-up
  ++step_;
  if (losses != nullptr) *losses = l;
  return true;
}

bool Mapper::set_feature_decoder(const FeatureAutoencoder& decoder, std::string* why) {
  if (decoder.latent_dim() != config_.feature_dim) {
    return fail(why, "mapper: the decoder's latent has " + std::to_string(decoder.latent_dim()) +
                         " channels, the map's " + std::to_string(config_.feature_dim));
  }
  decoder_ = decoder;
  decoder_->set_mode(AutoencoderMode::online);
  return true;
}

bool Mapper::continue_feature_decoder(const FeatureAutoencoder& heads, std::string* why) {
  if (feature_decoder() == nullptr) return true;
  if (!decoder_->same_body(heads)) {
    return fail(why, "the map's online heads (heads.fae) belong to other autoencoder weights than this "
                     "server's features.autoencoder_path: its Gaussians' latents are in another space");
  }
  decoder_ = heads;
  decoder_->set_mode(AutoencoderMode::online);
  published_heads_steps_ = -1;  // the next version carries them
  return true;
}

const FeatureAutoencoder* Mapper::feature_decoder() const {
  return config_.feature_loss == MapperConfig::FeatureLoss::decoded && decoder_ ? &*decoder_ : nullptr;
}

bool Mapper::decoded_features(const StoredKeyframe& kf) const {
  return feature_decoder() != nullptr && !kf.feature_observation.empty();
}

namespace {

// The rendered latents [K, D] at an observation's pixels, scaled onto a render of another size
// (the refinement's); `at` receives each sample's pixel index in the render.
void gather_latents(const PlanarImage& rendered, const FeatureObservation& obs, std::vector<float>* f,
                    std::vector<std::size_t>* at) {
  const int D = rendered.channels, W = rendered.width, H = rendered.height;
  const float sx = static_cast<float>(W) / static_cast<float>(obs.width);
  const float sy = static_cast<float>(H) / static_cast<float>(obs.height);
  f->resize(obs.size() * static_cast<std::size_t>(D));
  at->resize(obs.size());
  for (std::size_t k = 0; k < obs.size(); ++k) {
    const int x = obs.pixels[k] % obs.width, y = obs.pixels[k] / obs.width;
    const int u = std::min(W - 1, static_cast<int>((static_cast<float>(x) + 0.5f) * sx));
    const int v = std::min(H - 1, static_cast<int>((static_cast<float>(y) + 0.5f) * sy));
    (*at)[k] = static_cast<std::size_t>(v) * W + u;
    for (int c = 0; c < D; ++c) (*f)[k * D + c] = rendered.plane(c)[(*at)[k]];
  }
}

}  // namespace

bool Mapper::decoded_feature_loss(const StoredKeyframe& kf, const PlanarImage& rendered, double weight,
                                  double* loss, PlanarImage* grad, std::string* why) {
  const FeatureObservation& obs = kf.feature_observation;
  const int D = map_.feature_dim;
  if (rendered.channels != D) return fail(why, "mapper: rendered latent has the wrong channel count");
  std::vector<std::size_t> at;
  gather_latents(rendered, obs, &f_samples_, &at);
  obs.samples(decoder_->input_mean(), decoder_->input_std(), &u_samples_);
  grad_f_samples_.resize(f_samples_.size());
  const int K = static_cast<int>(obs.size());
  // ||phi^(l)(f) - F_obs||_1 over the samples, in units of each channel's spread (loss_l1): an
  // unbiased estimate of the mean over the image's pixels.
  *loss = weight * decoder_->feature_loss(f_samples_.data(), u_samples_.data(), K, grad_f_samples_.data());
  *grad = PlanarImage(rendered.width, rendered.height, D);
  for (int k = 0; k < K; ++k)
    for (int c = 0; c < D; ++c)
      grad->plane(c)[at[k]] += static_cast<float>(weight) * grad_f_samples_[static_cast<std::size_t>(k) * D + c];
  return true;
}

double Mapper::decoded_feature_error(const RenderView& view, const FeatureObservation& observation,
                                     const FeatureAutoencoder& decoder, std::string* why) const {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (map_.feature_dim == 0 || map_.empty()) {
    fail(why, "mapper: the map has no features");
    return nan;
  }
  if (decoder.latent_dim() != map_.feature_dim || observation.channels != decoder.input_dim() ||
      observation.empty()) {
    fail(why, "mapper: decoder, observation and map do not match");
    return nan;
  }
  RenderSettings settings = config_.render;
  settings.features = true;
  RenderResult r;
  if (!rasterizer_->forward(map_, view, settings, &r, why)) return nan;
  std::vector<float> f, u, u_hat;
  std::vector<std::size_t> at;
  gather_latents(r.features, observation, &f, &at);
  observation.samples(decoder.input_mean(), decoder.input_std(), &u);
  const int K = static_cast<int>(observation.size());
  u_hat.resize(u.size());
  decoder.decode(f.data(), K, u_hat.data());
  return decoder.loss_l1(u_hat.data(), u.data(), K, nullptr);
}

std::size_t Mapper::prune(double percentile) {
  const std::size_t n = map_.size();
  std::vector<std::uint8_t> keep(n, 1);
  std::size_t pruned_importance = 0;
  // Eq. pruning_set over the candidates this round saw (the rest have no importance evidence).
  std::vector<float> scores;
  auto candidate = [&](std::size_t i) {
    return seen_[i] && (!config_.prune_new_only || new_in_round_[i]);
  };
  for (std::size_t i = 0; i < n; ++i) {
    if (candidate(i)) scores.push_back(importance_[i]);
  }
  if (percentile > 0.0 && scores.size() > 10) {
    const std::size_t k = static_cast<std::size_t>(percentile * static_cast<double>(scores.size()));
    std::nth_element(scores.begin(), scores.begin() + k, scores.end());
    const float threshold = scores[k];
    for (std::size_t i = 0; i < n; ++i) {
      if (candidate(i) && importance_[i] < threshold) {
        keep[i] = 0;
        ++pruned_importance;
      }
    }
  }
  // Standard 3DGS pruning: nearly transparent or too large.
  for (std::size_t i = 0; i < n; ++i) {
    if (!keep[i]) continue;
    const float opacity = 1.0f / (1.0f + std::exp(-map_.opacity_logits[i]));
    const float* ls = map_.log_scales.data() + 3 * i;
    const float largest = std::exp(std::max({ls[0], ls[1], ls[2]}));
    if (opacity < config_.min_opacity || largest > config_.max_scale) keep[i] = 0;
  }
  map_.keep_only(keep);
  adam_.keep_only(keep);
  keep_rows(&anchor_, 1, keep);
  reset_round();
  new_in_round_.assign(map_.size(), 0);
  return pruned_importance;
}

// Mip-Splatting's 3D filter from the highest sampling rate f / z over the keyframes whose view
// contains the Gaussian's centre, f of the input images.
void Mapper::recompute_filter_3d(std::size_t first) {
  for (std::size_t i = first; i < map_.size(); ++i) {
    const Eigen::Vector3d p(map_.means[3 * i], map_.means[3 * i + 1], map_.means[3 * i + 2]);
    double best_rate = 0.0;
    for (const StoredKeyframe& kf : keyframes_) {
      const Eigen::Vector3d c = kf.view.T_camera_world * p;
      if (c.z() <= config_.render.near_plane) continue;
      const Eigen::Vector2d px = kf.view.camera.project(c);
      if (!kf.view.camera.contains(px)) continue;
      best_rate = std::max(best_rate, kf.view.camera.fx / config_.training_scale / c.z());
    }
    if (best_rate > 0.0) {
      map_.filter_3d[i] = static_cast<float>(config_.filter_3d_factor / (best_rate * best_rate));
    }
  }
}

void Mapper::drop_most_redundant_keyframe() {
  const auto gap = [&](const StoredKeyframe& a, const StoredKeyframe& b) {
    const PoseMotion m = pose_motion(a.view.T_camera_world.inverse(), b.view.T_camera_world.inverse());
    return motion_in_thresholds(m, config_.mapping_keyframe_translation, config_.mapping_keyframe_rotation_deg);
  };
  std::size_t drop = 1;
  double smallest = std::numeric_limits<double>::infinity();
  for (std::size_t i = 1; i + 1 < keyframes_.size(); ++i) {
    const double g = gap(keyframes_[i - 1], keyframes_[i + 1]);
    if (g < smallest) smallest = g, drop = i;
  }
  keyframes_.erase(keyframes_.begin() + static_cast<std::ptrdiff_t>(drop));
}

std::vector<std::int64_t> Mapper::keyframe_ids() const {
  std::vector<std::int64_t> ids;
  for (const StoredKeyframe& kf : keyframes_) ids.push_back(kf.frame_id);
  return ids;
}

void Mapper::reset_round() {
  importance_.assign(map_.size(), 0.0f);
  seen_.assign(map_.size(), 0);
}

void Mapper::publish() {
  versions_.publish(std::make_shared<const GaussianMap>(map_));
  // The stored keyframes' images go with the version: headers only, the pixels are shared.
  auto images = std::make_shared<std::vector<KeyframeImages>>();
  images->reserve(keyframes_.size());
  for (const StoredKeyframe& kf : keyframes_) {
    images->push_back({kf.frame_id, kf.input_camera, kf.view.T_camera_world.inverse(), kf.refine_colour, kf.refine_depth});
  }
  {
    std::lock_guard<std::mutex> lock(heads_mutex_);
    kept_images_ = std::move(images);
  }
  // The heads go with the version (copied only when LoRA stepped since: ~0.4 MB, next to the map's copy).
  const FeatureAutoencoder* heads = feature_decoder();
  if (heads == nullptr || heads->online_steps() == published_heads_steps_) return;
  auto copy = std::make_shared<const FeatureAutoencoder>(*heads);
  published_heads_steps_ = heads->online_steps();
  std::lock_guard<std::mutex> lock(heads_mutex_);
  heads_ = std::move(copy);
}

std::shared_ptr<const std::vector<KeyframeImages>> Mapper::published_keyframe_images() const {
  std::lock_guard<std::mutex> lock(heads_mutex_);
  return kept_images_;
}

std::shared_ptr<const FeatureAutoencoder> Mapper::published_heads() const {
  std::lock_guard<std::mutex> lock(heads_mutex_);
  return heads_;
}

bool Mapper::add_keyframe(const MapperKeyframe& keyframe, RefinementStats* stats,
                          std::string* why) {
  RefinementStats s;
  StoredKeyframe kf;
  if (!store(keyframe, &kf, why)) return false;
  keyframe_pose_[keyframe.frame_id] = keyframe.T_world_camera;  // where its Gaussians are placed
  auto t0 = std::chrono::steady_clock::now();
  s.inserted = insert_gaussians(kf, keyframe, &s.at_capacity);
  // The decoded L_feat needs the dense latent only for the new Gaussians' initial values.
  if (decoded_features(kf)) kf.feature_target = PlanarImage();
  // The stored keyframe this one revisits, if any, makes way for it.
  const auto revisited =
      find_revisited(keyframes_.begin(), keyframes_.end(), keyframe.T_world_camera, config_.revisit_translation,
                     config_.revisit_rotation_deg, [](const StoredKeyframe& k) { return k.view.T_camera_world.inverse(); });
  if (revisited != keyframes_.end()) {
    keyframes_.erase(revisited);  // the newest stays last (sample_keyframe)
    s.replaced_keyframe = true;
  }
  if (keyframes_.size() >= config_.max_stored_keyframes) {
    drop_most_redundant_keyframe();
    s.dropped_keyframe = true;
  }
  keyframes_.push_back(std::move(kf));
  s.insert_ms = ms_since(t0);

  // A mapping keyframe prunes with the mapping percentile (keyframe_policy.hpp).
  const Eigen::Isometry3d& T = keyframe.T_world_camera;
  s.mapping_keyframe = !last_mapping_keyframe_ ||
                       is_mapping_keyframe(pose_motion(*last_mapping_keyframe_, T),
                                           config_.mapping_keyframe_translation,
                                           config_.mapping_keyframe_rotation_deg);
  if (s.mapping_keyframe) last_mapping_keyframe_ = T, last_mapping_keyframe_id_ = keyframe.frame_id;

  t0 = std::chrono::steady_clock::now();
  reset_round();
  for (int it = 0; it < config_.iterations_per_keyframe && !map_.empty() && !hurry_; ++it) {
    if (!step(keyframes_[sample_keyframe(false)], &s.last_losses, why)) return false;
    ++s.iterations;
  }
  s.optimise_ms = ms_since(t0);
  t0 = std::chrono::steady_clock::now();
  const std::size_t before = map_.size();
  if (s.iterations > 0) {
    s.pruned_importance = prune(s.mapping_keyframe ? config_.prune_percentile_mapping
                                                   : config_.prune_percentile_tracking);
  }
  s.pruned_standard = before - map_.size() - s.pruned_importance;
  s.prune_ms = ms_since(t0);
  publish();
  if (stats != nullptr) *stats = s;
  return true;
}

bool Mapper::optimise(int iterations, std::string* why) {
  if (hurry_) return true;  // no copy of the map per idle round while a shutdown drains
  for (int it = 0; it < iterations && !keyframes_.empty() && !map_.empty() && !hurry_; ++it) {
    if (!step(keyframes_[sample_keyframe(false)], nullptr, why)) return false;
  }
  publish();
  return true;
}

bool Mapper::refine(int steps, std::string* why, const std::function<void(int, int)>& progress,
                    const std::atomic<bool>* stop) {
  if (keyframes_.empty() || map_.empty()) return true;
  recompute_filter_3d(0);
  const GaussianLearningRates& lr = config_.learning_rates;
  // Refinement has its own schedule over all Gaussians (below), not the per-Gaussian decay.
  adam_.set_row_decay(kAdamMeans, 0);
  const auto online_rates = [&] {
    adam_.set_learning_rate(kAdamMeans, lr.means);
    adam_.set_row_decay(kAdamMeans, lr.means_decay_steps, lr.means_decay_floor);
  };
  for (int it = 0; it < steps; ++it) {
    if (stop != nullptr && stop->load()) {
      online_rates();
      publish();
      return fail(why, "refinement stopped after " + std::to_string(it) + " of " + std::to_string(steps) + " steps");
    }
    // 3DGS's position schedule: log-linear decay to 1/100 of the rate over the refinement.
    const float t = steps > 1 ? static_cast<float>(it) / static_cast<float>(steps - 1) : 0.0f;
    adam_.set_learning_rate(kAdamMeans, lr.means * std::pow(0.01f, t));
    const StoredKeyframe& kf = keyframes_[sample_keyframe(true)];
    StoredKeyframe view;
    const bool stepped = config_.refine_scale <= config_.training_scale
                             ? step(kf, nullptr, why)
                             : refine_view(kf, &view, why) && step(view, nullptr, why);
    if (!stepped) {
      online_rates();
      return false;
    }
    if (progress && ((it + 1) % 10 == 0 || it + 1 == steps)) progress(it + 1, steps);
  }
  online_rates();
  publish();
  return true;
}

bool Mapper::set_map(const GaussianMap& map, std::string* why) {
  std::string reason;
  if (!map.is_consistent(&reason)) return fail(why, "map: " + reason);
  if (map.sh_degree != config_.sh_degree || map.feature_dim != config_.feature_dim) {
    return fail(why, "map: SH degree " + std::to_string(map.sh_degree) + " and " +
                         std::to_string(map.feature_dim) + " feature channels, the mapper is set "
                         "up for " + std::to_string(config_.sh_degree) + " and " +
                         std::to_string(config_.feature_dim));
  }
  map_ = map;
  anchor_.assign(map_.size(), -1);
  if (map_.filter_3d.size() != map_.size()) map_.filter_3d.assign(map_.size(), 0.0f);
  adam_ = make_gaussian_adam(map_, config_.learning_rates);
  adam_.settle_rows(kAdamMeans);  // a map given whole was optimised already: its means have settled
  reset_round();
  new_in_round_.assign(map_.size(), 0);
  publish();
  return true;
}

std::size_t Mapper::move_keyframes(const std::vector<std::pair<std::int64_t, Eigen::Isometry3d>>& T_world_keyframe) {
  std::unordered_map<std::int64_t, Eigen::Isometry3d> delta;  // T_new T_old^-1 per keyframe that moved
  for (const auto& [id, T_new] : T_world_keyframe) {
    const auto it = keyframe_pose_.find(id);
    if (it == keyframe_pose_.end()) continue;
    const Eigen::Isometry3d D = T_new * it->second.inverse();
    it->second = T_new;
    if (D.translation().norm() < 1e-7 && Eigen::AngleAxisd(D.rotation()).angle() < 1e-7) continue;
    delta[id] = D;
  }
  if (delta.empty()) return 0;
  std::size_t moved = 0;
  for (std::size_t i = 0; i < map_.size(); ++i) {
    const auto it = delta.find(anchor_[i]);
    if (it == delta.end()) continue;
    const Eigen::Isometry3f D = it->second.cast<float>();
    float* m = map_.means.data() + 3 * i;
    const Eigen::Vector3f mean = D * Eigen::Vector3f(m[0], m[1], m[2]);
    m[0] = mean.x(), m[1] = mean.y(), m[2] = mean.z();
    float* r = map_.rotations.data() + 4 * i;  // w, x, y, z: Gaussian -> world
    const Eigen::Quaternionf q = Eigen::Quaternionf(D.rotation()) * Eigen::Quaternionf(r[0], r[1], r[2], r[3]);
    r[0] = q.w(), r[1] = q.x(), r[2] = q.y(), r[3] = q.z();
    ++moved;
  }
  for (StoredKeyframe& kf : keyframes_) {
    const auto it = delta.find(kf.frame_id);
    if (it != delta.end()) kf.view.T_camera_world = (it->second * kf.view.T_camera_world.inverse()).inverse();
  }
  if (const auto it = delta.find(last_mapping_keyframe_id_); it != delta.end() && last_mapping_keyframe_) {
    last_mapping_keyframe_ = it->second * *last_mapping_keyframe_;
  }
  publish();
  return moved;
}

}  // namespace fslam::core

// Online 3DGS mapping (paper: Modeling Losses, Semantic gradient-based pruning, Post-trajectory
// refinement): keyframes insert Gaussians where the map does not yet explain them, each
// keyframe triggers a refinement round of capped gradient steps on the total loss
// (eq. total_loss) followed by importance pruning (eq. sem_importance, pruning_set), and the map
// is published as immutable versions.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include "fslam/core/features/feature_autoencoder.hpp"
#include "fslam/core/features/feature_observation.hpp"
#include "fslam/core/geometry/pinhole_camera.hpp"
#include "fslam/core/map/gaussian_map.hpp"
#include "fslam/core/mapping/adam.hpp"
#include "fslam/core/mapping/image_losses.hpp"
#include "fslam/core/render/planar_image.hpp"
#include "fslam/core/render/rasterizer.hpp"
#include "fslam/core/tracking/gaussian_points.hpp"

namespace fslam::core {

// Weights of eq. total_loss. The paper names the terms but not their values; these are ours
// (docs/mapping.md says how they were chosen).
struct MappingLossWeights {
  double rgb_l1 = 0.8;         // lambda_1
  double rgb_ssim = 0.2;       // lambda_2 (3DGS's lambda_dssim)
  double feature_l1 = 1.0;     // lambda_f
  double depth_l1 = 1.0;       // lambda_d, per metre of mean absolute depth error
  double depth_pcc = 0.1;      // lambda_pcc
  PccConfig pcc;               // p = 8 pixels
  double normal = 0.05;        // lambda_n, for each of the two cosine terms
  double erank_lambda_0 = 0.0;      // eq. lambda_ramp
  double erank_lambda_max = 0.005;
  double erank_ramp_steps = 2000.0;  // T, optimisation steps
  double erank_epsilon = 1e-2;
  double thin = 0.05;          // lambda_thin, per metre of the smallest scale
};

struct MapperConfig {
  int sh_degree = 0;           // 0..3
  int feature_dim = 16;        // D of the Gaussians' latent
  // Renders for training at this fraction of the input size. 0.25 (160x120 from 640x480):
  // measured on redkitchen 0-119, 0.5 gave +0.2 dB held-out PSNR at 2.2x the mapping time
  // (docs/mapping.md).
  double training_scale = 0.25;
  // Post-trajectory refinement renders at this fraction of the input size when it is above
  // training_scale (0: at training_scale); each keyframe keeps its colour and depth at this
  // size (at training_scale when not above it: kept_scale()), 0.54 MB per 640x480 keyframe at 0.5. Measured on redkitchen 0-299 with
  // --refine 2000: 23.73-23.80 dB held-out against 22.83 at training_scale (docs/mapping.md).
  double refine_scale = 0.5;
  // Insertion: lattice stride on the training-resolution image where the map does not explain
  // the keyframe: accumulated opacity below new_alpha, or the rendered surface farther than the
  // observed one by more than new_depth_margin (+ new_depth_relative * depth).
  int insert_stride = 1;
  // Where new Gaussians come from: the training image's lattice (above), or the tracker's source
  // Gaussians of the keyframe (MapperKeyframe::source_world, as GS-ICP-SLAM shares them), so that
  // the frame and the map the tracker registers against use one representation.
  enum class InsertFrom : std::uint8_t { lattice, source };
  InsertFrom insert_from = InsertFrom::lattice;
  // insert_from = source: a source Gaussian is new unless the map already has a Gaussian mean in
  // its cell of this edge (metres). A 3D test rather than the rendered-coverage one above: with
  // rendered coverage a keyframe's source lattice left the map sparse (8.5k Gaussians on
  // redkitchen 0-299). Measured with the cells: 2.5x the Gaussians, +0.4 dB held-out PSNR and
  // 40 % fewer frames/s (docs/tracking.md "Tracking against the Gaussian map").
  float source_min_distance = 0.015f;
  float new_alpha = 0.5f;
  float new_depth_margin = 0.05f;     // metres
  float new_depth_relative = 0.02f;
  float min_depth = 0.3f;             // metres; observed depth outside is not used
  float max_depth = 6.0f;
  float initial_opacity = 0.7f;
  float initial_scale_factor = 0.75f; // in-plane sigma = factor * lattice spacing on the surface
  float initial_thickness = 0.1f;     // normal sigma = thickness * in-plane sigma
  // A map's bound (issue 23: a client cannot exhaust the server's memory): at this many Gaussians
  // a keyframe inserts nothing new (RefinementStats::at_capacity) and optimisation and pruning go
  // on. ~1 KiB each in a live session (docs/reliability.md). 0: no bound.
  int max_gaussians = 2000000;
  // Refinement round per keyframe: a cap on gradient steps (the paper's trade-off between
  // photometric convergence and drift), sampling the newest keyframe with this probability
  // and otherwise any keyframe uniformly (chosen on redkitchen 0-299, docs/mapping.md).
  int iterations_per_keyframe = 30;
  double newest_keyframe_probability = 0.2;
  // Eq. pruning_set percentiles: tracking keyframes 10 %, mapping keyframes 30 %. A keyframe is a
  // mapping keyframe when it moved at least this far from the last mapping keyframe
  // (is_mapping_keyframe in fslam/core/tracking/keyframe_policy.hpp, the tracker's measure).
  double prune_percentile_tracking = 0.10;
  double prune_percentile_mapping = 0.30;
  // The candidates of eq. pruning_set: the Gaussians this round inserted ("the gradient-based
  // impact of new Gaussians", paper), or every Gaussian the round saw when false
  // (docs/mapping.md: measured, the latter empties the map).
  bool prune_new_only = true;
  double mapping_keyframe_translation = 0.15;  // metres
  double mapping_keyframe_rotation_deg = 9.0;
  // A keyframe within both of these of a stored keyframe's pose replaces it, so the stored
  // keyframes (colour and depth, ~0.6 MB each at 640x480) grow with the poses covered, not with
  // time: a camera that keeps revisiting a room keeps its memory flat (docs/reliability.md).
  // 0 for either: every keyframe is kept. Measured on redkitchen 0-299 (docs/reliability.md):
  // 5 cm / 5 deg replaced 11 of 43 keyframes and cost 0.4 dB held-out PSNR; 2 cm / 2 deg replaced
  // none there.
  double revisit_translation = 0.02;  // metres
  double revisit_rotation_deg = 2.0;
  // At most this many stored keyframes (>= 3; ~0.6 MB each at 640x480), for a camera that keeps
  // exploring new ground: past it, the stored keyframe whose neighbours in time are closest
  // (mapping_keyframe_* units) makes room; the first and the newest stay.
  std::size_t max_stored_keyframes = 1000;
  // Standard 3DGS pruning after each round.
  float min_opacity = 0.005f;
  float max_scale = 0.5f;             // metres, largest axis
  // Mip-Splatting 3D filter: variance = filter_3d_factor * (z / f)^2 at the highest sampling
  // rate over the keyframes that see the Gaussian, f of the input images (not of the reduced
  // training renders: that blurred full-resolution renders and cost 0.3 cm depth L1, measured).
  float filter_3d_factor = 0.2f;
  // L_feat (eq. modeling_losses). `decoded`, the paper's: the rendered latent at the keyframe's
  // feature_samples pixels, decoded by the heads phi^(l) (set_feature_decoder; their LoRA
  // adapters train online, one Adam step per mapping step), against the encoder's pyramid there.
  // `latent`: the rendered latent against phi(u) at every training pixel (before issue 19).
  // Without a decoder the latent form is used. docs/mapping.md compares the two.
  enum class FeatureLoss : std::uint8_t { decoded, latent };
  FeatureLoss feature_loss = FeatureLoss::decoded;
  // Sample pixels per keyframe for the decoded L_feat (MapperKeyframe::feature_observation),
  // ~360 B each stored; about one per 3x3 pixels of a 160x120 training image.
  int feature_samples = 2048;
  RenderSettings render;
  GaussianLearningRates learning_rates;
  MappingLossWeights loss;
  std::uint32_t seed = 1;
  bool is_valid(std::string* why = nullptr) const;
};

// One keyframe as the mapper receives it.
struct MapperKeyframe {
  std::int64_t frame_id = 0;
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
  PinholeCamera camera;  // of colour and depth
  cv::Mat colour;        // [H, W] CV_8UC3 RGB
  cv::Mat depth;         // [H, W] CV_32FC1 metres, 0 = missing
  // Optional [D, h, w] at the training resolution (empty = none): phi(u) per pixel, the new
  // Gaussians' initial latents, and the latent L_feat's target.
  PlanarImage feature_target;
  // The decoded L_feat's target (FeatureLoss::decoded): u at sample pixels of the training image.
  FeatureObservation feature_observation;
  // The tracker's source Gaussians of this frame in world coordinates (insert_from = source),
  // sampled every `source_stride` input pixels; empty: the lattice is used.
  GaussianPoints source_world;
  int source_stride = 8;
};

// Per-step loss values (already weighted).
struct MappingLosses {
  double rgb_l1 = 0, rgb_ssim = 0, feature_l1 = 0, depth_l1 = 0, depth_pcc = 0;
  double normal_expected = 0, normal_median = 0, erank = 0, thin = 0;
  double total() const {
    return rgb_l1 + rgb_ssim + feature_l1 + depth_l1 + depth_pcc + normal_expected +
           normal_median + erank + thin;
  }
};

struct RefinementStats {
  std::size_t inserted = 0;
  std::size_t pruned_importance = 0;
  std::size_t pruned_standard = 0;
  int iterations = 0;
  bool mapping_keyframe = false;
  bool replaced_keyframe = false;  // it took the place of a stored keyframe it revisits
  bool dropped_keyframe = false;   // a stored keyframe made room for it (max_stored_keyframes)
  bool at_capacity = false;  // insertion stopped at MapperConfig::max_gaussians
  MappingLosses last_losses;
  double insert_ms = 0, optimise_ms = 0, prune_ms = 0;
};

// A stored keyframe's images as the mapper keeps them for refinement, at refine_scale (or
// training_scale when that is not smaller) of `input_camera`: saved with a map
// (`keyframe_images.bin`, core/io/keyframe_images_file.hpp) so that a map loaded later can be
// refined, and an extend session keeps optimising the regions mapped before it.
struct KeyframeImages {
  std::int64_t frame_id = 0;
  PinholeCamera input_camera;  // of the frame the keyframe came from
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();
  cv::Mat colour;  // CV_8UC3 RGB, input_camera.scaled(Mapper::kept_scale()) in size
  cv::Mat depth;   // CV_32FC1 metres, 0 = missing, the same size
};

class Mapper {
 public:
  Mapper(const MapperConfig& config, std::shared_ptr<const Rasterizer> rasterizer);

  // Inserts the keyframe's unexplained pixels as Gaussians, runs one refinement round and
  // publishes the map. False with `why` on bad input (sizes, intrinsics, pose).
  bool add_keyframe(const MapperKeyframe& keyframe, RefinementStats* stats, std::string* why);
  // Extra gradient steps over sampled keyframes (idle time in real-time mode), then publishes.
  bool optimise(int iterations, std::string* why);
  // Shutdown: from now on add_keyframe inserts and publishes without gradient steps (one running
  // stops within a step) and optimise does nothing (no step, no version). Every keyframe is still
  // in the map; the optimisation skipped is left to a later session or refinement. Any thread.
  void hurry() { hurry_ = true; }
  // Post-trajectory refinement: recompute the 3D filter over all keyframes, then `steps` steps
  // with keyframes drawn uniformly; no insertion or importance pruning.
  // progress (optional) is called every few steps with (steps done, steps). When `stop` (optional)
  // turns true, the steps done so far are published and refine returns false saying so.
  bool refine(int steps, std::string* why,
              const std::function<void(int, int)>& progress = nullptr,
              const std::atomic<bool>* stop = nullptr);
  // The heads the decoded L_feat runs through (a copy; its LoRA adapters train online from here).
  // Its latent width must be the map's. Without one, L_feat is the latent form.
  bool set_feature_decoder(const FeatureAutoencoder& decoder, std::string* why);
  // The online-adapted heads, or nullptr when L_feat is the latent form. Mapping thread only.
  const FeatureAutoencoder* feature_decoder() const;
  // A copy of the online heads as of the newest published map version, or null when L_feat is
  // the latent form. Any thread: a server saves them with the map (heads.fae).
  std::shared_ptr<const FeatureAutoencoder> published_heads() const;
  // Extend (resume a saved map): L_feat continues through `heads`, the map's online heads, instead
  // of the pretrained ones. Their shapes, normalisation and body must be this decoder's, since the
  // tracker's phi makes frame latents in that latent space; false with `why` otherwise. The LoRA
  // optimiser starts afresh, so its warm-up runs again. Without a decoder (features off or the
  // latent L_feat) there is nothing to continue: true.
  bool continue_feature_decoder(const FeatureAutoencoder& heads, std::string* why);
  // Mean decoded L_feat (loss_l1, before lambda_f) of the map rendered at `view` against
  // `observation` (its pixels index an image of the view's aspect), decoded by `decoder`: the
  // held-out reconstruction error of the heads. NaN + why when it cannot be measured.
  double decoded_feature_error(const RenderView& view, const FeatureObservation& observation,
                               const FeatureAutoencoder& decoder, std::string* why) const;
  // The stored keyframes' images as of the newest published version (their pixels shared, never
  // changed in place), oldest first. Any thread: a server saves them with the map.
  std::shared_ptr<const std::vector<KeyframeImages>> published_keyframe_images() const;
  // Takes `images` (a saved map's, published_keyframe_images) as stored keyframes, oldest first,
  // renumbered -n..-1 so that they never meet a new frame's id, before any keyframe was added;
  // publishes. They carry no feature targets: steps on them fit colour and geometry, not the
  // latents. Past max_stored_keyframes the most redundant make room. False with `why` on images
  // of another size than input_camera.scaled(kept_scale()) or a bad pose or camera.
  bool restore_keyframes(const std::vector<KeyframeImages>& images, std::string* why);
  // The scale of input images at which stored keyframes keep their images (refine_scale, or
  // training_scale when refine_scale is not larger).
  double kept_scale() const { return std::max(config_.refine_scale, config_.training_scale); }
  // Replaces the map (resume from a saved map); keyframes are kept. Its Gaussians have no
  // anchor keyframe: loop closure never moves them.
  bool set_map(const GaussianMap& map, std::string* why);
  // Loop closure (docs/relocalisation.md): keyframe `id` now lies at T_world_camera. The
  // Gaussians it inserted (their anchor) move rigidly with it, mean and rotation by
  // T_new T_old^-1 (view-dependent SH are not rotated: corrections are small), and so does its
  // stored view. Ids the mapper never took are skipped. Publishes a version when anything moved;
  // returns how many Gaussians moved. Mapping thread, between steps.
  std::size_t move_keyframes(const std::vector<std::pair<std::int64_t, Eigen::Isometry3d>>& T_world_keyframe);

  const GaussianMap& map() const { return map_; }
  MapVersions& versions() { return versions_; }
  std::size_t keyframe_count() const { return keyframes_.size(); }
  // The frame ids of the stored keyframes, oldest first.
  std::vector<std::int64_t> keyframe_ids() const;
  std::int64_t total_steps() const { return step_; }
  const MapperConfig& config() const { return config_; }
  // The cap on gradient steps of the next refinement rounds (real-time mode lowers it when
  // keyframes queue up).
  void set_iterations_per_keyframe(int iterations) { config_.iterations_per_keyframe = iterations; }

 private:
  struct StoredKeyframe {
    std::int64_t frame_id = 0;
    PinholeCamera input_camera;   // of the images the keyframe came with
    RenderView view;              // at the training resolution
    PlanarImage colour;           // [3, h, w] in [0, 1]
    PlanarImage depth;            // [1, h, w] metres, 0 = missing
    PlanarImage normals;          // [3, h, w] from the observed depth
    PlanarImage feature_target;   // [D, h, w] or empty (dropped after insertion when decoded)
    FeatureObservation feature_observation;  // the decoded L_feat's target, or empty
    cv::Mat refine_colour;        // CV_8UC3 at kept_scale() (refinement's and saving's images)
    cv::Mat refine_depth;         // CV_32FC1 metres at kept_scale()
  };
  bool store(const MapperKeyframe& keyframe, StoredKeyframe* out, std::string* why) const;
  // Colour in [0, 1], depth inside the mapper's range and normals of images of camera `cam`.
  bool make_view(const cv::Mat& colour, const cv::Mat& depth, const PinholeCamera& cam,
                 const Eigen::Isometry3d& T_world_camera, StoredKeyframe* out,
                 std::string* why) const;
  bool refine_view(const StoredKeyframe& kf, StoredKeyframe* out, std::string* why) const;
  std::size_t insert_gaussians(const StoredKeyframe& kf, const MapperKeyframe& input, bool* at_capacity);
  // Erases the interior stored keyframe whose removal leaves the smallest gap between its
  // neighbours (MapperConfig::max_stored_keyframes).
  void drop_most_redundant_keyframe();
  // Appends one Gaussian seen by `kf` at training pixel (u, v) and depth z: observed point
  // p_world, surface normal n_world, sigmas in and across the surface (metres), colour and
  // features from the keyframe's images. sh: scratch of sh_per_gaussian() values.
  void insert_one(const StoredKeyframe& kf, int u, int v, const Eigen::Vector3f& p_world,
                  const Eigen::Vector3f& n_world, float sigma_plane, float sigma_normal, float z,
                  std::vector<float>* sh);
  bool covered(const RenderResult& rendered, int u, int v, float z) const;
  bool step(const StoredKeyframe& kf, MappingLosses* losses, std::string* why);
  bool decoded_features(const StoredKeyframe& kf) const;
  // The decoded L_feat of one step: loss (weighted) and its gradient image on the rendered latent
  // (zero away from the sample pixels); accumulates the LoRA gradients.
  bool decoded_feature_loss(const StoredKeyframe& kf, const PlanarImage& rendered, double weight,
                            double* loss, PlanarImage* grad, std::string* why);
  std::size_t prune(double percentile);
  void reset_round();
  void recompute_filter_3d(std::size_t first);
  void publish();
  std::size_t sample_keyframe(bool uniform);

  MapperConfig config_;
  std::shared_ptr<const Rasterizer> rasterizer_;
  GaussianMap map_;
  AdamOptimizer adam_;
  MapVersions versions_;
  std::vector<StoredKeyframe> keyframes_;
  std::int64_t step_ = 0;
  std::mt19937 rng_;
  // Accumulated over the current refinement round, [N].
  std::vector<float> importance_;
  std::vector<std::uint8_t> seen_;
  std::vector<std::uint8_t> new_in_round_;  // [N] inserted by this round's keyframe
  GaussianGradients grads_;
  std::optional<FeatureAutoencoder> decoder_;  // online heads of the decoded L_feat
  std::int64_t published_heads_steps_ = -1;    // decoder_'s online steps at the last copy
  std::atomic<bool> hurry_{false};             // hurry(): no more gradient steps
  mutable std::mutex heads_mutex_;             // guards heads_ and kept_images_
  std::shared_ptr<const FeatureAutoencoder> heads_;
  std::shared_ptr<const std::vector<KeyframeImages>> kept_images_ = std::make_shared<std::vector<KeyframeImages>>();
  std::vector<float> f_samples_, u_samples_, grad_f_samples_;  // [K, D], [K, C], [K, D] scratch
  std::optional<Eigen::Isometry3d> last_mapping_keyframe_;
  std::int64_t last_mapping_keyframe_id_ = 0;
  // Per Gaussian, the frame id of the keyframe that inserted it (-1: set_map's); and per
  // keyframe id ever added, its pose as the mapper last placed it (move_keyframes).
  std::vector<std::int64_t> anchor_;
  std::unordered_map<std::int64_t, Eigen::Isometry3d> keyframe_pose_;
};

}  // namespace fslam::core

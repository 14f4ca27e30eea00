// The feature autoencoder of paper sec. "Online Feature Rasterization": a joint encoder phi
// compresses the concatenated pyramid sample u_i (352 = 256 + 64 + 32 channels by default) into
// the Gaussians' latent f_i in R^D, and one light head phi^(l) per level decodes f back to that
// level. LoRA blocks on the heads' layers start at zero, so adaptation begins from the pretrained
// decoder exactly; pretraining trains the body with LoRA frozen, online SLAM freezes the body and
// trains LoRA only, with a learning-rate warm-up.
//
// Every buffer is row-major float32 over a batch of N samples: u [N, C] with C = sum of the
// level channels in level order (coarsest first, as sample_features writes it), f [N, D].
// Forward and backward are written out by hand (docs/features_autoencoder.md gives the shapes);
// forward passes are const and may run concurrently, backward and step are not.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "fslam/core/features/feature_pyramid.hpp"
#include "fslam/core/mapping/adam.hpp"

namespace fslam::core {

enum class AutoencoderActivation { gelu, relu };
const char* to_string(AutoencoderActivation activation);

// Online LoRA learning rate with a linear warm-up (paper: "a gradual warmup of the learning
// rate"): rate(t) = learning_rate * min(1, (t + 1) / warmup_steps) for the t-th online step.
struct LoraSchedule {
  float learning_rate = 1e-3f;  // Adam step size of A and B after the warm-up
  int warmup_steps = 200;       // steps to reach learning_rate; 0 = no warm-up
  float rate(std::int64_t step) const;
  bool is_valid(std::string* why = nullptr) const;
};

struct FeatureAutoencoderConfig {
  // C_l per level, coarsest first; must match the feature encoder (FeatureEncoder::level_shapes).
  std::vector<int> level_channels = {256, 64, 32};
  int latent_dim = 16;       // D; the map's latent width (SlamPipeline takes it from here)
  int encoder_hidden = 64;   // phi: C -> encoder_hidden -> D
  // phi^(l): D -> head_hidden -> C_l. 16 keeps the decode of 2,000 samples near 1 ms on one
  // core (32: about 2 ms, for ~8 % lower held-out error; docs/features_autoencoder.md).
  int head_hidden = 16;
  AutoencoderActivation activation = AutoencoderActivation::gelu;  // after each hidden layer
  int lora_rank = 4;         // r of every LoRA block
  float lora_alpha = 4.0f;   // LoRA output scale = lora_alpha / lora_rank
  std::uint32_t seed = 1;    // initial body weights and LoRA A
  LoraSchedule online;       // not stored in the weights file

  int input_dim() const;     // C = sum of level_channels
  bool is_valid(std::string* why = nullptr) const;
};

enum class AutoencoderMode {
  pretrain,  // body trainable, LoRA frozen (B stays 0)
  online,    // body frozen, LoRA A and B trainable
};

// Intermediates of one forward pass, kept for the matching backward. Filled by encode / decode;
// its contents are the autoencoder's business.
struct AutoencoderTape {
  int n = 0;
  std::vector<float> x;                       // [N, C] standardised input
  std::vector<float> enc_pre, enc_act;        // [N, encoder_hidden]
  std::vector<float> f;                       // [N, D] decoder input
  std::vector<std::vector<float>> head_pre;   // per level [N, head_hidden]
  std::vector<std::vector<float>> head_act;   // per level [N, head_hidden]
};

// One parameter tensor inside the flat parameter array: [rows, cols] row-major at `offset`.
struct AutoencoderTensor {
  std::string name;  // "encoder.0.weight", "head.2.1.lora_b", ...
  int rows = 0;
  int cols = 0;
  std::size_t offset = 0;
  bool lora = false;
  std::size_t size() const { return static_cast<std::size_t>(rows) * cols; }
};

class FeatureAutoencoder {
 public:
  // Random body (PyTorch's Linear default, seeded), LoRA A small random, B = 0, identity input
  // normalisation; online mode. An invalid config is a bug: check is_valid first.
  explicit FeatureAutoencoder(const FeatureAutoencoderConfig& config = {});

  // phi (paper: f_i = phi(u_i)). u: [N, C] encoder units; f: [N, D].
  void encode(const float* u, int n, float* f, AutoencoderTape* tape = nullptr) const;
  // The heads phi^(l) concatenated in level order. f: [N, D]; u_hat: [N, C] encoder units.
  void decode(const float* f, int n, float* u_hat, AutoencoderTape* tape = nullptr) const;

  // Backward of decode recorded in `tape`. grad_u_hat: [N, C] dL/du_hat. Writes grad_f [N, D]
  // (dL/df, optional: the mapper's path to the Gaussians' latents) and accumulates the trainable
  // heads' parameter gradients (body in pretrain mode, LoRA in online mode).
  void backward_decode(const AutoencoderTape& tape, const float* grad_u_hat, float* grad_f);
  // Backward of encode recorded in `tape`. grad_f: [N, D]. Writes grad_u [N, C] (optional) and
  // accumulates the encoder's gradients in pretrain mode.
  void backward_encode(const AutoencoderTape& tape, const float* grad_f, float* grad_u);

  // The reconstruction loss of eq. modeling_losses' L_feat term, before lambda_f:
  //   L = 1/N sum_n 1/L sum_l 1/C_l sum_{c in l} |u_hat - u_obs| / s_c,
  // s_c the stored per-channel standard deviation: each level weighs the same whatever its
  // channel count, and channels are compared in units of their spread. u_hat, u_obs: [N, C];
  // grad (optional) [N, C] is overwritten with dL/du_hat (sign(0) = 0). Returns L.
  double loss_l1(const float* u_hat, const float* u_obs, int n, float* grad) const;

  // The mapper's feature term in one call: decode the rendered latents f [N, D], loss_l1
  // against the observed pyramid samples u_obs [N, C], and backward: writes grad_f [N, D]
  // (dL/df, to be sent through the rasteriser to the Gaussians' latents; optional) and
  // accumulates the trainable parameters' gradients. Runs in chunks of kChunk samples so the
  // [N, C] intermediates stay in cache. Returns L (mean over all N).
  double feature_loss(const float* f, const float* u_obs, int n, float* grad_f);
  static constexpr int kChunk = 1024;

  void set_mode(AutoencoderMode mode) { mode_ = mode; }
  AutoencoderMode mode() const { return mode_; }
  // Clears the accumulated gradients.
  void zero_grad();
  // One Adam step of the trainable set at `learning_rate`, then zero_grad.
  void step(float learning_rate);
  // One online step at config().online.rate(online_steps()).
  void step_online();
  std::int64_t online_steps() const { return online_steps_; }

  // Per-channel mean and standard deviation [C] of the encoder output: encode standardises
  // u to (u - mean) / std and decode undoes it. std values must be positive.
  bool set_normalisation(std::vector<float> mean, std::vector<float> std, std::string* why);
  const std::vector<float>& input_mean() const { return mean_; }
  const std::vector<float>& input_std() const { return std_; }

  // Reparametrises encoder and heads so that encode(u) has zero mean and unit standard
  // deviation per latent dimension over samples u [N, C]; decode(encode(u)) is unchanged up to
  // rounding. A pixel the renderer blends with empty space (latent 0) then decodes to the mean
  // feature, and latent learning rates are in standard deviations. LoRA must still be zero (B).
  void standardise_latent(const float* u, int n);

  // Self-describing little-endian file (docs/features_autoencoder.md): magic, version, config,
  // normalisation, every tensor by name and shape. `notes` records provenance (free text).
  bool save(const std::string& path, std::string* why) const;
  // Replaces *this with the file's contents (online mode, fresh optimiser) or leaves it
  // untouched and says why: missing file, wrong magic or version, inconsistent shapes,
  // truncation, trailing bytes, non-finite values.
  bool load(const std::string& path, std::string* why);
  // load, then check the level channels against the encoder in use.
  bool load(const std::string& path, const std::vector<FeatureLevelShape>& encoder_levels,
            std::string* why);
  // True when `other` has this one's shapes, normalisation and body (encoder and heads without
  // LoRA) bit for bit: then both map features to the same latent space, whatever their LoRA.
  bool same_body(const FeatureAutoencoder& other) const;
  // False + why unless the level channels equal `encoder_levels`' channels.
  bool check_levels(const std::vector<FeatureLevelShape>& encoder_levels, std::string* why) const;

  const FeatureAutoencoderConfig& config() const { return config_; }
  int input_dim() const { return config_.input_dim(); }
  int latent_dim() const { return config_.latent_dim; }
  const std::string& notes() const { return notes_; }
  void set_notes(std::string notes) { notes_ = std::move(notes); }

  // Parameter access, for tests, inspection and copying LoRA state.
  const std::vector<AutoencoderTensor>& tensors() const { return tensors_; }
  int find_tensor(const std::string& name) const;  // index or -1
  float* tensor_data(int i) { return params_.data() + tensors_[i].offset; }
  const float* tensor_data(int i) const { return params_.data() + tensors_[i].offset; }
  const float* tensor_grad(int i) const { return grads_.data() + tensors_[i].offset; }
  const std::vector<float>& parameters() const { return params_; }
  std::size_t body_size() const { return body_size_; }  // LoRA tensors follow the body's

 private:
  struct Linear {  // y = x W^T + b (+ scale * (x A^T) B^T)
    int w = -1, b = -1, lora_a = -1, lora_b = -1;  // tensor indices
  };
  void build_layout();
  // W + scale B A of a head layer, [out, in].
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> merged_weight(
      const Linear& layer) const;
  int add_tensor(const std::string& name, int rows, int cols, bool lora);
  bool trainable(int tensor) const;
  // loss_l1 of n samples, normalised by `total` samples instead of n.
  double l1(const float* u_hat, const float* u_obs, int n, int total, float* grad) const;
  float lora_scale() const { return config_.lora_alpha / static_cast<float>(config_.lora_rank); }

  FeatureAutoencoderConfig config_;
  AutoencoderMode mode_ = AutoencoderMode::online;
  std::vector<AutoencoderTensor> tensors_;
  std::size_t body_size_ = 0;
  std::vector<float> params_;  // every tensor, body first
  std::vector<float> grads_;   // same layout
  std::vector<float> mean_, std_;  // [C]
  Linear enc0_, enc1_;
  std::vector<Linear> head0_, head1_;  // per level
  std::vector<int> level_offset_;      // first column of each level in u
  AdamOptimizer adam_;                 // group 0: body, group 1: LoRA
  std::int64_t online_steps_ = 0;
  std::string notes_;
};

// ---- Pretraining (paper: "pretrained on unrelated datasets") ----------------------------------

struct AutoencoderPretrainOptions {
  int steps = 3000;
  int batch = 256;                 // samples per Adam step
  float learning_rate = 2e-3f;     // Adam, cosine-decayed to learning_rate / 10 at the last step
  std::uint32_t seed = 1;          // pixel sampling and batch order
  int pixels_per_image = 2000;     // random (u, v) sampled once per pyramid
  int eval_samples = 4096;         // samples for the before / after errors
  bool is_valid(std::string* why = nullptr) const;
};

struct AutoencoderPretrainStats {
  std::size_t train_samples = 0;
  double train_error_before = 0, train_error_after = 0;       // loss_l1 on training samples
  double held_out_error_before = 0, held_out_error_after = 0;  // 0 without held-out samples
  int steps = 0;
};

// Called every few steps with (steps done, steps, mean training loss since the last call).
using AutoencoderPretrainProgress = std::function<void(int done, int total, double loss)>;

// `count` samples u at uniformly random pixel positions of `pyramid`, appended to *out as
// [count, C] rows.
void sample_training_features(const FeaturePyramid& pyramid, int count, std::mt19937* rng,
                              std::vector<float>* out);

// Pretrains on samples [M, C] (row-major): sets the normalisation from them (a channel's std is
// floored at 1e-2 x the median channel std), runs options.steps Adam steps of the body on
// loss_l1 of decode(encode(u)) in pretrain mode, then standardises the latent over the
// evaluation subset; leaves *ae in online mode. held_out (optional, [K, C]) is only evaluated.
// False + why for mismatched sizes or options.
bool pretrain_autoencoder_on_samples(const std::vector<float>& samples,
                                     const std::vector<float>* held_out,
                                     const AutoencoderPretrainOptions& options,
                                     FeatureAutoencoder* ae,
                                     const AutoencoderPretrainProgress& progress,
                                     AutoencoderPretrainStats* stats, std::string* why);

// The same on options.pixels_per_image random pixels of each pyramid; every pyramid must have
// the autoencoder's level channels.
bool pretrain_autoencoder(const std::vector<FeaturePyramid>& pyramids,
                          const AutoencoderPretrainOptions& options, FeatureAutoencoder* ae,
                          const AutoencoderPretrainProgress& progress,
                          AutoencoderPretrainStats* stats, std::string* why);

// Mean loss_l1 of decode(encode(u)) over samples [M, C], in batches.
double reconstruction_error(const FeatureAutoencoder& ae, const std::vector<float>& samples);

}  // namespace fslam::core

// The feature autoencoder phi (paper: feature compression): config, layout, initial weights and the forward pass.
#include "fslam/core/features/feature_autoencoder.hpp"

#include <Eigen/Core>
#include <cassert>
#include <cmath>
#include <numeric>

#include "autoencoder_math.hpp"
#include "fslam/core/error.hpp"

namespace fslam::core {

using namespace autoencoder_detail;  // NOLINT: the file's own helpers, private to core/src/features

const char* to_string(AutoencoderActivation activation) {
  switch (activation) {
    case AutoencoderActivation::gelu: return "gelu";
    case AutoencoderActivation::relu: return "relu";
  }
  return "?";
}

float LoraSchedule::rate(std::int64_t step) const {
  if (warmup_steps <= 0 || step + 1 >= warmup_steps) return learning_rate;
  return learning_rate * static_cast<float>(step + 1) / static_cast<float>(warmup_steps);
}

bool LoraSchedule::is_valid(std::string* why) const {
  if (!(std::isfinite(learning_rate) && learning_rate >= 0.0f))
    return fail(why, "autoencoder: online learning rate must be finite and >= 0");
  if (warmup_steps < 0) return fail(why, "autoencoder: online warm-up steps must be >= 0");
  return true;
}

int FeatureAutoencoderConfig::input_dim() const {
  return std::accumulate(level_channels.begin(), level_channels.end(), 0);
}

bool FeatureAutoencoderConfig::is_valid(std::string* why) const {
  if (level_channels.empty() || level_channels.size() > 16)
    return fail(why, "autoencoder: 1 to 16 feature levels required, got " +
                         std::to_string(level_channels.size()));
  for (int c : level_channels)
    if (c < 1 || c > 4096)
      return fail(why, "autoencoder: level channels must be 1..4096, got " + std::to_string(c));
  const auto in_range = [](int v, int hi) { return v >= 1 && v <= hi; };
  if (!in_range(latent_dim, 1024))
    return fail(why, "autoencoder: latent_dim must be 1..1024, got " + std::to_string(latent_dim));
  if (!in_range(encoder_hidden, 4096) || !in_range(head_hidden, 4096))
    return fail(why, "autoencoder: hidden widths must be 1..4096");
  if (activation != AutoencoderActivation::gelu && activation != AutoencoderActivation::relu)
    return fail(why, "autoencoder: unknown activation");
  if (!in_range(lora_rank, 256))
    return fail(why, "autoencoder: lora_rank must be 1..256, got " + std::to_string(lora_rank));
  if (!(std::isfinite(lora_alpha) && lora_alpha > 0.0f))
    return fail(why, "autoencoder: lora_alpha must be positive and finite");
  return online.is_valid(why);
}

// ---- Layout and initialisation -----------------------------------------------------------------

FeatureAutoencoder::FeatureAutoencoder(const FeatureAutoencoderConfig& config)
    : config_(config), adam_(1, AdamSettings{0.9, 0.999, 1e-8}) {
  assert(config_.is_valid());
  build_layout();
  const int C = config_.input_dim();
  mean_.assign(static_cast<std::size_t>(C), 0.0f);
  std_.assign(static_cast<std::size_t>(C), 1.0f);

  // PyTorch's nn.Linear default, U(-1/sqrt(in), 1/sqrt(in)) for weights and biases, and the
  // same for LoRA A (as PEFT's kaiming_uniform(a = sqrt(5))); LoRA B = 0, the paper's
  // "zero-convolution", so the adapted decoder starts equal to the pretrained one.
  std::mt19937 rng(config_.seed);
  for (std::size_t t = 0; t < tensors_.size(); ++t) {
    const AutoencoderTensor& tensor = tensors_[t];
    const bool is_bias = ends_with(tensor.name, "bias");
    const bool is_lora_b = ends_with(tensor.name, "lora_b");
    // fan-in: the weight's columns; a bias uses its weight's (the tensor before it).
    const int fan_in = is_bias ? tensors_[t - 1].cols : tensor.cols;
    const float bound = 1.0f / std::sqrt(static_cast<float>(fan_in));
    float* p = params_.data() + tensor.offset;
    for (std::size_t i = 0; i < tensor.size(); ++i)
      p[i] = is_lora_b ? 0.0f : bound * (2.0f * uniform01(&rng) - 1.0f);
  }
  adam_.add_group("body", body_size_, 0.0f);
  adam_.add_group("lora", params_.size() - body_size_, 0.0f);
}

int FeatureAutoencoder::add_tensor(const std::string& name, int rows, int cols, bool lora) {
  AutoencoderTensor t;
  t.name = name;
  t.rows = rows;
  t.cols = cols;
  t.lora = lora;
  t.offset = tensors_.empty() ? 0 : tensors_.back().offset + tensors_.back().size();
  tensors_.push_back(t);
  return static_cast<int>(tensors_.size()) - 1;
}

void FeatureAutoencoder::build_layout() {
  const int C = config_.input_dim(), D = config_.latent_dim, He = config_.encoder_hidden;
  const int Hd = config_.head_hidden, r = config_.lora_rank;
  const int L = static_cast<int>(config_.level_channels.size());
  // Body first so that it is one contiguous Adam group; LoRA after it.
  enc0_ = {add_tensor("encoder.0.weight", He, C, false),
           add_tensor("encoder.0.bias", 1, He, false)};
  enc1_ = {add_tensor("encoder.1.weight", D, He, false),
           add_tensor("encoder.1.bias", 1, D, false)};
  head0_.resize(static_cast<std::size_t>(L));
  head1_.resize(static_cast<std::size_t>(L));
  for (int l = 0; l < L; ++l) {
    const std::string h = "head." + std::to_string(l) + ".";
    const int Cl = config_.level_channels[static_cast<std::size_t>(l)];
    head0_[l].w = add_tensor(h + "0.weight", Hd, D, false);
    head0_[l].b = add_tensor(h + "0.bias", 1, Hd, false);
    head1_[l].w = add_tensor(h + "1.weight", Cl, Hd, false);
    head1_[l].b = add_tensor(h + "1.bias", 1, Cl, false);
  }
  body_size_ = tensors_.back().offset + tensors_.back().size();
  for (int l = 0; l < L; ++l) {
    const std::string h = "head." + std::to_string(l) + ".";
    const int Cl = config_.level_channels[static_cast<std::size_t>(l)];
    head0_[l].lora_a = add_tensor(h + "0.lora_a", r, D, true);
    head0_[l].lora_b = add_tensor(h + "0.lora_b", Hd, r, true);
    head1_[l].lora_a = add_tensor(h + "1.lora_a", r, Hd, true);
    head1_[l].lora_b = add_tensor(h + "1.lora_b", Cl, r, true);
  }
  params_.assign(tensors_.back().offset + tensors_.back().size(), 0.0f);
  grads_.assign(params_.size(), 0.0f);
  level_offset_.assign(static_cast<std::size_t>(L), 0);
  for (int l = 1; l < L; ++l)
    level_offset_[l] =
        level_offset_[l - 1] + config_.level_channels[static_cast<std::size_t>(l - 1)];
}

int FeatureAutoencoder::find_tensor(const std::string& name) const {
  for (std::size_t i = 0; i < tensors_.size(); ++i)
    if (tensors_[i].name == name) return static_cast<int>(i);
  return -1;
}

bool FeatureAutoencoder::trainable(int tensor) const {
  return tensors_[static_cast<std::size_t>(tensor)].lora == (mode_ == AutoencoderMode::online);
}

bool FeatureAutoencoder::set_normalisation(std::vector<float> mean, std::vector<float> std,
                                           std::string* why) {
  const std::size_t C = static_cast<std::size_t>(input_dim());
  if (mean.size() != C || std.size() != C)
    return fail(why, "autoencoder: normalisation needs " + std::to_string(C) + " means and stds");
  for (std::size_t c = 0; c < C; ++c)
    if (!std::isfinite(mean[c]) || !(std::isfinite(std[c]) && std[c] > 0.0f))
      return fail(why, "autoencoder: normalisation of channel " + std::to_string(c) +
                           " is not finite or its std is not positive");
  mean_ = std::move(mean);
  std_ = std::move(std);
  return true;
}

// ---- Forward ------------------------------------------------------------------------------------

void FeatureAutoencoder::encode(const float* u, int n, float* f, AutoencoderTape* tape) const {
  AutoencoderTape local;
  AutoencoderTape& t = tape ? *tape : local;
  t.n = n;
  const int C = input_dim(), D = latent_dim(), He = config_.encoder_hidden;
  if (n <= 0) return;
  const auto T = [&](int i) { return tensor_data(i); };
  // x = (u - mean) / std: the body sees standardised channels.
  t.x.resize(sz(n, C));
  const Eigen::Map<const Eigen::RowVectorXf> mean(mean_.data(), C), stdev(std_.data(), C);
  out(t.x.data(), n, C).array() =
      (in(u, n, C).array().rowwise() - mean.array()).rowwise() / stdev.array();
  // phi: x -> act(x W0^T + b0) -> . W1^T + b1 (paper: f_i = phi(u_i)).
  t.enc_pre.resize(sz(n, He));
  auto pre = out(t.enc_pre.data(), n, He);
  pre.noalias() = in(t.x.data(), n, C) * in(T(enc0_.w), He, C).transpose();
  pre.rowwise() += row(T(enc0_.b), He);
  activate(config_.activation, t.enc_pre, &t.enc_act);
  auto latent = out(f, n, D);
  latent.noalias() = in(t.enc_act.data(), n, He) * in(T(enc1_.w), D, He).transpose();
  latent.rowwise() += row(T(enc1_.b), D);
}

RowMat FeatureAutoencoder::merged_weight(const Linear& layer) const {
  const AutoencoderTensor& w = tensors_[static_cast<std::size_t>(layer.w)];
  const int r = config_.lora_rank;
  // W + s B A: exactly W while B = 0, so LoRA's zero start changes nothing.
  RowMat merged = in(tensor_data(layer.w), w.rows, w.cols);
  merged.noalias() += lora_scale() * in(tensor_data(layer.lora_b), w.rows, r) *
                      in(tensor_data(layer.lora_a), r, w.cols);
  return merged;
}

void FeatureAutoencoder::decode(const float* f, int n, float* u_hat, AutoencoderTape* tape) const {
  AutoencoderTape local;
  AutoencoderTape& t = tape ? *tape : local;
  t.n = n;
  const int C = input_dim(), D = latent_dim(), Hd = config_.head_hidden;
  const std::size_t L = config_.level_channels.size();
  if (n <= 0) return;
  t.f.assign(f, f + sz(n, D));
  t.head_pre.resize(L);
  t.head_act.resize(L);
  const auto F = in(f, n, D);
  for (std::size_t l = 0; l < L; ++l) {
    const int Cl = config_.level_channels[l], c0 = level_offset_[l];
    // phi^(l) with a LoRA block on each layer:
    //   h = act(f (W0 + s B0 A0)^T + b0),  x_hat_l = h (W1 + s B1 A1)^T + b1,
    // and back to encoder units, u_hat_l = x_hat_l * std + mean. The LoRA products are merged
    // into the weights and the de-standardisation into the last layer once per call, so a
    // sample costs the two products only.
    t.head_pre[l].resize(sz(n, Hd));
    auto pre = out(t.head_pre[l].data(), n, Hd);
    pre.noalias() = F * merged_weight(head0_[l]).transpose();
    pre.rowwise() += row(tensor_data(head0_[l].b), Hd);
    activate(config_.activation, t.head_pre[l], &t.head_act[l]);

    const Eigen::Map<const Eigen::VectorXf> stdev(std_.data() + c0, Cl);
    const Eigen::Map<const Eigen::RowVectorXf> mean(mean_.data() + c0, Cl);
    RowMat w1 = merged_weight(head1_[l]);
    w1.array().colwise() *= stdev.array();
    const Eigen::RowVectorXf b1 =
        row(tensor_data(head1_[l].b), Cl).cwiseProduct(stdev.transpose()) + mean;
    auto y = out(u_hat + c0, n, Cl, C);
    y.noalias() = in(t.head_act[l].data(), n, Hd) * w1.transpose();
    y.rowwise() += b1;
  }
}

}  // namespace fslam::core

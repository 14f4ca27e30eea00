#include "fslam/core/features/feature_autoencoder.hpp"

#include <Eigen/Core>
#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <numeric>

#include "fslam/core/error.hpp"

namespace fslam::core {
namespace {

using RowMat = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using Stride = Eigen::OuterStride<>;
using In = Eigen::Map<const RowMat, 0, Stride>;  // a [rows, cols] block of a wider buffer
using Out = Eigen::Map<RowMat, 0, Stride>;

In in(const float* p, int rows, int cols, int stride) { return In(p, rows, cols, Stride(stride)); }
In in(const float* p, int rows, int cols) { return in(p, rows, cols, cols); }
Out out(float* p, int rows, int cols, int stride) { return Out(p, rows, cols, Stride(stride)); }
Out out(float* p, int rows, int cols) { return out(p, rows, cols, cols); }
Eigen::Map<const Eigen::RowVectorXf> row(const float* p, int n) {
  return Eigen::Map<const Eigen::RowVectorXf>(p, n);
}
bool ends_with(const std::string& s, const std::string& tail) {
  return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}
constexpr double kPi = 3.14159265358979323846;

// Portable uniform [0, 1) from mt19937's standardised output (std::uniform_real_distribution
// differs between standard libraries, and the initial weights should not).
float uniform01(std::mt19937* rng) {
  return static_cast<float>((*rng)() >> 8) * (1.0f / 16777216.0f);
}

// GELU, tanh form (Hendrycks & Gimpel 2016): 0.5 x (1 + tanh(k (x + 0.044715 x^3))).
constexpr float kGeluK = 0.7978845608f;  // sqrt(2 / pi)
constexpr float kGeluC = 0.044715f;

Eigen::Map<const Eigen::ArrayXf> array(const std::vector<float>& v) {
  return Eigen::Map<const Eigen::ArrayXf>(v.data(), static_cast<Eigen::Index>(v.size()));
}

void activate(AutoencoderActivation a, const std::vector<float>& pre, std::vector<float>* act) {
  act->resize(pre.size());
  const auto x = array(pre);
  auto y = Eigen::Map<Eigen::ArrayXf>(act->data(), static_cast<Eigen::Index>(act->size()));
  if (a == AutoencoderActivation::relu) y = x.max(0.0f);
  else y = 0.5f * x * (1.0f + (kGeluK * (x + kGeluC * x.cube())).tanh());
}

// grad *= activation'(pre), elementwise.
void activate_backward(AutoencoderActivation a, const std::vector<float>& pre, float* grad) {
  const auto x = array(pre);
  auto g = Eigen::Map<Eigen::ArrayXf>(grad, static_cast<Eigen::Index>(pre.size()));
  if (a == AutoencoderActivation::relu) {
    g *= (x > 0.0f).cast<float>();
  } else {
    const Eigen::ArrayXf t = (kGeluK * (x + kGeluC * x.cube())).tanh();
    g *= 0.5f * (1.0f + t) +
         0.5f * x * (1.0f - t.square()) * kGeluK * (1.0f + 3.0f * kGeluC * x.square());
  }
}

std::size_t sz(int n, int c) { return static_cast<std::size_t>(n) * static_cast<std::size_t>(c); }

}  // namespace

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

// ---- Backward -----------------------------------------------------------------------------------

void FeatureAutoencoder::backward_decode(const AutoencoderTape& t, const float* grad_u_hat,
                                         float* grad_f) {
  const int n = t.n, C = input_dim(), D = latent_dim(), Hd = config_.head_hidden;
  const int r = config_.lora_rank;
  const std::size_t L = config_.level_channels.size();
  if (n <= 0) return;
  assert(t.f.size() == sz(n, D) && t.head_act.size() == L);
  const float s = lora_scale();
  const auto T = [&](int i) { return tensor_data(i); };
  const auto G = [&](int i) {
    return grads_.data() + tensors_[static_cast<std::size_t>(i)].offset;
  };

  // dL/dx_hat = dL/du_hat * std.
  const Eigen::Map<const Eigen::RowVectorXf> stdev(std_.data(), C);
  const RowMat dx = in(grad_u_hat, n, C).array().rowwise() * stdev.array();
  RowMat df = RowMat::Zero(n, D);
  RowMat dh(n, Hd), z, dz;
  const auto F = in(t.f.data(), n, D);
  for (std::size_t l = 0; l < L; ++l) {
    const int Cl = config_.level_channels[l];
    const auto dy = in(dx.data() + level_offset_[l], n, Cl, C);
    const auto H = in(t.head_act[l].data(), n, Hd);
    // Second layer, y = h W1^T + b1 + s (h A1^T) B1^T.
    const Linear& l1 = head1_[l];
    if (trainable(l1.w)) {
      out(G(l1.w), Cl, Hd).noalias() += dy.transpose() * H;
      out(G(l1.b), 1, Cl) += dy.colwise().sum();
    }
    if (trainable(l1.lora_b)) {
      z.noalias() = H * in(T(l1.lora_a), r, Hd).transpose();
      dz.noalias() = s * dy * in(T(l1.lora_b), Cl, r);
      out(G(l1.lora_b), Cl, r).noalias() += s * dy.transpose() * z;
      out(G(l1.lora_a), r, Hd).noalias() += dz.transpose() * H;
    }
    dh.noalias() = dy * merged_weight(l1);
    // Through the activation to the first layer, h = act(f W0^T + b0 + s (f A0^T) B0^T).
    activate_backward(config_.activation, t.head_pre[l], dh.data());
    const Linear& l0 = head0_[l];
    if (trainable(l0.w)) {
      out(G(l0.w), Hd, D).noalias() += dh.transpose() * F;
      out(G(l0.b), 1, Hd) += dh.colwise().sum();
    }
    if (trainable(l0.lora_b)) {
      z.noalias() = F * in(T(l0.lora_a), r, D).transpose();
      dz.noalias() = s * dh * in(T(l0.lora_b), Hd, r);
      out(G(l0.lora_b), Hd, r).noalias() += s * dh.transpose() * z;
      out(G(l0.lora_a), r, D).noalias() += dz.transpose() * F;
    }
    if (grad_f) df.noalias() += dh * merged_weight(l0);
  }
  if (grad_f) out(grad_f, n, D) = df;
}

void FeatureAutoencoder::backward_encode(const AutoencoderTape& t, const float* grad_f,
                                         float* grad_u) {
  const int n = t.n, C = input_dim(), D = latent_dim(), He = config_.encoder_hidden;
  if (n <= 0) return;
  assert(t.x.size() == sz(n, C) && t.enc_act.size() == sz(n, He));
  const bool train = trainable(enc0_.w);
  if (!train && !grad_u) return;
  const auto T = [&](int i) { return tensor_data(i); };
  const auto G = [&](int i) {
    return grads_.data() + tensors_[static_cast<std::size_t>(i)].offset;
  };
  const auto df = in(grad_f, n, D);
  if (train) {
    out(G(enc1_.w), D, He).noalias() += df.transpose() * in(t.enc_act.data(), n, He);
    out(G(enc1_.b), 1, D) += df.colwise().sum();
  }
  RowMat dh = df * in(T(enc1_.w), D, He);
  activate_backward(config_.activation, t.enc_pre, dh.data());
  if (train) {
    out(G(enc0_.w), He, C).noalias() += dh.transpose() * in(t.x.data(), n, C);
    out(G(enc0_.b), 1, He) += dh.colwise().sum();
  }
  if (grad_u) {
    // dL/du = dL/dx / std.
    const Eigen::Map<const Eigen::RowVectorXf> stdev(std_.data(), C);
    auto du = out(grad_u, n, C);
    du.noalias() = dh * in(T(enc0_.w), He, C);
    du.array().rowwise() /= stdev.array();
  }
}

double FeatureAutoencoder::loss_l1(const float* u_hat, const float* u_obs, int n,
                                   float* grad) const {
  return l1(u_hat, u_obs, n, n, grad);
}

double FeatureAutoencoder::l1(const float* u_hat, const float* u_obs, int n, int total,
                              float* grad) const {
  const int C = input_dim();
  const std::size_t L = config_.level_channels.size();
  if (n <= 0) return 0.0;
  // w_c = 1 / (N L C_l s_c): every level weighs the same (the 32-channel fine level is not
  // drowned by the 256-channel coarse one), every channel is in units of its spread.
  std::vector<float> weight(static_cast<std::size_t>(C));
  for (std::size_t l = 0; l < L; ++l)
    for (int c = 0; c < config_.level_channels[l]; ++c) {
      const int k = level_offset_[l] + c;
      weight[k] = static_cast<float>(1.0 / (static_cast<double>(total) * L *
                                            config_.level_channels[l] * std_[k]));
    }
  const Eigen::Map<const Eigen::ArrayXf> w(weight.data(), C);
  Eigen::ArrayXf d(C);
  double loss = 0.0;  // rows summed in float, the batch in double
  for (int i = 0; i < n; ++i) {
    d = Eigen::Map<const Eigen::ArrayXf>(u_hat + sz(i, C), C) -
        Eigen::Map<const Eigen::ArrayXf>(u_obs + sz(i, C), C);
    loss += static_cast<double>((d.abs() * w).sum());
    // Branch-free sign(d) * w_c (0 where d = 0); a plain loop GCC vectorises.
    if (grad) {
      float* g = grad + sz(i, C);
      for (int c = 0; c < C; ++c)
        g[c] = weight[c] * (static_cast<float>(d[c] > 0.0f) - static_cast<float>(d[c] < 0.0f));
    }
  }
  return loss;
}

double FeatureAutoencoder::feature_loss(const float* f, const float* u_obs, int n, float* grad_f) {
  const int C = input_dim(), D = latent_dim();
  if (n <= 0) return 0.0;
  std::vector<float> u_hat(sz(std::min(n, kChunk), C)), grad(u_hat.size());
  AutoencoderTape tape;
  double loss = 0.0;
  for (int first = 0; first < n; first += kChunk) {
    const int m = std::min(kChunk, n - first);
    decode(f + sz(first, D), m, u_hat.data(), &tape);
    loss += l1(u_hat.data(), u_obs + sz(first, C), m, n, grad.data());
    backward_decode(tape, grad.data(), grad_f ? grad_f + sz(first, D) : nullptr);
  }
  return loss;
}

void FeatureAutoencoder::standardise_latent(const float* u, int n) {
  const int D = latent_dim(), He = config_.encoder_hidden, Hd = config_.head_hidden;
  if (n <= 0) return;
  std::vector<float> f(sz(n, D));
  encode(u, n, f.data());
  const auto F = in(f.data(), n, D);
  const Eigen::RowVectorXf mu = F.colwise().mean();
  const Eigen::RowVectorXf sigma =
      ((F.rowwise() - mu).array().square().colwise().mean().sqrt()).max(1e-3f).matrix();
  // f = mu + sigma f': the encoder's last layer outputs f', and every head's first layer,
  // f W0^T + b0, becomes f' (W0 diag(sigma))^T + (b0 + W0 mu).
  auto w1 = out(tensor_data(enc1_.w), D, He);
  auto b1 = out(tensor_data(enc1_.b), 1, D);
  w1.array().colwise() /= sigma.transpose().array();
  b1.array() = (b1.array() - mu.array()) / sigma.array();
  for (const Linear& l0 : head0_) {
    assert(in(tensor_data(l0.lora_b), Hd, config_.lora_rank).isZero(0.0f));
    auto w0 = out(tensor_data(l0.w), Hd, D);
    auto b0 = out(tensor_data(l0.b), 1, Hd);
    b0 += mu * w0.transpose();
    w0.array().rowwise() *= sigma.array();
  }
}

// ---- Optimisation -------------------------------------------------------------------------------

void FeatureAutoencoder::zero_grad() { std::fill(grads_.begin(), grads_.end(), 0.0f); }

void FeatureAutoencoder::step(float learning_rate) {
  const bool online = mode_ == AutoencoderMode::online;
  const int group = online ? 1 : 0;
  const std::size_t first = online ? body_size_ : 0;
  const std::size_t count = online ? params_.size() - body_size_ : body_size_;
  adam_.set_learning_rate(group, learning_rate);
  adam_.step(group, params_.data() + first, grads_.data() + first, count);
  if (online) ++online_steps_;
  zero_grad();
}

void FeatureAutoencoder::step_online() {
  assert(mode_ == AutoencoderMode::online);
  step(config_.online.rate(online_steps_));
}

bool FeatureAutoencoder::check_levels(const std::vector<FeatureLevelShape>& encoder_levels,
                                      std::string* why) const {
  std::vector<int> channels;
  for (const auto& s : encoder_levels) channels.push_back(s.channels);
  if (channels == config_.level_channels) return true;
  const auto list = [](const std::vector<int>& v) {
    std::string text;
    for (int c : v) text += (text.empty() ? "" : ", ") + std::to_string(c);
    return "[" + text + "]";
  };
  return fail(why, "autoencoder: trained for level channels " + list(config_.level_channels) +
                       " but the feature encoder produces " + list(channels));
}

// ---- Weights file ------------------------------------------------------------------------------
// Little-endian throughout: magic "FSLAMFAE", u32 version, the config, u32 notes length + bytes,
// f32 mean[C], f32 std[C], u32 tensor count, then per tensor u32 name length + name, u32 rows,
// u32 cols, f32 data[rows * cols]. Nothing may follow.
namespace {

constexpr char kMagic[8] = {'F', 'S', 'L', 'A', 'M', 'F', 'A', 'E'};
constexpr std::uint32_t kVersion = 1;
constexpr std::uint32_t kMaxNotes = 1u << 20;
constexpr std::uint32_t kMaxName = 256;

class Writer {
 public:
  void u32(std::uint32_t v) {
    for (int i = 0; i < 4; ++i) bytes_.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
  }
  void f32(float v) {
    std::uint32_t bits;
    std::memcpy(&bits, &v, 4);
    u32(bits);
  }
  void floats(const float* p, std::size_t n) {
    for (std::size_t i = 0; i < n; ++i) f32(p[i]);
  }
  void text(const std::string& s) {
    u32(static_cast<std::uint32_t>(s.size()));
    bytes_.insert(bytes_.end(), s.begin(), s.end());
  }
  void raw(const char* p, std::size_t n) { bytes_.insert(bytes_.end(), p, p + n); }
  const std::vector<char>& bytes() const { return bytes_; }

 private:
  std::vector<char> bytes_;
};

class Reader {
 public:
  explicit Reader(std::vector<char> bytes) : bytes_(std::move(bytes)) {}
  // Each read fails once the file is too short, naming what it was reading.
  bool u32(std::uint32_t* v, const char* what) {
    if (!need(4, what)) return false;
    *v = 0;
    for (int i = 0; i < 4; ++i)
      *v |= static_cast<std::uint32_t>(static_cast<unsigned char>(bytes_[pos_ + i])) << (8 * i);
    pos_ += 4;
    return true;
  }
  bool f32(float* v, const char* what) {
    std::uint32_t bits;
    if (!u32(&bits, what)) return false;
    std::memcpy(v, &bits, 4);
    return true;
  }
  bool floats(float* p, std::size_t n, const char* what) {
    if (!need(4 * n, what)) return false;
    for (std::size_t i = 0; i < n; ++i) f32(p + i, what);
    return true;
  }
  bool text(std::string* s, std::uint32_t max, const char* what) {
    std::uint32_t n;
    if (!u32(&n, what)) return false;
    if (n > max) return fail_with(std::string(what) + " is " + std::to_string(n) + " bytes long");
    if (!need(n, what)) return false;
    s->assign(bytes_.data() + pos_, n);
    pos_ += n;
    return true;
  }
  bool magic() {
    if (bytes_.size() < sizeof(kMagic) || std::memcmp(bytes_.data(), kMagic, sizeof(kMagic)) != 0)
      return fail_with("not a feature autoencoder file (wrong magic)");
    pos_ = sizeof(kMagic);
    return true;
  }
  bool at_end() {
    if (pos_ == bytes_.size()) return true;
    return fail_with(std::to_string(bytes_.size() - pos_) +
                     " unexpected bytes after the last tensor");
  }
  bool fail_with(const std::string& message) {
    error_ = message;
    return false;
  }
  const std::string& error() const { return error_; }

 private:
  bool need(std::size_t n, const char* what) {
    if (bytes_.size() - pos_ >= n) return true;
    return fail_with("truncated at byte " + std::to_string(bytes_.size()) + " while reading " +
                     what);
  }
  std::vector<char> bytes_;
  std::size_t pos_ = 0;
  std::string error_;
};

}  // namespace

bool FeatureAutoencoder::save(const std::string& path, std::string* why) const {
  Writer w;
  w.raw(kMagic, sizeof(kMagic));
  w.u32(kVersion);
  w.u32(static_cast<std::uint32_t>(config_.level_channels.size()));
  for (int c : config_.level_channels) w.u32(static_cast<std::uint32_t>(c));
  w.u32(static_cast<std::uint32_t>(config_.latent_dim));
  w.u32(static_cast<std::uint32_t>(config_.encoder_hidden));
  w.u32(static_cast<std::uint32_t>(config_.head_hidden));
  w.u32(static_cast<std::uint32_t>(config_.activation));
  w.u32(static_cast<std::uint32_t>(config_.lora_rank));
  w.f32(config_.lora_alpha);
  w.u32(config_.seed);
  w.text(notes_);
  w.floats(mean_.data(), mean_.size());
  w.floats(std_.data(), std_.size());
  w.u32(static_cast<std::uint32_t>(tensors_.size()));
  for (const auto& t : tensors_) {
    w.text(t.name);
    w.u32(static_cast<std::uint32_t>(t.rows));
    w.u32(static_cast<std::uint32_t>(t.cols));
    w.floats(params_.data() + t.offset, t.size());
  }
  std::ofstream file(path, std::ios::binary | std::ios::trunc);
  if (!file) return fail(why, "autoencoder: cannot write " + path);
  file.write(w.bytes().data(), static_cast<std::streamsize>(w.bytes().size()));
  file.close();
  if (!file) return fail(why, "autoencoder: writing " + path + " failed");
  return true;
}

bool FeatureAutoencoder::load(const std::string& path, std::string* why) {
  std::ifstream file(path, std::ios::binary);
  if (!file) return fail(why, "autoencoder: cannot open " + path);
  Reader r(std::vector<char>(std::istreambuf_iterator<char>(file), {}));
  const auto bad = [&](const std::string& message) {
    return fail(why, "autoencoder weights " + path + ": " + message);
  };
  if (!r.magic()) return bad(r.error());
  std::uint32_t version = 0;
  if (!r.u32(&version, "the version")) return bad(r.error());
  if (version != kVersion)
    return bad("version " + std::to_string(version) + ", this build reads version " +
               std::to_string(kVersion));

  FeatureAutoencoderConfig config;
  std::uint32_t levels = 0, v = 0;
  if (!r.u32(&levels, "the level count")) return bad(r.error());
  if (levels < 1 || levels > 16) return bad(std::to_string(levels) + " levels (1..16 allowed)");
  config.level_channels.assign(levels, 0);
  std::uint32_t dims[5];
  for (auto& c : config.level_channels) {
    if (!r.u32(&v, "the level channels")) return bad(r.error());
    c = static_cast<int>(std::min<std::uint32_t>(v, 1u << 30));
  }
  for (auto& d : dims)
    if (!r.u32(&d, "the layer sizes")) return bad(r.error());
  const auto to_int = [](std::uint32_t x) {
    return static_cast<int>(std::min<std::uint32_t>(x, 1u << 30));
  };
  config.latent_dim = to_int(dims[0]);
  config.encoder_hidden = to_int(dims[1]);
  config.head_hidden = to_int(dims[2]);
  if (dims[3] > 1) return bad("unknown activation code " + std::to_string(dims[3]));
  config.activation = static_cast<AutoencoderActivation>(dims[3]);
  config.lora_rank = to_int(dims[4]);
  if (!r.f32(&config.lora_alpha, "lora_alpha") || !r.u32(&config.seed, "the seed"))
    return bad(r.error());
  config.online = config_.online;  // a run-time setting, not the file's
  std::string reason;
  if (!config.is_valid(&reason)) return bad(reason);

  FeatureAutoencoder loaded(config);
  if (!r.text(&loaded.notes_, kMaxNotes, "the notes")) return bad(r.error());
  if (!r.floats(loaded.mean_.data(), loaded.mean_.size(), "the normalisation means") ||
      !r.floats(loaded.std_.data(), loaded.std_.size(), "the normalisation stds"))
    return bad(r.error());
  if (!loaded.set_normalisation(loaded.mean_, loaded.std_, &reason)) return bad(reason);
  std::uint32_t count = 0;
  if (!r.u32(&count, "the tensor count")) return bad(r.error());
  if (count != loaded.tensors_.size())
    return bad(std::to_string(count) + " tensors, the stored shapes need " +
               std::to_string(loaded.tensors_.size()));
  for (const auto& t : loaded.tensors_) {
    std::string name;
    std::uint32_t rows = 0, cols = 0;
    if (!r.text(&name, kMaxName, "a tensor name") || !r.u32(&rows, "a tensor shape") ||
        !r.u32(&cols, "a tensor shape"))
      return bad(r.error());
    if (name != t.name || rows != static_cast<std::uint32_t>(t.rows) ||
        cols != static_cast<std::uint32_t>(t.cols))
      return bad("tensor '" + name + "' [" + std::to_string(rows) + ", " + std::to_string(cols) +
                 "] where '" + t.name + "' [" + std::to_string(t.rows) + ", " +
                 std::to_string(t.cols) + "] belongs");
    float* p = loaded.params_.data() + t.offset;
    if (!r.floats(p, t.size(), "tensor data")) return bad(r.error());
    if (!std::all_of(p, p + t.size(), [](float x) { return std::isfinite(x); }))
      return bad("tensor '" + t.name + "' has non-finite values");
  }
  if (!r.at_end()) return bad(r.error());
  *this = std::move(loaded);
  return true;
}

bool FeatureAutoencoder::load(const std::string& path,
                              const std::vector<FeatureLevelShape>& encoder_levels,
                              std::string* why) {
  FeatureAutoencoder candidate(config_);
  if (!candidate.load(path, why)) return false;
  std::string reason;
  if (!candidate.check_levels(encoder_levels, &reason))
    return fail(why, reason + " (weights " + path + ")");
  *this = std::move(candidate);
  return true;
}

// ---- Pretraining -------------------------------------------------------------------------------

bool AutoencoderPretrainOptions::is_valid(std::string* why) const {
  if (steps < 1) return fail(why, "autoencoder pretraining: steps must be >= 1");
  if (batch < 1) return fail(why, "autoencoder pretraining: batch must be >= 1");
  if (!(std::isfinite(learning_rate) && learning_rate > 0.0f))
    return fail(why, "autoencoder pretraining: learning rate must be positive");
  if (pixels_per_image < 1)
    return fail(why, "autoencoder pretraining: pixels_per_image must be >= 1");
  if (eval_samples < 1) return fail(why, "autoencoder pretraining: eval_samples must be >= 1");
  return true;
}

void sample_training_features(const FeaturePyramid& pyramid, int count, std::mt19937* rng,
                              std::vector<float>* out) {
  const std::size_t C = static_cast<std::size_t>(pyramid.dim());
  const std::size_t first = out->size();
  out->resize(first + C * static_cast<std::size_t>(std::max(count, 0)));
  for (int i = 0; i < count; ++i) {
    const float u = uniform01(rng) * static_cast<float>(pyramid.image_width - 1);
    const float v = uniform01(rng) * static_cast<float>(pyramid.image_height - 1);
    sample_features(pyramid, u, v, out->data() + first + C * static_cast<std::size_t>(i));
  }
}

double reconstruction_error(const FeatureAutoencoder& ae, const std::vector<float>& samples) {
  const int C = ae.input_dim(), D = ae.latent_dim();
  const std::size_t m = samples.size() / static_cast<std::size_t>(C);
  if (m == 0) return 0.0;
  constexpr std::size_t kBatch = 1024;
  std::vector<float> f(kBatch * D), u_hat(kBatch * C);
  double total = 0.0;
  for (std::size_t first = 0; first < m; first += kBatch) {
    const int n = static_cast<int>(std::min(kBatch, m - first));
    const float* u = samples.data() + first * C;
    ae.encode(u, n, f.data());
    ae.decode(f.data(), n, u_hat.data());
    total += ae.loss_l1(u_hat.data(), u, n, nullptr) * n;
  }
  return total / static_cast<double>(m);
}

bool pretrain_autoencoder_on_samples(const std::vector<float>& samples,
                                     const std::vector<float>* held_out,
                                     const AutoencoderPretrainOptions& options,
                                     FeatureAutoencoder* ae,
                                     const AutoencoderPretrainProgress& progress,
                                     AutoencoderPretrainStats* stats, std::string* why) {
  if (!options.is_valid(why)) return false;
  const int C = ae->input_dim(), D = ae->latent_dim();
  const std::size_t Cs = static_cast<std::size_t>(C);
  if (samples.empty() || samples.size() % Cs != 0)
    return fail(why, "autoencoder pretraining: samples must be a non-empty [M, " +
                         std::to_string(C) + "] array");
  if (held_out && held_out->size() % Cs != 0)
    return fail(why, "autoencoder pretraining: held-out samples must be [K, " +
                         std::to_string(C) + "]");
  const std::size_t m = samples.size() / Cs;

  // Per-channel standardisation from the training samples. A near-constant channel's std is
  // floored so that it does not blow up its residuals.
  std::vector<double> sum(Cs, 0.0), sq(Cs, 0.0);
  for (std::size_t i = 0; i < m; ++i)
    for (std::size_t c = 0; c < Cs; ++c) {
      const double x = samples[i * Cs + c];
      sum[c] += x;
      sq[c] += x * x;
    }
  std::vector<float> mean(Cs), stdev(Cs);
  for (std::size_t c = 0; c < Cs; ++c) {
    mean[c] = static_cast<float>(sum[c] / m);
    const double mu = sum[c] / m;
    stdev[c] = static_cast<float>(std::sqrt(std::max(0.0, sq[c] / m - mu * mu)));
  }
  std::vector<float> sorted = stdev;
  std::nth_element(sorted.begin(), sorted.begin() + Cs / 2, sorted.end());
  const float min_std = std::max(1e-2f * sorted[Cs / 2], 1e-6f);
  for (float& s : stdev) s = std::max(s, min_std);
  if (!ae->set_normalisation(mean, stdev, why)) return false;

  // A fixed evaluation subset of the training samples.
  std::mt19937 rng(options.seed);
  std::vector<float> eval;
  for (int i = 0; i < options.eval_samples && static_cast<std::size_t>(i) < m; ++i) {
    const std::size_t k = m <= static_cast<std::size_t>(options.eval_samples) ? i : rng() % m;
    eval.insert(eval.end(), samples.begin() + k * Cs, samples.begin() + (k + 1) * Cs);
  }
  AutoencoderPretrainStats s;
  s.train_samples = m;
  s.train_error_before = reconstruction_error(*ae, eval);
  if (held_out) s.held_out_error_before = reconstruction_error(*ae, *held_out);

  ae->set_mode(AutoencoderMode::pretrain);
  ae->zero_grad();
  const int B = options.batch;
  std::vector<float> u(Cs * B), f(static_cast<std::size_t>(D) * B), u_hat(Cs * B), grad(Cs * B),
      grad_f(static_cast<std::size_t>(D) * B);
  AutoencoderTape tape;
  const int report_every = std::max(1, options.steps / 100);
  double running = 0.0;
  int running_count = 0;
  for (int t = 0; t < options.steps; ++t) {
    for (int b = 0; b < B; ++b) {
      const std::size_t k = rng() % m;
      std::copy(samples.begin() + k * Cs, samples.begin() + (k + 1) * Cs, u.begin() + b * Cs);
    }
    ae->encode(u.data(), B, f.data(), &tape);
    ae->decode(f.data(), B, u_hat.data(), &tape);
    running += ae->loss_l1(u_hat.data(), u.data(), B, grad.data());
    ++running_count;
    ae->backward_decode(tape, grad.data(), grad_f.data());
    ae->backward_encode(tape, grad_f.data(), nullptr);
    // Cosine decay from learning_rate to learning_rate / 10.
    const double done = options.steps > 1 ? static_cast<double>(t) / (options.steps - 1) : 1.0;
    const double lr = options.learning_rate * (0.1 + 0.45 * (1.0 + std::cos(kPi * done)));
    ae->step(static_cast<float>(lr));
    if (progress && ((t + 1) % report_every == 0 || t + 1 == options.steps)) {
      progress(t + 1, options.steps, running / running_count);
      running = 0.0;
      running_count = 0;
    }
  }
  ae->standardise_latent(eval.data(), static_cast<int>(eval.size() / Cs));
  ae->set_mode(AutoencoderMode::online);
  s.steps = options.steps;
  s.train_error_after = reconstruction_error(*ae, eval);
  if (held_out) s.held_out_error_after = reconstruction_error(*ae, *held_out);
  if (stats) *stats = s;
  return true;
}

bool pretrain_autoencoder(const std::vector<FeaturePyramid>& pyramids,
                          const AutoencoderPretrainOptions& options, FeatureAutoencoder* ae,
                          const AutoencoderPretrainProgress& progress,
                          AutoencoderPretrainStats* stats, std::string* why) {
  if (!options.is_valid(why)) return false;
  if (pyramids.empty()) return fail(why, "autoencoder pretraining: no feature pyramids");
  std::mt19937 rng(options.seed);
  std::vector<float> samples;
  for (const auto& p : pyramids) {
    if (!ae->check_levels(p.shapes(), why)) return false;
    if (p.image_width < 1 || p.image_height < 1)
      return fail(why, "autoencoder pretraining: a pyramid has no image size");
    sample_training_features(p, options.pixels_per_image, &rng, &samples);
  }
  AutoencoderPretrainOptions training = options;
  training.seed = options.seed + 1;  // batches independent of the pixel positions
  return pretrain_autoencoder_on_samples(samples, nullptr, training, ae, progress, stats, why);
}

}  // namespace fslam::core

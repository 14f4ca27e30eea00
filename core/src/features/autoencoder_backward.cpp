// The feature autoencoder's backward pass, its losses and the latent's standardisation.
#include "fslam/core/features/feature_autoencoder.hpp"

#include <Eigen/Core>
#include <algorithm>
#include <cassert>
#include <cmath>

#include "autoencoder_math.hpp"
#include "fslam/core/error.hpp"

namespace fslam::core {

using namespace autoencoder_detail;  // NOLINT: the file's own helpers, private to core/src/features

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
      add_column_sums(dy.data(), n, Cl, C, G(l1.b));
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
      add_column_sums(dh.data(), n, Hd, Hd, G(l0.b));
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
    add_column_sums(grad_f, n, D, D, G(enc1_.b));
  }
  RowMat dh = df * in(T(enc1_.w), D, He);
  activate_backward(config_.activation, t.enc_pre, dh.data());
  if (train) {
    out(G(enc0_.w), He, C).noalias() += dh.transpose() * in(t.x.data(), n, C);
    add_column_sums(dh.data(), n, He, He, G(enc0_.b));
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
  // std::sqrt, not Eigen's packet sqrt (rsqrt and a Newton step, whose bits differ between CPU
  // vendors): the weights should not depend on the processor that trained them.
  const Eigen::RowVectorXf sigma = ((F.rowwise() - mu).array().square().colwise().mean())
                                       .unaryExpr([](float v) { return std::sqrt(v); })
                                       .max(1e-3f)
                                       .matrix();
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

}  // namespace fslam::core

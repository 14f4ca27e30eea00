// The feature autoencoder (paper sec. "Online Feature Rasterization"): hand-written gradients
// against central differences, LoRA's zero start and which parameters each mode trains, the
// warm-up, the weights file, and that pretraining learns to reconstruct unseen images.
//
// Gradient tolerance: the network runs in float, so a central difference with step h has a
// rounding error of about 1e-7 |L| / h; with h = 1e-2 and |L| ~ 1 that is ~1e-5, and the
// truncation error (GELU is smooth) ~h^2 = 1e-4. We accept
// |fd - analytic| <= 2e-3 + 2e-2 |analytic|.
#include "fslam/core/features/feature_autoencoder.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "fslam/core/features/feature_encoder.hpp"
#include "fslam/core/synth/synthetic_scene.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

constexpr double kAbsTol = 2e-3;
constexpr double kRelTol = 2e-2;

std::vector<float> random_vector(std::size_t n, std::uint32_t seed, float scale = 1.0f) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> normal(0.0f, scale);
  std::vector<float> v(n);
  for (float& x : v) x = normal(rng);
  return v;
}

// Levels of 6, 4 and 3 channels: small enough to check every parameter.
FeatureAutoencoderConfig small_config(
    AutoencoderActivation activation = AutoencoderActivation::gelu) {
  FeatureAutoencoderConfig c;
  c.level_channels = {6, 4, 3};
  c.latent_dim = 3;
  c.encoder_hidden = 5;
  c.head_hidden = 4;
  c.lora_rank = 2;
  c.lora_alpha = 3.0f;
  c.activation = activation;
  c.seed = 11;
  return c;
}

// A non-trivial normalisation so that its factors are part of every check.
void set_test_normalisation(FeatureAutoencoder* ae) {
  const std::size_t C = static_cast<std::size_t>(ae->input_dim());
  std::vector<float> mean = random_vector(C, 5, 0.5f), stdev(C);
  for (std::size_t c = 0; c < C; ++c) stdev[c] = 0.5f + 0.1f * static_cast<float>(c % 7);
  std::string why;
  ASSERT_TRUE(ae->set_normalisation(mean, stdev, &why)) << why;
}

// Gives every LoRA B random values, so that gradients through and of LoRA are non-trivial.
void randomise_lora_b(FeatureAutoencoder* ae) {
  for (int t = 0; t < static_cast<int>(ae->tensors().size()); ++t)
    if (ae->tensors()[t].name.find("lora_b") != std::string::npos) {
      const auto v = random_vector(ae->tensors()[t].size(), 100 + t, 0.3f);
      std::copy(v.begin(), v.end(), ae->tensor_data(t));
    }
}

// A smooth test loss on the reconstruction, L = sum w . decode(encode(u)), so that the check
// sees the network's derivatives and not L1's kinks.
struct Probe {
  int n = 0;
  std::vector<float> u, w;  // [N, C]
};

Probe make_probe(const FeatureAutoencoder& ae, int n) {
  Probe p;
  p.n = n;
  const std::size_t size = static_cast<std::size_t>(n) * ae.input_dim();
  p.u = random_vector(size, 21);
  for (std::size_t i = 0; i < size; ++i) p.u[i] = ae.input_mean()[i % ae.input_dim()] + p.u[i];
  p.w = random_vector(size, 22, 0.2f);
  return p;
}

// pattern (optional): which hidden pre-activations are positive, to tell when a finite
// difference of a ReLU network straddles a kink.
double probe_loss(const FeatureAutoencoder& ae, const Probe& p, const float* u,
                  std::vector<bool>* pattern = nullptr) {
  std::vector<float> f(static_cast<std::size_t>(p.n) * ae.latent_dim()), u_hat(p.w.size());
  AutoencoderTape tape;
  ae.encode(u, p.n, f.data(), &tape);
  ae.decode(f.data(), p.n, u_hat.data(), &tape);
  double loss = 0.0;
  for (std::size_t i = 0; i < u_hat.size(); ++i) loss += static_cast<double>(p.w[i]) * u_hat[i];
  if (pattern) {
    pattern->clear();
    for (float x : tape.enc_pre) pattern->push_back(x > 0.0f);
    for (const auto& head : tape.head_pre)
      for (float x : head) pattern->push_back(x > 0.0f);
  }
  return loss;
}

// Runs encode, decode and both backward passes on the probe; returns dL/du.
std::vector<float> probe_backward(FeatureAutoencoder* ae, const Probe& p) {
  AutoencoderTape tape;
  std::vector<float> f(static_cast<std::size_t>(p.n) * ae->latent_dim()), u_hat(p.w.size());
  std::vector<float> grad_f(f.size()), grad_u(p.u.size());
  ae->zero_grad();
  ae->encode(p.u.data(), p.n, f.data(), &tape);
  ae->decode(f.data(), p.n, u_hat.data(), &tape);
  ae->backward_decode(tape, p.w.data(), grad_f.data());
  ae->backward_encode(tape, grad_f.data(), grad_u.data());
  return grad_u;
}

void expect_close(double fd, double analytic, const std::string& what) {
  EXPECT_LE(std::abs(fd - analytic), kAbsTol + kRelTol * std::abs(analytic))
      << what << ": finite difference " << fd << ", analytic " << analytic;
}

// Checks the accumulated gradient of every trainable tensor (or `per_tensor` random entries of
// each) against central differences; returns how many entries were checked. With ReLU, an
// entry whose +-h evaluations switch any hidden unit on or off is skipped (the difference
// quotient then measures the kink, not the derivative); at most 5 % may be.
int check_parameter_gradients(FeatureAutoencoder* ae, const Probe& p, int per_tensor = 0) {
  probe_backward(ae, p);
  const bool online = ae->mode() == AutoencoderMode::online;
  std::mt19937 rng(3);
  std::vector<bool> centre, plus_pattern, minus_pattern;
  probe_loss(*ae, p, p.u.data(), &centre);
  int checked = 0, skipped = 0;
  for (int t = 0; t < static_cast<int>(ae->tensors().size()); ++t) {
    const AutoencoderTensor& tensor = ae->tensors()[t];
    if (tensor.lora != online) {
      for (std::size_t i = 0; i < tensor.size(); ++i)
        EXPECT_EQ(ae->tensor_grad(t)[i], 0.0f) << tensor.name << " is frozen in this mode";
      continue;
    }
    const std::size_t count =
        per_tensor > 0 ? std::min<std::size_t>(per_tensor, tensor.size()) : tensor.size();
    for (std::size_t k = 0; k < count; ++k) {
      const std::size_t i = per_tensor > 0 ? rng() % tensor.size() : k;
      float* x = ae->tensor_data(t) + i;
      const float saved = *x;
      const float h = ae->config().activation == AutoencoderActivation::relu ? 1e-3f : 1e-2f;
      *x = saved + h;
      const double plus = probe_loss(*ae, p, p.u.data(), &plus_pattern);
      *x = saved - h;
      const double minus = probe_loss(*ae, p, p.u.data(), &minus_pattern);
      *x = saved;
      if (ae->config().activation == AutoencoderActivation::relu &&
          (plus_pattern != centre || minus_pattern != centre)) {
        ++skipped;
        continue;
      }
      expect_close((plus - minus) / (2.0 * h), ae->tensor_grad(t)[i],
                   tensor.name + "[" + std::to_string(i) + "]");
      ++checked;
    }
  }
  EXPECT_LE(skipped, (checked + skipped) / 20) << "too many ReLU kinks straddled";
  return checked + skipped;
}

void check_input_gradients(FeatureAutoencoder* ae, const Probe& p, int max_entries = 0) {
  const std::vector<float> grad_u = probe_backward(ae, p);
  std::mt19937 rng(4);
  const std::size_t count = max_entries > 0 ? max_entries : p.u.size();
  for (std::size_t k = 0; k < count; ++k) {
    const std::size_t i = max_entries > 0 ? rng() % p.u.size() : k;
    std::vector<float> u = p.u;
    const float h = 1e-2f;
    u[i] = p.u[i] + h;
    const double plus = probe_loss(*ae, p, u.data());
    u[i] = p.u[i] - h;
    const double minus = probe_loss(*ae, p, u.data());
    expect_close((plus - minus) / (2.0 * h), grad_u[i], "dL/du[" + std::to_string(i) + "]");
  }
}

// dL/df of decode alone: the mapper's hook from the rendered latent back to the Gaussians.
void check_latent_gradients(FeatureAutoencoder* ae, const Probe& p) {
  const int D = ae->latent_dim();
  std::vector<float> f(static_cast<std::size_t>(p.n) * D), u_hat(p.w.size()), grad_f(f.size());
  ae->encode(p.u.data(), p.n, f.data());
  AutoencoderTape tape;
  ae->decode(f.data(), p.n, u_hat.data(), &tape);
  ae->backward_decode(tape, p.w.data(), grad_f.data());
  ae->zero_grad();
  const auto decode_loss = [&](const std::vector<float>& latent) {
    std::vector<float> out(p.w.size());
    ae->decode(latent.data(), p.n, out.data());
    double loss = 0.0;
    for (std::size_t i = 0; i < out.size(); ++i) loss += static_cast<double>(p.w[i]) * out[i];
    return loss;
  };
  for (std::size_t i = 0; i < f.size(); ++i) {
    std::vector<float> g = f;
    const float h = 1e-2f;
    g[i] = f[i] + h;
    const double plus = decode_loss(g);
    g[i] = f[i] - h;
    const double minus = decode_loss(g);
    expect_close((plus - minus) / (2.0 * h), grad_f[i], "dL/df[" + std::to_string(i) + "]");
  }
}

TEST(FeatureAutoencoder, ConfigValidation) {
  std::string why;
  EXPECT_TRUE(FeatureAutoencoderConfig{}.is_valid(&why)) << why;
  EXPECT_EQ(FeatureAutoencoderConfig{}.input_dim(), 352);
  FeatureAutoencoderConfig c;
  c.level_channels = {};
  EXPECT_FALSE(c.is_valid(&why));
  c = {};
  c.latent_dim = 0;
  EXPECT_FALSE(c.is_valid(&why));
  EXPECT_NE(why.find("latent_dim"), std::string::npos) << why;
  c = {};
  c.lora_rank = 0;
  EXPECT_FALSE(c.is_valid(&why));
  c = {};
  c.lora_alpha = std::nanf("");
  EXPECT_FALSE(c.is_valid(&why));
  c = {};
  c.online.warmup_steps = -1;
  EXPECT_FALSE(c.is_valid(&why));
}

TEST(FeatureAutoencoder, ShapesAndLayout) {
  const FeatureAutoencoder ae;
  // Body: 352*64+64 + 64*16+16 + per level (16*16+16 + 16*C_l+C_l) = 30,432.
  EXPECT_EQ(ae.body_size(), 30432u);
  // LoRA: per level r*16 + 16*r + r*16 + C_l*r with r = 4.
  EXPECT_EQ(ae.parameters().size() - ae.body_size(), 3u * (64 + 64 + 64) + 352u * 4);
  for (const auto& t : ae.tensors()) EXPECT_EQ(t.lora, t.offset >= ae.body_size()) << t.name;
  const int b = ae.find_tensor("head.2.1.lora_b");
  ASSERT_GE(b, 0);
  EXPECT_EQ(ae.tensors()[b].rows, 32);  // C_2 x r
  EXPECT_EQ(ae.tensors()[b].cols, 4);
  EXPECT_EQ(ae.find_tensor("no.such"), -1);
}

TEST(FeatureAutoencoder, BodyGradientsMatchFiniteDifferences) {
  for (auto activation : {AutoencoderActivation::gelu, AutoencoderActivation::relu}) {
    SCOPED_TRACE(to_string(activation));
    FeatureAutoencoder ae(small_config(activation));
    set_test_normalisation(&ae);
    randomise_lora_b(&ae);  // the body's gradients must include the LoRA paths
    ae.set_mode(AutoencoderMode::pretrain);
    const Probe p = make_probe(ae, 5);
    EXPECT_EQ(check_parameter_gradients(&ae, p), static_cast<int>(ae.body_size()));
  }
}

TEST(FeatureAutoencoder, LoraGradientsMatchFiniteDifferences) {
  FeatureAutoencoder ae(small_config());
  set_test_normalisation(&ae);
  randomise_lora_b(&ae);  // with B = 0 the gradient of A is zero and checks nothing
  ae.set_mode(AutoencoderMode::online);
  const Probe p = make_probe(ae, 5);
  EXPECT_EQ(check_parameter_gradients(&ae, p),
            static_cast<int>(ae.parameters().size() - ae.body_size()));
}

TEST(FeatureAutoencoder, InputAndLatentGradientsMatchFiniteDifferences) {
  FeatureAutoencoder ae(small_config());
  set_test_normalisation(&ae);
  randomise_lora_b(&ae);
  const Probe p = make_probe(ae, 4);
  check_input_gradients(&ae, p);
  check_latent_gradients(&ae, p);
}

TEST(FeatureAutoencoder, DefaultSizeGradientsMatchFiniteDifferences) {
  // The 352 -> 64 -> 16 network, sampled: 12 entries per tensor, 60 inputs, every latent.
  FeatureAutoencoder ae;
  set_test_normalisation(&ae);
  randomise_lora_b(&ae);
  const Probe p = make_probe(ae, 3);
  ae.set_mode(AutoencoderMode::pretrain);
  EXPECT_GT(check_parameter_gradients(&ae, p, 12), 100);
  ae.set_mode(AutoencoderMode::online);
  EXPECT_GT(check_parameter_gradients(&ae, p, 12), 100);
  check_input_gradients(&ae, p, 60);
  check_latent_gradients(&ae, p);
}

TEST(FeatureAutoencoder, LossL1WeighsLevelsEquallyAndMatchesFiniteDifferences) {
  FeatureAutoencoder ae(small_config());
  set_test_normalisation(&ae);
  const int n = 3, C = ae.input_dim();
  const std::vector<float> a = random_vector(static_cast<std::size_t>(n) * C, 31);
  std::vector<float> b = random_vector(a.size(), 32);
  std::vector<float> grad(a.size());
  const double loss = ae.loss_l1(a.data(), b.data(), n, grad.data());
  // By hand: 1/N sum_n 1/3 sum_l 1/C_l sum_c |a - b| / s_c.
  const std::vector<int> channels = {6, 4, 3};
  double expected = 0.0;
  for (int i = 0; i < n; ++i)
    for (int l = 0, c0 = 0; l < 3; c0 += channels[l], ++l)
      for (int c = c0; c < c0 + channels[l]; ++c)
        expected += std::abs(a[i * C + c] - b[i * C + c]) / ae.input_std()[c] /
                    (n * 3.0 * channels[l]);
  EXPECT_NEAR(loss, expected, 1e-6 * expected);
  // A unit error on every channel of one level costs 1/3 whatever the level's width.
  std::vector<float> shifted = b;
  for (int i = 0; i < n; ++i)
    for (int c = 10; c < 13; ++c) shifted[i * C + c] += ae.input_std()[c];
  EXPECT_NEAR(ae.loss_l1(shifted.data(), b.data(), n, nullptr), 1.0 / 3.0, 1e-6);
  // Central differences away from the kinks.
  for (std::size_t i = 0; i < a.size(); ++i) {
    const float h = 1e-2f;  // rows are summed in float: a larger step keeps rounding small
    if (std::abs(a[i] - b[i]) < 10 * h) continue;
    std::vector<float> x = a;
    x[i] = a[i] + h;
    const double plus = ae.loss_l1(x.data(), b.data(), n, nullptr);
    x[i] = a[i] - h;
    const double minus = ae.loss_l1(x.data(), b.data(), n, nullptr);
    EXPECT_NEAR((plus - minus) / (2.0 * h), grad[i], 2e-3 * std::abs(grad[i])) << i;
  }
  // sign(0) = 0: a perfect reconstruction has no gradient.
  ae.loss_l1(b.data(), b.data(), n, grad.data());
  for (float g : grad) EXPECT_EQ(g, 0.0f);
}

TEST(FeatureAutoencoder, FeatureLossIsDecodeL1AndBackwardInChunks) {
  FeatureAutoencoder ae;
  set_test_normalisation(&ae);
  randomise_lora_b(&ae);
  const int n = FeatureAutoencoder::kChunk * 2 + 300;  // three chunks, the last one partial
  const int C = ae.input_dim(), D = ae.latent_dim();
  const std::vector<float> f = random_vector(static_cast<std::size_t>(n) * D, 51);
  const std::vector<float> obs = random_vector(static_cast<std::size_t>(n) * C, 52);

  // Reference: the whole batch at once.
  AutoencoderTape tape;
  std::vector<float> u_hat(obs.size()), grad(obs.size()), grad_f(f.size());
  ae.decode(f.data(), n, u_hat.data(), &tape);
  const double loss = ae.loss_l1(u_hat.data(), obs.data(), n, grad.data());
  ae.backward_decode(tape, grad.data(), grad_f.data());
  const std::vector<float> lora_grad(ae.tensor_grad(0) + ae.body_size(),
                                     ae.tensor_grad(0) + ae.parameters().size());
  ae.zero_grad();

  std::vector<float> chunked_f(f.size());
  EXPECT_NEAR(ae.feature_loss(f.data(), obs.data(), n, chunked_f.data()), loss, 1e-6 * loss);
  for (std::size_t i = 0; i < f.size(); ++i)
    ASSERT_NEAR(chunked_f[i], grad_f[i], 1e-6 + 1e-4 * std::abs(grad_f[i])) << i;
  for (std::size_t i = 0; i < lora_grad.size(); ++i)
    ASSERT_NEAR(ae.tensor_grad(0)[ae.body_size() + i], lora_grad[i],
                1e-6 + 1e-4 * std::abs(lora_grad[i]))
        << i;
}

TEST(FeatureAutoencoder, StandardisingTheLatentKeepsTheReconstruction) {
  FeatureAutoencoder ae;
  set_test_normalisation(&ae);
  const Probe p = make_probe(ae, 200);
  const int D = ae.latent_dim();
  std::vector<float> f(static_cast<std::size_t>(p.n) * D), before(p.u.size()), after(p.u.size());
  ae.encode(p.u.data(), p.n, f.data());
  ae.decode(f.data(), p.n, before.data());
  ae.standardise_latent(p.u.data(), p.n);
  ae.encode(p.u.data(), p.n, f.data());
  ae.decode(f.data(), p.n, after.data());
  for (std::size_t i = 0; i < before.size(); ++i)
    ASSERT_NEAR(after[i], before[i], 1e-4 * (1.0 + std::abs(before[i]))) << i;
  for (int d = 0; d < D; ++d) {
    double mean = 0, square = 0;
    for (int i = 0; i < p.n; ++i) {
      mean += f[i * D + d] / p.n;
      square += f[i * D + d] * f[i * D + d] / p.n;
    }
    EXPECT_NEAR(mean, 0.0, 1e-4) << d;
    EXPECT_NEAR(std::sqrt(square - mean * mean), 1.0, 1e-3) << d;
  }
}

// Decodes with every LoRA tensor zeroed: the plain pretrained decoder.
std::vector<float> decode_without_lora(FeatureAutoencoder ae, const std::vector<float>& f, int n) {
  for (int t = 0; t < static_cast<int>(ae.tensors().size()); ++t)
    if (ae.tensors()[t].lora) std::fill_n(ae.tensor_data(t), ae.tensors()[t].size(), 0.0f);
  std::vector<float> u_hat(static_cast<std::size_t>(n) * ae.input_dim());
  ae.decode(f.data(), n, u_hat.data());
  return u_hat;
}

TEST(FeatureAutoencoder, LoraStartsAtZeroSoTheAdaptedDecoderIsThePretrainedOne) {
  FeatureAutoencoder ae;
  set_test_normalisation(&ae);
  const int n = 7;
  const std::vector<float> f = random_vector(static_cast<std::size_t>(n) * ae.latent_dim(), 41);
  for (const auto& t : ae.tensors()) {
    if (t.name.find("lora_b") == std::string::npos) continue;
    const float* b = ae.parameters().data() + t.offset;
    EXPECT_TRUE(std::all_of(b, b + t.size(), [](float x) { return x == 0.0f; })) << t.name;
  }
  const int a = ae.find_tensor("head.0.0.lora_a");
  EXPECT_NE(ae.tensor_data(a)[0], 0.0f) << "A starts small and random, not zero";
  std::vector<float> u_hat(static_cast<std::size_t>(n) * ae.input_dim());
  ae.decode(f.data(), n, u_hat.data());
  EXPECT_EQ(u_hat, decode_without_lora(ae, f, n)) << "bit-identical at initialisation";

  // Pretraining keeps B at exactly zero, so this still holds after it.
  ae.set_mode(AutoencoderMode::pretrain);
  const Probe p = make_probe(ae, 8);
  for (int i = 0; i < 3; ++i) {
    probe_backward(&ae, p);
    ae.step(1e-2f);
  }
  ae.decode(f.data(), n, u_hat.data());
  EXPECT_EQ(u_hat, decode_without_lora(ae, f, n));
  // One online step moves B, and the decoder with it.
  ae.set_mode(AutoencoderMode::online);
  probe_backward(&ae, p);
  ae.step(1e-2f);
  ae.decode(f.data(), n, u_hat.data());
  EXPECT_NE(u_hat, decode_without_lora(ae, f, n));
}

TEST(FeatureAutoencoder, EachModeTrainsOnlyItsParameters) {
  FeatureAutoencoder ae;
  set_test_normalisation(&ae);
  const Probe p = make_probe(ae, 16);
  const std::size_t body = ae.body_size();
  const auto body_of = [&](const FeatureAutoencoder& x) {
    return std::vector<float>(x.parameters().begin(), x.parameters().begin() + body);
  };
  const auto lora_of = [&](const FeatureAutoencoder& x) {
    return std::vector<float>(x.parameters().begin() + body, x.parameters().end());
  };

  ae.set_mode(AutoencoderMode::online);
  const std::vector<float> body_before = body_of(ae), lora_before = lora_of(ae);
  for (int i = 0; i < 5; ++i) {
    probe_backward(&ae, p);
    ae.step_online();
  }
  EXPECT_EQ(body_of(ae), body_before) << "online mode must leave the body bit-identical";
  EXPECT_NE(lora_of(ae), lora_before);
  EXPECT_EQ(ae.online_steps(), 5);

  ae.set_mode(AutoencoderMode::pretrain);
  const std::vector<float> lora_adapted = lora_of(ae);
  for (int i = 0; i < 5; ++i) {
    probe_backward(&ae, p);
    ae.step(1e-3f);
  }
  EXPECT_EQ(lora_of(ae), lora_adapted) << "pretraining must leave LoRA untouched";
  EXPECT_NE(body_of(ae), body_before);
  EXPECT_EQ(ae.online_steps(), 5);
}

TEST(FeatureAutoencoder, TrainingDoesNotDependOnWhereItsBuffersLie) {
  // Copies of one autoencoder, each allocated after a pad that moves the heap by 48 bytes, train
  // on one probe in both modes: their parameters must agree bit for bit. Before, a bias gradient
  // (Eigen's colwise().sum() into the gradient buffer) and Adam's packet sqrt depended on the
  // buffers' 32-byte alignment, and the trained weights on the heap's layout (a longer --out
  // path gave other weights). Layers of 16 to 40 values, so that vector and scalar paths both run.
  FeatureAutoencoderConfig config;
  config.level_channels = {40, 24, 16};
  config.latent_dim = 8;
  config.encoder_hidden = 24;
  config.head_hidden = 16;
  FeatureAutoencoder base(config);
  set_test_normalisation(&base);
  randomise_lora_b(&base);
  const Probe p = make_probe(base, 37);

  std::vector<std::vector<char>> pads;
  std::vector<std::unique_ptr<FeatureAutoencoder>> copies;  // all alive: no block is reused
  std::vector<std::uintptr_t> alignments;
  std::vector<float> reference;
  for (int k = 0; k < 6; ++k) {
    pads.emplace_back(40);  // a 48-byte heap chunk
    copies.push_back(std::make_unique<FeatureAutoencoder>(base));
    FeatureAutoencoder& ae = *copies.back();
    alignments.push_back(reinterpret_cast<std::uintptr_t>(ae.parameters().data()) % 32);
    for (int i = 0; i < 20; ++i) {
      probe_backward(&ae, p);
      ae.step(1e-2f);
    }
    ae.set_mode(AutoencoderMode::online);
    for (int i = 0; i < 20; ++i) {
      probe_backward(&ae, p);
      ae.step_online();
    }
    if (k == 0) reference = ae.parameters();
    else EXPECT_EQ(ae.parameters(), reference) << "copy " << k << ", parameters at " << alignments.back() << " mod 32";
  }
  std::sort(alignments.begin(), alignments.end());
  if (std::unique(alignments.begin(), alignments.end()) - alignments.begin() < 2)
    GTEST_SKIP() << "the allocator placed every copy at one alignment: nothing was compared";
}

TEST(FeatureAutoencoder, LoraLearningRateWarmsUpLinearly) {
  LoraSchedule s;
  s.learning_rate = 1e-2f;
  s.warmup_steps = 10;
  EXPECT_FLOAT_EQ(s.rate(0), 1e-3f);
  EXPECT_FLOAT_EQ(s.rate(4), 5e-3f);
  EXPECT_FLOAT_EQ(s.rate(9), 1e-2f);
  EXPECT_FLOAT_EQ(s.rate(1000), 1e-2f);
  s.warmup_steps = 0;
  EXPECT_FLOAT_EQ(s.rate(0), 1e-2f);

  // step_online applies it: Adam's first step moves each parameter with a non-zero gradient by
  // exactly the learning rate (m / sqrt(v) = sign(g) after bias correction).
  FeatureAutoencoderConfig config;
  config.online.learning_rate = 1e-2f;
  config.online.warmup_steps = 10;
  FeatureAutoencoder ae(config);
  const Probe p = make_probe(ae, 16);
  const int b = ae.find_tensor("head.0.1.lora_b");
  const std::vector<float> before(ae.tensor_data(b), ae.tensor_data(b) + ae.tensors()[b].size());
  probe_backward(&ae, p);
  ae.step_online();
  double largest = 0.0;
  for (std::size_t i = 0; i < before.size(); ++i)
    largest = std::max(largest, static_cast<double>(std::abs(ae.tensor_data(b)[i] - before[i])));
  EXPECT_NEAR(largest, 1e-3, 1e-6);
}

// ---- Weights file ----------------------------------------------------------------------------

std::vector<char> read_bytes(const std::filesystem::path& path) {
  std::ifstream f(path, std::ios::binary);
  return std::vector<char>(std::istreambuf_iterator<char>(f), {});
}
void write_bytes(const std::filesystem::path& path, const std::vector<char>& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

TEST(FeatureAutoencoder, SaveLoadRoundTrip) {
  const auto dir = test::fresh_temp_dir("ae");
  FeatureAutoencoderConfig config = small_config(AutoencoderActivation::relu);
  FeatureAutoencoder ae(config);
  set_test_normalisation(&ae);
  randomise_lora_b(&ae);
  ae.set_notes("test weights");
  std::string why;
  ASSERT_TRUE(ae.save((dir / "w.fae").string(), &why)) << why;

  FeatureAutoencoder loaded;  // default (352-channel) config: the file's replaces it
  ASSERT_TRUE(loaded.load((dir / "w.fae").string(), &why)) << why;
  EXPECT_EQ(loaded.config().level_channels, config.level_channels);
  EXPECT_EQ(loaded.config().latent_dim, config.latent_dim);
  EXPECT_EQ(loaded.config().activation, AutoencoderActivation::relu);
  EXPECT_EQ(loaded.config().lora_rank, config.lora_rank);
  EXPECT_EQ(loaded.config().lora_alpha, config.lora_alpha);
  EXPECT_EQ(loaded.parameters(), ae.parameters());
  EXPECT_EQ(loaded.input_mean(), ae.input_mean());
  EXPECT_EQ(loaded.input_std(), ae.input_std());
  EXPECT_EQ(loaded.notes(), "test weights");
  EXPECT_EQ(loaded.mode(), AutoencoderMode::online);
  // 8 magic + 4 version + 4 levels + 3*4 channels + 5*4 sizes + 4 alpha + 4 seed + 4 + 12 notes
  // + 2*13*4 normalisation + 4 count + per tensor (4 + name + 8 + 4 * size).
  std::size_t expected = 8 + 4 + 4 + 12 + 20 + 4 + 4 + 4 + 12 + 104 + 4;
  for (const auto& t : ae.tensors()) expected += 4 + t.name.size() + 8 + 4 * t.size();
  EXPECT_EQ(std::filesystem::file_size(dir / "w.fae"), expected);

  // Checked against the encoder's levels.
  const std::vector<FeatureLevelShape> matching = {{6, 8, 8}, {4, 16, 16}, {3, 32, 32}};
  const std::vector<FeatureLevelShape> builtin = {{256, 64, 64}, {64, 128, 128}, {32, 256, 256}};
  FeatureAutoencoder checked;
  EXPECT_TRUE(checked.load((dir / "w.fae").string(), matching, &why)) << why;
  EXPECT_FALSE(checked.load((dir / "w.fae").string(), builtin, &why));
  EXPECT_NE(why.find("[6, 4, 3]"), std::string::npos) << why;
  EXPECT_NE(why.find("[256, 64, 32]"), std::string::npos) << why;
  EXPECT_EQ(checked.config().level_channels, config.level_channels) << "kept the earlier load";
}

TEST(FeatureAutoencoder, LoadRejectsBrokenFilesAndKeepsItsState) {
  const auto dir = test::fresh_temp_dir("ae");
  FeatureAutoencoder ae(small_config());
  std::string why;
  ASSERT_TRUE(ae.save((dir / "good.fae").string(), &why)) << why;
  const std::vector<char> good = read_bytes(dir / "good.fae");

  FeatureAutoencoder target;
  const std::vector<float> untouched = target.parameters();
  const auto expect_error = [&](const std::vector<char>& bytes, const std::string& needle) {
    write_bytes(dir / "bad.fae", bytes);
    EXPECT_FALSE(target.load((dir / "bad.fae").string(), &why)) << needle;
    EXPECT_NE(why.find(needle), std::string::npos) << "expected '" << needle << "' in: " << why;
    EXPECT_EQ(target.parameters(), untouched);
  };

  EXPECT_FALSE(target.load((dir / "missing.fae").string(), &why));
  EXPECT_NE(why.find("cannot open"), std::string::npos) << why;

  std::vector<char> bytes = good;
  bytes[0] = 'X';
  expect_error(bytes, "wrong magic");
  expect_error({}, "wrong magic");

  bytes = good;
  bytes[8] = 2;  // version 2
  expect_error(bytes, "version 2");

  for (std::size_t cut : {10u, 20u, 60u, 200u, static_cast<unsigned>(good.size() - 1)})
    expect_error(std::vector<char>(good.begin(), good.begin() + cut), "truncated");

  bytes = good;
  bytes.push_back(0);
  expect_error(bytes, "unexpected bytes");

  // The first tensor's stored rows say 6 where the header's sizes give 5.
  bytes = good;
  const std::string name = "encoder.0.weight";
  const auto at = std::search(bytes.begin(), bytes.end(), name.begin(), name.end());
  ASSERT_NE(at, bytes.end());
  *(at + name.size()) = 6;
  expect_error(bytes, "where 'encoder.0.weight' [5, 13] belongs");

  bytes = good;
  bytes[12] = 0;  // zero levels
  expect_error(bytes, "levels");

  bytes = good;
  const float nan = std::nanf("");
  std::memcpy(bytes.data() + good.size() - 4, &nan, 4);  // the last value of the last tensor
  expect_error(bytes, "non-finite");
}

// ---- Pretraining ---------------------------------------------------------------------------

// Builtin-encoder pyramids of synthetic views: `count` poses spread over a 10 s trajectory in
// room `seed`, rendered at 160x120 and encoded at 256x256 (levels 16x16, 32x32, 64x64).
std::vector<FeaturePyramid> synthetic_pyramids(std::uint64_t seed, int count) {
  FeatureEncoderConfig config;
  config.builtin.input_width = 256;
  config.builtin.input_height = 256;
  std::string why;
  auto encoder = make_feature_encoder(config, &why);
  EXPECT_NE(encoder, nullptr) << why;
  const SyntheticRoom room = make_room(seed);
  SynthOptions options;
  options.seed = seed;
  const Trajectory trajectory = make_trajectory(room, options);
  const PinholeCamera camera = synth_default_camera().scaled(0.25);
  std::vector<FeaturePyramid> pyramids(static_cast<std::size_t>(count));
  for (int i = 0; i < count; ++i) {
    const std::size_t frame = (trajectory.size() - 1) * i / std::max(count - 1, 1);
    const SynthView view = render_view(room, camera, trajectory[frame].T_world_camera);
    EXPECT_TRUE(encoder->encode(view.colour, &pyramids[i], &why)) << why;
  }
  return pyramids;
}

TEST(FeatureAutoencoder, PretrainingLearnsToReconstructUnseenImages) {
  // Four rooms to learn from, another to test on (seeds used nowhere else).
  std::vector<FeaturePyramid> train;
  for (std::uint64_t seed : {101, 102, 103, 104})
    for (auto& p : synthetic_pyramids(seed, 2)) train.push_back(std::move(p));
  std::vector<float> held_out;
  std::mt19937 rng(9);
  for (const auto& p : synthetic_pyramids(201, 2))
    sample_training_features(p, 2000, &rng, &held_out);

  FeatureAutoencoder ae;  // the default 352 -> 64 -> 16 network
  AutoencoderPretrainOptions options;
  options.steps = 600;
  options.batch = 128;
  options.pixels_per_image = 1000;
  int calls = 0, last_done = 0;
  AutoencoderPretrainStats stats;
  std::string why;
  ASSERT_TRUE(pretrain_autoencoder(
      train, options, &ae, [&](int done, int total, double loss) {
        ++calls;
        EXPECT_GT(done, last_done);
        EXPECT_EQ(total, options.steps);
        EXPECT_TRUE(std::isfinite(loss));
        last_done = done;
      }, &stats, &why)) << why;
  EXPECT_EQ(last_done, options.steps);
  EXPECT_GE(calls, 10);
  EXPECT_EQ(ae.mode(), AutoencoderMode::online);
  EXPECT_EQ(stats.train_samples, 8000u);

  // Errors are loss_l1: mean absolute errors in units of each channel's spread. "Before" on the
  // held-out room is the untrained network with the same normalisation. Measured: train
  // 0.79 -> 0.23, held-out room 0.85 -> 0.39 (rooms 203 and 105: ratios 0.50 and 0.51).
  FeatureAutoencoder untrained;
  ASSERT_TRUE(untrained.set_normalisation(ae.input_mean(), ae.input_std(), &why)) << why;
  const double held_out_before = reconstruction_error(untrained, held_out);
  const double held_out_after = reconstruction_error(ae, held_out);
  std::printf("[ reconstruction ] train %.3f -> %.3f, held-out room %.3f -> %.3f\n",
              stats.train_error_before, stats.train_error_after, held_out_before, held_out_after);
  // The latent comes out standardised (over the training samples; the held-out room's are
  // near it).
  std::vector<float> f(held_out.size() / ae.input_dim() * ae.latent_dim());
  ae.encode(held_out.data(), static_cast<int>(f.size() / ae.latent_dim()), f.data());
  double mean = 0, square = 0;
  for (float x : f) mean += x / f.size(), square += static_cast<double>(x) * x / f.size();
  EXPECT_LT(std::abs(mean), 0.5);
  EXPECT_NEAR(std::sqrt(square), 1.0, 0.5);
  EXPECT_GT(stats.train_error_before, 0.5);
  EXPECT_LT(stats.train_error_after, 0.4 * stats.train_error_before);
  EXPECT_LT(held_out_after, 0.6 * held_out_before);
}

TEST(FeatureAutoencoder, PretrainingRejectsMismatchedInput) {
  FeatureAutoencoder ae(small_config());
  AutoencoderPretrainOptions options;
  std::string why;
  EXPECT_FALSE(pretrain_autoencoder({}, options, &ae, nullptr, nullptr, &why));
  FeaturePyramid p;
  p.image_width = 4;
  p.image_height = 4;
  p.levels.resize(1);
  p.levels[0].resize({5, 4, 4});
  EXPECT_FALSE(pretrain_autoencoder({p}, options, &ae, nullptr, nullptr, &why));
  EXPECT_NE(why.find("level channels"), std::string::npos) << why;
  EXPECT_FALSE(pretrain_autoencoder_on_samples(std::vector<float>(14), nullptr, options, &ae,
                                               nullptr, nullptr, &why));
  options.steps = 0;
  EXPECT_FALSE(pretrain_autoencoder_on_samples(std::vector<float>(13), nullptr, options, &ae,
                                               nullptr, nullptr, &why));
}

}  // namespace
}  // namespace fslam::core

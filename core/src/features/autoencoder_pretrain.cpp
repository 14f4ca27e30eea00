// Pretraining the feature autoencoder on sampled encoder features (paper: "pretrained on unrelated datasets").
#include "fslam/core/features/feature_autoencoder.hpp"

#include <algorithm>
#include <cmath>

#include "autoencoder_math.hpp"
#include "fslam/core/error.hpp"

namespace fslam::core {

using namespace autoencoder_detail;  // NOLINT: the file's own helpers, private to core/src/features

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

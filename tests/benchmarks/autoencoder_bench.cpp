// Feature autoencoder cost per batch on one thread: encode (phi, what insertion pays per new
// Gaussian), decode (the heads, per rendered pixel), and the mapper's online training step
// (feature_loss: decode + L1 + backward to dL/df and LoRA, then Adam on LoRA). Median thread
// CPU time over --repeats runs.
// Usage: fslam_bench_autoencoder [--pixels 2000,19200] [--repeats 50] [--latent 16]
//        [--encoder-hidden 64] [--head-hidden 32] [--activation gelu|relu]
#include <algorithm>
#include <cstdio>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "fslam/core/compute/product_blocking.hpp"
#include "fslam/core/compute/thread_clock.hpp"
#include "fslam/core/features/feature_autoencoder.hpp"

namespace {

using namespace fslam::core;

double median_ms(int repeats, const std::function<void()>& run) {
  std::vector<double> ms;
  run();  // warm-up: allocations and caches
  for (int i = 0; i < repeats; ++i) {
    const double t0 = thread_cpu_ms();
    run();
    ms.push_back(thread_cpu_ms() - t0);
  }
  std::nth_element(ms.begin(), ms.begin() + ms.size() / 2, ms.end());
  return ms[ms.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  fslam::core::use_portable_product_blocking();  // the products planned as fslam and the server plan them
  CLI::App app{"feature autoencoder cost per batch, one thread"};
  std::vector<int> pixels = {2000, 19200};
  int repeats = 50;
  FeatureAutoencoderConfig config;
  std::string activation = to_string(config.activation);
  app.add_option("--pixels", pixels, "batch sizes (19200 = a 160x120 training render)")
      ->delimiter(',');
  app.add_option("--repeats", repeats)->capture_default_str();
  app.add_option("--latent", config.latent_dim)->capture_default_str();
  app.add_option("--encoder-hidden", config.encoder_hidden)->capture_default_str();
  app.add_option("--head-hidden", config.head_hidden)->capture_default_str();
  app.add_option("--activation", activation)
      ->check(CLI::IsMember({"gelu", "relu"}))
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  config.activation =
      activation == "relu" ? AutoencoderActivation::relu : AutoencoderActivation::gelu;
  FeatureAutoencoder ae(config);
  const int C = ae.input_dim(), D = ae.latent_dim();
  std::printf("network %d -> %d -> %d, heads %d -> %d -> C_l, %s, LoRA rank %d\n", C,
              config.encoder_hidden, D, D, config.head_hidden, to_string(config.activation),
              config.lora_rank);
  std::printf("%8s %10s %10s %14s %12s %16s\n", "N", "encode ms", "decode ms", "online step ms",
              "us/pixel", "pretrain step ms");
  std::mt19937 rng(1);
  std::normal_distribution<float> normal;
  for (int n : pixels) {
    std::vector<float> u(static_cast<std::size_t>(n) * C), obs(u.size()), u_hat(u.size()),
        grad(u.size()), f(static_cast<std::size_t>(n) * D), grad_f(f.size());
    for (float& x : u) x = normal(rng);
    for (float& x : obs) x = normal(rng);
    AutoencoderTape tape;
    const double encode = median_ms(repeats, [&] { ae.encode(u.data(), n, f.data()); });
    const double decode = median_ms(repeats, [&] { ae.decode(f.data(), n, u_hat.data()); });
    ae.set_mode(AutoencoderMode::online);
    const double online = median_ms(repeats, [&] {
      ae.feature_loss(f.data(), obs.data(), n, grad_f.data());
      ae.step_online();
    });
    ae.set_mode(AutoencoderMode::pretrain);
    const double pretrain = median_ms(repeats, [&] {
      ae.encode(u.data(), n, f.data(), &tape);
      ae.decode(f.data(), n, u_hat.data(), &tape);
      ae.loss_l1(u_hat.data(), u.data(), n, grad.data());
      ae.backward_decode(tape, grad.data(), grad_f.data());
      ae.backward_encode(tape, grad_f.data(), nullptr);
      ae.step(1e-4f);
    });
    std::printf("%8d %10.3f %10.3f %14.3f %12.3f %16.3f\n", n, encode, decode, online,
                1e3 * online / n, pretrain);
  }
  return 0;
}

// The feature autoencoder's Adam steps: the body in pretrain mode, the LoRA blocks online.
#include "fslam/core/features/feature_autoencoder.hpp"

#include <algorithm>
#include <cassert>

#include "autoencoder_math.hpp"
#include "fslam/core/error.hpp"

namespace fslam::core {

using namespace autoencoder_detail;  // NOLINT: the file's own helpers, private to core/src/features

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

}  // namespace fslam::core

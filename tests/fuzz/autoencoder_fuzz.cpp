// Fuzz target: the feature autoencoder's .fae weights file (a user supplies it; a corrupt or
// hostile file must be refused with a reason, never crash or allocate without bound).
#include <cstdint>
#include <string>

#include "fslam/core/features/feature_autoencoder.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = fslam::fuzz::write_scratch("weights.fae", data, size);
  fslam::core::FeatureAutoencoder model;
  std::string why;
  if (!model.load(path, &why)) {
    if (why.empty()) __builtin_trap();
    return 0;
  }
  if (model.latent_dim() <= 0 || model.input_dim() <= 0) __builtin_trap();
  return 0;
}

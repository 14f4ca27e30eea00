// Fuzz target: opening a user-supplied ONNX image encoder (make_feature_encoder parses it with
// OpenCV's dnn module and runs it once on a blank image to learn its outputs), at 32x32, the
// seed models' input size. OpenCV itself is not instrumented: this target checks that every
// parse or run failure comes back as an error, not a crash.
#include <cstdint>
#include <string>

#include "fslam/core/features/feature_encoder.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  fslam::core::FeatureEncoderConfig config;
  config.backend = fslam::core::FeatureBackend::onnx;
  config.onnx.model_path = fslam::fuzz::write_scratch("model.onnx", data, size);
  config.onnx.input_width = config.onnx.input_height = 32;
  std::string why;
  auto encoder = fslam::core::make_feature_encoder(config, &why);
  if (!encoder && why.empty()) __builtin_trap();
  return 0;
}

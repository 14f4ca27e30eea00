#include "fslam/core/features/feature_encoder.hpp"

#include <cmath>
#include <filesystem>
#include <set>
#include <string>

#include "encoders.hpp"
#include "fslam/core/error.hpp"

namespace fslam::core {

const char* to_string(FeatureBackend backend) {
  switch (backend) {
    case FeatureBackend::builtin: return "builtin";
    case FeatureBackend::onnx: return "onnx";
  }
  return "?";
}

bool parse_feature_backend(const std::string& text, FeatureBackend* backend, std::string* why) {
  if (text == "builtin") *backend = FeatureBackend::builtin;
  else if (text == "onnx") *backend = FeatureBackend::onnx;
  else return fail(why, "unknown feature encoder backend '" + text + "' (builtin, onnx)");
  return true;
}

bool BuiltinFeatureConfig::is_valid(std::string* why) const {
  // Multiples of 16 keep the three strides exact; 64 leaves a 4x4 coarse level.
  const auto ok = [](int n) { return n >= 64 && n % 16 == 0 && n <= 16384; };
  if (!ok(input_width) || !ok(input_height))
    return fail(why, "features.builtin input size must be multiples of 16 between 64 and 16384 "
                     "pixels, got " + std::to_string(input_width) + "x" +
                     std::to_string(input_height));
  return true;
}

bool OnnxFeatureConfig::is_valid(std::string* why) const {
  if (model_path.empty()) return fail(why, "features.onnx.model_path is required");
  if (input_width < 1 || input_height < 1 || input_width > 16384 || input_height > 16384)
    return fail(why, "features.onnx input size must be between 1 and 16384 pixels, got " +
                         std::to_string(input_width) + "x" + std::to_string(input_height));
  for (int c = 0; c < 3; ++c) {
    if (!std::isfinite(mean[c]))
      return fail(why, "features.onnx.mean must be finite (0..1 units, RGB order)");
    if (!(std::isfinite(std[c]) && std[c] > 0.0f))
      return fail(why, "features.onnx.std must be positive and finite (0..1 units, RGB order), "
                       "got " + std::to_string(std[c]) + " for channel " + std::to_string(c));
  }
  if (colour_order != ColourOrder::rgb && colour_order != ColourOrder::bgr)
    return fail(why, "features.onnx.colour_order is not rgb or bgr");
  if (!output_names.empty()) {
    if (static_cast<int>(output_names.size()) != kFeatureLevelCount)
      return fail(why, "features.onnx.output_names must name " +
                           std::to_string(kFeatureLevelCount) + " outputs (or none), got " +
                           std::to_string(output_names.size()));
    std::set<std::string> unique(output_names.begin(), output_names.end());
    if (unique.size() != output_names.size() || unique.count(""))
      return fail(why, "features.onnx.output_names must be distinct and non-empty");
  }
  return true;
}

bool FeatureEncoderConfig::is_valid(std::string* why) const {
  switch (backend) {
    case FeatureBackend::builtin: return builtin.is_valid(why);
    case FeatureBackend::onnx: return onnx.is_valid(why);
  }
  return fail(why, "features.backend is not a known backend");
}

std::unique_ptr<FeatureEncoder> make_feature_encoder(const FeatureEncoderConfig& config,
                                                     std::string* why) {
  if (!config.is_valid(why)) return nullptr;
  if (config.backend == FeatureBackend::builtin) return detail::make_builtin_encoder(config.builtin);
  std::error_code ec;
  if (!std::filesystem::is_regular_file(config.onnx.model_path, ec)) {
    fail(why, "features.onnx.model_path '" + config.onnx.model_path + "' is not a readable file");
    return nullptr;
  }
  return detail::make_onnx_encoder(config.onnx, why);
}

namespace detail {

bool check_encoder_input(const cv::Mat& rgb, std::string* why) {
  if (rgb.empty()) return fail(why, "feature encoder: empty image");
  if (rgb.type() != CV_8UC3)
    return fail(why, "feature encoder: expected an 8-bit 3-channel RGB image, got type " +
                         std::to_string(rgb.type()) + " with " + std::to_string(rgb.channels()) +
                         " channels");
  return true;
}

std::string shapes_to_string(const std::vector<FeatureLevelShape>& shapes) {
  std::string s;
  for (const auto& l : shapes) {
    if (!s.empty()) s += ", ";
    s += "[" + std::to_string(l.channels) + ", " + std::to_string(l.height) + ", " +
         std::to_string(l.width) + "]";
  }
  return s;
}

}  // namespace detail
}  // namespace fslam::core

// Image feature encoders: one FeaturePyramid per frame (paper sec. "Online Feature
// Rasterization"), from either a user-supplied ONNX network (e.g. SAM2's Hiera image encoder) or
// the builtin classical descriptor pyramid that needs no model file. docs/features.md has the
// contract, the builtin channels and their limits, and how to export an ONNX encoder.
#pragma once

#include <array>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "fslam/core/features/feature_pyramid.hpp"

namespace fslam::core {

enum class FeatureBackend { builtin, onnx };
const char* to_string(FeatureBackend backend);
// Accepts "builtin" and "onnx".
bool parse_feature_backend(const std::string& text, FeatureBackend* backend, std::string* why);

// The builtin descriptor pyramid. The frame is treated as if resized to input_width x
// input_height without keeping aspect (SAM2's policy) and analysed at strides 16, 8 and 4, so the
// levels are input/16, input/8 and input/4 with 256, 64 and 32 channels.
struct BuiltinFeatureConfig {
  int input_width = 1024;   // pixels, a multiple of 16, at least 64
  int input_height = 1024;  // pixels, a multiple of 16, at least 64
  bool is_valid(std::string* why = nullptr) const;
};

enum class ColourOrder { rgb, bgr };

// A user-supplied ONNX image encoder run through OpenCV's dnn module (CPU).
struct OnnxFeatureConfig {
  std::string model_path;   // .onnx file; required
  int input_width = 1024;   // pixels; the frame is resized to this without keeping aspect
  int input_height = 1024;  // pixels
  // Normalisation, in 0..1 units and RGB order whatever colour_order is: the network sees
  // (pixel / 255 - mean) / std. Defaults are ImageNet's, which SAM2 uses.
  std::array<float, 3> mean = {0.485f, 0.456f, 0.406f};
  std::array<float, 3> std = {0.229f, 0.224f, 0.225f};
  ColourOrder colour_order = ColourOrder::rgb;  // channel order of the network's input tensor
  // The three [1, C, H, W] outputs to use; empty = the network's unconnected outputs. Either way
  // the levels are ordered by spatial size, coarsest first (ties keep the given order).
  std::vector<std::string> output_names;
  bool is_valid(std::string* why = nullptr) const;
};

struct FeatureEncoderConfig {
  FeatureBackend backend = FeatureBackend::builtin;
  BuiltinFeatureConfig builtin;
  OnnxFeatureConfig onnx;
  // Validates the chosen backend's section only (a model file's existence is checked by
  // make_feature_encoder, which opens it).
  bool is_valid(std::string* why = nullptr) const;
};

// Number of levels of the paper's contract; both backends produce exactly this many.
inline constexpr int kFeatureLevelCount = 3;

// A per-frame encoder. Not thread-safe: one instance per thread that encodes.
class FeatureEncoder {
 public:
  virtual ~FeatureEncoder() = default;
  // Shapes of the levels encode() produces, coarsest first; fixed for the encoder's lifetime.
  virtual const std::vector<FeatureLevelShape>& level_shapes() const = 0;
  // Encodes one frame. rgb: [H, W] CV_8UC3, RGB order, any size. Fills *out, reusing its
  // buffers; false + why for a bad image or a network that misbehaves.
  virtual bool encode(const cv::Mat& rgb, FeaturePyramid* out, std::string* why) = 0;
  // One line for logs: backend, input size, level shapes.
  virtual std::string describe() const = 0;
  int dim() const { return feature_dim(level_shapes()); }
};

// The encoder for `config`, or nullptr + why for an invalid config, a missing or unreadable model
// file, or a network whose outputs break the contract (the ONNX network is run once on a blank
// image here to learn and check its output shapes).
std::unique_ptr<FeatureEncoder> make_feature_encoder(const FeatureEncoderConfig& config,
                                                     std::string* why);

// Names of the builtin encoder's channels per level, coarsest first ("L@4" = lightness pooled
// over ~4 fine-level pixels; docs/features.md explains them).
std::vector<std::vector<std::string>> builtin_feature_channel_names();

}  // namespace fslam::core

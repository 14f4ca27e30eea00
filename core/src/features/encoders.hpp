// The two FeatureEncoder implementations, reached only through make_feature_encoder.
#pragma once

#include <memory>
#include <string>

#include "fslam/core/features/feature_encoder.hpp"

namespace fslam::core::detail {

// config must be valid.
std::unique_ptr<FeatureEncoder> make_builtin_encoder(const BuiltinFeatureConfig& config);

// config must be valid; nullptr + why when the model cannot be loaded or breaks the contract.
std::unique_ptr<FeatureEncoder> make_onnx_encoder(const OnnxFeatureConfig& config,
                                                  std::string* why);

// rgb is a non-empty CV_8UC3 image, or false + why.
bool check_encoder_input(const cv::Mat& rgb, std::string* why);

std::string shapes_to_string(const std::vector<FeatureLevelShape>& shapes);

}  // namespace fslam::core::detail

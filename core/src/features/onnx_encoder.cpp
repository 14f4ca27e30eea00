// A user-supplied ONNX image encoder (e.g. SAM2's Hiera image encoder, paper sec. "Online
// Feature Rasterization") run through OpenCV's dnn module on the CPU.
#include <algorithm>
#include <cstring>
#include <memory>
#include <numeric>
#include <string>
#include <vector>

#include <opencv2/dnn.hpp>
#include <opencv2/imgproc.hpp>

#include "encoders.hpp"
#include "fslam/core/error.hpp"
#include "fslam/core/features/onnx_check.hpp"

namespace fslam::core::detail {
namespace {

std::string mat_shape(const cv::Mat& m) {
  std::string s = "[";
  for (int i = 0; i < m.dims; ++i) s += (i ? ", " : "") + std::to_string(m.size[i]);
  return s + "]";
}

std::string join(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += (s.empty() ? "'" : ", '") + x + "'";
  return s.empty() ? "none" : s;
}

class OnnxFeatureEncoder final : public FeatureEncoder {
 public:
  explicit OnnxFeatureEncoder(const OnnxFeatureConfig& config) : config_(config) {}

  // Loads the network, picks its outputs and learns their shapes from one blank frame.
  bool load(std::string* why) {
    const std::string prefix = "features.onnx model '" + config_.model_path + "': ";
    std::string bad;
    if (!read_onnx_net(config_.model_path, &net_, &bad)) return fail(why, prefix + bad);
    net_.setPreferableBackend(cv::dnn::DNN_BACKEND_OPENCV);
    net_.setPreferableTarget(cv::dnn::DNN_TARGET_CPU);

    const std::vector<std::string> unconnected = net_.getUnconnectedOutLayersNames();
    names_ = config_.output_names.empty() ? unconnected : config_.output_names;
    if (static_cast<int>(names_.size()) != kFeatureLevelCount)
      return fail(why, prefix + "has " + std::to_string(names_.size()) + " outputs (" +
                           join(names_) + "), expected " + std::to_string(kFeatureLevelCount) +
                           " feature maps; name them in features.onnx.output_names");
    for (const auto& n : names_)
      if (net_.getLayerId(n) < 0)
        return fail(why, prefix + "has no output named '" + n + "' (its outputs: " +
                             join(unconnected) + ")");

    const cv::Mat blank(config_.input_height, config_.input_width, CV_8UC3, cv::Scalar::all(128));
    std::vector<cv::Mat> outs;
    if (!run(blank, &outs, why)) return false;
    for (std::size_t i = 0; i < outs.size(); ++i) {
      const cv::Mat& m = outs[i];
      if (m.dims != 4 || m.size[0] != 1 || m.type() != CV_32F)
        return fail(why, prefix + "output '" + names_[i] + "' has shape " + mat_shape(m) +
                             (m.type() != CV_32F ? " and a non-float32 type" : "") +
                             ", expected a float32 [1, C, H, W] feature map");
    }
    // Pyramid order: coarsest first, whatever order the network or the config lists them in.
    order_.resize(outs.size());
    std::iota(order_.begin(), order_.end(), 0);
    std::stable_sort(order_.begin(), order_.end(), [&](int x, int y) {
      return static_cast<long>(outs[x].size[2]) * outs[x].size[3] <
             static_cast<long>(outs[y].size[2]) * outs[y].size[3];
    });
    for (int i : order_) shapes_.push_back({outs[i].size[1], outs[i].size[2], outs[i].size[3]});
    return true;
  }

  const std::vector<FeatureLevelShape>& level_shapes() const override { return shapes_; }

  std::string describe() const override {
    return "onnx '" + config_.model_path + "' " + std::to_string(config_.input_width) + "x" +
           std::to_string(config_.input_height) + " -> " + shapes_to_string(shapes_);
  }

  bool encode(const cv::Mat& rgb, FeaturePyramid* out, std::string* why) override {
    if (!check_encoder_input(rgb, why)) return false;
    std::vector<cv::Mat> outs;
    if (!run(rgb, &outs, why)) return false;
    out->image_width = rgb.cols;
    out->image_height = rgb.rows;
    out->levels.resize(shapes_.size());
    for (std::size_t l = 0; l < shapes_.size(); ++l) {
      const int i = order_[l];
      const cv::Mat& m = outs[i];
      if (m.dims != 4 || m.type() != CV_32F || m.size[0] != 1 ||
          FeatureLevelShape{m.size[1], m.size[2], m.size[3]} != shapes_[l])
        return fail(why, "features.onnx output '" + names_[i] + "' changed shape to " +
                             mat_shape(m) + " (was [1, " + shapes_to_string({shapes_[l]}) + "])");
      out->levels[l].resize(shapes_[l]);
      const cv::Mat dense = m.isContinuous() ? m : m.clone();
      std::memcpy(out->levels[l].data.data(), dense.ptr<float>(),
                  out->levels[l].data.size() * sizeof(float));
    }
    return true;
  }

 private:
  // rgb -> [1, 3, H, W] float32 blob of (pixel / 255 - mean) / std in the network's colour order.
  void preprocess(const cv::Mat& rgb, cv::Mat* blob) const {
    const cv::Size size(config_.input_width, config_.input_height);
    cv::Mat resized = rgb;
    if (rgb.size() != size) {
      const bool shrink = rgb.cols >= size.width && rgb.rows >= size.height;
      cv::resize(rgb, resized, size, 0, 0, shrink ? cv::INTER_AREA : cv::INTER_LINEAR);
    }
    const int dims[4] = {1, 3, size.height, size.width};
    blob->create(4, dims, CV_32F);
    const std::size_t plane = static_cast<std::size_t>(size.height) * size.width;
    for (int c = 0; c < 3; ++c) {
      const int src = config_.colour_order == ColourOrder::rgb ? c : 2 - c;  // input is RGB
      const float scale = 1.0f / (255.0f * config_.std[src]);
      const float shift = -config_.mean[src] / config_.std[src];
      float* dst = blob->ptr<float>() + c * plane;
      for (int y = 0; y < size.height; ++y) {
        const std::uint8_t* p = resized.ptr<std::uint8_t>(y);
        for (int x = 0; x < size.width; ++x) *dst++ = p[3 * x + src] * scale + shift;
      }
    }
  }

  bool run(const cv::Mat& rgb, std::vector<cv::Mat>* outs, std::string* why) {
    cv::Mat blob;
    preprocess(rgb, &blob);
    try {
      net_.setInput(blob);
      net_.forward(*outs, names_);
    } catch (const std::exception& e) {
      return fail(why, "features.onnx model '" + config_.model_path +
                           "' failed on a [1, 3, " + std::to_string(config_.input_height) + ", " +
                           std::to_string(config_.input_width) + "] input: " + e.what());
    }
    if (outs->size() != names_.size())
      return fail(why, "features.onnx model '" + config_.model_path + "' returned " +
                           std::to_string(outs->size()) + " outputs for " +
                           std::to_string(names_.size()) + " names");
    return true;
  }

  OnnxFeatureConfig config_;
  cv::dnn::Net net_;
  std::vector<std::string> names_;  // the outputs, in the network's (or config's) order
  std::vector<int> order_;          // pyramid level l is names_[order_[l]]
  std::vector<FeatureLevelShape> shapes_;
};

}  // namespace

std::unique_ptr<FeatureEncoder> make_onnx_encoder(const OnnxFeatureConfig& config,
                                                  std::string* why) {
  auto encoder = std::make_unique<OnnxFeatureEncoder>(config);
  if (!encoder->load(why)) return nullptr;
  return encoder;
}

}  // namespace fslam::core::detail

#include "fslam/server/grounding.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>

#include <opencv2/dnn.hpp>
#include <opencv2/imgproc.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/features/onnx_check.hpp"

namespace fslam::server {

struct GroundingDetector::Net {
  cv::dnn::Net net;
};

bool GroundingConfig::is_valid(std::string* why) const {
  if (input_size < 32 || input_size > 4096) {
    return core::fail(why, "server: grounding_input_size must be in [32, 4096]");
  }
  if (!(box_threshold > 0 && box_threshold < 1)) {
    return core::fail(why, "server: grounding_box_threshold must be in (0, 1)");
  }
  return true;
}

std::vector<std::string> split_tokens(const std::string& text) {
  std::vector<std::string> tokens;
  std::string word;
  auto flush = [&] {
    if (!word.empty()) tokens.push_back(word);
    word.clear();
  };
  for (const char ch : text) {
    const auto c = static_cast<unsigned char>(ch);
    if (std::isspace(c)) {
      flush();
    } else if (c < 128 && std::ispunct(c)) {
      flush();
      tokens.emplace_back(1, ch);
    } else {
      word += static_cast<char>(c < 128 ? std::tolower(c) : c);  // UTF-8 bytes stay as they are
    }
  }
  flush();
  return tokens;
}

GroundingDetector::GroundingDetector() = default;
GroundingDetector::~GroundingDetector() = default;

bool GroundingDetector::load(const GroundingConfig& config, std::string* why) {
  if (!config.is_valid(why)) return false;
  const std::string vocab_path = config.model + ".vocab.txt";
  std::ifstream vocab(vocab_path);
  if (!vocab) return core::fail(why, "grounding model: cannot read its vocabulary " + vocab_path);
  vocabulary_.clear();
  std::string line;
  for (int id = 0; std::getline(vocab, line); ++id) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    vocabulary_.emplace(line, id);  // the first line of a repeated token wins
  }
  if (vocabulary_.empty()) return core::fail(why, "grounding model: " + vocab_path + " is empty");
  const auto unk = vocabulary_.find("[UNK]");
  unknown_id_ = unk == vocabulary_.end() ? 0 : unk->second;
  auto net = std::make_unique<Net>();
  std::string bad;
  if (!core::read_onnx_net(config.model, &net->net, &bad)) {
    return core::fail(why, "grounding model " + config.model + ": " + bad);
  }
  std::lock_guard<std::mutex> lock(mutex_);
  config_ = config;
  net_ = std::move(net);
  return true;
}

std::vector<float> GroundingDetector::token_ids(const std::string& text) const {
  std::vector<float> ids;
  for (const std::string& token : split_tokens(text)) {
    const auto it = vocabulary_.find(token);
    ids.push_back(static_cast<float>(it == vocabulary_.end() ? unknown_id_ : it->second));
  }
  return ids;
}

bool GroundingDetector::detect(const cv::Mat& rgb, const std::string& text,
                               std::vector<GroundedBox>* boxes, std::string* why) const {
  boxes->clear();
  if (!net_) return core::fail(why, "grounding: no model loaded");
  if (rgb.empty() || rgb.type() != CV_8UC3) return core::fail(why, "grounding: expected an RGB image");
  std::vector<float> tokens = token_ids(text);
  if (tokens.empty()) return core::fail(why, "grounding: the text has no words");
  // image [1, 3, S, S] float32: RGB in [0, 1], ImageNet mean and std per channel.
  const int s = config_.input_size;
  cv::Mat resized, unit;
  cv::resize(rgb, resized, cv::Size(s, s), 0, 0, cv::INTER_LINEAR);
  resized.convertTo(unit, CV_32FC3, 1.0 / 255.0);
  cv::subtract(unit, cv::Scalar(0.485, 0.456, 0.406), unit);
  cv::divide(unit, cv::Scalar(0.229, 0.224, 0.225), unit);
  const cv::Mat image = cv::dnn::blobFromImage(unit);  // HWC -> NCHW, channel order kept
  const int length = static_cast<int>(tokens.size());
  const cv::Mat token_blob(std::vector<int>{1, length}, CV_32F, tokens.data());  // [1, L]
  std::vector<cv::Mat> out;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    try {
      net_->net.setInput(image, "image");
      net_->net.setInput(token_blob, "tokens");
      net_->net.forward(out, std::vector<cv::String>{"boxes", "logits"});
    } catch (const std::exception& e) {
      return core::fail(why, std::string("grounding model: ") + e.what());
    }
  }
  // boxes [1, Q, 4] (cx, cy, w, h, normalised), logits [1, Q, L].
  if (out.size() != 2 || out[0].dims != 3 || out[0].size[0] != 1 || out[0].size[2] != 4 ||
      out[1].dims != 3 || out[1].size[1] != out[0].size[1] || out[1].size[2] != length) {
    return core::fail(why, "grounding model: outputs must be boxes [1, Q, 4] and logits [1, Q, L] "
                           "for L text tokens (docs/segmentation.md)");
  }
  const int queries = out[0].size[1];
  const auto* box = out[0].ptr<float>();
  const auto* logit = out[1].ptr<float>();
  const double w = rgb.cols, h = rgb.rows;
  for (int q = 0; q < queries; ++q) {
    float best = -INFINITY;
    for (int t = 0; t < length; ++t) best = std::max(best, logit[q * length + t]);
    const float score = 1.0f / (1.0f + std::exp(-best));
    if (!(score >= config_.box_threshold)) continue;
    const float* b = box + 4 * q;
    GroundedBox g;
    g.u0 = std::clamp((b[0] - 0.5 * b[2]) * w, 0.0, w);
    g.u1 = std::clamp((b[0] + 0.5 * b[2]) * w, 0.0, w);
    g.v0 = std::clamp((b[1] - 0.5 * b[3]) * h, 0.0, h);
    g.v1 = std::clamp((b[1] + 0.5 * b[3]) * h, 0.0, h);
    g.score = score;
    if (g.u1 > g.u0 && g.v1 > g.v0) boxes->push_back(g);
  }
  std::sort(boxes->begin(), boxes->end(),
            [](const GroundedBox& a, const GroundedBox& b) { return a.score > b.score; });
  return true;
}

}  // namespace fslam::server

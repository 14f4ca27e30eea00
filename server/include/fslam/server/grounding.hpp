// Text prompts: a user-supplied grounding detector (an ONNX model run through OpenCV dnn) turns a
// text and a rendered view into boxes, which segmentation then treats as box prompts. The model's
// contract (inputs, outputs, vocabulary) is ours and docs/segmentation.md states it.
#pragma once

#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include <opencv2/core/mat.hpp>

namespace fslam::server {

struct GroundingConfig {
  std::string model;            // ONNX file; its vocabulary is <model>.vocab.txt
  int input_size = 800;         // pixels: the view is resized to input_size x input_size
  float box_threshold = 0.35f;  // a box is kept when its score (max token probability) reaches it
  bool is_valid(std::string* why = nullptr) const;
};

// A detected box in pixels of the view: [u0, u1) x [v0, v1), clipped to the view.
struct GroundedBox {
  double u0 = 0, v0 = 0, u1 = 0, v1 = 0;
  float score = 0;  // max over the text's tokens of sigmoid(logit)
};

// Lower-cased words and punctuation marks, split on whitespace; each punctuation mark is a token
// of its own ("red cup." -> red, cup, .).
std::vector<std::string> split_tokens(const std::string& text);

class GroundingDetector {
 public:
  GroundingDetector();
  ~GroundingDetector();
  // Reads the model and its vocabulary; false with `why` when either is missing or unreadable.
  bool load(const GroundingConfig& config, std::string* why);
  // Boxes scoring at least box_threshold for `text` in `rgb` (CV_8UC3, RGB), best first.
  // Safe to call from several threads (runs are serialised: one network, one set of buffers).
  bool detect(const cv::Mat& rgb, const std::string& text, std::vector<GroundedBox>* boxes,
              std::string* why) const;
  // The token ids of `text` ([UNK]'s id, or 0, for words not in the vocabulary).
  std::vector<float> token_ids(const std::string& text) const;

 private:
  struct Net;
  GroundingConfig config_;
  std::unordered_map<std::string, int> vocabulary_;
  int unknown_id_ = 0;
  mutable std::mutex mutex_;  // guards net_ (cv::dnn::Net::forward is not reentrant)
  std::unique_ptr<Net> net_;
};

}  // namespace fslam::server

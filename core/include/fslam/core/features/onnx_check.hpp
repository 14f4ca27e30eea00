// A check of a user's ONNX file before OpenCV's importer reads it. OpenCV 4.6's readNetFromONNX
// copies a tensor's declared shape worth of data without checking that the file holds that much
// (a heap-buffer-overflow the `onnx` fuzz target finds in seconds, docs/reliability.md). This
// walks the file's protobuf (model -> graph -> initializers, and the tensors of node attributes,
// subgraphs included) and refuses, with a reason, a file that is not protobuf, a tensor whose
// data is shorter than its shape says, or a node that reads a name no graph input, initializer or
// earlier node defines (OpenCV then dereferences a null blob). It does not validate the model
// otherwise.
#pragma once

#include <string>

#include <opencv2/dnn.hpp>

namespace fslam::core {

bool check_onnx_file(const std::string& path, std::string* why);
// check_onnx_file, then OpenCV's importer, any exception it throws (cv::Exception, and
// std::length_error on some bad models) an error: what every ONNX model the product opens goes
// through (the feature encoder, the grounding detector).
bool read_onnx_net(const std::string& path, cv::dnn::Net* net, std::string* why);

}  // namespace fslam::core

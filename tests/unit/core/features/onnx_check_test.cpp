// check_onnx_file against protobufs written here byte by byte (onnx.proto's field numbers), and
// against the tiny models make_test_onnx_models.py writes at build time.
#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

#include "fslam/core/features/feature_encoder.hpp"
#include "fslam/core/features/onnx_check.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

std::string varint(std::uint64_t v) {
  std::string out;
  do {
    out += static_cast<char>((v & 0x7f) | (v > 0x7f ? 0x80 : 0));
    v >>= 7;
  } while (v != 0);
  return out;
}
std::string number(int field, std::uint64_t v) { return varint(static_cast<std::uint64_t>(field) << 3) + varint(v); }
std::string bytes(int field, const std::string& b) {
  return varint(static_cast<std::uint64_t>(field) << 3 | 2) + varint(b.size()) + b;
}

// TensorProto: FLOAT (1) of shape `dims` holding `raw` bytes of raw_data.
std::string float_tensor(const std::string& name, std::initializer_list<std::uint64_t> dims, std::size_t raw) {
  std::string t;
  for (const std::uint64_t d : dims) t += number(1, d);
  return t + number(2, 1) + bytes(8, name) + bytes(9, std::string(raw, '\0'));
}
std::string model_with_graph(const std::string& graph) { return number(1, 8) + bytes(7, graph); }

std::string check(const std::string& content) {
  const fs::path path = test::fresh_temp_dir("onnx_check") / "model.onnx";
  std::ofstream(path, std::ios::binary) << content;
  std::string why;
  return check_onnx_file(path.string(), &why) ? "ok" : why;
}

TEST(OnnxCheck, WholeTensorsPass) {
  EXPECT_EQ(check(model_with_graph(bytes(5, float_tensor("w", {2, 3}, 24)))), "ok");
  EXPECT_EQ(check(model_with_graph(bytes(5, float_tensor("empty", {0, 3}, 0)))), "ok");
  // float_data, packed: 2 x 2 floats.
  std::string typed = number(1, 2) + number(1, 2) + number(2, 1) + bytes(4, std::string(16, '\0'));
  EXPECT_EQ(check(model_with_graph(bytes(5, typed))), "ok");
}

// The heap-buffer-overflow the onnx fuzz target found in OpenCV 4.6's importer: a shape that
// asks for more data than the tensor holds. Refused before OpenCV sees it.
TEST(OnnxCheck, ATensorShorterThanItsShapeIsRefused) {
  const std::string why = check(model_with_graph(bytes(5, float_tensor("w", {1000}, 12))));
  EXPECT_NE(why.find("tensor 'w' (initializer) declares 1000 elements of 4 bytes but holds 12 bytes"),
            std::string::npos)
      << why;
  // The same inside a Constant node's attribute, in a subgraph of an If node's attribute.
  const std::string constant = bytes(4, "Constant") + bytes(5, bytes(1, "value") + bytes(5, float_tensor("c", {9, 9}, 8)));
  const std::string in_subgraph = bytes(4, "If") + bytes(5, bytes(1, "then_branch") + bytes(6, bytes(1, constant)));
  EXPECT_NE(check(model_with_graph(bytes(1, in_subgraph))).find("tensor 'c' (node attribute) declares 81"),
            std::string::npos);
  // float_data holding 3 of 4 values; a shape whose element count overflows 64 bits.
  std::string typed = number(1, 2) + number(1, 2) + number(2, 1) + bytes(4, std::string(12, '\0'));
  EXPECT_NE(check(model_with_graph(bytes(5, typed))).find("declares 4 elements but holds 3"), std::string::npos);
  EXPECT_NE(check(model_with_graph(bytes(5, float_tensor("huge", {1ull << 40, 1ull << 40}, 4)))).find("too large"),
            std::string::npos);
}

// The null dereference the onnx fuzz target found next (crash input kept as
// tests/fuzz/corpus/onnx/regression-undefined-input): a Conv whose weights' name nothing defines.
TEST(OnnxCheck, ANodeReadingAnUndefinedNameIsRefused) {
  const std::string input = bytes(11, bytes(1, "image"));  // a graph input (ValueInfoProto.name)
  const std::string conv = bytes(1, "image") + bytes(1, "w") + bytes(2, "out") + bytes(3, "conv") + bytes(4, "Conv");
  EXPECT_EQ(check(model_with_graph(bytes(1, conv) + bytes(5, float_tensor("w", {4, 3, 1, 1}, 48)) + input)), "ok");
  EXPECT_NE(check(model_with_graph(bytes(1, conv) + bytes(5, float_tensor("v", {4, 3, 1, 1}, 48)) + input))
                .find("node 'conv' (Conv) reads 'w', which no graph input, initializer or earlier node defines"),
            std::string::npos);
  // Order matters: a node may not read what a later node writes.
  const std::string relu = bytes(1, "out") + bytes(2, "relu_out") + bytes(3, "relu") + bytes(4, "Relu");
  EXPECT_NE(check(model_with_graph(bytes(1, relu) + bytes(1, conv) + bytes(5, float_tensor("w", {4, 3, 1, 1}, 48)) +
                                   input))
                .find("node 'relu' (Relu) reads 'out'"),
            std::string::npos);
  // A subgraph sees its enclosing graph's names.
  const std::string inner = bytes(1, bytes(1, "image") + bytes(2, "y") + bytes(3, "inner") + bytes(4, "Relu"));
  const std::string node_if = bytes(4, "If") + bytes(5, bytes(1, "then_branch") + bytes(6, inner));
  EXPECT_EQ(check(model_with_graph(bytes(1, node_if) + input)), "ok");
}

TEST(OnnxCheck, NotProtobufIsRefused) {
  EXPECT_NE(check("this is not a protobuf").find("not a valid ONNX protobuf"), std::string::npos);
  // A length that runs past the end of the file.
  EXPECT_NE(check(number(1, 8) + varint(7 << 3 | 2) + varint(1000) + "abc").find("not a valid ONNX protobuf"),
            std::string::npos);
  EXPECT_NE(check("").find("is empty"), std::string::npos);
}

TEST(OnnxCheck, TheEncoderRefusesATruncatedTensorWithTheCheckSReason) {
  const fs::path path = test::fresh_temp_dir("onnx_check") / "bad.onnx";
  std::ofstream(path, std::ios::binary) << model_with_graph(bytes(5, float_tensor("w", {1000}, 12)));
  FeatureEncoderConfig config;
  config.backend = FeatureBackend::onnx;
  config.onnx.model_path = path.string();
  config.onnx.input_width = config.onnx.input_height = 32;
  std::string why;
  EXPECT_EQ(make_feature_encoder(config, &why), nullptr);
  EXPECT_NE(why.find("declares 1000 elements"), std::string::npos) << why;
}

// Every input that once crashed the onnx fuzz target (tests/fuzz/corpus/onnx/regression-*) is
// a clear error now: the two above, and a model on which readNetFromONNX throws
// std::length_error (caught with the encoder's other load errors).
TEST(OnnxCheck, TheFuzzRegressionsAreClearErrors) {
  const fs::path corpus = fs::path(FSLAM_TEST_COMMON_DIR) / ".." / "fuzz" / "corpus" / "onnx";
  int tried = 0;
  for (const auto& entry : fs::directory_iterator(corpus)) {
    if (entry.path().filename().string().rfind("regression-", 0) != 0) continue;
    FeatureEncoderConfig config;
    config.backend = FeatureBackend::onnx;
    config.onnx.model_path = entry.path().string();
    config.onnx.input_width = config.onnx.input_height = 32;
    std::string why;
    EXPECT_EQ(make_feature_encoder(config, &why), nullptr) << entry.path();
    EXPECT_FALSE(why.empty()) << entry.path();
    ++tried;
  }
  EXPECT_GE(tried, 2) << "regression inputs missing from " << corpus;
}

#ifdef FSLAM_TEST_ONNX_DIR
TEST(OnnxCheck, TheTestModelsPass) {
  int checked = 0;
  for (const char* name : {"tiny_pyramid.onnx", "two_outputs.onnx", "flat_output.onnx"}) {
    const fs::path path = fs::path(FSLAM_TEST_ONNX_DIR) / name;
    if (!fs::exists(path)) continue;
    std::string why;
    EXPECT_TRUE(check_onnx_file(path.string(), &why)) << name << ": " << why;
    ++checked;
  }
  if (checked == 0) GTEST_SKIP() << "the test models were not generated (needs python3-onnx at configure time)";
}
#endif

}  // namespace
}  // namespace fslam::core

// Frames as they come off the wire (frame_codec.hpp): what is refused before decoding (sizes,
// headers that disagree with the frame, decompression bombs) and what decodes.
#include "fslam/server/frame_codec.hpp"

#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

namespace fslam::server {
namespace {

// A frame message over `colour` / `depth` payloads (kept alive by the caller).
struct WireFrame {
  std::vector<std::uint8_t> colour, depth;
  fslam_proto_Frame msg{};

  WireFrame(int width, int height, int colour_w, int colour_h, fslam_proto_ImageEncoding colour_encoding) {
    cv::Mat rgb(colour_h, colour_w, CV_8UC3, cv::Scalar(40, 120, 200));
    cv::Mat z(height, width, CV_16UC1, cv::Scalar(1500));
    cv::imencode(colour_encoding == fslam_proto_ENCODING_JPEG ? ".jpg" : ".png", rgb, colour);
    cv::imencode(".png", z, depth);
    msg.frame_id = 3;
    msg.timestamp = 1.5;
    msg.intrinsics = {0.9 * width, 0.9 * width, width / 2.0, height / 2.0,
                      static_cast<std::uint32_t>(width), static_cast<std::uint32_t>(height)};
    msg.depth_scale = 1000.0f;
    msg.colour = {colour_encoding, static_cast<std::uint32_t>(width), static_cast<std::uint32_t>(height), 3, 1,
                  {}};
    msg.colour.data._buffer = colour.data();
    msg.colour.data._length = msg.colour.data._maximum = static_cast<std::uint32_t>(colour.size());
    msg.depth = {fslam_proto_ENCODING_PNG, static_cast<std::uint32_t>(width), static_cast<std::uint32_t>(height), 1,
                 2, {}};
    msg.depth.data._buffer = depth.data();
    msg.depth.data._length = msg.depth.data._maximum = static_cast<std::uint32_t>(depth.size());
  }
};

TEST(FrameCodec, HeadersGiveTheImageSize) {
  for (auto [ext, encoding] : {std::pair{".png", fslam_proto_ENCODING_PNG}, std::pair{".jpg", fslam_proto_ENCODING_JPEG}}) {
    std::vector<std::uint8_t> bytes;
    cv::imencode(ext, cv::Mat(37, 91, CV_8UC3, cv::Scalar(1, 2, 3)), bytes);
    std::uint32_t w = 0, h = 0;
    ASSERT_TRUE(encoded_image_size(bytes.data(), bytes.size(), encoding, &w, &h)) << ext;
    EXPECT_EQ(w, 91u) << ext;
    EXPECT_EQ(h, 37u) << ext;
    EXPECT_FALSE(encoded_image_size(bytes.data(), 10, encoding, &w, &h)) << ext << ": truncated";
    bytes[1] ^= 0xFF;
    EXPECT_FALSE(encoded_image_size(bytes.data(), bytes.size(), encoding, &w, &h)) << ext << ": bad signature";
  }
}

TEST(FrameCodec, AcceptsAndDecodesAGoodFrame) {
  for (auto encoding : {fslam_proto_ENCODING_PNG, fslam_proto_ENCODING_JPEG}) {
    WireFrame wire(64, 48, 64, 48, encoding);
    EncodedFrame accepted;
    std::string why;
    ASSERT_TRUE(accept_frame(wire.msg, &accepted, &why)) << why;
    core::RgbdFrame frame;
    ASSERT_TRUE(decode_frame(accepted, &frame, &why)) << why;
    EXPECT_EQ(frame.colour.cols, 64);
    EXPECT_NEAR(frame.depth.at<float>(10, 10), 1.5f, 1e-6f);  // metres
  }
}

// A small payload whose header declares a huge image is refused before anything is decoded.
TEST(FrameCodec, RefusesHeadersThatDisagreeWithTheFrameAndOversizedFrames) {
  for (auto encoding : {fslam_proto_ENCODING_PNG, fslam_proto_ENCODING_JPEG}) {
    WireFrame wire(64, 48, 640, 480, encoding);  // the colour payload is 640x480
    EncodedFrame accepted;
    std::string why;
    EXPECT_FALSE(accept_frame(wire.msg, &accepted, &why));
    EXPECT_NE(why.find("header says 640x480"), std::string::npos) << why;
  }
  WireFrame big(64, 48, 64, 48, fslam_proto_ENCODING_PNG);
  big.msg.intrinsics.width = big.msg.colour.width = big.msg.depth.width = 16000;
  big.msg.intrinsics.height = big.msg.colour.height = big.msg.depth.height = 12000;
  big.msg.intrinsics.fx = big.msg.intrinsics.fy = 14000;
  EncodedFrame accepted;
  std::string why;
  EXPECT_FALSE(accept_frame(big.msg, &accepted, &why));
  EXPECT_NE(why.find("over the limit"), std::string::npos) << why;
  WireFrame garbage(64, 48, 64, 48, fslam_proto_ENCODING_PNG);
  garbage.colour.assign(garbage.colour.size(), 0x42);
  EXPECT_FALSE(accept_frame(garbage.msg, &accepted, &why));
  EXPECT_NE(why.find("header cannot be read"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::server

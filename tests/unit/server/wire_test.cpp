// The wire conversions (wire.hpp). Frames as they come off the wire: what is refused before
// decoding (sizes, headers that disagree with the frame, decompression bombs, poses that are not
// rigid) and what decodes; poses both ways; result images and the buffers they point into.
#include "fslam/server/wire.hpp"

#include <cstring>
#include <limits>
#include <vector>

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <opencv2/core.hpp>
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
    msg.intrinsics = {0.9f * width, 0.9f * width, width / 2.0f, height / 2.0f,
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

// An encoding value outside the enum (a peer's bytes can hold any) is refused with its number, not
// read as the enum (undefined behaviour: found by tests/fuzz/frame_fuzz.cpp, whose crashing input
// is in tests/fuzz/corpus/frame/).
TEST(FrameCodec, RefusesAnUnknownEncodingValue) {
  for (fslam_proto_Image fslam_proto_Frame::*image : {&fslam_proto_Frame::colour, &fslam_proto_Frame::depth}) {
    WireFrame wire(64, 48, 64, 48, fslam_proto_ENCODING_PNG);
    const std::uint32_t value = 51;
    std::memcpy(&(wire.msg.*image).encoding, &value, sizeof value);
    EncodedFrame accepted;
    std::string why;
    EXPECT_FALSE(accept_frame(wire.msg, &accepted, &why));
    EXPECT_NE(why.find("unknown encoding 51"), std::string::npos) << why;
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

TEST(FrameCodec, RefusesAGroundTruthPoseThatIsNotRigid) {
  WireFrame wire(64, 48, 64, 48, fslam_proto_ENCODING_PNG);
  wire.msg.has_gt_pose = true;
  wire.msg.gt_pose.rotation[3] = 1.0;
  wire.msg.gt_pose.translation[0] = 0.25;
  EncodedFrame accepted;
  std::string why;
  ASSERT_TRUE(accept_frame(wire.msg, &accepted, &why)) << why;
  ASSERT_TRUE(accepted.T_world_camera_gt.has_value());
  EXPECT_NEAR(accepted.T_world_camera_gt->translation().x(), 0.25, 1e-12);  // metres
  wire.msg.gt_pose.rotation[3] = 0.9;  // |q| = 0.9: not a rotation
  EXPECT_FALSE(accept_frame(wire.msg, &accepted, &why));
  EXPECT_EQ(why, "ground-truth pose: translation must be finite and the quaternion unit length");
}

TEST(Wire, PosesRoundTripAndNonRigidOnesAreRefused) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.5, -1.25, 2.0);
  fslam_proto_Pose pose{};
  to_wire(T, &pose);
  Eigen::Isometry3d back;
  std::string why;
  ASSERT_TRUE(from_wire(pose, &back, &why)) << why;
  EXPECT_LT((back.translation() - T.translation()).norm(), 1e-12);                    // metres
  EXPECT_LT(Eigen::AngleAxisd(back.linear().transpose() * T.linear()).angle(), 1e-9);  // radians
  pose.translation[1] = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(from_wire(pose, &back, &why));
  EXPECT_NE(why.find("translation must be finite"), std::string::npos) << why;
}

TEST(Wire, ResultImagesArePngsThatPointIntoTheirBuffers) {
  cv::Mat mask(4, 6, CV_8UC1, cv::Scalar(0)), depth(4, 6, CV_16UC1, cv::Scalar(1234));
  mask.at<std::uint8_t>(2, 3) = 255;
  fslam_proto_Result result{};
  ResultImages images;
  ASSERT_TRUE(attach_images({mask, depth}, &result.images, &images));
  ASSERT_EQ(result.images._length, 2u);
  ASSERT_EQ(result.images._buffer, images.images.data());
  const fslam_proto_Image& wire_depth = result.images._buffer[1];
  EXPECT_EQ(wire_depth.encoding, fslam_proto_ENCODING_PNG);
  EXPECT_EQ(wire_depth.width, 6u);
  EXPECT_EQ(wire_depth.height, 4u);
  EXPECT_EQ(wire_depth.channels, 1);
  EXPECT_EQ(wire_depth.bytes_per_channel, 2);
  EXPECT_EQ(wire_depth.data._buffer, images.buffers[1].data());
  for (int i = 0; i < 2; ++i) {
    const fslam_proto_Image& image = result.images._buffer[i];
    const cv::Mat bytes(1, static_cast<int>(image.data._length), CV_8UC1, image.data._buffer);
    const cv::Mat decoded = cv::imdecode(bytes, cv::IMREAD_UNCHANGED);
    const cv::Mat& sent = i == 0 ? mask : depth;
    ASSERT_EQ(decoded.type(), sent.type());
    EXPECT_EQ(cv::norm(decoded, sent, cv::NORM_INF), 0.0) << "image " << i;  // lossless
  }
}

}  // namespace
}  // namespace fslam::server

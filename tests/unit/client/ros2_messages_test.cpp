// The ROS 2 interfaces on the wire (docs/ros2.md, "Wire compatibility"): the bytes Cyclone DDS
// writes for our IDL against the plain-CDR layout of the ROS 2 message definitions, our rosbag2
// record parser against those bytes, the conversions of camera images and the stamp pairing.
#include <cmath>
#include <cstring>
#include <limits>

#include <gtest/gtest.h>

#include "fslam/client/ros2_messages.hpp"
#include "ros2/geometry_msgs.h"
#include "ros2/sensor_msgs.h"
#include "ros2_cdr.hpp"
#include "test_support.hpp"

namespace fslam {
namespace {

namespace ros2 = client::ros2;
using test::CdrLayout;

class Ros2Wire : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    test::use_loopback_dds();
    participant_ = dds_create_participant(DDS_DOMAIN_DEFAULT, nullptr, nullptr);
  }
  static void TearDownTestSuite() { dds_delete(participant_); }
  void SetUp() override { ASSERT_GT(participant_, 0); }
  static std::string topic(const char* name) { return "rt/ros2wire" + std::to_string(getpid()) + "/" + name; }
  static dds_entity_t participant_;
};
dds_entity_t Ros2Wire::participant_ = 0;

// Drops the padding Cyclone adds to a multiple of 4 bytes (counted in the low bits of the
// encapsulation options) and clears the options, so that layouts compare field by field.
std::vector<std::uint8_t> unpadded(std::vector<std::uint8_t> b) {
  if (b.size() < 4) return b;
  const std::size_t padding = b[3] & 3u;
  b.resize(b.size() - padding);
  b[2] = b[3] = 0;
  return b;
}

TEST_F(Ros2Wire, TypeNamesAreTheOnesRos2Registers) {
  EXPECT_STREQ(sensor_msgs_msg_dds__Image__desc.m_typename, "sensor_msgs::msg::dds_::Image_");
  EXPECT_STREQ(sensor_msgs_msg_dds__CameraInfo__desc.m_typename, "sensor_msgs::msg::dds_::CameraInfo_");
  EXPECT_STREQ(sensor_msgs_msg_dds__CompressedImage__desc.m_typename, "sensor_msgs::msg::dds_::CompressedImage_");
  EXPECT_STREQ(geometry_msgs_msg_dds__PoseStamped__desc.m_typename, "geometry_msgs::msg::dds_::PoseStamped_");
  EXPECT_EQ(ros2::dds_topic("/camera/color/image_raw"), "rt/camera/color/image_raw");
  EXPECT_EQ(ros2::dds_topic("tf"), "rt/tf");
}

// sensor_msgs/Image: header (stamp sec, nanosec; frame_id), height, width, encoding,
// is_bigendian (1 byte), step (aligned to 4 after it), data.
TEST_F(Ros2Wire, ImageIsPlainCdrInDeclarationOrder) {
  std::vector<std::uint8_t> pixels(2 * 9);
  for (std::size_t i = 0; i < pixels.size(); ++i) pixels[i] = static_cast<std::uint8_t>(10 + i);
  std::string frame = "camera_color_optical_frame", encoding = "rgb8";
  sensor_msgs_msg_dds__Image_ m{};
  m.header.stamp = {708, 256};
  m.header.frame_id = frame.data();
  m.height = 2;
  m.width = 3;
  m.encoding = encoding.data();
  m.is_bigendian = 0;
  m.step = 9;
  m.data = {static_cast<std::uint32_t>(pixels.size()), static_cast<std::uint32_t>(pixels.size()), pixels.data(), false};
  const std::vector<std::uint8_t> wire = test::cdr_of(participant_, &sensor_msgs_msg_dds__Image__desc, &m, topic("image"));
  ASSERT_FALSE(wire.empty());
  const auto expected = CdrLayout()
                            .put<std::int32_t>(708).put<std::uint32_t>(256).string(frame)
                            .put<std::uint32_t>(2).put<std::uint32_t>(3).string(encoding)
                            .put<std::uint8_t>(0).put<std::uint32_t>(9).octets(pixels)
                            .bytes();
  EXPECT_EQ(unpadded(wire), expected);
  EXPECT_EQ(wire[0], 0x00);
  EXPECT_EQ(wire[1], 0x01) << "CDR_LE (XCDR1), as rmw_cyclonedds_cpp writes";

  ros2::ImageMsg back;
  std::string why;
  ASSERT_TRUE(ros2::parse_image(wire.data(), wire.size(), &back, &why)) << why;
  EXPECT_EQ(back.stamp.sec, 708);
  EXPECT_EQ(back.stamp.nanosec, 256u);
  EXPECT_EQ(back.frame_id, frame);
  EXPECT_EQ(back.encoding, "rgb8");
  EXPECT_EQ(back.step, 9u);
  ASSERT_EQ(back.size, pixels.size());
  EXPECT_EQ(std::memcmp(back.data, pixels.data(), pixels.size()), 0);
  EXPECT_FALSE(ros2::parse_image(wire.data(), wire.size() - 8, &back, &why)) << "a truncated record is refused";
}

// geometry_msgs/PoseStamped: header, then seven doubles aligned to 8 from the first byte after
// the encapsulation header.
TEST_F(Ros2Wire, PoseStampedAlignsItsDoublesAfterTheHeader) {
  std::string frame = "map";
  geometry_msgs_msg_dds__PoseStamped_ m{};
  m.header.stamp = {1490149580, 117017840};
  m.header.frame_id = frame.data();
  m.pose.position = {3.835, -1.5, 0.25};
  m.pose.orientation = {0.0, 0.0, 0.7071067811865476, 0.7071067811865476};
  const auto wire = test::cdr_of(participant_, &geometry_msgs_msg_dds__PoseStamped__desc, &m, topic("pose"));
  ASSERT_FALSE(wire.empty());
  CdrLayout expected;
  expected.put<std::int32_t>(1490149580).put<std::uint32_t>(117017840).string(frame);
  for (double v : {3.835, -1.5, 0.25, 0.0, 0.0, 0.7071067811865476, 0.7071067811865476}) expected.put<double>(v);
  // 8 (stamp) + 4 + 4 ("map\0") = 16: already aligned; the first double starts at byte 4 + 16.
  EXPECT_EQ(expected.bytes().size(), 4u + 16u + 7u * 8u);
  EXPECT_EQ(unpadded(wire), expected.bytes());
}

TEST_F(Ros2Wire, CameraInfoParsesFromWhatCycloneWrites) {
  std::string frame = "cam", model = "plumb_bob";
  double d[5] = {0.1, -0.2, 0.0, 0.0, 0.05};
  sensor_msgs_msg_dds__CameraInfo_ m{};
  m.header.stamp = {5, 7};
  m.header.frame_id = frame.data();
  m.height = 480;
  m.width = 640;
  m.distortion_model = model.data();
  m.d = {5, 5, d, false};
  const double k[9] = {525, 0, 319.5, 0, 526, 239.5, 0, 0, 1};
  std::memcpy(m.k, k, sizeof k);
  m.roi.do_rectify = true;
  const auto wire = test::cdr_of(participant_, &sensor_msgs_msg_dds__CameraInfo__desc, &m, topic("info"));
  ros2::CameraInfoMsg back;
  std::string why;
  ASSERT_TRUE(ros2::parse_camera_info(wire.data(), wire.size(), &back, &why)) << why;
  EXPECT_EQ(back.distortion_model, model);
  ASSERT_EQ(back.d.size(), 5u);
  EXPECT_DOUBLE_EQ(back.d[4], 0.05);
  client::CameraIntrinsics intrinsics;
  ASSERT_TRUE(ros2::intrinsics_of(back, &intrinsics, &why)) << why;
  EXPECT_FLOAT_EQ(intrinsics.fx, 525.0f);
  EXPECT_FLOAT_EQ(intrinsics.fy, 526.0f);
  EXPECT_FLOAT_EQ(intrinsics.cx, 319.5f);
  EXPECT_FLOAT_EQ(intrinsics.cy, 239.5f);
  EXPECT_EQ(intrinsics.width, 640u);
}

ros2::ImageMsg image(const std::string& encoding, std::uint32_t w, std::uint32_t h, std::uint32_t step,
                     const std::vector<std::uint8_t>& data) {
  ros2::ImageMsg m;
  m.encoding = encoding;
  m.width = w;
  m.height = h;
  m.step = step;
  m.data = data.data();
  m.size = data.size();
  return m;
}

TEST(Ros2Images, ColourEncodingsBecomeRgbRowsWithoutTheirPadding) {
  // 2x2 bgr8 rows padded to 8 bytes.
  const std::vector<std::uint8_t> bgr = {1, 2, 3, 4, 5, 6, 0, 0, 7, 8, 9, 10, 11, 12, 0, 0};
  std::vector<std::uint8_t> rgb;
  std::string why;
  ASSERT_TRUE(ros2::colour_to_rgb8(image("bgr8", 2, 2, 8, bgr), &rgb, &why)) << why;
  EXPECT_EQ(rgb, (std::vector<std::uint8_t>{3, 2, 1, 6, 5, 4, 9, 8, 7, 12, 11, 10}));
  ASSERT_TRUE(ros2::colour_to_rgb8(image("mono8", 2, 1, 2, {40, 50}), &rgb, &why)) << why;
  EXPECT_EQ(rgb, (std::vector<std::uint8_t>{40, 40, 40, 50, 50, 50}));
  EXPECT_FALSE(ros2::colour_to_rgb8(image("yuv422", 2, 2, 4, bgr), &rgb, &why));
  EXPECT_NE(why.find("unknown encoding 'yuv422'"), std::string::npos) << why;
  EXPECT_FALSE(ros2::colour_to_rgb8(image("rgb8", 2, 3, 8, bgr), &rgb, &why)) << "16 bytes for 3 rows of 8";
  EXPECT_NE(why.find("needs 24 bytes, has 16"), std::string::npos) << why;
  EXPECT_FALSE(ros2::colour_to_rgb8(image("rgb8", 3, 2, 8, bgr), &rgb, &why)) << "step under a row";
}

TEST(Ros2Images, DepthInMillimetresOrMetresBecomesLosslessUnits) {
  std::vector<std::uint16_t> units;
  float scale = 0;
  std::string why;
  // 16UC1 big-endian: 0x04D2 = 1234 mm.
  ros2::ImageMsg be = image("16UC1", 1, 1, 2, {0x04, 0xD2});
  be.is_bigendian = 1;
  std::vector<std::uint8_t> keep = {0x04, 0xD2};
  be.data = keep.data();
  ASSERT_TRUE(ros2::depth_to_u16(be, &units, &scale, &why)) << why;
  EXPECT_EQ(units[0], 1234);
  EXPECT_EQ(scale, 1000.0f);
  // 32FC1: 1.5 m, NaN, -1 m, 20 m (beyond 13.1 m) -> 7500, missing, missing, missing.
  const float metres[4] = {1.5f, std::numeric_limits<float>::quiet_NaN(), -1.0f, 20.0f};
  std::vector<std::uint8_t> bytes(sizeof metres);
  std::memcpy(bytes.data(), metres, sizeof metres);
  ASSERT_TRUE(ros2::depth_to_u16(image("32FC1", 4, 1, 16, bytes), &units, &scale, &why)) << why;
  EXPECT_EQ(scale, 5000.0f);
  EXPECT_EQ(units, (std::vector<std::uint16_t>{7500, 0, 0, 0}));
  EXPECT_FALSE(ros2::depth_to_u16(image("8UC1", 4, 1, 4, bytes), &units, &scale, &why));
  EXPECT_NE(why.find("unknown encoding"), std::string::npos);
}

TEST(Ros2Pairing, PairsWithinTheToleranceAndReportsWhatCannotPair) {
  using Stream = ros2::StampPairer::Stream;
  ros2::StampPairer pairer(0.010);
  EXPECT_TRUE(pairer.add(Stream::colour, 1, 1.000).empty());
  auto out = pairer.add(Stream::depth, 2, 1.004);  // 4 ms apart: a pair
  ASSERT_EQ(out.size(), 1u);
  EXPECT_TRUE(out[0].paired);
  EXPECT_EQ(out[0].colour, 1u);
  EXPECT_EQ(out[0].depth, 2u);
  EXPECT_TRUE(pairer.add(Stream::colour, 3, 2.000).empty());
  out = pairer.add(Stream::depth, 4, 2.050);  // 50 ms: colour 3 can never pair now
  ASSERT_EQ(out.size(), 1u);
  EXPECT_FALSE(out[0].paired);
  EXPECT_EQ(out[0].id, 3u);
  EXPECT_NE(out[0].why.find("no depth within 10 ms"), std::string::npos) << out[0].why;
  out = pairer.add(Stream::colour, 5, 2.052);  // pairs with depth 4 (2 ms)
  ASSERT_EQ(out.size(), 1u);
  EXPECT_TRUE(out[0].paired);
  EXPECT_EQ(out[0].depth, 4u);
  EXPECT_TRUE(pairer.add(Stream::depth, 6, 3.0).empty());
  EXPECT_EQ(pairer.flush().size(), 1u);
}

}  // namespace
}  // namespace fslam

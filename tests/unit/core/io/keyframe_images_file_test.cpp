#include "fslam/core/io/keyframe_images_file.hpp"

#include <cstring>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "fslam/core/geometry/se3.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

// Two keyframes of a 64x48 camera kept at half scale: textured colour, depth with holes and a
// value past the 13.1-m range of the saved depth.
std::vector<KeyframeImages> sample_keyframes() {
  std::vector<KeyframeImages> keyframes(2);
  for (std::size_t k = 0; k < keyframes.size(); ++k) {
    KeyframeImages& kf = keyframes[k];
    kf.frame_id = 7 * static_cast<std::int64_t>(k) - 2;
    kf.input_camera = {50.0, 51.0, 31.5, 23.5, 64, 48};
    kf.T_world_camera = se3_exp((Vector6d() << 0.1 * k, -0.2, 1.5, 0.05 * k, 0.3, -0.1).finished());
    kf.colour.create(24, 32, CV_8UC3);
    kf.depth.create(24, 32, CV_32FC1);
    for (int v = 0; v < 24; ++v)
      for (int u = 0; u < 32; ++u) {
        kf.colour.at<cv::Vec3b>(v, u) = cv::Vec3b(static_cast<std::uint8_t>(u * 8), static_cast<std::uint8_t>(v * 10 + k),
                                                  static_cast<std::uint8_t>((u * v) % 256));
        kf.depth.at<float>(v, u) = (u + v) % 9 == 0 ? 0.0f : 0.5f + 0.01234f * static_cast<float>(u + 2 * v);
      }
    kf.depth.at<float>(0, 1) = 20.0f;  // past 65535 / 5000 m
  }
  return keyframes;
}

std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

TEST(KeyframeImagesFile, RoundTripsColourExactlyAndDepthToHalfAUnit) {
  const auto dir = test::fresh_temp_dir("kfi");
  const std::string path = (dir / "keyframe_images.bin").string();
  const std::vector<KeyframeImages> keyframes = sample_keyframes();
  std::string why;
  ASSERT_TRUE(write_keyframe_images_file(path, keyframes, &why)) << why;
  std::vector<KeyframeImages> back;
  ASSERT_TRUE(read_keyframe_images_file(path, &back, &why)) << why;
  ASSERT_EQ(back.size(), keyframes.size());
  for (std::size_t k = 0; k < keyframes.size(); ++k) {
    const KeyframeImages &a = keyframes[k], &b = back[k];
    EXPECT_EQ(b.frame_id, a.frame_id);
    EXPECT_EQ(b.input_camera.width, 64);
    EXPECT_EQ(b.input_camera.height, 48);
    EXPECT_DOUBLE_EQ(b.input_camera.fy, 51.0);
    EXPECT_DOUBLE_EQ(b.input_camera.cx, 31.5);
    EXPECT_LT((b.T_world_camera.matrix() - a.T_world_camera.matrix()).cwiseAbs().maxCoeff(), 1e-15);
    ASSERT_EQ(b.colour.type(), CV_8UC3);
    ASSERT_EQ(b.depth.type(), CV_32FC1);
    ASSERT_EQ(b.colour.size(), a.colour.size());
    EXPECT_EQ(cv::norm(b.colour, a.colour, cv::NORM_INF), 0.0) << "colour (RGB order) must come back exactly";
    EXPECT_FLOAT_EQ(b.depth.at<float>(0, 1), 0.0f) << "depth past 13.1 m is saved as missing";
    float worst = 0;
    for (int v = 0; v < 24; ++v)
      for (int u = 0; u < 32; ++u) {
        if (v == 0 && u == 1) continue;
        const float x = a.depth.at<float>(v, u), y = b.depth.at<float>(v, u);
        if (x == 0.0f) {
          EXPECT_EQ(y, 0.0f);
        }
        worst = std::max(worst, std::abs(x - y));
      }
    EXPECT_LE(worst, 0.000101f) << "depth is rounded to 1/5000 m (half a unit: 0.1 mm, and float rounding)";
  }
}

TEST(KeyframeImagesFile, CorruptOrTruncatedFilesAreErrorsThatSayWhere) {
  const auto dir = test::fresh_temp_dir("kfi_bad");
  const std::string path = (dir / "keyframe_images.bin").string();
  std::string why;
  ASSERT_TRUE(write_keyframe_images_file(path, sample_keyframes(), &why)) << why;
  const std::string bytes = read_bytes(path);
  std::vector<KeyframeImages> out;
  // Every truncation is refused (never a crash), and leaves the output empty.
  for (std::size_t n = 0; n < bytes.size(); n += 97) {
    EXPECT_FALSE(parse_keyframe_images_file(bytes.substr(0, n), "t", &out, &why)) << n;
    EXPECT_TRUE(out.empty());
  }
  std::string bad = bytes;
  bad[7] = '9';
  EXPECT_FALSE(parse_keyframe_images_file(bad, "t", &out, &why));
  EXPECT_NE(why.find("FSLMKFI1"), std::string::npos) << why;
  // Keyframe 0's rotation (after magic 8, count 4, id 8, camera 40): scaled, not a rotation.
  bad = bytes;
  double r00 = 0;
  std::memcpy(&r00, bad.data() + 60, 8);
  r00 *= 2.0;
  std::memcpy(bad.data() + 60, &r00, 8);
  EXPECT_FALSE(parse_keyframe_images_file(bad, "t", &out, &why));
  EXPECT_NE(why.find("keyframe 0: pose rotation is not a rotation"), std::string::npos) << why;
  // Its input camera narrowed below the images' width (principal point kept inside): the PNG
  // header is checked before decoding.
  bad = bytes;
  const double cx = 11.5;
  const std::uint32_t narrow = 24;
  std::memcpy(bad.data() + 36, &cx, 8);
  std::memcpy(bad.data() + 52, &narrow, 4);  // width
  EXPECT_FALSE(parse_keyframe_images_file(bad, "t", &out, &why));
  EXPECT_NE(why.find("within the input camera's size"), std::string::npos) << why;
  // Trailing bytes.
  EXPECT_FALSE(parse_keyframe_images_file(bytes + "x", "t", &out, &why));
  EXPECT_NE(why.find("1 bytes after the last keyframe"), std::string::npos) << why;
  // Images of two sizes, or not 8-bit colour / float depth, are not written.
  std::vector<KeyframeImages> mismatched = sample_keyframes();
  mismatched[1].depth = cv::Mat(10, 10, CV_32FC1, cv::Scalar(1.0f));
  EXPECT_FALSE(write_keyframe_images_file(path, mismatched, &why));
  EXPECT_NE(why.find("one size"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::core

#include "fslam/core/io/keyframe_file.hpp"

#include <cmath>
#include <cstring>
#include <limits>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "fslam/core/geometry/se3.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

// Two keyframes with distinct poses, descriptors, points and thumbnails, and one without
// keypoints (a textureless view: described, nothing to match).
std::vector<DescribedKeyframe> sample_keyframes() {
  std::vector<DescribedKeyframe> keyframes(3);
  for (std::size_t k = 0; k < keyframes.size(); ++k) {
    DescribedKeyframe& kf = keyframes[k];
    kf.id = 40 * static_cast<std::int64_t>(k) + 3;
    kf.T_world_camera = se3_exp((Vector6d() << 0.1 * k, -0.2, 1.5, 0.05 * k, 0.3, -0.1).finished());
    const int K = k == 2 ? 0 : 4 + static_cast<int>(k);
    kf.description.descriptors.create(K, 32, CV_8UC1);
    for (int i = 0; i < K; ++i)
      for (int b = 0; b < 32; ++b) kf.description.descriptors.at<std::uint8_t>(i, b) = static_cast<std::uint8_t>(i * 31 + b + k);
    for (int i = 0; i < K; ++i) kf.description.points.emplace_back(0.1f * i, -0.05f * i, 1.0f + 0.25f * i);
    for (int g = 0; g < 12; ++g) kf.description.global.push_back(0.01f * g - 0.05f * static_cast<float>(k));
  }
  return keyframes;
}

std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

TEST(KeyframeFile, RoundTripsEveryField) {
  const auto dir = test::fresh_temp_dir("kf");
  const std::string path = (dir / "keyframes.bin").string();
  const std::vector<DescribedKeyframe> keyframes = sample_keyframes();
  std::string why;
  ASSERT_TRUE(write_keyframe_file(path, keyframes, &why)) << why;
  std::vector<DescribedKeyframe> back;
  ASSERT_TRUE(read_keyframe_file(path, &back, &why)) << why;
  ASSERT_EQ(back.size(), keyframes.size());
  for (std::size_t k = 0; k < keyframes.size(); ++k) {
    const DescribedKeyframe &a = keyframes[k], &b = back[k];
    EXPECT_EQ(b.id, a.id);
    EXPECT_LT((b.T_world_camera.matrix() - a.T_world_camera.matrix()).cwiseAbs().maxCoeff(), 1e-15);
    ASSERT_EQ(b.description.points.size(), a.description.points.size());
    for (std::size_t i = 0; i < a.description.points.size(); ++i)
      EXPECT_EQ(b.description.points[i], a.description.points[i]);
    ASSERT_EQ(b.description.descriptors.rows, a.description.descriptors.rows);
    if (a.description.descriptors.rows > 0) {
      EXPECT_EQ(b.description.descriptors.cols, 32);
      EXPECT_EQ(cv::norm(b.description.descriptors, a.description.descriptors, cv::NORM_HAMMING), 0.0);
    }
    EXPECT_EQ(b.description.global, a.description.global);
  }
}

TEST(KeyframeFile, CorruptFilesAreClearErrors) {
  const auto dir = test::fresh_temp_dir("kfbad");
  const std::string good = (dir / "good.bin").string();
  std::string why;
  ASSERT_TRUE(write_keyframe_file(good, sample_keyframes(), &why)) << why;
  const std::string bytes = read_bytes(good);
  std::vector<DescribedKeyframe> back;
  const auto expect_error = [&](const std::string& corrupt, const std::string& fragment) {
    back.assign(1, DescribedKeyframe{});
    std::string error;
    EXPECT_FALSE(parse_keyframe_file(corrupt, "kf.bin", &back, &error)) << fragment;
    EXPECT_NE(error.find("kf.bin"), std::string::npos) << error;
    EXPECT_NE(error.find(fragment), std::string::npos) << error;
    EXPECT_TRUE(back.empty()) << "a refused file leaves no half-read keyframes";
  };
  expect_error("", "no FSLMKFD1 header");
  expect_error("FSLMKFD2" + bytes.substr(8), "no FSLMKFD1 header");
  expect_error(bytes.substr(0, 10), "truncated before the keyframe count");
  // Every cut inside the keyframes is an error, never a crash or a shorter list.
  for (std::size_t cut = 12; cut < bytes.size(); cut += 7)
    EXPECT_FALSE(parse_keyframe_file(bytes.substr(0, cut), "kf.bin", &back, &why)) << "cut at " << cut;
  expect_error(bytes + "x", "1 bytes after the last keyframe");
  std::string huge = bytes;
  const std::uint32_t many = 0x7fffffff;
  std::memcpy(huge.data() + 8, &many, 4);
  expect_error(huge, "the file is too short for them");
  // The first keyframe's pose: translation x (after id and the 9 rotation values) as NaN, then
  // the rotation scaled (not orthonormal).
  const std::size_t pose_at = 12 + 8;
  std::string nan_pose = bytes;
  const double nan = std::nan("");
  std::memcpy(nan_pose.data() + pose_at + 9 * 8, &nan, 8);
  expect_error(nan_pose, "non-finite pose");
  std::string scaled = bytes;
  const double two = 2.0;
  std::memcpy(scaled.data() + pose_at, &two, 8);
  expect_error(scaled, "not a rotation");
  // A keypoint coordinate made infinite (first keyframe: 4 keypoints after its 32-byte rows).
  std::string inf_point = bytes;
  const float inf = std::numeric_limits<float>::infinity();
  std::memcpy(inf_point.data() + pose_at + 12 * 8 + 8 + 4 * 32, &inf, 4);
  expect_error(inf_point, "non-finite keypoint");
  EXPECT_FALSE(read_keyframe_file((dir / "missing.bin").string(), &back, &why));
  EXPECT_NE(why.find("missing.bin"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::core

#include <cmath>
#include <filesystem>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "dataset_fixtures.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/io/trajectory_io.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

constexpr double kStart = 1305031102.0;  // TUM-like absolute stamps, s
constexpr int kWidth = 8;
constexpr int kHeight = 6;

// The ground-truth motion: x, y, z linear in time, rotation about one fixed axis, so geodesic
// interpolation between samples reproduces it exactly.
Eigen::Isometry3d true_pose(double t) {
  const double s = t - kStart;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.8 * s, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.5 * s, -0.2 * s, 0.1 * s + 1.0);
  return T;
}

double rgb_stamp(int i) { return kStart + 0.1 * i + 0.001; }

// Ten colour frames at 10 Hz. Depth is 10 ms late, except frame 4's, which is 34 ms late and so
// unmatched (associate.py drops that frame); one extra depth image has no colour partner.
// Colour i is filled with 20 i, depth i with 1 + 0.02 i metres, so pairings can be checked.
// Ground truth runs at 33 Hz with a gap from 0.74 s to 1.0 s.
fs::path write_sequence(const std::string& name, bool with_intrinsics = true) {
  const fs::path dir = test::fresh_temp_dir(name);
  std::string rgb = "# color images\n# file: 'test.bag'\n# timestamp filename\n";
  std::string depth = "# depth maps\n# file: 'test.bag'\n# timestamp filename\n";
  for (int i = 0; i < 10; ++i) {
    const std::string rs = cv::format("%.6f", rgb_stamp(i));
    const std::string ds = cv::format("%.6f", rgb_stamp(i) + (i == 4 ? 0.034 : 0.010));
    rgb += rs + " rgb/" + rs + ".png\n";
    depth += ds + " depth/" + ds + ".png\n";
    test::write_colour(dir / "rgb" / (rs + ".png"), kWidth, kHeight, 20 * i);
    test::write_depth(dir / "depth" / (ds + ".png"), kWidth, kHeight,
                      static_cast<std::uint16_t>(5000 + 100 * i));
  }
  const std::string extra = cv::format("%.6f", kStart + 2.0);
  depth += extra + " depth/" + extra + ".png\n";
  test::write_depth(dir / "depth" / (extra + ".png"), kWidth, kHeight, 1);
  test::write_text(dir / "rgb.txt", rgb);
  test::write_text(dir / "depth.txt", depth);

  Trajectory gt;
  for (int k = 0; k < 40; ++k) {
    const double s = 0.05 + 0.03 * k;
    // Stamped as the file will hold them (microseconds), so the poses are exact at the stamps.
    const double t = std::round((kStart + s) * 1e6) / 1e6;
    if (s < 0.75 || s >= 1.0) gt.push_back({t, true_pose(t)});
  }
  std::string why;
  EXPECT_TRUE(write_tum_trajectory((dir / "groundtruth.txt").string(), gt, &why)) << why;
  if (with_intrinsics)
    test::write_text(dir / "intrinsics.txt", "# fx fy cx cy width height\n10 11 3.5 2.5 8 6\n");
  return dir;
}

std::unique_ptr<Dataset> open_tum(const fs::path& dir, DatasetOptions options = {}) {
  options.kind = "tum";
  std::string why;
  auto dataset = open_dataset(dir.string(), options, &why);
  EXPECT_TRUE(dataset) << why;
  return dataset;
}

std::string open_error(const fs::path& dir, DatasetOptions options = {}) {
  options.kind = "tum";
  std::string why;
  EXPECT_FALSE(open_dataset(dir.string(), options, &why)) << "opened " << dir;
  return why;
}

TEST(Tum, AssociatesLikeAssociatePy) {
  const auto dataset = open_tum(write_sequence("associate"));
  ASSERT_TRUE(dataset);
  EXPECT_EQ(dataset->kind(), "tum");
  EXPECT_DOUBLE_EQ(dataset->depth_scale(), 5000.0);
  const std::vector<int> expected = {0, 1, 2, 3, 5, 6, 7, 8, 9};  // frame 4 has no depth partner
  ASSERT_EQ(dataset->size(), expected.size());
  for (std::size_t k = 0; k < expected.size(); ++k) {
    const int i = expected[k];
    RgbdFrame frame;
    std::string why;
    ASSERT_TRUE(dataset->load(k, &frame, &why)) << why;
    EXPECT_EQ(frame.id, static_cast<std::int64_t>(k));
    EXPECT_NEAR(frame.timestamp, rgb_stamp(i), 1e-6);  // the colour stamp
    EXPECT_EQ(frame.colour.at<cv::Vec3b>(2, 3), cv::Vec3b(20 * i, 20 * i + 1, 20 * i + 2));
    EXPECT_FLOAT_EQ(frame.depth.at<float>(2, 3), 1.0f + 0.02f * i) << "paired with wrong depth";
  }
}

TEST(Tum, InterpolatesGroundTruthBetweenBracketingSamples) {
  const auto dataset = open_tum(write_sequence("interpolate"));
  ASSERT_TRUE(dataset);
  ASSERT_TRUE(dataset->has_ground_truth());
  // Frame at 0.001 s precedes the first sample (0.05 s); 0.801 and 0.901 fall in the gap.
  const std::vector<bool> has_pose = {false, true, true, true, true, true, true, false, false};
  const Trajectory gt = dataset->ground_truth();
  EXPECT_EQ(gt.size(), 6u);
  std::size_t next = 0;
  for (std::size_t k = 0; k < dataset->size(); ++k) {
    RgbdFrame frame;
    std::string why;
    ASSERT_TRUE(dataset->load(k, &frame, &why)) << why;
    ASSERT_EQ(frame.T_world_camera_gt.has_value(), has_pose[k]) << "frame " << k;
    if (!has_pose[k]) continue;
    const Eigen::Isometry3d truth = true_pose(frame.timestamp);
    // Nearest-sample lookup would be off by up to 7.5 mm here; interpolation is exact up to the
    // file's 6-decimal stamps and 9-decimal poses.
    EXPECT_LT((frame.T_world_camera_gt->translation() - truth.translation()).norm(), 1e-6);
    EXPECT_LT(rotation_angle(frame.T_world_camera_gt->linear().transpose() * truth.linear()), 1e-6);
    ASSERT_LT(next, gt.size());
    EXPECT_DOUBLE_EQ(gt[next].timestamp, frame.timestamp);
    EXPECT_TRUE(gt[next].T_world_camera.isApprox(*frame.T_world_camera_gt));
    ++next;
  }
}

TEST(Tum, IntrinsicsFileThenOverride) {
  const fs::path dir = write_sequence("intrinsics");
  auto dataset = open_tum(dir);
  ASSERT_TRUE(dataset);
  EXPECT_DOUBLE_EQ(dataset->camera().fx, 10.0);
  EXPECT_DOUBLE_EQ(dataset->camera().fy, 11.0);
  EXPECT_DOUBLE_EQ(dataset->camera().cx, 3.5);
  EXPECT_DOUBLE_EQ(dataset->camera().cy, 2.5);
  EXPECT_EQ(dataset->camera().width, kWidth);
  EXPECT_EQ(dataset->camera().height, kHeight);
  EXPECT_NAMES_FILE(dataset->camera_source(), "intrinsics.txt");

  DatasetOptions options;
  options.intrinsics = PinholeCamera{20.0, 21.0, 4.0, 3.0, 0, 0};
  dataset = open_tum(dir, options);
  ASSERT_TRUE(dataset);
  EXPECT_DOUBLE_EQ(dataset->camera().fx, 20.0);
  EXPECT_EQ(dataset->camera().width, kWidth);
}

// Presets need full-size images: their principal points lie outside anything smaller.
fs::path write_full_size_sequence(const std::string& folder) {
  const fs::path dir = test::fresh_temp_dir("presets") / folder;
  test::write_text(dir / "rgb.txt", "1.000000 rgb/1.000000.png\n");
  test::write_text(dir / "depth.txt", "1.010000 depth/1.010000.png\n");
  test::write_colour(dir / "rgb" / "1.000000.png", 640, 480, 0);
  test::write_depth(dir / "depth" / "1.010000.png", 640, 480, 5000);
  return dir;
}

TEST(Tum, PresetsFromTheFolderName) {
  struct Case {
    const char* folder;
    double fx, fy, cx, cy;
  };
  for (const Case& c : {Case{"rgbd_dataset_freiburg1_xyz", 517.3, 516.5, 318.6, 255.3},
                        Case{"rgbd_dataset_freiburg2_desk", 520.9, 521.0, 325.1, 249.7},
                        Case{"fr3_office", 535.4, 539.2, 320.1, 247.6}}) {
    const auto dataset = open_tum(write_full_size_sequence(c.folder));
    ASSERT_TRUE(dataset) << c.folder;
    EXPECT_DOUBLE_EQ(dataset->camera().fx, c.fx) << c.folder;
    EXPECT_DOUBLE_EQ(dataset->camera().fy, c.fy) << c.folder;
    EXPECT_DOUBLE_EQ(dataset->camera().cx, c.cx) << c.folder;
    EXPECT_DOUBLE_EQ(dataset->camera().cy, c.cy) << c.folder;
    EXPECT_EQ(dataset->camera().width, 640);
    EXPECT_FALSE(dataset->has_ground_truth());  // no groundtruth.txt: fine, just none
  }
  // An intrinsics.txt wins over the preset.
  const fs::path dir = write_full_size_sequence("rgbd_dataset_freiburg1_room");
  test::write_text(dir / "intrinsics.txt", "500 500 320 240 640 480\n");
  const auto dataset = open_tum(dir);
  ASSERT_TRUE(dataset);
  EXPECT_DOUBLE_EQ(dataset->camera().fx, 500.0);
}

TEST(Tum, WithoutIntrinsicsSaysHowToPassThem) {
  const fs::path dir = write_sequence("no_intrinsics", false);
  const std::string why = open_error(dir);
  EXPECT_NE(why.find("intrinsics.txt"), std::string::npos) << why;
  EXPECT_NE(why.find("--intrinsics"), std::string::npos) << why;
  EXPECT_NAMES_FILE(why, dir.string());
}

TEST(Tum, LabelsWhenPresent) {
  const fs::path dir = write_sequence("labels");
  auto dataset = open_tum(dir);
  ASSERT_TRUE(dataset);
  EXPECT_FALSE(dataset->has_labels());
  const std::string stamp = cv::format("%.6f", rgb_stamp(1));
  const cv::Mat instance(kHeight, kWidth, CV_16UC1, cv::Scalar(7));
  const cv::Mat cls(kHeight, kWidth, CV_16UC1, cv::Scalar(300));
  fs::create_directories(dir / "labels" / "instance");
  fs::create_directories(dir / "labels" / "class");
  std::string why;
  ASSERT_TRUE(
      write_image((dir / "labels" / "instance" / (stamp + ".png")).string(), instance, &why));
  ASSERT_TRUE(write_image((dir / "labels" / "class" / (stamp + ".png")).string(), cls, &why));
  dataset = open_tum(dir);
  ASSERT_TRUE(dataset);
  EXPECT_TRUE(dataset->has_labels());
  cv::Mat a, b;
  ASSERT_TRUE(dataset->load_labels(1, &a, &b, &why)) << why;
  ASSERT_EQ(a.type(), CV_16UC1);
  EXPECT_EQ(a.at<std::uint16_t>(5, 7), 7);
  EXPECT_EQ(b.at<std::uint16_t>(0, 0), 300);
  EXPECT_FALSE(dataset->load_labels(0, &a, &b, &why));  // frame 0 has none

  // A label image of the wrong size is named.
  ASSERT_TRUE(write_image((dir / "labels" / "class" / (stamp + ".png")).string(),
                          cv::Mat(3, 3, CV_16UC1, cv::Scalar(1)), &why));
  EXPECT_FALSE(dataset->load_labels(1, &a, &b, &why));
  EXPECT_NAMES_FILE(why, stamp + ".png");
}

TEST(Tum, LoadsFromManyThreads) {
  const auto dataset = open_tum(write_sequence("threads"));
  ASSERT_TRUE(dataset);
  std::vector<RgbdFrame> frames(dataset->size());
  std::vector<std::thread> threads;
  std::vector<int> ok(dataset->size(), 0);
  for (std::size_t k = 0; k < dataset->size(); ++k)
    threads.emplace_back([&, k] { ok[k] = dataset->load(k, &frames[k], nullptr); });
  for (auto& t : threads) t.join();
  for (std::size_t k = 0; k < dataset->size(); ++k) {
    ASSERT_TRUE(ok[k]) << k;
    RgbdFrame serial;
    ASSERT_TRUE(dataset->load(k, &serial, nullptr));
    EXPECT_EQ(cv::norm(serial.depth, frames[k].depth, cv::NORM_INF), 0.0);
  }
}

TEST(Tum, MissingFilesAreNamed) {
  fs::path dir = write_sequence("missing_list");
  fs::remove(dir / "depth.txt");
  EXPECT_NAMES_FILE(open_error(dir), "depth.txt");

  dir = write_sequence("missing_image");
  const std::string stamp = cv::format("%.6f", rgb_stamp(3));
  fs::remove(dir / "rgb" / (stamp + ".png"));
  EXPECT_NAMES_FILE(open_error(dir), stamp + ".png");
}

TEST(Tum, BadListsAreNamed) {
  fs::path dir = write_sequence("bad_stamp");
  test::write_text(dir / "rgb.txt", "# header\nabc rgb/x.png\n");
  std::string why = open_error(dir);
  EXPECT_NAMES_FILE(why, "rgb.txt:2");

  dir = write_sequence("no_pairs");
  test::write_text(dir / "rgb.txt", cv::format("%.6f rgb/x.png\n", kStart + 50.0));
  EXPECT_NAMES_FILE(open_error(dir), "rgb.txt");
}

TEST(Tum, UnreadableAndMismatchedImagesAreNamed) {
  fs::path dir = write_sequence("garbage");
  const std::string stamp = cv::format("%.6f", rgb_stamp(2));
  test::write_text(dir / "rgb" / (stamp + ".png"), "not a png");
  auto dataset = open_tum(dir);
  ASSERT_TRUE(dataset);
  RgbdFrame frame;
  std::string why;
  EXPECT_FALSE(dataset->load(2, &frame, &why));
  EXPECT_NAMES_FILE(why, stamp + ".png");

  dir = write_sequence("size");
  const std::string depth_stamp = cv::format("%.6f", rgb_stamp(5) + 0.010);
  test::write_depth(dir / "depth" / (depth_stamp + ".png"), 4, 3, 5000);
  dataset = open_tum(dir);
  ASSERT_TRUE(dataset);
  EXPECT_FALSE(dataset->load(4, &frame, &why));  // position 4 is colour frame 5
  EXPECT_NAMES_FILE(why, depth_stamp + ".png");

  // intrinsics.txt's size disagrees with the images: caught when opening.
  dir = write_sequence("stated_size");
  test::write_text(dir / "intrinsics.txt", "10 11 3.5 2.5 16 12\n");
  why = open_error(dir);
  EXPECT_NAMES_FILE(why, "intrinsics.txt");
  EXPECT_NAMES_FILE(why, ".png");
}

TEST(Tum, BadIntrinsicsAreNamed) {
  for (const std::string text :
       {"10 11 3.5 2.5 8\n", "10 11 3.5 2.5 8 6\n1 2 3 4 5 6\n", "-10 11 3.5 2.5 8 6\n",
        "10 11 30 2.5 8 6\n", "10 11 3.5 2.5 8.5 6\n", "10 11 inf 2.5 8 6\n"}) {
    const fs::path dir = write_sequence("bad_intrinsics");
    test::write_text(dir / "intrinsics.txt", text);
    EXPECT_NAMES_FILE(open_error(dir), "intrinsics.txt") << "for '" << text << "'";
  }
}

TEST(Tum, BadGroundTruthIsNamed) {
  fs::path dir = write_sequence("nan_pose");
  test::write_text(dir / "groundtruth.txt", "1305031102.1 0 0 nan 0 0 0 1\n");
  EXPECT_NAMES_FILE(open_error(dir), "groundtruth.txt:1");

  // A TUM pose's rotation is a quaternion: one far from unit norm is not a rotation.
  dir = write_sequence("non_rigid_pose");
  test::write_text(dir / "groundtruth.txt", "1305031102.1 0 0 0 0 0 0 2\n");
  EXPECT_NAMES_FILE(open_error(dir), "groundtruth.txt:1");
}

TEST(Tum, BadSelectionNamesTheFolder) {
  const fs::path dir = write_sequence("selection");
  DatasetOptions options;
  std::string why;
  ASSERT_TRUE(FrameSelection::parse("9:12", &options.frames, &why));
  EXPECT_NAMES_FILE(open_error(dir, options), dir.string());
  ASSERT_TRUE(FrameSelection::parse("1:9:3", &options.frames, &why));
  const auto dataset = open_tum(dir, options);
  ASSERT_TRUE(dataset);
  ASSERT_EQ(dataset->size(), 3u);
  EXPECT_EQ(dataset->id(1), 4);
  EXPECT_NEAR(dataset->timestamp(1), rgb_stamp(5), 1e-6);  // position 4 is colour frame 5
}

}  // namespace
}  // namespace fslam::core

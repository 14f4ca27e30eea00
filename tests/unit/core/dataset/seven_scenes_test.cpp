#include <chrono>
#include <cmath>
#include <filesystem>
#include <iostream>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "dataset_fixtures.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/geometry/se3.hpp"
#include "fslam/core/io/image_io.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

std::unique_ptr<Dataset> open_or_fail(const fs::path& path, const DatasetOptions& options = {}) {
  std::string why;
  auto dataset = open_dataset(path.string(), options, &why);
  EXPECT_TRUE(dataset) << why;
  return dataset;
}

// Valid depth lies in the Kinect's range and never comes from the 65535 "no return" code.
void expect_plausible_depth(const cv::Mat& depth, const std::string& what) {
  ASSERT_EQ(depth.type(), CV_32FC1) << what;
  double lo = 0.0, hi = 0.0;
  cv::minMaxLoc(depth, &lo, &hi, nullptr, nullptr, depth > 0.0f);
  EXPECT_GE(lo, 0.3) << what;
  EXPECT_LE(hi, 8.0) << what;
  EXPECT_GT(cv::countNonZero(depth > 0.0f), depth.total() / 2) << what;
}

TEST(SevenScenes, RedkitchenIndex) {
  FSLAM_REQUIRE_DATA("redkitchen");
  const auto dataset = open_or_fail(test::data_dir() / "redkitchen");
  ASSERT_TRUE(dataset);
  EXPECT_EQ(dataset->kind(), "7scenes");
  ASSERT_EQ(dataset->size(), 600u);
  const PinholeCamera& c = dataset->camera();
  EXPECT_DOUBLE_EQ(c.fx, 585.0);
  EXPECT_DOUBLE_EQ(c.fy, 585.0);
  EXPECT_DOUBLE_EQ(c.cx, 320.0);
  EXPECT_DOUBLE_EQ(c.cy, 240.0);
  EXPECT_EQ(c.width, 640);
  EXPECT_EQ(c.height, 480);
  EXPECT_DOUBLE_EQ(dataset->depth_scale(), 1000.0);
  EXPECT_EQ(dataset->id(0), 0);
  EXPECT_DOUBLE_EQ(dataset->timestamp(0), 0.0);
  EXPECT_EQ(dataset->id(599), 599);
  EXPECT_DOUBLE_EQ(dataset->timestamp(599), 599.0 / 30.0);
  EXPECT_FALSE(dataset->has_labels());

  ASSERT_TRUE(dataset->has_ground_truth());
  const Trajectory gt = dataset->ground_truth();
  ASSERT_EQ(gt.size(), 600u);
  double path = 0.0;
  for (std::size_t i = 0; i < gt.size(); ++i) {
    EXPECT_TRUE(is_finite(gt[i].T_world_camera)) << i;
    EXPECT_TRUE(is_rigid(gt[i].T_world_camera.matrix(), 1e-9)) << i;  // orthonormalised
    EXPECT_DOUBLE_EQ(gt[i].timestamp, static_cast<double>(i) / 30.0);
    if (i > 0) {
      const double step =
          (gt[i].T_world_camera.translation() - gt[i - 1].T_world_camera.translation()).norm();
      EXPECT_LT(step, 0.05) << "jump at frame " << i;  // hand-held: a few mm per frame
      path += step;
    }
  }
  EXPECT_GT(path, 3.0);  // 7.4 mm/frame on average (data README)
  EXPECT_LT(path, 6.0);
  // The orthonormalised pose is the file's matrix up to its rounding.
  Eigen::Matrix4d first;
  first << 9.093128999999999795e-01, 2.726222899999999894e-01, -3.142243299999999961e-01,
      -3.404563400000000239e-01, -2.724861800000000223e-01, 9.610497999999999541e-01,
      4.527962600000000337e-02, 1.646981800000000065e-02, 3.143392500000000145e-01,
      4.444964600000000238e-02, 9.482093499999999509e-01, 2.965691699999999931e-01, 0, 0, 0, 1;
  EXPECT_LT((gt[0].T_world_camera.matrix() - first).cwiseAbs().maxCoeff(), 1e-3);
}

TEST(SevenScenes, RedkitchenFramesAndInvalidDepth) {
  FSLAM_REQUIRE_DATA("redkitchen");
  const auto dataset = open_or_fail(test::data_dir() / "redkitchen");
  ASSERT_TRUE(dataset);
  // 33, 163 and 233 hold raw 65535 pixels; 0 and 599 are the ends.
  for (std::size_t index : {0u, 33u, 163u, 233u, 599u}) {
    RgbdFrame frame;
    std::string why;
    ASSERT_TRUE(dataset->load(index, &frame, &why)) << why;
    const std::string what = "frame " + std::to_string(index);
    EXPECT_EQ(frame.id, static_cast<std::int64_t>(index));
    EXPECT_DOUBLE_EQ(frame.timestamp, static_cast<double>(index) / 30.0);
    ASSERT_EQ(frame.colour.type(), CV_8UC3);
    EXPECT_EQ(frame.colour.size(), cv::Size(640, 480));
    EXPECT_EQ(frame.depth.size(), cv::Size(640, 480));
    ASSERT_TRUE(frame.T_world_camera_gt.has_value());
    EXPECT_TRUE(frame.T_world_camera_gt->isApprox(dataset->ground_truth()[index].T_world_camera));
    expect_plausible_depth(frame.depth, what);

    // Every 0 and 65535 pixel, and only those, is missing; the rest is raw / 1000.
    cv::Mat raw;
    ASSERT_TRUE(read_single_channel_image(
        (test::data_dir() / "redkitchen" / cv::format("frame-%06zu.depth.png", index)).string(),
        &raw, &why));
    int codes = 0;
    for (int v = 0; v < raw.rows; ++v)
      for (int u = 0; u < raw.cols; ++u) {
        const std::uint16_t r = raw.at<std::uint16_t>(v, u);
        const float d = frame.depth.at<float>(v, u);
        if (r == 0 || r == 65535) {
          ASSERT_EQ(d, 0.0f) << what << " at " << u << "," << v;
          codes += r == 65535;
        } else {
          ASSERT_FLOAT_EQ(d, static_cast<float>(r) / 1000.0f) << what;
        }
      }
    if (index == 33 || index == 163 || index == 233) {
      EXPECT_GT(codes, 0) << what;
    }
  }
}

TEST(SevenScenes, RedkitchenRangeAndStride) {
  FSLAM_REQUIRE_DATA("redkitchen");
  const auto all = open_or_fail(test::data_dir() / "redkitchen");
  DatasetOptions options;
  std::string why;
  ASSERT_TRUE(FrameSelection::parse("100:200:10", &options.frames, &why)) << why;
  const auto some = open_or_fail(test::data_dir() / "redkitchen", options);
  ASSERT_TRUE(all && some);
  ASSERT_EQ(some->size(), 10u);
  const Trajectory gt_all = all->ground_truth();
  const Trajectory gt = some->ground_truth();
  ASSERT_EQ(gt.size(), 10u);
  for (std::size_t k = 0; k < some->size(); ++k) {
    const std::size_t number = 100 + 10 * k;
    EXPECT_EQ(some->id(k), static_cast<std::int64_t>(number));
    EXPECT_DOUBLE_EQ(some->timestamp(k), static_cast<double>(number) / 30.0);
    EXPECT_DOUBLE_EQ(gt[k].timestamp, gt_all[number].timestamp);
    EXPECT_TRUE(gt[k].T_world_camera.isApprox(gt_all[number].T_world_camera, 1e-12));
  }
  RgbdFrame frame;
  ASSERT_TRUE(some->load(9, &frame, &why)) << why;
  EXPECT_EQ(frame.id, 190);
  EXPECT_FALSE(some->load(10, &frame, &why));
  EXPECT_NE(why.find("redkitchen"), std::string::npos) << why;
}

TEST(SevenScenes, Png50MatchesRedkitchen) {
  FSLAM_REQUIRE_DATA("redkitchen_png50");
  FSLAM_REQUIRE_DATA("redkitchen");
  const auto png = open_or_fail(test::data_dir() / "redkitchen_png50");
  const auto jpg = open_or_fail(test::data_dir() / "redkitchen");
  ASSERT_TRUE(png && jpg);
  EXPECT_EQ(png->kind(), "7scenes");
  ASSERT_EQ(png->size(), 50u);
  EXPECT_EQ(png->camera().width, 640);
  EXPECT_DOUBLE_EQ(png->camera().fx, 585.0);
  EXPECT_NE(png->camera_source().find("data/camera-intrinsics.txt"), std::string::npos);
  const Trajectory gt_png = png->ground_truth();
  const Trajectory gt_jpg = jpg->ground_truth();
  ASSERT_EQ(gt_png.size(), 50u);
  for (std::size_t k = 0; k < 50; ++k) {
    EXPECT_EQ(png->id(k), static_cast<std::int64_t>(150 + k));
    EXPECT_DOUBLE_EQ(png->timestamp(k), (150.0 + k) / 30.0);
    EXPECT_TRUE(gt_png[k].T_world_camera.isApprox(gt_jpg[150 + k].T_world_camera, 1e-12)) << k;
  }
  for (std::size_t k : {0u, 13u, 49u}) {  // 163 holds 65535 codes
    RgbdFrame a, b;
    std::string why;
    ASSERT_TRUE(png->load(k, &a, &why)) << why;
    ASSERT_TRUE(jpg->load(150 + k, &b, &why)) << why;
    EXPECT_EQ(a.id, b.id);
    EXPECT_EQ(cv::norm(a.depth, b.depth, cv::NORM_INF), 0.0) << k;
    EXPECT_TRUE(a.T_world_camera_gt->isApprox(*b.T_world_camera_gt, 1e-12));
    // Same pictures, one lossless and one JPEG.
    EXPECT_LT(cv::norm(a.colour, b.colour, cv::NORM_L1) / static_cast<double>(a.colour.total() * 3),
              8.0);
  }
}

// Loads every frame once, single-threaded, and prints the time per frame (opt-in:
// --gtest_also_run_disabled_tests --gtest_filter=SevenScenes.DISABLED_LoadAllRedkitchenFrames).
TEST(SevenScenes, DISABLED_LoadAllRedkitchenFrames) {
  FSLAM_REQUIRE_DATA("redkitchen");
  const auto start = std::chrono::steady_clock::now();
  const auto dataset = open_or_fail(test::data_dir() / "redkitchen");
  ASSERT_TRUE(dataset);
  const auto opened = std::chrono::steady_clock::now();
  double load_s = 0.0;
  for (std::size_t i = 0; i < dataset->size(); ++i) {
    RgbdFrame frame;
    std::string why;
    const auto t0 = std::chrono::steady_clock::now();
    ASSERT_TRUE(dataset->load(i, &frame, &why)) << why;
    load_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    expect_plausible_depth(frame.depth, "frame " + std::to_string(i));
  }
  const double open_ms = std::chrono::duration<double, std::milli>(opened - start).count();
  std::cout << "open " << open_ms << " ms, load " << 1e3 * load_s / dataset->size()
            << " ms/frame over " << dataset->size() << " frames\n";
}

// A three-frame flat 7-Scenes folder of 8x6 images the error tests damage one way each.
fs::path write_small_sequence(const std::string& name) {
  const fs::path dir = test::fresh_temp_dir(name);
  test::write_text(dir / "camera-intrinsics.txt", "5 0 3.5\n0 5 2.5\n0 0 1\n");
  for (int i = 0; i < 3; ++i) {
    const std::string stem = cv::format("frame-%06d", i);
    test::write_colour(dir / (stem + ".color.png"), 8, 6, 10 * i);
    test::write_depth(dir / (stem + ".depth.png"), 8, 6, static_cast<std::uint16_t>(1000 + i));
    test::write_text(dir / (stem + ".pose.txt"),
                     cv::format("1 0 0 %d\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", i));
  }
  return dir;
}

std::string open_error(const fs::path& dir, const DatasetOptions& options = {}) {
  std::string why;
  EXPECT_FALSE(open_dataset(dir.string(), options, &why)) << "opened " << dir;
  return why;
}

std::string load_error(const fs::path& dir, std::size_t index) {
  std::string why;
  const auto dataset = open_dataset(dir.string(), {}, &why);
  EXPECT_TRUE(dataset) << why;
  if (!dataset) return why;
  RgbdFrame frame;
  EXPECT_FALSE(dataset->load(index, &frame, &why)) << "loaded frame " << index << " of " << dir;
  return why;
}

TEST(SevenScenes, SmallSequenceReads) {
  const fs::path dir = write_small_sequence("ok");
  const auto dataset = open_or_fail(dir);
  ASSERT_TRUE(dataset);
  EXPECT_EQ(dataset->size(), 3u);
  EXPECT_EQ(dataset->camera().width, 8);
  RgbdFrame frame;
  std::string why;
  ASSERT_TRUE(dataset->load(2, &frame, &why)) << why;
  EXPECT_FLOAT_EQ(frame.depth.at<float>(3, 4), 1.002f);
  EXPECT_EQ(frame.colour.at<cv::Vec3b>(0, 0), cv::Vec3b(20, 21, 22));
  EXPECT_DOUBLE_EQ(frame.T_world_camera_gt->translation().x(), 2.0);
  cv::Mat instance;
  EXPECT_FALSE(dataset->load_labels(0, &instance, nullptr, &why));
}

TEST(SevenScenes, ColourCameraRegistersColourOntoTheDepthPixels) {
  const fs::path dir = write_small_sequence("colour_camera");
  // A 16x12 colour sensor with twice the depth camera's focal length, co-located: depth pixel u
  // sees colour pixel 2 (u - 3.5) + 7.5 = 2u + 0.5. Its red channel is 10 per colour pixel.
  cv::Mat rgb(12, 16, CV_8UC3);
  for (int v = 0; v < rgb.rows; ++v)
    for (int u = 0; u < rgb.cols; ++u) rgb.at<cv::Vec3b>(v, u) = cv::Vec3b(10 * u, 50, 50);
  std::string why;
  ASSERT_TRUE(write_image((dir / "frame-000001.color.png").string(), rgb, &why)) << why;
  DatasetOptions options;
  ASSERT_TRUE(ColourCamera::parse("10,10,7.5,5.5,0,0,0", &options.colour_camera.emplace(), &why))
      << why;
  const auto dataset = open_or_fail(dir, options);
  ASSERT_TRUE(dataset);
  RgbdFrame frame;
  ASSERT_TRUE(dataset->load(1, &frame, &why)) << why;
  ASSERT_EQ(frame.colour.size(), cv::Size(8, 6));  // the depth camera's pixels
  for (int u = 0; u < 7; ++u)
    EXPECT_NEAR(frame.colour.at<cv::Vec3b>(3, u)[0], 20 * u + 5, 1) << "pixel " << u;

  // A colour camera that states its size checks the images against it.
  ASSERT_TRUE(ColourCamera::parse("10,10,7.5,5.5,0,0,0", &options.colour_camera.emplace(), &why));
  options.colour_camera->camera.width = 20;
  options.colour_camera->camera.height = 12;
  const auto strict = open_or_fail(dir, options);
  ASSERT_TRUE(strict);
  EXPECT_FALSE(strict->load(1, &frame, &why));
  EXPECT_NAMES_FILE(why, "frame-000001.color.png");
}

TEST(SevenScenes, WithoutIntrinsicsFileUsesPublishedValues) {
  const fs::path dir = write_small_sequence("no_intrinsics");
  fs::remove(dir / "camera-intrinsics.txt");
  // 585/320/240 do not fit 8x6 images, so the explicit override must rescue it.
  std::string why = open_error(dir);
  EXPECT_NE(why.find("7-Scenes default intrinsics"), std::string::npos) << why;
  DatasetOptions options;
  options.intrinsics = PinholeCamera{4.0, 4.0, 3.5, 2.5, 0, 0};
  const auto dataset = open_or_fail(dir, options);
  ASSERT_TRUE(dataset);
  EXPECT_DOUBLE_EQ(dataset->camera().fx, 4.0);
  EXPECT_EQ(dataset->camera().height, 6);
}

TEST(SevenScenes, MissingFilesAreNamed) {
  fs::path dir = write_small_sequence("missing_colour");
  fs::remove(dir / "frame-000001.color.png");
  EXPECT_NAMES_FILE(open_error(dir), "frame-000001.color.png");

  dir = write_small_sequence("missing_pose");
  fs::remove(dir / "frame-000002.pose.txt");
  EXPECT_NAMES_FILE(open_error(dir), "frame-000002.pose.txt");

  dir = test::fresh_temp_dir("empty");
  EXPECT_NAMES_FILE(open_error(dir, DatasetOptions{"7scenes", {}, {}, {}}), dir.string());
}

TEST(SevenScenes, UnreadableAndMismatchedImagesAreNamed) {
  fs::path dir = write_small_sequence("garbage_colour");
  test::write_text(dir / "frame-000001.color.png", "not a png");
  EXPECT_NAMES_FILE(load_error(dir, 1), "frame-000001.color.png");

  dir = write_small_sequence("garbage_first_depth");  // probed when opening
  test::write_text(dir / "frame-000000.depth.png", "not a png");
  EXPECT_NAMES_FILE(open_error(dir), "frame-000000.depth.png");

  dir = write_small_sequence("depth_8bit");
  test::write_colour(dir / "frame-000002.depth.png", 8, 6, 1);
  const std::string why = load_error(dir, 2);
  EXPECT_NAMES_FILE(why, "frame-000002.depth.png");

  dir = write_small_sequence("depth_size");
  test::write_depth(dir / "frame-000002.depth.png", 4, 3, 1000);
  EXPECT_NAMES_FILE(load_error(dir, 2), "frame-000002.depth.png");

  dir = write_small_sequence("colour_size");
  test::write_colour(dir / "frame-000001.color.png", 8, 7, 1);
  EXPECT_NAMES_FILE(load_error(dir, 1), "frame-000001.color.png");
}

TEST(SevenScenes, BadIntrinsicsAreNamed) {
  fs::path dir = write_small_sequence("negative_focal");
  test::write_text(dir / "camera-intrinsics.txt", "-5 0 3.5\n0 5 2.5\n0 0 1\n");
  std::string why = open_error(dir);
  EXPECT_NAMES_FILE(why, "camera-intrinsics.txt");
  EXPECT_NE(why.find("bad intrinsics"), std::string::npos) << why;

  dir = write_small_sequence("short_matrix");
  test::write_text(dir / "camera-intrinsics.txt", "5 0 3.5\n0 5 2.5\n");
  EXPECT_NAMES_FILE(open_error(dir), "camera-intrinsics.txt");

  dir = write_small_sequence("skewed");
  test::write_text(dir / "camera-intrinsics.txt", "5 0.5 3.5\n0 5 2.5\n0 0 1\n");
  EXPECT_NAMES_FILE(open_error(dir), "camera-intrinsics.txt");

  dir = write_small_sequence("outside");
  test::write_text(dir / "camera-intrinsics.txt", "5 0 30\n0 5 2.5\n0 0 1\n");
  EXPECT_NAMES_FILE(open_error(dir), "camera-intrinsics.txt");
}

TEST(SevenScenes, BadPosesAreNamed) {
  fs::path dir = write_small_sequence("nan_pose");
  test::write_text(dir / "frame-000001.pose.txt", "1 0 0 nan\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
  std::string why = open_error(dir);
  EXPECT_NAMES_FILE(why, "frame-000001.pose.txt");
  EXPECT_NE(why.find("non-finite"), std::string::npos) << why;

  dir = write_small_sequence("scaled_pose");
  test::write_text(dir / "frame-000002.pose.txt", "2 0 0 0\n0 2 0 0\n0 0 2 0\n0 0 0 1\n");
  why = open_error(dir);
  EXPECT_NAMES_FILE(why, "frame-000002.pose.txt");
  EXPECT_NE(why.find("rigid"), std::string::npos) << why;

  dir = write_small_sequence("mirrored_pose");
  test::write_text(dir / "frame-000000.pose.txt", "-1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
  EXPECT_NAMES_FILE(open_error(dir), "frame-000000.pose.txt");

  dir = write_small_sequence("short_pose");
  test::write_text(dir / "frame-000000.pose.txt", "1 0 0 0\n0 1 0 0\n0 0 1 0\n");
  EXPECT_NAMES_FILE(open_error(dir), "frame-000000.pose.txt");
}

TEST(SevenScenes, BadSelectionNamesTheFolder) {
  const fs::path dir = write_small_sequence("selection");
  DatasetOptions options;
  std::string why;
  ASSERT_TRUE(FrameSelection::parse("3:", &options.frames, &why));
  why = open_error(dir, options);
  EXPECT_NAMES_FILE(why, dir.string());
  EXPECT_NE(why.find("3:"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::core

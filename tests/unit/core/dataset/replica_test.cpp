#include <filesystem>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "dataset_fixtures.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "fslam/core/geometry/se3.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

constexpr const char* kCamParams =
    R"({"camera": {"w": 8, "h": 6, "fx": 5.0, "fy": 5.5, "cx": 3.5, "cy": 2.5, "scale": 1000.0}})";

// Frame i's camera-to-world pose: a turn of 0.1 i rad about z and a step of i along x.
Eigen::Isometry3d replica_pose(int i) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(i, 0.5, -1.0);
  return T;
}

std::string traj_line(const Eigen::Matrix4d& M) {
  std::string line;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) line += cv::format("%.17g ", M(r, c));
  return line + "\n";
}

// Replica/cam_params.json and Replica/room0/{results/frameNNNNNN.jpg, depthNNNNNN.png, traj.txt}
// with 8x6 images; depth i holds 1000 + i raw units.
fs::path write_scene(const std::string& name, int frames = 3) {
  const fs::path parent = test::fresh_temp_dir(name);
  const fs::path scene = parent / "room0";
  test::write_text(parent / "cam_params.json", kCamParams);
  std::string traj;
  for (int i = 0; i < frames; ++i) {
    test::write_colour(scene / "results" / cv::format("frame%06d.jpg", i), 8, 6, 40 * i);
    test::write_depth(scene / "results" / cv::format("depth%06d.png", i), 8, 6,
                      static_cast<std::uint16_t>(1000 + i));
    traj += traj_line(replica_pose(i).matrix());
  }
  test::write_text(scene / "traj.txt", traj);
  return scene;
}

std::unique_ptr<Dataset> open_replica(const fs::path& dir, DatasetOptions options = {}) {
  std::string why;
  auto dataset = open_dataset(dir.string(), options, &why);
  EXPECT_TRUE(dataset) << why;
  return dataset;
}

std::string open_error(const fs::path& dir, DatasetOptions options = {}) {
  options.kind = "replica";
  std::string why;
  EXPECT_FALSE(open_dataset(dir.string(), options, &why)) << "opened " << dir;
  return why;
}

TEST(Replica, ReadsSceneWithParentCamParams) {
  const fs::path scene = write_scene("read");
  const auto dataset = open_replica(scene);
  ASSERT_TRUE(dataset);
  EXPECT_EQ(dataset->kind(), "replica");
  ASSERT_EQ(dataset->size(), 3u);
  EXPECT_DOUBLE_EQ(dataset->camera().fx, 5.0);
  EXPECT_DOUBLE_EQ(dataset->camera().fy, 5.5);
  EXPECT_DOUBLE_EQ(dataset->camera().cx, 3.5);
  EXPECT_DOUBLE_EQ(dataset->camera().cy, 2.5);
  EXPECT_EQ(dataset->camera().width, 8);
  EXPECT_EQ(dataset->camera().height, 6);
  EXPECT_DOUBLE_EQ(dataset->depth_scale(), 1000.0);
  EXPECT_NAMES_FILE(dataset->camera_source(), "cam_params.json");
  ASSERT_TRUE(dataset->has_ground_truth());
  for (int i = 0; i < 3; ++i) {
    RgbdFrame frame;
    std::string why;
    ASSERT_TRUE(dataset->load(i, &frame, &why)) << why;
    EXPECT_EQ(frame.id, i);
    EXPECT_DOUBLE_EQ(frame.timestamp, i / 30.0);
    EXPECT_FLOAT_EQ(frame.depth.at<float>(5, 7), (1000.0f + i) / 1000.0f);
    EXPECT_NEAR(frame.colour.at<cv::Vec3b>(3, 3)[0], 40 * i, 3);  // JPEG
    ASSERT_TRUE(frame.T_world_camera_gt);
    EXPECT_TRUE(frame.T_world_camera_gt->isApprox(replica_pose(i), 1e-12));
  }
}

TEST(Replica, CamParamsInSceneFolderWinsAndScaleIsOptional) {
  const fs::path scene = write_scene("scene_params");
  test::write_text(scene / "cam_params.json",
                   R"({"camera": {"w": 8, "h": 6, "fx": 7, "fy": 7, "cx": 4, "cy": 3}})");
  const auto dataset = open_replica(scene);
  ASSERT_TRUE(dataset);
  EXPECT_DOUBLE_EQ(dataset->camera().fx, 7.0);
  EXPECT_DOUBLE_EQ(dataset->depth_scale(), 6553.5);
}

TEST(Replica, DefaultsWithoutCamParams) {
  const fs::path scene = write_scene("defaults");
  fs::remove(scene.parent_path() / "cam_params.json");
  // The defaults describe 1200x680 renders; these 8x6 images are caught when opening.
  const std::string why = open_error(scene);
  EXPECT_NAMES_FILE(why, "depth000000.png");
  EXPECT_NE(why.find("1200x680"), std::string::npos) << why;
  DatasetOptions options;
  options.intrinsics = PinholeCamera{5.0, 5.0, 3.5, 2.5, 0, 0};
  const auto dataset = open_replica(scene, options);
  ASSERT_TRUE(dataset);
  EXPECT_DOUBLE_EQ(dataset->depth_scale(), 6553.5);
  EXPECT_EQ(dataset->camera().width, 8);
}

TEST(Replica, StrideAndTrajLongerThanImages) {
  const fs::path scene = write_scene("stride", 5);
  // Drop frames 0 and 1: frame numbers, not positions, pick the traj.txt line.
  fs::remove(scene / "results" / "frame000000.jpg");
  fs::remove(scene / "results" / "depth000000.png");
  fs::remove(scene / "results" / "frame000001.jpg");
  fs::remove(scene / "results" / "depth000001.png");
  DatasetOptions options;
  std::string why;
  ASSERT_TRUE(FrameSelection::parse("::2", &options.frames, &why));
  const auto dataset = open_replica(scene, options);
  ASSERT_TRUE(dataset);
  ASSERT_EQ(dataset->size(), 2u);  // numbers 2 and 4
  const Trajectory gt = dataset->ground_truth();
  ASSERT_EQ(gt.size(), 2u);
  EXPECT_EQ(dataset->id(1), 4);
  EXPECT_DOUBLE_EQ(gt[1].timestamp, 4.0 / 30.0);
  EXPECT_TRUE(gt[1].T_world_camera.isApprox(replica_pose(4), 1e-12));
}

TEST(Replica, MissingFilesAreNamed) {
  fs::path scene = write_scene("missing_colour");
  fs::remove(scene / "results" / "frame000001.jpg");
  EXPECT_NAMES_FILE(open_error(scene), "frame000001.jpg");

  scene = write_scene("short_traj");
  test::write_text(scene / "traj.txt", traj_line(Eigen::Matrix4d::Identity()));
  const std::string why = open_error(scene);
  EXPECT_NAMES_FILE(why, "traj.txt");
  EXPECT_NAMES_FILE(why, "depth000001.png");

  scene = test::fresh_temp_dir("no_results");
  EXPECT_NAMES_FILE(open_error(scene), "results");
}

TEST(Replica, UnreadableAndMismatchedImagesAreNamed) {
  fs::path scene = write_scene("garbage");
  test::write_text(scene / "results" / "depth000002.png", "not a png");
  auto dataset = open_replica(scene);
  ASSERT_TRUE(dataset);
  RgbdFrame frame;
  std::string why;
  EXPECT_FALSE(dataset->load(2, &frame, &why));
  EXPECT_NAMES_FILE(why, "depth000002.png");

  scene = write_scene("size");
  test::write_colour(scene / "results" / "frame000001.jpg", 16, 6, 0);
  dataset = open_replica(scene);
  ASSERT_TRUE(dataset);
  EXPECT_FALSE(dataset->load(1, &frame, &why));
  EXPECT_NAMES_FILE(why, "frame000001.jpg");
}

TEST(Replica, BadCamParamsAreNamed) {
  for (const std::string& text :
       {std::string("{\"camera\": {\"w\": 8, \"h\": 6, \"fx\": 5"),                 // truncated
        std::string(R"({"cam": {}})"),                                              // no camera
        std::string(R"({"camera": {"w": 8, "h": 6, "fy": 5, "cx": 3, "cy": 2}})"),  // no fx
        std::string(R"({"camera": {"w": 8, "h": 6, "fx": "x", "fy": 5, "cx": 3, "cy": 2}})"),
        std::string(R"({"camera": {"w": 8, "h": 6, "fx": -5, "fy": 5, "cx": 3, "cy": 2}})"),
        std::string(R"({"camera": {"w": 8.5, "h": 6, "fx": 5, "fy": 5, "cx": 3, "cy": 2}})"),
        std::string(
            R"({"camera": {"w": 8, "h": 6, "fx": 5, "fy": 5, "cx": 3, "cy": 2, "scale": 0}})")}) {
    const fs::path scene = write_scene("bad_params", 1);
    test::write_text(scene.parent_path() / "cam_params.json", text);
    EXPECT_NAMES_FILE(open_error(scene), "cam_params.json") << "for " << text;
  }
}

TEST(Replica, BadPosesAreNamed) {
  fs::path scene = write_scene("short_row");
  test::write_text(scene / "traj.txt", traj_line(replica_pose(0).matrix()) + "1 0 0 0 0 1 0 0\n" +
                                           traj_line(replica_pose(2).matrix()));
  EXPECT_NAMES_FILE(open_error(scene), "traj.txt:2");

  scene = write_scene("nan");
  test::write_text(scene / "traj.txt", traj_line(replica_pose(0).matrix()) +
                                           "1 0 0 nan 0 1 0 0 0 0 1 0 0 0 0 1\n" +
                                           traj_line(replica_pose(2).matrix()));
  std::string why = open_error(scene);
  EXPECT_NAMES_FILE(why, "traj.txt:2");
  EXPECT_NE(why.find("non-finite"), std::string::npos) << why;

  scene = write_scene("non_rigid");
  Eigen::Matrix4d sheared = replica_pose(1).matrix();
  sheared(0, 1) += 0.3;
  test::write_text(scene / "traj.txt", traj_line(replica_pose(0).matrix()) + traj_line(sheared) +
                                           traj_line(replica_pose(2).matrix()));
  why = open_error(scene);
  EXPECT_NAMES_FILE(why, "traj.txt:2");
  EXPECT_NE(why.find("rigid"), std::string::npos) << why;
}

TEST(Replica, BadSelectionNamesTheFolder) {
  const fs::path scene = write_scene("selection");
  DatasetOptions options;
  std::string why;
  ASSERT_TRUE(FrameSelection::parse("3:4", &options.frames, &why));
  EXPECT_NAMES_FILE(open_error(scene, options), scene.string());
}

}  // namespace
}  // namespace fslam::core

// Map folders (save / load / path rules) and the render result images the server sends.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>

#include <gtest/gtest.h>

#include "fslam/proto/types.h"
#include "fslam/server/map_files.hpp"
#include "fslam/server/render_images.hpp"
#include "test_support.hpp"

namespace fslam::server {
namespace {

StoredMap small_map() {
  auto map = std::make_shared<core::GaussianMap>();
  map->sh_degree = 1;
  map->feature_dim = 4;
  for (int i = 0; i < 5; ++i) {
    const float mean[3] = {0.1f * i, -0.2f, 1.5f + 0.01f * i};
    const float rotation[4] = {0.9f, 0.1f, -0.2f, 0.05f * i};
    const float log_scale[3] = {-4.f, -4.5f, -6.f};
    const float sh[12] = {0.1f, 0.2f, 0.3f, 0.01f * i, 0, 0, 0, 0, 0, 0, 0, -0.02f};
    const float feat[4] = {0.5f, -0.5f, 0.25f * i, 1.f};
    map->push_back(mean, rotation, log_scale, 0.3f * i - 1.f, sh, feat, 1e-6f * i);
  }
  StoredMap stored;
  stored.gaussians = map;
  stored.camera = {525.0, 525.0, 319.5, 239.5, 640, 480};
  for (int i = 0; i < 3; ++i) {
    FramePose p;
    p.frame_id = 10 + 7 * static_cast<std::uint64_t>(i);
    p.timestamp = 1305031102.175304 + 0.033 * i;
    p.T_world_camera.linear() =
        Eigen::AngleAxisd(0.3 * i + 0.123456789, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    p.T_world_camera.translation() = Eigen::Vector3d(1.0 / 3.0, -2.0 * i, 0.1);
    stored.poses.push_back(p);
  }
  return stored;
}

TEST(MapFiles, SaveThenLoadGivesTheSameMapPosesAndCamera) {
  const auto dir = test::fresh_temp_dir("maps") / "room";
  const StoredMap saved = small_map();
  std::string why;
  ASSERT_TRUE(save_map_folder(dir.string(), saved, &why)) << why;
  EXPECT_TRUE(is_map_folder(dir.string()));
  EXPECT_FALSE(std::filesystem::exists(dir.string() + ".saving"));
  StoredMap loaded;
  ASSERT_TRUE(load_map_folder(dir.string(), &loaded, &why)) << why;
  const core::GaussianMap &a = *saved.gaussians, &b = *loaded.gaussians;
  EXPECT_EQ(a.means, b.means);
  EXPECT_EQ(a.log_scales, b.log_scales);
  EXPECT_EQ(a.opacity_logits, b.opacity_logits);
  EXPECT_EQ(a.sh, b.sh);
  EXPECT_EQ(a.features, b.features);
  EXPECT_EQ(a.filter_3d, b.filter_3d);
  EXPECT_EQ(loaded.camera.fx, saved.camera.fx);
  EXPECT_EQ(loaded.camera.width, 640);
  ASSERT_EQ(loaded.poses.size(), saved.poses.size());
  for (std::size_t i = 0; i < saved.poses.size(); ++i) {
    EXPECT_EQ(loaded.poses[i].frame_id, saved.poses[i].frame_id);
    EXPECT_EQ(loaded.poses[i].timestamp, saved.poses[i].timestamp);  // %.17g: exact
    EXPECT_LT((loaded.poses[i].T_world_camera.matrix() - saved.poses[i].T_world_camera.matrix())
                  .cwiseAbs().maxCoeff(), 1e-15);
  }
  // Saving again replaces the folder whole.
  StoredMap smaller = saved;
  smaller.poses.resize(1);
  ASSERT_TRUE(save_map_folder(dir.string(), smaller, &why)) << why;
  ASSERT_TRUE(load_map_folder(dir.string(), &loaded, &why)) << why;
  EXPECT_EQ(loaded.poses.size(), 1u);
  EXPECT_FALSE(std::filesystem::exists(dir.string() + ".old"));
}

TEST(MapFiles, BadFoldersAreClearErrors) {
  const auto dir = test::fresh_temp_dir("bad");
  StoredMap loaded;
  std::string why;
  EXPECT_FALSE(load_map_folder((dir / "missing").string(), &loaded, &why));
  EXPECT_NE(why.find("map.ply"), std::string::npos) << why;
  ASSERT_TRUE(save_map_folder((dir / "m").string(), small_map(), &why)) << why;
  std::ofstream(dir / "m" / "poses.txt") << "3 0.5 1 2 3 0 0 0 2\n";  // not a unit quaternion
  EXPECT_FALSE(load_map_folder((dir / "m").string(), &loaded, &why));
  EXPECT_NE(why.find("line 1"), std::string::npos) << why;
  std::ofstream(dir / "m" / "poses.txt") << "3 0.5 1 2\n";
  EXPECT_FALSE(load_map_folder((dir / "m").string(), &loaded, &why));
  std::ofstream(dir / "m" / "camera.txt") << "525 525 319.5\n";
  EXPECT_FALSE(load_map_folder((dir / "m").string(), &loaded, &why));
  EXPECT_NE(why.find("camera.txt"), std::string::npos) << why;
}

TEST(MapFiles, RequestedFoldersStayUnderMapDir) {
  std::string folder, why;
  ASSERT_TRUE(resolve_map_folder("/srv/maps", "", "kitchen", &folder, &why)) << why;
  EXPECT_EQ(folder, "/srv/maps/kitchen");
  ASSERT_TRUE(resolve_map_folder("/srv/maps", "archive/monday", "kitchen", &folder, &why)) << why;
  EXPECT_EQ(folder, "/srv/maps/archive/monday");
  EXPECT_FALSE(resolve_map_folder("/srv/maps", "../etc", "kitchen", &folder, &why));
  EXPECT_FALSE(resolve_map_folder("/srv/maps", "a/../../b", "kitchen", &folder, &why));
  EXPECT_FALSE(resolve_map_folder("/srv/maps", "/etc", "kitchen", &folder, &why));
  EXPECT_FALSE(resolve_map_folder("/srv/maps", "", "..", &folder, &why));
  EXPECT_FALSE(resolve_map_folder("", "x", "kitchen", &folder, &why));
  EXPECT_NE(why.find("map_dir"), std::string::npos) << why;
}

TEST(RenderChannels, DepthIsNormalisedByOpacityInDepthScaleUnits) {
  core::RenderResult r;
  r.colour = core::PlanarImage(2, 1, 3, 0.5f);
  r.depth = core::PlanarImage(2, 1, 1);
  r.alpha = core::PlanarImage(2, 1, 1);
  r.median_depth = core::PlanarImage(2, 1, 1, 2.0f);
  r.depth.at(0, 0, 0) = 0.8f * 2.5f;  // 80 % opaque at 2.5 m
  r.alpha.at(0, 0, 0) = 0.8f;
  r.depth.at(0, 0, 1) = 0.3f * 1.0f;  // too transparent to claim a depth
  r.alpha.at(0, 0, 1) = 0.3f;
  const core::PinholeCamera camera{2.0, 2.0, 0.5, 0.0, 2, 1};
  const auto images = render_channels(r, camera, fslam_proto_CHANNEL_DEPTH | fslam_proto_CHANNEL_COLOUR |
                                                     fslam_proto_CHANNEL_OPACITY, 5000.0f);
  ASSERT_EQ(images.size(), 3u);
  EXPECT_EQ(images[0].channel, fslam_proto_CHANNEL_COLOUR);
  EXPECT_EQ(images[0].image.type(), CV_8UC3);
  ASSERT_EQ(images[1].channel, fslam_proto_CHANNEL_DEPTH);
  ASSERT_EQ(images[1].image.type(), CV_16UC1);
  EXPECT_EQ(images[1].image.at<std::uint16_t>(0, 0), 12500);  // 2.5 m at 5000 per metre
  EXPECT_EQ(images[1].image.at<std::uint16_t>(0, 1), 0);
  EXPECT_EQ(images[2].image.at<std::uint8_t>(0, 0), 204);     // 0.8 * 255
  std::vector<std::uint8_t> png;
  EXPECT_TRUE(encode_png(images[1].image, &png));
  EXPECT_GT(png.size(), 8u);
}

}  // namespace
}  // namespace fslam::server

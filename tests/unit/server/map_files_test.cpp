// Map folders (save / load / path rules) and the render result images the server sends.
#include <sched.h>
#include <sys/mount.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "fslam/proto/types.h"
#include "fslam/server/map_files.hpp"
#include "fslam/server/wire.hpp"
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
  EXPECT_FALSE(std::filesystem::exists(dir.parent_path() / ".room.saving"));
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
  EXPECT_FALSE(std::filesystem::exists(dir.parent_path() / ".room.old"));
}

// The online heads (heads.fae) go with the map: saved bit for bit, absent when the map has none,
// and a damaged file is the load's clear error.
TEST(MapFiles, OnlineFeatureHeadsAreSavedAndLoadedWithTheMap) {
  namespace fs = std::filesystem;
  const auto dir = test::fresh_temp_dir("heads") / "room";
  core::FeatureAutoencoderConfig config;
  config.level_channels = {6, 4};
  config.latent_dim = 4;
  config.encoder_hidden = 8;
  config.head_hidden = 8;
  auto heads = std::make_shared<core::FeatureAutoencoder>(config);
  for (int i = 0; i < static_cast<int>(heads->tensors().size()); ++i)  // LoRA as online mapping left it
    if (heads->tensors()[i].lora)
      for (std::size_t k = 0; k < heads->tensors()[i].size(); ++k) heads->tensor_data(i)[k] = 0.01f * (k % 7) - 0.03f;
  StoredMap saved = small_map();
  std::string why;
  ASSERT_TRUE(save_map_folder(dir.string(), saved, &why)) << why;  // mapped without the decoded L_feat
  EXPECT_FALSE(fs::exists(dir / "heads.fae"));
  StoredMap loaded;
  ASSERT_TRUE(load_map_folder(dir.string(), &loaded, &why)) << why;
  EXPECT_EQ(loaded.heads, nullptr);

  saved.heads = heads;
  ASSERT_TRUE(save_map_folder(dir.string(), saved, &why)) << why;
  ASSERT_TRUE(load_map_folder(dir.string(), &loaded, &why)) << why;
  ASSERT_NE(loaded.heads, nullptr);
  EXPECT_EQ(loaded.heads->parameters(), heads->parameters());
  EXPECT_TRUE(loaded.heads->same_body(*heads));

  fs::resize_file(dir / "heads.fae", fs::file_size(dir / "heads.fae") - 3);
  EXPECT_FALSE(load_map_folder(dir.string(), &loaded, &why));
  EXPECT_NE(why.find("load map: "), std::string::npos) << why;
  EXPECT_NE(why.find("heads.fae"), std::string::npos) << why;
  EXPECT_NE(why.find("truncated"), std::string::npos) << why;
}

// A save killed at any point leaves a whole version that recover_map_folder (run by the server
// at start and before each save) puts back in place: the states each step of the swap leaves.
TEST(MapFiles, AnInterruptedSaveRecoversAWholeVersion) {
  namespace fs = std::filesystem;
  const auto root = test::fresh_temp_dir("interrupted");
  const fs::path dir = root / "m", staging = root / ".m.saving", old = root / ".m.old";
  StoredMap v1 = small_map(), v2 = small_map();
  v2.poses.resize(1);
  std::string why, note;
  auto poses_in = [&](const fs::path& d) {
    StoredMap loaded;
    return load_map_folder(d.string(), &loaded, &why) ? loaded.poses.size() : std::size_t{0};
  };
  // Killed after the old version moved aside, before the new one moved in: the new one wins.
  ASSERT_TRUE(save_map_folder(staging.string(), v2, &why)) << why;  // a complete staging folder
  std::ofstream(staging / ".complete").close();
  ASSERT_TRUE(save_map_folder(old.string(), v1, &why)) << why;
  ASSERT_TRUE(recover_map_folder(dir.string(), &note));
  EXPECT_NE(note.find("interrupted save"), std::string::npos) << note;
  EXPECT_EQ(poses_in(dir), 1u);
  EXPECT_FALSE(fs::exists(staging));
  EXPECT_FALSE(fs::exists(old));
  // Killed while writing the new version, with the old one aside: the old one comes back.
  fs::remove_all(dir);
  ASSERT_TRUE(save_map_folder(old.string(), v1, &why)) << why;
  fs::create_directories(staging);
  std::ofstream(staging / "map.ply") << "ply\nformat ascii 1.0\n";  // half written, no marker
  ASSERT_TRUE(recover_map_folder(dir.string(), &note));
  EXPECT_NE(note.find("previous version"), std::string::npos) << note;
  EXPECT_EQ(poses_in(dir), 3u);
  EXPECT_FALSE(fs::exists(staging));
  // Killed before the swap, or after it: the map in place stays, the leftovers go.
  fs::create_directories(staging);
  ASSERT_TRUE(save_map_folder(old.string(), v2, &why)) << why;
  ASSERT_TRUE(recover_map_folder(dir.string(), &note));
  EXPECT_NE(note.find("leftovers"), std::string::npos) << note;
  EXPECT_EQ(poses_in(dir), 3u);
  EXPECT_FALSE(fs::exists(staging));
  EXPECT_FALSE(fs::exists(old));
  // Nothing to recover from: no map, and a clear false.
  EXPECT_FALSE(recover_map_folder((root / "never").string(), &note));
}

// A full disk: the save fails saying so, the previous version stays whole and nothing is left
// behind. The disk is a 256 KiB tmpfs in a mount namespace of this test process's own.
TEST(MapFiles, AFullDiskIsAClearErrorAndKeepsThePreviousVersion) {
  namespace fs = std::filesystem;
  const fs::path root = test::fresh_temp_dir("fulldisk") / "disk";
  fs::create_directories(root);
  if (geteuid() != 0 || unshare(CLONE_NEWNS) != 0 || mount("none", "/", nullptr, MS_REC | MS_PRIVATE, nullptr) != 0 ||
      mount("fslam-test", root.c_str(), "tmpfs", 0, "size=256k") != 0) {
    GTEST_SKIP() << "needs root and a private mount namespace for a small tmpfs: " << std::strerror(errno);
  }
  StoredMap big = small_map();
  auto gaussians = std::make_shared<core::GaussianMap>(*big.gaussians);
  while (gaussians->size() < 8000) gaussians->append(*big.gaussians);  // ~1 MB of PLY
  big.gaussians = gaussians;
  std::string why;
  ASSERT_TRUE(save_map_folder((root / "m").string(), small_map(), &why)) << why;
  EXPECT_FALSE(save_map_folder((root / "m").string(), big, &why));
  EXPECT_NE(why.find("No space left on device"), std::string::npos) << why;
  EXPECT_NE(why.find("map.ply"), std::string::npos) << why;
  StoredMap loaded;
  ASSERT_TRUE(load_map_folder((root / "m").string(), &loaded, &why)) << why;
  EXPECT_EQ(loaded.gaussians->means, small_map().gaussians->means);
  EXPECT_EQ(loaded.poses.size(), 3u);
  EXPECT_FALSE(save_map_folder((root / "n").string(), big, &why));
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(root)) names.push_back(entry.path().filename().string());
  EXPECT_EQ(names, std::vector<std::string>{"m"}) << "a failed save left files behind";
  EXPECT_EQ(umount(root.c_str()), 0) << std::strerror(errno);
}

TEST(MapFiles, SavingAMapLeavesTheUsersOtherFoldersAlone) {
  namespace fs = std::filesystem;
  const auto root = test::fresh_temp_dir("neighbours");
  std::string why;
  // Folders (even maps) named like the old staging names belong to someone else.
  ASSERT_TRUE(save_map_folder((root / "m.old").string(), small_map(), &why)) << why;
  ASSERT_TRUE(save_map_folder((root / "m.saving").string(), small_map(), &why)) << why;
  ASSERT_TRUE(save_map_folder((root / "m").string(), small_map(), &why)) << why;
  ASSERT_TRUE(save_map_folder((root / "m").string(), small_map(), &why)) << why;
  EXPECT_TRUE(is_map_folder((root / "m.old").string()));
  EXPECT_TRUE(is_map_folder((root / "m.saving").string()));
}

TEST(MapFiles, MapNamesAreFolderNames) {
  std::string why;
  EXPECT_TRUE(valid_map_name("kitchen-2_v1.0", &why)) << why;
  const std::vector<std::string> bad_names = {"", "../x", "a/b", ".hidden", "sp ace", std::string(129, 'a'),
                                              std::string("nul\0", 4)};
  for (const std::string& bad : bad_names) {
    EXPECT_FALSE(valid_map_name(bad, &why)) << "'" << bad << "'";
    EXPECT_FALSE(why.empty());
  }
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

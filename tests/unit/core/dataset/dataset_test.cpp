#include <filesystem>

#include <gtest/gtest.h>

#include "dataset_fixtures.hpp"
#include "fslam/core/dataset/dataset.hpp"
#include "test_support.hpp"

namespace fslam::core {
namespace {

namespace fs = std::filesystem;

std::string detect(const fs::path& dir) {
  std::string kind, why;
  EXPECT_TRUE(detect_dataset_kind(dir.string(), &kind, &why)) << why;
  return kind;
}

TEST(Dataset, DetectsEachLayoutFromItsFiles) {
  const fs::path root = test::fresh_temp_dir("layouts");
  test::write_text(root / "tum" / "rgb.txt", "");
  test::write_text(root / "tum" / "depth.txt", "");
  test::write_text(root / "flat" / "frame-000000.depth.png", "");
  test::write_text(root / "nested" / "data" / "rgbd-frames" / "frame-000150.depth.png", "");
  test::write_text(root / "room0" / "results" / "depth000000.png", "");
  EXPECT_EQ(detect(root / "tum"), "tum");
  EXPECT_EQ(detect(root / "flat"), "7scenes");
  EXPECT_EQ(detect(root / "nested"), "7scenes");
  EXPECT_EQ(detect(root / "room0"), "replica");
}

TEST(Dataset, DetectsTheSharedData) {
  FSLAM_REQUIRE_DATA("redkitchen_png50");
  EXPECT_EQ(detect(test::data_dir() / "redkitchen_png50"), "7scenes");
  EXPECT_EQ(detect(test::data_dir() / "redkitchen_png50/"), "7scenes");
}

TEST(Dataset, UndetectableFolderSaysWhatItLookedFor) {
  const fs::path dir = test::fresh_temp_dir("nothing");
  test::write_text(dir / "readme.txt", "hello");
  std::string why;
  EXPECT_FALSE(open_dataset(dir.string(), {}, &why));
  EXPECT_NAMES_FILE(why, dir.string());
  EXPECT_NE(why.find("rgb.txt"), std::string::npos) << why;
  EXPECT_NE(why.find("frame-NNNNNN.depth.png"), std::string::npos) << why;
  EXPECT_NE(why.find("depthNNNNNN.png"), std::string::npos) << why;
}

TEST(Dataset, MissingFolderAndUnknownKind) {
  const fs::path dir = test::fresh_temp_dir("missing");
  std::string why;
  EXPECT_FALSE(open_dataset((dir / "nope").string(), {}, &why));
  EXPECT_NAMES_FILE(why, "nope");
  EXPECT_FALSE(open_dataset((dir / "nope").string(), DatasetOptions{"tum", {}, {}, {}}, &why));
  EXPECT_NAMES_FILE(why, "nope");
  test::write_text(dir / "file", "x");
  EXPECT_FALSE(open_dataset((dir / "file").string(), {}, &why));
  EXPECT_NE(why.find("not a folder"), std::string::npos) << why;
  EXPECT_FALSE(open_dataset(dir.string(), DatasetOptions{"scannet", {}, {}, {}}, &why));
  EXPECT_NE(why.find("scannet"), std::string::npos) << why;
  EXPECT_EQ(dataset_kinds(), (std::vector<std::string>{"tum", "7scenes", "replica"}));
}

}  // namespace
}  // namespace fslam::core

// REQUEST_MAP_GAUSSIANS end to end over loopback DDS: the real fslam-server serving a constructed
// map (the three panels of tests/common/panel_scene.hpp) and the client library reading it in
// chunks, as fslam-gateway does for the browser viewer (docs/viewer.md).
#include <unistd.h>

#include <cmath>
#include <string>

#include <gtest/gtest.h>

#include "cli_runner.hpp"
#include "fslam/client/client.hpp"
#include "fslam/server/map_files.hpp"
#include "panel_scene.hpp"

namespace fslam {
namespace {

TEST(MapExport, AServedMapIsReadInChunksOfOneVersion) {
  test::use_loopback_dds();
  const std::string dir = test::fresh_temp_dir("export").string();
  const std::string prefix = "export" + std::to_string(getpid());
  server::StoredMap stored;
  stored.gaussians = std::make_shared<core::GaussianMap>(test::panel_map());
  stored.camera = test::kPanelCamera;
  std::string why;
  ASSERT_TRUE(server::save_map_folder(dir + "/maps/panels", stored, &why)) << why;
  test::ScopedServer server("--prefix " + prefix + " --map-dir " + dir + "/maps", dir + "/server.log");
  ASSERT_GT(server.pid(), 0);
  const core::GaussianMap& map = *stored.gaussians;
  ASSERT_GT(map.size(), 1000u) << "the panels should need several chunks of 500";

  client::ClientOptions options;
  options.prefix = prefix;
  client::Client c(options);
  client::MapGaussians got;
  ASSERT_TRUE(c.map_gaussians({"panels", 0, 500}, &got, 30000, &why)) << why;
  EXPECT_FALSE(got.unchanged);
  EXPECT_EQ(got.version, 1u);
  ASSERT_EQ(got.count, map.size());
  ASSERT_EQ(got.records.size(), map.size() * client::kGaussianRecordBytes);
  EXPECT_EQ(got.requests, (map.size() + 499) / 500);
  // Every record is its Gaussian, in the map's order (means exact, scales to float precision).
  for (std::size_t i = 0; i < map.size(); i += 97) {
    const client::GaussianRecord g = client::unpack_gaussian(&got.records[i * client::kGaussianRecordBytes]);
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(g.mean[k], map.means[3 * i + k]) << "Gaussian " << i;
      EXPECT_NEAR(g.scale[k], std::exp(map.log_scales[3 * i + k]), 1e-6) << "Gaussian " << i;
    }
  }
  // Asked again since that version: nothing to send.
  client::MapGaussians again;
  ASSERT_TRUE(c.map_gaussians({"panels", got.version, 0}, &again, 30000, &why)) << why;
  EXPECT_TRUE(again.unchanged);
  EXPECT_EQ(again.version, got.version);
  EXPECT_TRUE(again.records.empty());
  EXPECT_EQ(again.requests, 1u);
  // An unknown map is an error result that says so.
  EXPECT_FALSE(c.map_gaussians({"nowhere", 0, 0}, &again, 30000, &why));
  EXPECT_NE(why.find("no map named 'nowhere'"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam

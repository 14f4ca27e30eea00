// Segmentation queries end to end over loopback DDS: the real fslam-server serving a map whose
// objects are known, the client library and `fslam segment`. The pipeline does not distil
// features yet, so the featured map is constructed (as in core's segmentation test: two touching
// panels with different latents and a third with the first one's latent but apart in space) and
// saved as a map folder that the server loads at start.
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "cli_runner.hpp"
#include "panel_scene.hpp"
#include "fslam/client/client.hpp"
#include "fslam/core/eval/image_metrics.hpp"
#include "fslam/core/io/image_io.hpp"
#include "fslam/server/map_files.hpp"
#include "grounding_model.hpp"

namespace fslam {
namespace {

using test::fslam_bin;
using test::run_command;

constexpr int kD = test::kPanelFeatureDim;
const core::PinholeCamera kCamera = test::kPanelCamera;

// The three panels (tests/common/panel_scene.hpp), saved with the camera and one tracked pose
// (frame 0 at the origin).
bool write_panels(const std::string& folder, int feature_dim, std::string* why) {
  server::StoredMap stored;
  stored.gaussians = std::make_shared<core::GaussianMap>(test::panel_map(feature_dim));
  stored.camera = kCamera;
  stored.poses.push_back({0, 0.0, Eigen::Isometry3d::Identity()});
  return server::save_map_folder(folder, stored, why);
}

cv::Mat truth(int shift = 0) { return test::panel_truth(shift); }

cv::Mat mask_of(const client::SegmentOutput& out) {
  EXPECT_EQ(out.labels.bytes_per_channel, 1);
  return cv::Mat(static_cast<int>(out.labels.height), static_cast<int>(out.labels.width), CV_8UC1,
                 const_cast<std::uint8_t*>(out.labels.pixels.data()))
      .clone();
}

class Segment : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    test::use_loopback_dds();  // inherited by every process started below
    dir_ = test::fresh_temp_dir("segment").string();
    prefix_ = "seg" + std::to_string(getpid());
    if (!write_panels(dir_ + "/maps/panels", kD, &setup_why_) ||
        !write_panels(dir_ + "/maps/plain", 0, &setup_why_)) {
      return;
    }
    server_pid_ = test::start_server("--prefix " + prefix_ + " --map-dir " + dir_ + "/maps",
                                     dir_ + "/server.log");
  }
  static void TearDownTestSuite() { test::stop_process(server_pid_); }
  void SetUp() override {
    ASSERT_TRUE(setup_why_.empty()) << setup_why_;
    ASSERT_GT(server_pid_, 0) << "fslam-server did not start";
  }
  static client::ClientOptions options(const std::string& prefix = prefix_) {
    client::ClientOptions o;
    o.prefix = prefix;
    return o;
  }
  static client::SegmentQuery query(client::SegmentMode mode) {
    client::SegmentQuery q;
    q.map_name = "panels";
    q.mode = mode;
    q.view.from_frame = true;  // frame 0: the origin, the map's own camera
    return q;
  }
  static std::string dir_, prefix_, setup_why_;
  static pid_t server_pid_;
};
std::string Segment::dir_, Segment::prefix_, Segment::setup_why_;
pid_t Segment::server_pid_ = -1;

// Without a prompt: the three panels are three instances, and asking again gives the same ids.
TEST_F(Segment, PromptlessFindsThePanelsWithStableIds) {
  client::Client c(options());
  std::string why;
  client::SegmentOutput first, second;
  ASSERT_TRUE(c.segment(query(client::SegmentMode::promptless), &first, 20000, &why)) << why;
  ASSERT_EQ(first.labels.width, 160u);
  ASSERT_EQ(first.labels.height, 120u);
  ASSERT_EQ(first.labels.bytes_per_channel, 2);
  EXPECT_EQ(first.colour.width, 160u);
  EXPECT_EQ(first.colour.channels, 3);
  EXPECT_EQ(first.intrinsics.width, 160u);
  const cv::Mat ids(120, 160, CV_16UC1, first.labels.pixels.data());
  cv::Mat predicted;  // ids + 1 on the wire, -1 = none for the confusion
  ids.convertTo(predicted, CV_32SC1, 1.0, -1.0);
  core::InstanceOverlap overlap;
  core::InstanceMatchConfig match;
  match.predicted_none = -1;
  ASSERT_TRUE(core::accumulate_instance_overlap(predicted, truth(), match, &overlap, &why)) << why;
  const core::InstanceMatchResult score = core::match_instances(overlap);
  ASSERT_EQ(score.iou.size(), 3u);
  for (const auto& [id, iou] : score.iou) EXPECT_GT(iou, 0.9) << "panel " << id;
  std::set<int> instances(predicted.begin<int>(), predicted.end<int>());
  instances.erase(-1);
  EXPECT_EQ(instances.size(), 3u);

  ASSERT_TRUE(c.segment(query(client::SegmentMode::promptless), &second, 20000, &why)) << why;
  EXPECT_EQ(second.labels.pixels, first.labels.pixels) << "ids must be stable between requests";
  EXPECT_EQ(second.map_version, first.map_version);
}

// A point on the left panel selects it alone, in the prompt view and from another pose.
TEST_F(Segment, PointPromptMasksItsPanelFromAnyPose) {
  client::Client c(options());
  std::string why;
  client::SegmentQuery q = query(client::SegmentMode::points);
  q.points = {50.0f, 60.0f};
  client::SegmentOutput out;
  ASSERT_TRUE(c.segment(q, &out, 20000, &why)) << why;
  const cv::Mat mask = mask_of(out);
  EXPECT_GT(core::mask_iou(mask, truth(), 1), 0.9) << cv::countNonZero(mask) << " px";
  EXPECT_LT(core::mask_iou(mask, truth(), 3), 0.01) << "the far panel shares the latent, not the surface";

  // The same prompt, the mask rendered from 10 cm to the right: the panel moves 10 px left.
  q.has_output_view = true;
  q.output_view.translation[0] = 0.1;
  ASSERT_TRUE(c.segment(q, &out, 20000, &why)) << why;
  EXPECT_NEAR(out.translation[0], 0.1, 1e-9);
  EXPECT_GT(core::mask_iou(mask_of(out), truth(10), 1), 0.9);
}

// A box inside the right panel selects it; two boxes select the union of their panels.
TEST_F(Segment, BoxPromptsMaskTheirPanels) {
  client::Client c(options());
  std::string why;
  client::SegmentQuery q = query(client::SegmentMode::boxes);
  q.boxes = {84, 35, 126, 85};
  client::SegmentOutput out;
  ASSERT_TRUE(c.segment(q, &out, 20000, &why)) << why;
  cv::Mat mask = mask_of(out);
  EXPECT_GT(core::mask_iou(mask, truth(), 2), 0.9);
  EXPECT_LT(core::mask_iou(mask, truth(), 1), 0.01);

  q.boxes = {84, 35, 126, 85, 35, 35, 75, 85};
  ASSERT_TRUE(c.segment(q, &out, 20000, &why)) << why;
  mask = mask_of(out);
  cv::Mat both = (truth() == 1) | (truth() == 2);
  both.convertTo(both, CV_32SC1, 1.0 / 255.0);
  EXPECT_GT(core::mask_iou(mask, both, 1), 0.9);
}

// Every bad query gets an error result that says what is wrong.
TEST_F(Segment, BadQueriesGetClearErrors) {
  client::Client c(options());
  client::SegmentOutput out;
  auto error_of = [&](const client::SegmentQuery& q) {
    std::string why;
    EXPECT_FALSE(c.segment(q, &out, 20000, &why));
    return why;
  };
  client::SegmentQuery q = query(client::SegmentMode::text);
  q.text = "the left panel";
  EXPECT_NE(error_of(q).find("text queries need a grounding detector: set server.grounding_model to "
                             "an ONNX model (docs/segmentation.md)"),
            std::string::npos);
  q.text = "  ";
  EXPECT_NE(error_of(q).find("needs a text"), std::string::npos);

  q = query(client::SegmentMode::points);
  EXPECT_NE(error_of(q).find("needs at least one point"), std::string::npos);
  q.points = {50, 60, 70};
  EXPECT_NE(error_of(q).find("odd number"), std::string::npos);
  q.points = {50, 60, 170, 60};
  EXPECT_NE(error_of(q).find("(170, 60) lies outside the 160x120 view"), std::string::npos);
  q.points = {5, 5};  // inside the view, on no surface
  EXPECT_NE(error_of(q).find("hits no surface"), std::string::npos);

  q = query(client::SegmentMode::boxes);
  EXPECT_NE(error_of(q).find("needs at least one box"), std::string::npos);
  q.boxes = {80, 35, 60, 85};
  EXPECT_NE(error_of(q).find("needs u1 > u0"), std::string::npos);
  q.boxes = {84, 35, 126};
  EXPECT_NE(error_of(q).find("quadruples"), std::string::npos);
  q.boxes = {100, 35, 180, 85};
  EXPECT_NE(error_of(q).find("reaches outside the 160x120 view"), std::string::npos);

  q = query(client::SegmentMode::promptless);
  q.map_name = "no-such-map";
  EXPECT_NE(error_of(q).find("no map named 'no-such-map'"), std::string::npos);
  q.map_name = "plain";
  EXPECT_NE(error_of(q).find("the map carries no features; stream with features on"), std::string::npos);
  q = query(client::SegmentMode::promptless);
  q.view.frame_id = 7;
  EXPECT_NE(error_of(q).find("no tracked pose for frame 7"), std::string::npos);
}

// `fslam segment` writes the mask (or the instances and their ids) and the overlay.
TEST_F(Segment, CommandWritesMaskIdsAndOverlay) {
  std::string out, err;
  const std::string common = fslam_bin() + " segment --map panels --prefix " + prefix_ + " --timeout 20 ";
  ASSERT_EQ(run_command(common + "--pose 0,0,0,0,0,0,1 --points 50,60 --out " + dir_ +
                            "/mask.png --overlay " + dir_ + "/overlay.png",
                        &out, &err),
            0)
      << out << err;
  EXPECT_NE(out.find("mask of"), std::string::npos) << out;
  cv::Mat mask, overlay;
  std::string why;
  ASSERT_TRUE(core::read_single_channel_image(dir_ + "/mask.png", &mask, &why)) << why;
  EXPECT_EQ(mask.cols, 160);
  EXPECT_EQ(mask.rows, 120);
  EXPECT_GT(core::mask_iou(mask, truth(), 1), 0.9);
  ASSERT_TRUE(core::read_colour_image(dir_ + "/overlay.png", &overlay, &why)) << why;
  EXPECT_EQ(overlay.size(), cv::Size(160, 120));

  ASSERT_EQ(run_command(common + "--frame 0 --out " + dir_ + "/instances.png --overlay " + dir_ +
                            "/instances_overlay.png",
                        &out, &err),
            0)
      << out << err;
  EXPECT_NE(out.find("3 instances"), std::string::npos) << out;
  cv::Mat ids, coded;
  ASSERT_TRUE(core::read_single_channel_image(dir_ + "/instances.ids.png", &ids, &why)) << why;
  EXPECT_EQ(ids.type(), CV_16UC1);
  EXPECT_EQ(ids.size(), cv::Size(160, 120));
  ASSERT_TRUE(core::read_colour_image(dir_ + "/instances.png", &coded, &why)) << why;
  EXPECT_EQ(coded.size(), cv::Size(160, 120));
  EXPECT_TRUE(std::filesystem::exists(dir_ + "/instances_overlay.png"));

  EXPECT_NE(run_command(common + "--frame 0 --points 50 --out " + dir_ + "/x.png", &out, &err), 0);
  EXPECT_NE(err.find("u,v pairs"), std::string::npos) << err;
  EXPECT_NE(run_command(common + "--frame 0 --text panel --out " + dir_ + "/x.png", &out, &err), 0);
  EXPECT_NE(err.find("server.grounding_model"), std::string::npos) << err;
}

// A text query through a server with a grounding model: the tiny test model always finds a box
// over the left panel, which then selects that panel.
TEST_F(Segment, TextQueryGoesThroughTheGroundingModel) {
  std::string why;
  // The left panel covers pixels u 30..79, v 30..89 of the 160 x 120 view.
  const std::string model = test::make_grounding_model(dir_, 64, 55.0 / 160, 60.0 / 120,
                                                       50.0 / 160, 60.0 / 120, &why);
  if (model.empty()) GTEST_SKIP() << why;
  const std::string prefix = prefix_ + "text";
  test::ScopedServer server(
      "--prefix " + prefix + " --map-dir " + dir_ + "/maps --set server.grounding_model=" + model +
          " --set server.grounding_input_size=64 --set server.save_maps_at_shutdown=false",
      dir_ + "/text_server.log");
  ASSERT_GT(server.pid(), 0);
  {
    client::Client c(options(prefix));
    client::SegmentQuery q = query(client::SegmentMode::text);
    q.text = "the left panel";
    client::SegmentOutput out;
    const bool ok = c.segment(q, &out, 20000, &why);
    EXPECT_TRUE(ok) << why;
    if (ok) {
      EXPECT_GT(core::mask_iou(mask_of(out), truth(), 1), 0.9);
    }
  }
}

}  // namespace
}  // namespace fslam

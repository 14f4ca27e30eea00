// SlamPipeline's copy of the keyframe descriptions (what a save writes to keyframes.bin) against
// the tracker's relocaliser, when a camera goes back and forth over one stretch.
#include "fslam/core/pipeline/slam_pipeline.hpp"

#include <set>
#include <string>

#include <gtest/gtest.h>

#include "fslam/core/synth/synthetic_scene.hpp"

namespace fslam::core {
namespace {

std::set<std::int64_t> ids(const std::vector<DescribedKeyframe>& keyframes) {
  std::set<std::int64_t> out;
  for (const DescribedKeyframe& kf : keyframes) out.insert(kf.id);
  return out;
}

// Forward, back and forward again over 40 frames of the synthetic room: the second and third
// passes revisit the first's keyframe poses, so they replace descriptions instead of adding
// them, and the pipeline's copy holds exactly the relocaliser's keyframes.
TEST(SlamPipelineDescriptions, FollowTheRelocalisersKeyframesWhenTheCameraGoesBackAndForth) {
  const SyntheticRoom room = make_room(3);
  SynthOptions options;
  options.frames = 40;
  const Trajectory trajectory = make_trajectory(room, options);
  const PinholeCamera camera = options.camera.scaled(0.5);
  PipelineConfig config;
  config.mapping = false;
  config.tracker.preprocess.stride = 4;
  SlamPipeline pipeline(config, nullptr);
  std::int64_t id = 0;
  std::size_t after_first_pass = 0;
  for (int pass = 0; pass < 3; ++pass) {
    for (int k = 0; k < 40; ++k) {
      const std::size_t i = static_cast<std::size_t>(pass % 2 == 0 ? k : 39 - k);
      const SynthView view = render_view(room, camera, trajectory[i].T_world_camera);
      RgbdFrame frame;
      frame.id = id++;
      frame.timestamp = static_cast<double>(frame.id) / 30.0;
      frame.colour = view.colour;
      frame.depth = view.depth;
      frame.camera = camera;
      frame.T_world_camera_gt = trajectory[i].T_world_camera;
      TrackingResult result;
      std::string why;
      ASSERT_TRUE(pipeline.process_frame(frame, &result, &why)) << why;
    }
    if (pass == 0) after_first_pass = pipeline.described_keyframes().size();
  }
  const std::vector<DescribedKeyframe> described = pipeline.described_keyframes();
  ASSERT_GE(after_first_pass, 3u);
  EXPECT_EQ(ids(described), ids(pipeline.tracker().relocaliser().keyframes()));
  // Keyframes are made at other frames on each pass, so some poses are new; most are revisits.
  EXPECT_LT(described.size(), 2 * after_first_pass) << "three passes, " << after_first_pass << " after the first";
}

}  // namespace
}  // namespace fslam::core
